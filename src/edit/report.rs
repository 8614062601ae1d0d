//! The edit report (`edit --report report.json`): the fields of DESIGN.md
//! that tools and tests read (matching, fit, visibility, lowering
//! iterations, tiles written, changed cells, largest displacement, timings
//! per stage) plus a few details, serialised as JSON and written atomically.

use serde::Serialize;
use std::path::{Path, PathBuf};

use super::fit::StrokeFit;
use crate::sketch::MatchKind;

/// The whole report.
#[derive(Debug, Clone, Serialize)]
pub struct EditReport {
    pub dem: String,
    pub sketch: String,
    /// Where the corrected DEM went (the input for `--in-place`).
    pub output: String,
    pub views: Vec<ViewReport>,
    /// Files rewritten by the edit.
    pub tiles_written: Vec<String>,
    /// Files copied or linked unchanged into the output.
    pub tiles_unchanged: Vec<String>,
    /// Cells whose stored value changed.
    pub changed_cells: usize,
    /// Largest |M| over the DEM, metres.
    pub max_abs_displacement_m: f64,
    pub deformation: DeformationReport,
    pub timings_s: Timings,
    /// Notes (split strokes, depth-order conflicts, early stop of the
    /// matching, why nothing was written).
    pub notes: Vec<String>,
    /// Whether the corrected DEM was written (false for a dry run and when
    /// a stroke's fit is below `min_fit` without `--allow-partial`; then
    /// `changed_cells` counts what a write would have changed).
    pub written: bool,
    pub dry_run: bool,
    /// The `--min-fit` every stroke's `status` was judged against.
    pub min_fit: f64,
    /// The stroke-feature search of the whole sketch (its views are
    /// matched jointly).
    pub matching: MatchingReport,
    /// What each map-view correction of the sketch's `corrections` member
    /// did (as in the report of `demsketch correct`); absent without any.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub corrections: Vec<crate::correct::FeatureReport>,
}

/// Branch-and-bound of the matching.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct MatchingReport {
    /// Search nodes visited.
    pub nodes: u64,
    /// Most nodes allowed (`options.node_budget`).
    pub node_budget: u64,
    /// The budget ran out: the assignment is the best found within it, not
    /// proven optimal.
    pub stopped_early: bool,
}

/// Whether a stroke is fitted (`fit.fitted_fraction >= min_fit`), partly
/// fitted (below it, above 0) or not at all.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StrokeStatus {
    Fitted,
    Partial,
    Unfitted,
}

/// One view of the sketch.
#[derive(Debug, Clone, Serialize)]
pub struct ViewReport {
    pub name: String,
    /// Absolute eye altitude every render, fit and picture of the edit used
    /// (metres, the DEM's vertical datum): resolved once on the unedited
    /// DEM, above the surface the renderer draws.
    pub eye_alt_m: f64,
    pub strokes: Vec<StrokeReport>,
    /// Re-solves triggered by protruding silhouettes seen from this view.
    pub lowering_iterations: usize,
    /// Protruding silhouettes lowered, over all iterations.
    pub silhouettes_lowered: usize,
    /// Re-solves that moved mesh vertices to make the strokes this view's
    /// occluding contours (`edit::contour`).
    pub contour_iterations: usize,
    /// Features offered to matching (silhouettes, ridges).
    pub features: FeatureCounts,
    /// The matching (joint over all views) stopped at its node budget.
    pub matching_stopped_early: bool,
}

/// Features of a view.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct FeatureCounts {
    pub silhouettes: usize,
    pub ridges: usize,
}

/// One stroke (a piece, when a stroke folding back in x was split).
#[derive(Debug, Clone, Serialize)]
pub struct StrokeReport {
    pub id: String,
    pub source_id: String,
    #[serde(rename = "match")]
    pub matched: MatchReport,
    pub fit: StrokeFit,
    pub visible_fraction: f64,
    pub status: StrokeStatus,
    /// Why the stroke is not fitted (absent when it is).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// Share of the stroke that already lay on a silhouette of the
    /// unedited terrain (within about a pixel) and was kept as it was.
    pub on_silhouette: f64,
    /// How the points not on a silhouette were placed (counts of stroke
    /// points; see `edit::stretch_placement`).
    pub placement: super::stretch_placement::StretchPlacement,
    /// The 3D curve the stroke was placed at: `[x, y, z]` in the DEM's CRS,
    /// z the absolute height in metres (what `demsketch export geojson`
    /// draws), in stroke order; points that could not be placed are left out.
    /// When later passes placed the stroke again (the columns an earlier
    /// pass left unfitted, on the terrain it made), the curve of the last
    /// pass kept: the one the written terrain was fitted to.
    pub placed_curve: Vec<[f64; 3]>,
    /// The first pass's placement (`match.depth_m` and `placed_curve`)
    /// when a later pass placed the stroke again: what the passes' own
    /// checks measure against (the strokes as first placed); not written.
    #[serde(skip)]
    pub first_placed: Option<FirstPlaced>,
}

/// A stroke's placement by the first pass of an edit, kept when a later
/// pass's placement replaces it in the report ([`StrokeReport::first_placed`]).
#[derive(Debug, Clone)]
pub struct FirstPlaced {
    pub depth_m: [f64; 2],
    pub placed_curve: Vec<[f64; 3]>,
}

