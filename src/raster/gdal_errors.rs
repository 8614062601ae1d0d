//! GDAL's error messages, captured instead of printed. GDAL reports write
//! failures (a full disk, a failed flush) through its error handler, and in
//! GDAL 3.6 closing a dataset returns nothing, so a write whose errors went
//! to the default stderr printer could look like a success. [`install`]
//! replaces that printer with one that records failures; a write runs inside
//! [`capture`], which returns what GDAL reported while it ran, and the write
//! counts as failed when anything was reported. Messages outside a capture
//! are dropped (the call that failed returns the error itself), so GDAL's
//! `ERROR n:` lines never appear above demsketch's one-line message.

use std::cell::RefCell;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, Once};

use gdal::errors::CplErrType;

thread_local! {
    /// Failures reported on this thread while a capture runs on it.
    static CAPTURED: RefCell<Option<Vec<String>>> = const { RefCell::new(None) };
}

/// Captures running anywhere in the process.
static ACTIVE: AtomicUsize = AtomicUsize::new(0);
/// Failures reported on threads without a capture of their own (GDAL's
/// worker threads) while some capture runs; every capture that ends takes
/// them, so the write in progress fails.
static ORPHANS: Mutex<Vec<String>> = Mutex::new(Vec::new());

static INSTALL: Once = Once::new();

/// What is shown of every GDAL message besides capturing it (the CLI's
/// `--verbose` printer); nothing when unset.
type Echo = Box<dyn Fn(CplErrType, i32, &str) + Send + Sync>;
static ECHO: std::sync::OnceLock<Echo> = std::sync::OnceLock::new();

/// Install the capturing handler with `echo` also called for every GDAL
/// message (first call wins; the CLI shows messages with `--verbose`).
pub fn install_with_echo(echo: impl Fn(CplErrType, i32, &str) + Send + Sync + 'static) {
    let _ = ECHO.set(Box::new(echo));
    install();
}

/// Install the capturing error handler (once per process; later calls do
/// nothing).
pub fn install() {
    INSTALL.call_once(|| {
        gdal::config::set_error_handler(|class, no, msg| {
            if let Some(echo) = ECHO.get() {
                echo(class, no, msg);
            }
            if !matches!(class, CplErrType::Failure | CplErrType::Fatal) {
                return;
            }
            let line = msg.lines().next().unwrap_or("").trim().to_string();
            let mine = CAPTURED.with(|c| match c.borrow_mut().as_mut() {
                Some(v) => {
                    v.push(line.clone());
                    true
                }
                None => false,
            });
            if !mine && ACTIVE.load(Ordering::SeqCst) > 0 {
                if let Ok(mut o) = ORPHANS.lock() {
                    o.push(line);
                }
            }
        });
    });
}

/// Run `f`, returning its result and the GDAL failures reported while it
/// ran (on this thread, or on a thread without a capture of its own).
pub fn capture<T>(f: impl FnOnce() -> T) -> (T, Vec<String>) {
    install();
    let outer = CAPTURED.with(|c| c.borrow_mut().replace(Vec::new()));
    ACTIVE.fetch_add(1, Ordering::SeqCst);
    let value = f();
    ACTIVE.fetch_sub(1, Ordering::SeqCst);
    let mut errors = CAPTURED.with(|c| {
        let mut c = c.borrow_mut();
        let mine = c.take().unwrap_or_default();
        *c = outer;
        mine
    });
    if let Ok(mut o) = ORPHANS.lock() {
        errors.append(&mut o);
    }
    // A nested capture hands its failures on to the enclosing one too.
    CAPTURED.with(|c| {
        if let Some(v) = c.borrow_mut().as_mut() {
            v.extend(errors.iter().cloned());
        }
    });
    (value, errors)
}

/// The first failure, with `temp` (a temporary path GDAL names) replaced by
/// `target`, for a one-line message about the target.
pub fn first_failure(
    errors: &[String],
    temp: &std::path::Path,
    target: &std::path::Path,
) -> Option<String> {
    errors
        .first()
        .map(|e| e.replace(&temp.display().to_string(), &target.display().to_string()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_failure_inside_a_capture_is_captured() {
        let (r, errors) = super::capture(|| {
            gdal::DriverManager::get_driver_by_name("GTiff")
                .and_then(|d| d.create_with_band_type::<u8, _>("/no/such/dir/x.tif", 4, 4, 1))
        });
        assert!(r.is_err());
        assert!(!errors.is_empty(), "GDAL's failure was captured");
        let ((), none) = super::capture(|| ());
        assert!(none.is_empty());
    }
}
