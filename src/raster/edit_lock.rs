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
        mut waiting: impl FnMut(&str),
    ) -> Result<EditLock, RasterError> {
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
            match flock(&fd, FlockOperation::NonBlockingLockExclusive) {
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
            if !told {
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
