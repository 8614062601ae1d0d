//! One edit at a time: an advisory lock (`flock`) on the directory that
//! holds the DEM's files (a tile directory itself, or a single file's
//! directory). No lock file is created: the directory is locked through a
//! read-only handle, and the kernel releases the lock when the process
//! ends, however it ends. A second edit of the same DEM (or of another DEM
//! in the same directory) waits for the first, saying so in one line, for
//! at most the timeout it is given, then fails naming the DEM.

use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rustix::fs::{flock, FlockOperation, Mode, OFlags};

use super::RasterError;

/// How long an edit waits for another's lock before it says so.
pub const TELL_AFTER: Duration = Duration::from_secs(2);

/// The directory whose lock guards edits of `dem`.
pub fn lock_dir(dem: &Path) -> PathBuf {
    if dem.is_dir() {
        dem.to_path_buf()
    } else {
        super::atomic_file::parent_dir(dem).to_path_buf()
    }
}

/// The edit lock of a DEM, held until dropped.
pub struct EditLock {
    _fd: OwnedFd,
    /// The locked directory.
    pub dir: PathBuf,
}

impl EditLock {
    /// Take the edit lock of `dem`, waiting up to `timeout` while another
    /// process holds it; `waiting` is called once (with a one-line message)
    /// if it has to wait.
    pub fn acquire(
        dem: &Path,
        timeout: Duration,
        waiting: impl FnMut(&str),
    ) -> Result<EditLock, RasterError> {
        Self::acquire_as(dem, timeout, waiting, false)
    }

    /// [`EditLock::acquire`] as a shared lock: held by any number of
    /// processes at once (the workers of `demsketch batch run`, each
    /// writing its own tiles), never together with an exclusive one (an
    /// edit, a whole batch, `batch finish`).
    pub fn acquire_shared(
        dem: &Path,
        timeout: Duration,
        waiting: impl FnMut(&str),
    ) -> Result<EditLock, RasterError> {
        Self::acquire_as(dem, timeout, waiting, true)
    }

    fn acquire_as(
        dem: &Path,
        timeout: Duration,
        mut waiting: impl FnMut(&str),
        shared: bool,
    ) -> Result<EditLock, RasterError> {
        let op = if shared {
            FlockOperation::NonBlockingLockShared
        } else {
            FlockOperation::NonBlockingLockExclusive
        };
        let dir = lock_dir(dem);
        let fd = rustix::fs::open(
            &dir,
            OFlags::RDONLY | OFlags::DIRECTORY | OFlags::CLOEXEC,
            Mode::empty(),
        )
        .map_err(|e| RasterError::io(&dir, e.into()))?;
        let start = Instant::now();
        let mut told = false;
        loop {
            match flock(&fd, op) {
                Ok(()) => return Ok(EditLock { _fd: fd, dir }),
                Err(rustix::io::Errno::WOULDBLOCK) | Err(rustix::io::Errno::INTR) => {}
                Err(e) => {
                    return Err(RasterError::Write {
                        path: dem.to_path_buf(),
                        message: format!("cannot lock {} for the edit: {e}", dir.display()),
                    })
                }
            }
            if start.elapsed() >= timeout {
                return Err(RasterError::Write {
                    path: dem.to_path_buf(),
                    message: format!(
                        "another demsketch edit of this DEM is still running after {} s (--lock-timeout); nothing written",
                        timeout.as_secs_f64()
                    ),
                });
            }
            // Said once the wait lasts: a lock held for a moment (another
            // run failing on its input, a quick correction) is not news,
            // and would add a line to that run's one-line error.
            if !told && start.elapsed() >= TELL_AFTER {
                waiting(&format!(
                    "{}: another demsketch edit of this DEM is running; waiting for it (at most {} s, --lock-timeout)",
                    dem.display(),
                    timeout.as_secs_f64()
                ));
                told = true;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}
