//! The options of an edit and the limits and defaults it applies, and the
//! check of its output paths before anything is read.

use super::*;

/// Options of an edit.
#[derive(Debug, Clone)]
pub struct EditOptions {
    /// Where the corrected DEM goes.
    pub destination: Destination,
    /// Write the report here (JSON).
    pub report: Option<PathBuf>,
    /// Write before/after views and the height-change map into this directory.
    pub renders: Option<PathBuf>,
    /// Only the DEM within this distance of each viewpoint is read, metres
    /// (`None`: the whole DEM).
    pub max_distance_m: Option<f64>,
    /// Refraction coefficient k.
    pub refraction: f64,
    /// Most re-solves per view while lowering protruding silhouettes.
    pub max_lowering_iterations: usize,
    /// Most re-solves per view while fitting the strokes' contours
    /// ([`crate::edit::contour`]).
    pub max_contour_iterations: usize,
    /// Show progress on stderr (only drawn when stderr is a terminal).
    pub progress: bool,
    /// A progress bar, drawn or hidden, whose message the edit sets to the
    /// stage it is in: for a caller that shows progress elsewhere (the
    /// browser app reads it while the edit runs). Replaces the stderr
    /// spinner of `progress`.
    pub stage: Option<ProgressBar>,
    /// A stroke is fitted when at least this share of its columns is
    /// (`fitted_fraction`); below it, nothing is written
    /// ([`EditError::BelowMinFit`]) unless `allow_partial`.
    pub min_fit: f64,
    /// Write the edit even when a stroke's fit is below `min_fit`.
    pub allow_partial: bool,
    /// Compute everything and write the report and pictures, but not the
    /// DEM. Fails as a real run would (bad heights, fit below `min_fit`).
    pub dry_run: bool,
    /// Output format, creation options and overview resampling of the
    /// write-back (the provenance record is filled in by the edit).
    pub write: WriteOptions,
    /// Also write the height change as a GeoTIFF here.
    pub dz: Option<PathBuf>,
}

impl EditOptions {
    /// Defaults: 50 km view distance, k = 1/7, 4 lowering iterations, 6
    /// contour iterations, minimum fit [`DEFAULT_MIN_FIT`], no partial
    /// writes, not a dry run.
    pub fn new(destination: Destination) -> EditOptions {
        EditOptions {
            destination,
            report: None,
            renders: None,
            max_distance_m: Some(50_000.0),
            refraction: 1.0 / 7.0,
            max_lowering_iterations: 4,
            max_contour_iterations: 6,
            progress: false,
            stage: None,
            min_fit: DEFAULT_MIN_FIT,
            allow_partial: false,
            dry_run: false,
            write: WriteOptions::default(),
            dz: None,
        }
    }

    /// The edit's parameters as flags, for the provenance record.
    pub fn parameters(&self) -> String {
        let mut p = vec![
            format!(
                "--max-distance {}",
                self.max_distance_m.unwrap_or(f64::INFINITY)
            ),
            format!("--refraction {}", self.refraction),
            format!("--max-lowering-iterations {}", self.max_lowering_iterations),
            format!("--max-contour-iterations {}", self.max_contour_iterations),
            format!("--min-fit {}", self.min_fit),
        ];
        if self.allow_partial {
            p.push("--allow-partial".into());
        }
        if let Some(r) = &self.write.overview_resampling {
            p.push(format!("--overview-resampling {r}"));
        }
        if let Some(f) = &self.write.format {
            p.push(format!("-of {f}"));
        }
        for c in &self.write.creation_options {
            p.push(format!("-co {c}"));
        }
        p.push(match &self.destination {
            Destination::InPlace => "--in-place".into(),
            Destination::Path(o) => format!("--out {}", o.display()),
        });
        p.join(" ")
    }
}

/// The edit's cache of decoded blocks: the views' wedges are read once
/// (their terrains serve every re-render), so their blocks need not be kept;
/// the deformation's windows and the write re-read a few tiles.
pub(super) const EDIT_BLOCK_CACHE_BYTES: usize = 64 << 20;

/// A stroke end touches the terrain when, in the view before the edit,
/// terrain lies below it (or in a column beside it) no lower than this
/// rise over distance: the end's ray passes at most 10 % of the terrain's
/// distance above it (a landform raised by 100 m at 1 km), whatever the
/// camera's field of view ...
pub const TERRAIN_TOUCH_RISE: f64 = 0.10;

/// ... or within this many rows.
pub const TERRAIN_TOUCH_PX: f64 = 5.0;

/// Default of [`EditOptions::min_fit`] (`--min-fit`).
pub const DEFAULT_MIN_FIT: f64 = 0.9;

/// Default radius of the ground held fixed around each viewpoint, metres
/// (at least two cells; the sketch's `observer_radius_m` overrides it).
pub const OBSERVER_RADIUS_M: f64 = 100.0;

/// Fail early, before any work, on a view distance or refraction
/// coefficient out of range ([`crate::view::check_view_settings`], the
/// rule the command line checks its flags by) or a `min_fit` that is not
/// a number >= 0 ([`crate::view::check_min_fit`], the same): values a
/// caller passes on from its user.
pub(super) fn check_view_options(opts: &EditOptions) -> Result<(), EditError> {
    crate::view::check_view_settings(
        opts.max_distance_m,
        opts.refraction,
        crate::view::SettingNames::Options,
    )
    .map_err(|e| EditError::Options(e.to_string()))?;
    crate::view::check_min_fit(opts.min_fit, crate::view::SettingNames::Options)
        .map_err(|e| EditError::Options(e.to_string()))
}

/// Fail early, before any work, when an output cannot be written: its
/// parent directory must exist (write-back checks the rest).
pub(super) fn check_output_paths(opts: &EditOptions) -> Result<(), EditError> {
    let mut paths: Vec<&Path> = Vec::new();
    if let Destination::Path(p) = &opts.destination {
        paths.push(p);
    }
    paths.extend(opts.report.as_deref());
    paths.extend(opts.renders.as_deref());
    paths.extend(opts.dz.as_deref());
    for p in paths {
        let parent = p
            .parent()
            .filter(|q| !q.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        if !parent.is_dir() {
            return Err(EditError::Write {
                path: p.display().to_string(),
                message: "its parent directory does not exist".into(),
            });
        }
    }
    Ok(())
}
