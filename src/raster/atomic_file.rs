//! Temporary files and the moment they replace their targets. Everything
//! demsketch writes is first written into a *staging directory*: a new
//! directory beside the target, created exclusively (`mkdir`, which never
//! follows a symlink) with an unpredictable name `.demsketch-PID-RANDOM.tmp`
//! (the `tempfile` crate) and mode 700, so nothing planted in the target's
//! directory can redirect a write. A file is written there under the
//! target's own name, checked (see [`replace_file`]) and renamed over the
//! target; the staging directory is removed whatever happens.
//!
//! Staging directories are registered while they exist: on SIGINT or
//! SIGTERM ([`install_signal_cleanup`]) every registered one is removed and
//! the process exits 130 or 143. Renames run under [`commit_guard`], which
//! the signal handler takes first, so a signal never lands between the
//! renames of one edit. The PID in the name lets a later run tell the
//! directories of dead processes ([`clean_stale`]).

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard, Once};

/// Every temporary name demsketch creates starts with this.
pub const TEMP_PREFIX: &str = ".demsketch-";
/// ... and ends with this.
pub const TEMP_SUFFIX: &str = ".tmp";

/// Staging directories that exist now (removed on SIGINT/SIGTERM).
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
/// Held while temporary files are renamed over their targets.
static COMMIT: Mutex<()> = Mutex::new(());

fn lock<T>(m: &'static Mutex<T>) -> MutexGuard<'static, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Hold this while renaming temporary files into place: a SIGINT or
/// SIGTERM then waits until the renames are done.
pub fn commit_guard() -> MutexGuard<'static, ()> {
    lock(&COMMIT)
}

/// An exclusive, unpredictably named directory beside the files it stages,
/// removed (with whatever is still in it) when dropped.
pub struct Staging {
    dir: Option<tempfile::TempDir>,
}

impl Staging {
    /// Create a staging directory in `parent` (the directory of the targets).
    pub fn new_in(parent: &Path) -> std::io::Result<Staging> {
        let dir = tempfile::Builder::new()
            .prefix(&format!("{TEMP_PREFIX}{}-", std::process::id()))
            .suffix(TEMP_SUFFIX)
            .rand_bytes(10)
            .tempdir_in(parent)?;
        lock(&LIVE).push(dir.path().to_path_buf());
        Ok(Staging { dir: Some(dir) })
    }

    /// The staging directory.
    pub fn path(&self) -> &Path {
        self.dir.as_ref().map(|d| d.path()).unwrap_or(Path::new(""))
    }

    /// Where the temporary version of a file named `name` goes.
    pub fn file(&self, name: &OsStr) -> PathBuf {
        self.path().join(name)
    }

    /// Keep the directory (it is about to be renamed into place): it is no
    /// longer removed on drop or on a signal. Call under [`commit_guard`].
    pub fn keep(mut self) -> PathBuf {
        let dir = self.dir.take().map(|d| d.keep()).unwrap_or_default();
        lock(&LIVE).retain(|p| p != &dir);
        dir
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        if let Some(d) = self.dir.take() {
            let p = d.path().to_path_buf();
            drop(d);
            lock(&LIVE).retain(|q| q != &p);
        }
    }
}

static SIGNALS: Once = Once::new();

/// On SIGINT or SIGTERM: wait for renames in progress, remove every staging
/// directory, exit 130 (SIGINT) or 143 (SIGTERM). Also makes SIGXFSZ (a
/// file size limit reached) a plain write error instead of a kill. Once per
/// process.
pub fn install_signal_cleanup() {
    use signal_hook::consts::{SIGINT, SIGTERM, SIGXFSZ};
    SIGNALS.call_once(|| {
        static XFSZ: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
        let _ = signal_hook::flag::register(SIGXFSZ, &XFSZ);
        let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
            return;
        };
        let _ = std::thread::Builder::new()
            .name("demsketch-signals".into())
            .spawn(move || {
                if let Some(sig) = signals.forever().next() {
                    let _commit = commit_guard();
                    for dir in lock(&LIVE).drain(..) {
                        let _ = std::fs::remove_dir_all(dir);
                    }
                    eprintln!(
                        "demsketch: interrupted ({}); temporary files removed, nothing half-written",
                        if sig == SIGINT { "SIGINT" } else { "SIGTERM" }
                    );
                    // Exit at once: running the exit handlers (GDAL's
                    // among them) while other threads are inside GDAL
                    // could crash instead of exiting 130/143.
                    // SAFETY: `_exit` ends the process; nothing runs after.
                    unsafe { libc::_exit(128 + sig) };
                }
            });
    });
}

