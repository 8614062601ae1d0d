//! Batch edits: many sketches applied to one DEM (issue 15, items 3 and 4),
//! with the same bytes as applying them one after another with
//! `demsketch edit OUT --in-place`, in manifest order.
//!
//! - [`manifest`]: the list of sketches (a JSON manifest, a text list, or
//!   a directory of sketch files), read and checked before anything is
//!   written.
//! - [`footprint`]: the tiles an edit may read or write, bounded from its
//!   viewpoints, the view distance and the influence distance, before it
//!   runs; checked against what it did after it ran.
//! - [`plan`]: edits whose footprints share a tile are one *group*, applied
//!   in manifest order; different groups share no tile, so they run in any
//!   order, in parallel or in separate processes (an array job: one group
//!   per index), with the same bytes. The plan is a JSON file.
//! - [`record`]: the batch journal: one record per edit, written atomically
//!   before the edit starts (the digests of its footprint tiles) and after
//!   its tiles are renamed into place (done), so that a batch killed at any
//!   moment resumes without redoing or double-applying an edit.
//! - [`run`]: copying the DEM to the output, running one group or all of
//!   them (rayon), the per-edit reports and the batch summary.
//! - [`pyramid`]: the final step on a tile directory with
//!   `gdal_retile.py -levels` pyramid levels: the level tiles recomputed
//!   once, over the union of what the edits changed.
//! - [`steps`]: the array-job steps (plan, run one index, finish) as the
//!   CLI and the Python package call them.
//!
//! Each edit itself is [`crate::edit::run`] with `--in-place` on the output
//! (or, for a corrections file, [`crate::correct::run`]), so its write-back
//! is the edit's own (staged, verified, journalled renames,
//! [`crate::raster::journal`]).

pub mod footprint;
pub mod manifest;
pub mod plan;
pub mod pyramid;
pub mod record;
pub mod run;
pub mod steps;

pub use manifest::{EditKind, Manifest, ManifestEdit};
pub use plan::{BatchSettings, Group, Plan, PlannedEdit};
pub use run::{finish, prepare_output, run_all, run_group, BatchProgress, GroupOutcome, Summary};

use crate::edit::EditError;
use crate::raster::RasterError;

/// Errors of a batch. Every variant but [`BatchError::Internal`] and
/// [`BatchError::Footprint`] is the input's fault (exit 1).
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The manifest (or a sketch it names) is unusable.
    #[error("{path}: {message}")]
    Manifest { path: String, message: String },
    /// The plan file is unusable or does not match the output.
    #[error("{path}: {message}")]
    Plan { path: String, message: String },
    /// A file of the batch could not be written or read.
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    #[error(transparent)]
    Raster(#[from] RasterError),
    /// An edit failed in a way that stops its group.
    #[error("edit \"{id}\": {source}")]
    Edit {
        id: String,
        #[source]
        source: Box<EditError>,
    },
    /// A corrections edit failed in a way that stops its group.
    #[error("edit \"{id}\": {source}")]
    Correct {
        id: String,
        #[source]
        source: Box<crate::correct::CorrectError>,
    },
    /// An edit changed cells outside the footprint the plan gave it: the
    /// plan was not conservative (a bug); its group stops.
    #[error("edit \"{id}\": {message}")]
    Footprint { id: String, message: String },
    #[error("internal error: {0}")]
    Internal(String),
}

impl BatchError {
    /// True when the input is at fault (exit code 1), false for a bug
    /// (exit code 2).
    pub fn is_user_error(&self) -> bool {
        match self {
            BatchError::Raster(e) => e.is_user_error(),
            BatchError::Edit { source, .. } => source.is_user_error(),
            BatchError::Correct { source, .. } => source.is_user_error(),
            BatchError::Footprint { .. } | BatchError::Internal(_) => false,
            _ => true,
        }
    }
}

/// An I/O error naming `path`.
pub(crate) fn io_err(path: &std::path::Path, e: impl std::fmt::Display) -> BatchError {
    BatchError::Io {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}
