//! The batch journal: what became of each edit, recorded so that a batch
//! killed at any moment resumes without redoing or double-applying an edit.
//!
//! Per edit, in its group's directory (`STATE/groups/NNNNN/`, written by
//! one process at a time: the one running that group), two records, each
//! written atomically and verified ([`crate::raster::atomic_file::replace_file`]):
//!
//! 1. `EEEEE.pending.json`, before the edit starts: the size and CRC-32 of
//!    every tile of its footprint as they are then;
//! 2. `EEEEE.done.json`, after the edit's tiles are renamed into place (or
//!    it ended without writing): its status, the tiles it wrote, its report.
//!
//! On resume, after the edit journals of the group's tiles are finished
//! ([`crate::raster::journal::recover_where`]), an edit with a done record
//! is skipped; one with only a pending record was killed while it ran: if
//! every footprint tile still has its recorded digest, nothing of it was
//! applied and it runs again (an edit is a deterministic function of those
//! tiles); if any differs, its write-back was committed (the edit journal
//! makes it whole) and it is recorded as done without running again.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{io_err, BatchError};
use crate::raster::atomic_file::replace_file;
use crate::raster::journal::digest;

/// The state directory's name inside a tile-directory output.
pub const STATE_NAME: &str = ".demsketch_batch";

/// The batch's state directory of output `out`: `OUT/.demsketch_batch`
/// for a tile directory, `.NAME.demsketch_batch` beside a single file.
pub fn state_dir(out: &Path) -> PathBuf {
    if out.is_dir() {
        out.join(STATE_NAME)
    } else {
        let name = out
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        crate::raster::atomic_file::parent_dir(out).join(format!(".{name}.demsketch_batch"))
    }
}

/// Where the reports of the edits go.
pub fn reports_dir(state: &Path) -> PathBuf {
    state.join("reports")
}

/// The record directory of group `g`.
pub fn group_dir(state: &Path, g: usize) -> PathBuf {
    state.join("groups").join(format!("{g:05}"))
}

/// The directory holding a batch's tiles: `out` itself, or a single
/// file's directory.
pub fn tiles_dir(out: &Path) -> PathBuf {
    if out.is_dir() {
        out.to_path_buf()
    } else {
        crate::raster::atomic_file::parent_dir(out).to_path_buf()
    }
}

/// What an edit left, before it ran: its footprint tiles' digests.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pending {
    pub id: String,
    /// Tile file name -> (size, CRC-32).
    pub tiles: BTreeMap<String, (u64, u32)>,
}

/// How an edit ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Written (possibly changing no cell).
    Written,
    /// A stroke's fit is below `--min-fit`: nothing written (as `demsketch
    /// edit` exits 3).
    BelowMinFit,
    /// The edit failed on its input (as `demsketch edit` exits 1):
    /// nothing written.
    Failed,
    /// Found applied on resume: a run killed after its tiles were renamed,
    /// before this record; its report may be missing.
    Recovered,
}

/// What became of an edit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Done {
    pub id: String,
    pub index: usize,
    pub group: usize,
    pub status: Status,
    pub tiles_written: Vec<String>,
    pub changed_cells: usize,
    /// The report's path, when there is one.
    pub report: Option<PathBuf>,
    /// Why it was not written, or a note.
    pub message: Option<String>,
    pub seconds: f64,
    /// `[col, row, width, height]`: the window holding its changed cells
    /// (its deformation window), when it changed any; for the pyramid
    /// step ([`super::pyramid`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window: Option<[i64; 4]>,
}

fn pending_path(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("{index:05}.pending.json"))
}

fn done_path(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("{index:05}.done.json"))
}

/// Write `value` as JSON to `path`, atomically and verified.
pub(crate) fn write_json<T: Serialize + for<'de> Deserialize<'de> + PartialEq>(
    path: &Path,
    value: &T,
) -> Result<(), BatchError> {
    let text = serde_json::to_vec_pretty(value).map_err(|e| BatchError::Internal(e.to_string()))?;
    if let Some(d) = path.parent() {
        std::fs::create_dir_all(d).map_err(|e| io_err(d, e))?;
    }
    replace_file(
        path,
        |tmp| std::fs::write(tmp, &text).map_err(|e| e.to_string()),
        |tmp| {
            let back: T = serde_json::from_slice(&std::fs::read(tmp).map_err(|e| e.to_string())?)
                .map_err(|e| e.to_string())?;
            (back == *value)
                .then_some(())
                .ok_or_else(|| "it reads back different".to_string())
        },
    )
    .map_err(|m| io_err(path, m))
}

/// Read a JSON record; `Ok(None)` when it does not exist.
pub(crate) fn read_json<T: for<'de> Deserialize<'de>>(
    path: &Path,
) -> Result<Option<T>, BatchError> {
    match std::fs::read(path) {
        Ok(b) => serde_json::from_slice(&b)
            .map(Some)
            .map_err(|e| io_err(path, format!("unreadable batch record: {e}"))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io_err(path, e)),
    }
}

/// Digests of the named tiles in `dir` (a missing tile is an error).
pub fn tile_digests(
    dir: &Path,
    tiles: &[String],
) -> Result<BTreeMap<String, (u64, u32)>, BatchError> {
    tiles
        .iter()
        .map(|t| {
            let p = dir.join(t);
            digest(&p)
                .map(|d| (t.clone(), d))
                .map_err(|e| io_err(&p, e))
        })
        .collect()
}

/// The records of one group.
pub struct GroupRecords {
    dir: PathBuf,
}

impl GroupRecords {
    pub fn new(state: &Path, group: usize) -> GroupRecords {
        GroupRecords {
            dir: group_dir(state, group),
        }
    }

    pub fn done(&self, index: usize) -> Result<Option<Done>, BatchError> {
        read_json(&done_path(&self.dir, index))
    }

    pub fn pending(&self, index: usize) -> Result<Option<Pending>, BatchError> {
        read_json(&pending_path(&self.dir, index))
    }

    pub fn write_pending(&self, index: usize, p: &Pending) -> Result<(), BatchError> {
        write_json(&pending_path(&self.dir, index), p)
    }

    /// Record the edit done, then drop its pending record.
    pub fn write_done(&self, d: &Done) -> Result<(), BatchError> {
        write_json(&done_path(&self.dir, d.index), d)?;
        let _ = std::fs::remove_file(pending_path(&self.dir, d.index));
        Ok(())
    }
}

/// Was the edit with pending record `p` applied? True when a footprint
/// tile's digest differs from the recorded one.
pub fn was_applied(tiles: &Path, p: &Pending) -> Result<bool, BatchError> {
    let names: Vec<String> = p.tiles.keys().cloned().collect();
    let now = tile_digests(tiles, &names)?;
    Ok(now != p.tiles)
}