/// Is process `pid` alive (or not ours to signal, which also counts as
/// alive)?
pub fn process_alive(pid: u32) -> bool {
    let Some(p) = i32::try_from(pid)
        .ok()
        .and_then(rustix::process::Pid::from_raw)
    else {
        return false;
    };
    !matches!(
        rustix::process::test_kill_process(p),
        Err(rustix::io::Errno::SRCH)
    )
}

/// The PID in a temporary name demsketch made (`.demsketch-PID-…​.tmp`, or
/// the older `.NAME.demsketch-PID.tmp`), if `name` is one.
pub fn temp_owner(name: &str) -> Option<u32> {
    if !name.ends_with(TEMP_SUFFIX) {
        return None;
    }
    let rest = if let Some(r) = name.strip_prefix(TEMP_PREFIX) {
        r
    } else {
        let i = name.rfind(".demsketch-")?;
        &name[i + ".demsketch-".len()..]
    };
    let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
    digits.parse().ok()
}

/// Remove the temporary files and staging directories of dead processes in
/// `dir` (never a symlink, never one with an edit journal in it: those are
/// for [`super::journal::recover`]). Returns one line per removed entry.
pub fn clean_stale(dir: &Path) -> Vec<String> {
    let mut notes = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return notes;
    };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = temp_owner(&name) else {
            continue;
        };
        if pid == std::process::id() || process_alive(pid) {
            continue;
        }
        let Ok(meta) = std::fs::symlink_metadata(e.path()) else {
            continue;
        };
        let removed = if meta.is_dir() {
            if e.path().join(super::journal::JOURNAL_NAME).exists() {
                continue;
            }
            std::fs::remove_dir_all(e.path()).is_ok()
        } else if meta.is_file() {
            std::fs::remove_file(e.path()).is_ok()
        } else {
            false
        };
        if removed {
            notes.push(format!(
                "{}: removed the temporary files of an earlier run that did not finish (pid {pid})",
                e.path().display()
            ));
        }
    }
    notes
}

/// The directory a target file lives in (`.` for a bare name).
pub fn parent_dir(target: &Path) -> &Path {
    target
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Flush a directory's entries (after renames into it) to disk.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    std::fs::File::open(dir)?.sync_all()
}

/// Give `to` the mode, owner (when running as root) and extended
/// attributes of `from`, as far as permitted: an in-place rewrite keeps
/// what the user set on the file.
pub fn copy_file_attributes(from: &Path, to: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    let meta = std::fs::metadata(from)?;
    std::fs::set_permissions(to, meta.permissions())?;
    if rustix::process::geteuid().is_root() {
        std::os::unix::fs::chown(to, Some(meta.uid()), Some(meta.gid()))?;
        // chown may clear set-id bits: set the mode again.
        std::fs::set_permissions(to, meta.permissions())?;
    }
    if let Ok(names) = xattr::list(from) {
        for n in names {
            if let Ok(Some(v)) = xattr::get(from, &n) {
                let _ = xattr::set(to, &n, &v);
            }
        }
    }
    Ok(())
}

/// Write a file atomically and verified: `write` fills a temporary file (a
/// path in a fresh staging directory beside `target`, with the target's
/// file name) with any GDAL failure it reports captured; the file must then
/// be non-empty and pass `verify` (which re-reads it); it is flushed to
/// disk, given the mode of the file it replaces, and renamed over `target`.
/// Any failure leaves `target` as it was and no temporary file behind;
/// the message (one line, without the path) never names the temporary file.
pub fn replace_file(
    target: &Path,
    write: impl FnOnce(&Path) -> Result<(), String>,
    verify: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), String> {
    let name = target
        .file_name()
        .ok_or_else(|| "is not a file name".to_string())?;
    if std::fs::metadata(target)
        .map(|m| m.is_dir())
        .unwrap_or(false)
    {
        return Err("is a directory".into());
    }
    let dir = parent_dir(target);
    clean_stale(dir);
    let staging =
        Staging::new_in(dir).map_err(|e| format!("cannot create a temporary file: {e}"))?;
    let tmp = staging.file(name);
    let hide =
        |m: String| one_line(&m.replace(&tmp.display().to_string(), &target.display().to_string()));
    let (written, errors) = super::gdal_errors::capture(|| write(&tmp));
    written.map_err(hide)?;
    if let Some(e) = errors.first() {
        return Err(hide(format!("write failed: {e}")));
    }
    let size = std::fs::metadata(&tmp)
        .map_err(|e| hide(e.to_string()))?
        .len();
    if size == 0 {
        return Err("write failed: the written file is empty".into());
    }
    verify(&tmp).map_err(|e| hide(format!("the written file does not read back: {e}")))?;
    std::fs::File::open(&tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| hide(format!("write failed: {e}")))?;
    if std::fs::metadata(target)
        .map(|m| m.is_file())
        .unwrap_or(false)
    {
        let _ = copy_file_attributes(target, &tmp);
    }
    let _commit = commit_guard();
    std::fs::rename(&tmp, target).map_err(|e| hide(e.to_string()))?;
    let _ = sync_dir(dir);
    Ok(())
}

