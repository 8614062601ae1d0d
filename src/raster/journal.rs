//! The edit journal: how an in-place edit of several files is applied
//! whole even when the process is killed between two renames. Once every
//! new file is written and verified in the staging directory, a journal
//! (`journal.json` in that directory, itself written atomically) lists
//! each file with its size and CRC-32; then the files are renamed over
//! their targets one by one, and the journal is removed with the staging
//! directory after the last. A journal found later (by [`recover`], under
//! the edit lock, so its writer is dead) means the renames were cut short:
//! when every file is either still staged and intact or already in place,
//! the remaining renames are finished (rolled forward); when staged files
//! are missing or damaged and none was renamed yet, the staging directory
//! is removed (rolled back); both leave the DEM as if the edit ran once,
//! whole, or not at all.
//!
//! `DEMSKETCH_TEST_ABORT_AFTER_RENAMES=N` (test-only, undocumented for
//! users) kills the process with SIGKILL after N renames, so that tests
//! can interrupt a commit at a chosen point.

use std::io::Read;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::atomic_file::{commit_guard, sync_dir, Staging, TEMP_PREFIX};
use super::RasterError;

/// The journal's file name inside a staging directory.
pub const JOURNAL_NAME: &str = "journal.json";

/// One file of a journal: staged as `staging/name`, replacing `dir/name`.
#[derive(Debug, Serialize, Deserialize)]
struct Entry {
    name: String,
    size: u64,
    crc32: u32,
}

#[derive(Debug, Serialize, Deserialize)]
struct Journal {
    tool: String,
    pid: u32,
    entries: Vec<Entry>,
}

/// Size and CRC-32 of a file.
pub fn digest(path: &Path) -> std::io::Result<(u64, u32)> {
    let mut f = std::fs::File::open(path)?;
    let mut h = crc32fast::Hasher::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut size = 0u64;
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        size += n as u64;
        h.update(&buf[..n]);
    }
    Ok((size, h.finalize()))
}

fn io_err(path: &Path, e: std::io::Error) -> RasterError {
    RasterError::io(path, e)
}

/// Rename the staged files `staging/NAME` over `dir/NAME` for every name in
/// `names`, journalled: `dem` is the DEM the message names on failure.
/// Returns the staging directory, kept (the caller moves what else it
/// staged there, then removes it).
pub fn commit(
    dem: &Path,
    dir: &Path,
    staging: Staging,
    names: &[String],
) -> Result<PathBuf, RasterError> {
    let mut entries = Vec::new();
    for n in names {
        let (size, crc32) =
            digest(&staging.file(n.as_ref())).map_err(|e| io_err(&dir.join(n), e))?;
        entries.push(Entry {
            name: n.clone(),
            size,
            crc32,
        });
    }
    let journal = Journal {
        tool: format!("demsketch {}", env!("CARGO_PKG_VERSION")),
        pid: std::process::id(),
        entries,
    };
    let text = serde_json::to_vec_pretty(&journal).map_err(|e| RasterError::Write {
        path: dem.to_path_buf(),
        message: e.to_string(),
    })?;
    let part = staging.path().join("journal.json.part");
    let jpath = staging.path().join(JOURNAL_NAME);
    (|| -> std::io::Result<()> {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&part)?;
        f.write_all(&text)?;
        f.sync_all()?;
        std::fs::rename(&part, &jpath)?;
        sync_dir(staging.path())
    })()
    .map_err(|e| RasterError::Write {
        path: dem.to_path_buf(),
        message: format!("cannot write the edit journal: {e}; nothing changed"),
    })?;
    if let Some(ms) = test_env("DEMSKETCH_TEST_SLEEP_BEFORE_COMMIT_MS") {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
    let abort_after = test_env("DEMSKETCH_TEST_ABORT_AFTER_RENAMES");
    let _commit = commit_guard();
    // From the first rename on, the staging directory (journal and the
    // files still to be renamed) must outlive a failure: the next run
    // finishes the edit from it.
    let staged = staging.keep();
    for (i, n) in names.iter().enumerate() {
        if abort_after == Some(i as u64) {
            let _ = rustix::process::kill_process(
                rustix::process::getpid(),
                rustix::process::Signal::KILL,
            );
        }
        let target = dir.join(n);
        if let Err(e) = std::fs::rename(staged.join(n), &target) {
            if i == 0 {
                // Nothing replaced yet: nothing to finish.
                let _ = std::fs::remove_dir_all(&staged);
            }
            return Err(RasterError::Write {
                path: target.clone(),
                message: if i == 0 {
                    format!("cannot replace it: {e}; nothing changed")
                } else {
                    format!(
                        "cannot replace it after {i} of {} files: {e}; the next edit of this DEM finishes the edit",
                        names.len()
                    )
                },
            });
        }
    }
    let _ = sync_dir(dir);
    let _ = std::fs::remove_file(staged.join(JOURNAL_NAME));
    Ok(staged)
}