impl StrokeReport {
    /// The first pass's placed curve (the report's own when no later pass
    /// placed the stroke again).
    pub fn first_curve(&self) -> &[[f64; 3]] {
        match &self.first_placed {
            Some(f) => &f.placed_curve,
            None => &self.placed_curve,
        }
    }

    /// The first pass's placed depth range (see [`Self::first_curve`]).
    pub fn first_depth_m(&self) -> [f64; 2] {
        match &self.first_placed {
            Some(f) => f.depth_m,
            None => self.matched.depth_m,
        }
    }

    /// Takes a later pass's placement of this stroke (`later`, the same
    /// stroke's report from that pass) as the report's, keeping the first
    /// pass's for the passes' checks: the match (feature, kind, cost)
    /// stays the first pass's, the landform the stroke asked for.
    pub fn take_placement(&mut self, later: &StrokeReport) {
        if self.first_placed.is_none() {
            self.first_placed = Some(FirstPlaced {
                depth_m: self.matched.depth_m,
                placed_curve: std::mem::take(&mut self.placed_curve),
            });
        }
        self.matched.depth_m = later.matched.depth_m;
        self.placed_curve = later.placed_curve.clone();
    }
}

/// What a stroke was matched to.
#[derive(Debug, Clone, Serialize)]
pub struct MatchReport {
    pub kind: MatchKind,
    pub feature_id: Option<usize>,
    pub cost: Option<f64>,
    /// Position in the view's depth order (0 = nearest).
    pub depth_rank: usize,
    /// Depth range of the placed curve, metres.
    pub depth_m: [f64; 2],
}

/// The deformation that was written.
#[derive(Debug, Clone, Serialize)]
pub struct DeformationReport {
    /// `[col, row, width, height]` of the solved window on the DEM grid.
    pub window: [i64; 4],
    pub curve_constraints: usize,
    pub lowering_constraints: usize,
    pub influence_m: f64,
    pub solver: serde_json::Value,
}

/// Seconds per stage.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Timings {
    pub load: f64,
    pub features: f64,
    pub matching: f64,
    pub deformation: f64,
    pub lowering: f64,
    pub write: f64,
    pub total: f64,
}

impl Timings {
    /// Adds the stage times of `other` (a retry's, say) to these.
    pub fn add(&mut self, other: &Timings) {
        self.load += other.load;
        self.features += other.features;
        self.matching += other.matching;
        self.deformation += other.deformation;
        self.lowering += other.lowering;
        self.write += other.write;
        self.total += other.total;
    }
}

/// A file written atomically: a staging directory is created beside `path`
/// up front (which proves the directory is writable; exclusive, with an
/// unpredictable name, see [`crate::raster::atomic_file`]), and
/// [`StagedFile::commit`] writes the bytes there, reads them back and
/// renames the file into place. Dropped uncommitted, nothing is left.
/// [`StagedFile::reserve`] claims the disk space first, so that a report
/// written after the DEM does not fail on a disk the DEM just filled.
pub struct StagedFile {
    pub path: PathBuf,
    staging: crate::raster::atomic_file::Staging,
    reserved: u64,
}

impl StagedFile {
    /// Create the staging directory beside `path`.
    pub fn create(path: &Path) -> std::io::Result<StagedFile> {
        if path.file_name().is_none() {
            return Err(std::io::Error::other("is not a file name"));
        }
        if path.is_dir() {
            return Err(std::io::Error::other("is a directory"));
        }
        let dir = crate::raster::atomic_file::parent_dir(path);
        let staging = crate::raster::atomic_file::Staging::new_in(dir)?;
        Ok(StagedFile {
            path: path.to_path_buf(),
            staging,
            reserved: 0,
        })
    }

    /// Claim `bytes` of disk space for the file now (written as zeros,
    /// flushed): the commit then overwrites them in place.
    pub fn reserve(&mut self, bytes: u64) -> std::io::Result<()> {
        use std::io::Write;
        let tmp = self.staging.file(self.path.file_name().unwrap_or_default());
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        let block = vec![0u8; 1 << 16];
        let mut left = bytes;
        while left > 0 {
            let n = left.min(block.len() as u64) as usize;
            f.write_all(&block[..n])?;
            left -= n as u64;
        }
        f.sync_all()?;
        self.reserved = bytes;
        Ok(())
    }

    /// Write `bytes`, check them, and rename into place.
    pub fn commit(self, bytes: &[u8]) -> std::io::Result<()> {
        use std::io::{Seek, Write};
        let name = self.path.file_name().unwrap_or_default();
        let tmp = self.staging.file(name);
        if self.reserved > 0 {
            let mut f = std::fs::OpenOptions::new().write(true).open(&tmp)?;
            f.seek(std::io::SeekFrom::Start(0))?;
            f.write_all(bytes)?;
            f.set_len(bytes.len() as u64)?;
            f.sync_all()?;
            drop(f);
            if std::fs::read(&tmp)? != bytes {
                return Err(std::io::Error::other("the written file does not read back"));
            }
        } else {
            crate::raster::atomic_file::write_bytes_verified(&tmp, bytes)?;
        }
        let _commit = crate::raster::atomic_file::commit_guard();
        std::fs::rename(&tmp, &self.path)?;
        let _ = crate::raster::atomic_file::sync_dir(crate::raster::atomic_file::parent_dir(
            &self.path,
        ));
        Ok(())
    }
}