/// The first line of a message.
pub fn one_line(m: &str) -> String {
    m.lines().next().unwrap_or("").trim().to_string()
}

/// Write `bytes` to a new file `path` (never an existing one: `O_EXCL`),
/// flush it to disk and read it back: an error unless it holds exactly
/// `bytes`.
pub fn write_bytes_verified(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)?;
    f.write_all(bytes)?;
    f.sync_all()?;
    drop(f);
    if !reads_back(path, bytes)? {
        return Err(std::io::Error::other("the written file does not read back"));
    }
    Ok(())
}

/// Does the file at `path` hold exactly `bytes`? (Read in chunks: no second
/// copy of a large file in memory.)
fn reads_back(path: &Path, bytes: &[u8]) -> std::io::Result<bool> {
    use std::io::Read;
    let mut f = std::fs::File::open(path)?;
    let mut buf = vec![0u8; 1 << 20];
    let mut at = 0usize;
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            return Ok(at == bytes.len());
        }
        if at + n > bytes.len() || buf[..n] != bytes[at..at + n] {
            return Ok(false);
        }
        at += n;
    }
}

/// Let GDAL write a file in memory (`/vsimem/`), then write its bytes to
/// `tmp` ourselves ([`write_bytes_verified`]). GDAL never touches the disk:
/// a full disk is then a plain write error of ours, where libtiff, on a
/// disk that fills up while it writes, may return success or even loop
/// forever rewriting a truncated directory. `f` gets the in-memory path
/// (with `tmp`'s file name) and must have closed the dataset when it
/// returns; `initial` are bytes the in-memory file starts with (to update
/// a copy of an existing file), if any.
pub fn through_memory<T, E: std::fmt::Display>(
    tmp: &Path,
    initial: Option<Vec<u8>>,
    f: impl FnOnce(&Path) -> Result<T, E>,
) -> Result<T, String> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let name = tmp.file_name().unwrap_or(OsStr::new("out.tif"));
    let dir = PathBuf::from(format!(
        "/vsimem/demsketch-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::SeqCst)
    ));
    let mem = dir.join(name);
    let run = || -> Result<T, String> {
        if let Some(bytes) = initial {
            vsimem_write(&mem, &bytes)?;
        }
        let value = f(&mem).map_err(|e| one_line(&e.to_string()))?;
        let bytes =
            gdal::vsi::get_vsi_mem_file_bytes_owned(&mem).map_err(|e| one_line(&e.to_string()))?;
        write_bytes_verified(tmp, &bytes).map_err(|e| e.to_string())?;
        Ok(value)
    };
    let r = run().map_err(|m| m.replace(&mem.display().to_string(), &tmp.display().to_string()));
    // Sidecars GDAL may have left (statistics, masks).
    if let Ok(files) = gdal::vsi::read_dir(&dir, false) {
        for f in files {
            let _ = gdal::vsi::unlink_mem_file(dir.join(f));
        }
    }
    let _ = gdal::vsi::unlink_mem_file(&mem);
    r
}

/// Several outputs of one command, replaced together: each is first
/// written (by the usual verified writer) to its path inside a staging
/// directory beside its target ([`StagedOutputs::stage`]), and only when
/// all were written are they renamed over their targets
/// ([`StagedOutputs::commit`]). A failure of any leaves every target as
/// it was.
#[derive(Default)]
pub struct StagedOutputs {
    items: Vec<(Staging, PathBuf, PathBuf)>,
}

impl StagedOutputs {
    /// The path to write `target` to (inside a new staging directory).
    pub fn stage(&mut self, target: &Path) -> Result<PathBuf, String> {
        let name = target
            .file_name()
            .ok_or_else(|| format!("{}: is not a file name", target.display()))?;
        if std::fs::metadata(target)
            .map(|m| m.is_dir())
            .unwrap_or(false)
        {
            return Err(format!("{}: is a directory", target.display()));
        }
        let dir = parent_dir(target);
        clean_stale(dir);
        let staging = Staging::new_in(dir)
            .map_err(|e| format!("{}: cannot create a temporary file: {e}", target.display()))?;
        let tmp = staging.file(name);
        self.items
            .push((staging, tmp.clone(), target.to_path_buf()));
        Ok(tmp)
    }