/// A test hook's value from the environment.
fn test_env(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

/// A plain file name (no directory part, not `.`/`..`).
fn plain_name(n: &str) -> bool {
    !n.is_empty() && n != "." && n != ".." && !n.contains('/') && !n.contains('\0')
}

/// Finish or undo every journalled edit left in `dir` by a process that
/// died between its renames. Call with the edit lock of `dir` held. Returns
/// one line per journal handled; an error (naming `dem`) when a journal
/// cannot be applied either way (it is then kept).
pub fn recover(dem: &Path, dir: &Path) -> Result<Vec<String>, RasterError> {
    recover_where(dem, dir, |_| true)
}

/// The file names a journal in staging directory `staging` lists (`None`
/// when it has none or it cannot be read).
fn journal_names(staging: &Path) -> Option<Vec<String>> {
    let text = std::fs::read(staging.join(JOURNAL_NAME)).ok()?;
    let journal: Journal = serde_json::from_slice(&text).ok()?;
    Some(journal.entries.into_iter().map(|e| e.name).collect())
}

/// [`recover`] limited to the journals whose file names `mine` accepts
/// (an unreadable journal is handled, as by [`recover`], only when `mine`
/// accepts an empty list). For processes that share a directory and each
/// own a disjoint set of its files (the groups of `demsketch batch run`):
/// each recovers only the edits of its own files, never one another live
/// process is applying. Call with the lock of those files held.
pub fn recover_where(
    dem: &Path,
    dir: &Path,
    mine: impl Fn(&[String]) -> bool,
) -> Result<Vec<String>, RasterError> {
    let mut notes = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Ok(notes);
    };
    let mut stagings: Vec<PathBuf> = rd
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(TEMP_PREFIX))
        .filter(|e| e.file_type().map(|t| t.is_dir()).unwrap_or(false))
        .map(|e| e.path())
        .filter(|p| p.join(JOURNAL_NAME).is_file())
        .filter(|p| mine(&journal_names(p).unwrap_or_default()))
        .collect();
    stagings.sort();
    for s in stagings {
        notes.push(recover_one(dem, dir, &s)?);
    }
    Ok(notes)
}

fn recover_one(dem: &Path, dir: &Path, staging: &Path) -> Result<String, RasterError> {
    let bad = |m: String| RasterError::Write {
        path: dem.to_path_buf(),
        message: m,
    };
    let jpath = staging.join(JOURNAL_NAME);
    let text = std::fs::read(&jpath).map_err(|e| io_err(&jpath, e))?;
    let journal: Journal = serde_json::from_slice(&text).map_err(|e| {
        bad(format!(
            "unreadable edit journal {}: {e}; remove it to go on",
            jpath.display()
        ))
    })?;
    let (mut pending, mut done, mut broken) = (Vec::new(), 0usize, 0usize);
    for e in &journal.entries {
        if !plain_name(&e.name) {
            return Err(bad(format!(
                "edit journal {} names '{}', not a file of this DEM; remove it to go on",
                jpath.display(),
                e.name
            )));
        }
        let staged = staging.join(&e.name);
        let target = dir.join(&e.name);
        let is = |p: &Path| {
            std::fs::symlink_metadata(p)
                .map(|m| m.is_file())
                .unwrap_or(false)
                && digest(p).map(|d| d == (e.size, e.crc32)).unwrap_or(false)
        };
        if is(&staged) {
            pending.push(e.name.clone());
        } else if is(&target) {
            done += 1;
        } else {
            broken += 1;
        }
    }
    let n = journal.entries.len();
    let note = if broken == 0 {
        let _commit = commit_guard();
        for name in &pending {
            let target = dir.join(name);
            std::fs::rename(staging.join(name), &target).map_err(|e| io_err(&target, e))?;
        }
        let _ = sync_dir(dir);
        format!(
            "{}: finished an edit that process {} left half-applied ({} of {n} files were still to be replaced); the edit is now whole",
            dem.display(),
            journal.pid,
            pending.len()
        )
    } else if done == 0 {
        format!(
            "{}: rolled back an edit that process {} left unfinished (its new files were incomplete; nothing of it had been applied)",
            dem.display(),
            journal.pid
        )
    } else {
        return Err(bad(format!(
            "edit journal {}: {done} of {n} files were replaced but {broken} new files are missing or damaged; the DEM is half-edited, restore it from a backup",
            jpath.display()
        )));
    };
    std::fs::remove_dir_all(staging).map_err(|e| io_err(staging, e))?;
    Ok(note)
}