    /// `message` with every staged path replaced by its target.
    pub fn hide(&self, message: &str) -> String {
        let mut m = message.to_string();
        for (_, tmp, target) in &self.items {
            m = m.replace(&tmp.display().to_string(), &target.display().to_string());
        }
        one_line(&m)
    }

    /// Rename every staged file over its target (keeping the mode of the
    /// file it replaces).
    pub fn commit(self) -> Result<(), String> {
        let _commit = commit_guard();
        for (staging, tmp, target) in &self.items {
            if std::fs::metadata(target)
                .map(|m| m.is_file())
                .unwrap_or(false)
            {
                let _ = copy_file_attributes(target, tmp);
            }
            std::fs::rename(tmp, target).map_err(|e| format!("{}: {e}", target.display()))?;
            let _ = sync_dir(parent_dir(target));
            let _ = staging;
        }
        Ok(())
    }
}

/// Create the in-memory file `mem` holding `bytes`, in memory GDAL
/// allocates (the gdal crate's `create_mem_file` hands GDAL a Rust
/// allocation, which GDAL may later `realloc` with its own allocator).
fn vsimem_write(mem: &Path, bytes: &[u8]) -> Result<(), String> {
    use std::os::unix::ffi::OsStrExt;
    let name = std::ffi::CString::new(mem.as_os_str().as_bytes()).map_err(|e| e.to_string())?;
    let mode = c"wb";
    // SAFETY: valid NUL-terminated strings; the handle is checked and
    // closed; `bytes` outlives the write.
    unsafe {
        let f = gdal_sys::VSIFOpenL(name.as_ptr(), mode.as_ptr());
        if f.is_null() {
            return Err("cannot create an in-memory file".into());
        }
        let n = gdal_sys::VSIFWriteL(bytes.as_ptr().cast(), 1, bytes.len(), f);
        gdal_sys::VSIFCloseL(f);
        if n != bytes.len() {
            return Err("cannot fill an in-memory file".into());
        }
    }
    Ok(())
}

/// Band 1 of the raster at `path`, read by GDAL, must be `width` x
/// `height` and equal `expected` (NaN equal to NaN): the check of a
/// written raster before it replaces anything.
pub fn verify_band<T>(
    path: &Path,
    width: usize,
    height: usize,
    expected: &[T],
) -> Result<(), String>
where
    T: gdal::raster::GdalType + PartialEq + Copy,
{
    let ds = gdal::Dataset::open(path)
        .map_err(|e| format!("GDAL cannot open it: {}", one_line(&e.to_string())))?;
    if ds.raster_size() != (width, height) {
        return Err(format!(
            "its size is {:?}, not {width} x {height}",
            ds.raster_size()
        ));
    }
    let band = ds.rasterband(1).map_err(|e| e.to_string())?;
    let got = band
        .read_as::<T>((0, 0), (width, height), (width, height), None)
        .map_err(|e| format!("GDAL cannot read it: {}", one_line(&e.to_string())))?;
    #[allow(clippy::eq_op)]
    let same = |a: T, b: T| a == b || (a != a && b != b);
    if got.data().len() != expected.len()
        || got.data().iter().zip(expected).any(|(&a, &b)| !same(a, b))
    {
        return Err("its values differ from those written".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_owner_reads_the_pid_of_both_naming_schemes() {
        assert_eq!(temp_owner(".demsketch-1234-AbCdEfGhIj.tmp"), Some(1234));
        assert_eq!(temp_owner(".tile_0_0.tif.demsketch-99.tmp"), Some(99));
        assert_eq!(temp_owner("tile_0_0.tif"), None);
        assert_eq!(temp_owner(".demsketch-x.tmp"), None);
    }

    #[test]
    fn staging_directories_are_exclusive_and_removed() {
        let dir = tempfile::tempdir().unwrap();
        let s = Staging::new_in(dir.path()).unwrap();
        let p = s.path().to_path_buf();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        assert_eq!(temp_owner(&name), Some(std::process::id()));
        assert!(p.is_dir());
        drop(s);
        assert!(!p.exists());
    }

    #[test]
    fn replace_file_keeps_the_target_when_verification_fails() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("out.bin");
        std::fs::write(&target, b"old").unwrap();
        let r = replace_file(
            &target,
            |tmp| write_bytes_verified(tmp, b"new").map_err(|e| e.to_string()),
            |_| Err("no".into()),
        );
        assert!(r.is_err());
        assert_eq!(std::fs::read(&target).unwrap(), b"old");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        replace_file(
            &target,
            |tmp| write_bytes_verified(tmp, b"new").map_err(|e| e.to_string()),
            |_| Ok(()),
        )
        .unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
    }
}
