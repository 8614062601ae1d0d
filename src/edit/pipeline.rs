//! The edit pipeline, stage by stage. [`run`] calls one function per
//! stage, in order; the timings in the report use the names in
//! backquotes:
//!
//! 1. `load` (`load_views`): open the DEM (tile layer), read and
//!    validate the sketch, resolve every view's viewpoint (PROJ) and read
//!    the DEM window within the maximum view distance ([`Scene::open`]).
//! 2. `features` (`render_and_extract`, `scene_features`): render each
//!    view (exact depth buffer), extract its silhouettes, and the ridge
//!    network of the DEM around all views.
//! 3. `matching` (`match_strokes`): strokes of all views matched jointly
//!    ([`match_sketch`]), placed in 3D, converted to the DEM's CRS
//!    (`place_demands`).
//! 4. `deformation` (`deform`): displacement constraints diffused by
//!    multigrid, `H' = H + M` on the affected window.
//! 5. `lowering` (`super::rounds::refine`, `measure_strokes`): each
//!    view re-rendered on the edited terrain; protruding silhouettes
//!    lowered by the paper's `h` as new constraints, and the mesh vertices
//!    that decide the contour along strokes that do not fit yet put on the
//!    strokes' sight surfaces ([`super::contour`]); re-solve with the
//!    union, repeat until neither asks for more (or the iteration limits);
//!    fit and visibility measured on the final terrain.
//!
//! Stages 2 to 5 are one pass (`edit_pass`). When the first pass changed
//! the terrain and left a stroke short of a full fit, a second runs on the
//! terrain the first made (`second_pass`: the DEM read through an overlay
//! of it, as the write stores it, nothing written) and the deformations
//! are written as one (`compose`); while a pass is kept and leaves a
//! stroke unfitted, another follows, up to [`MAX_PASSES`], so that editing
//! the output again changes nothing (`all_passes`).
//!
//! Each view's skyline is one of the candidate features
//! ([`crate::sketch::skyline`]). Where a stroke matched to a skyline is
//! left unfitted, stages 3 to 5 of the pass run again without the
//! skylines (`match_and_fit`), and so does the whole edit (all its
//! passes, in `run_opened`); the skyline's is kept only where the other
//! does not fit the strokes better, in all or where its placed curves
//! are visible (`fits_better`).
//!
//! 6. `write` (`super::outputs::write_outputs`): affected tiles written
//!    back atomically, then the pictures and the report.

use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;

use super::fit::measure;
use super::on_silhouette::anchor_on_silhouettes;
use super::outputs::{write_outputs, Outcome, Sources};
use super::rendered_view::{RenderedView, StrokeCurve, StrokeRegion};
use super::report::{
    EditReport, FeatureCounts, MatchReport, MatchingReport, StrokeReport, StrokeStatus, Timings,
    ViewReport,
};
use super::rounds::{refine, Rounds};
use super::spikes::find_spikes;
use super::stretch_placement::{place_free_stretches, StretchPlacement};
use super::EditError;
use crate::deform::{
    deform_with_cells, CellConstraint, CurveConstraint, DeformError, DeformOptions, Deformation,
};
use crate::features::{detect_ridges, RidgeNetwork, RidgeParams};
use crate::raster::{Dem, Destination, HeightMap, Window, WriteOptions};
use crate::render::{FarLayers, Scene};
use crate::sketch::{
    match_sketch, EyeHeightSpec, PointSource, SceneProjection, SceneView, SketchFile, SketchMatch,
    SketchOptions, Stroke, ViewFeatureOptions, ViewInput, ViewSpec,
};
use crate::view::{Camera, LocalFrame};

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
    /// ([`super::contour`]).
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
const EDIT_BLOCK_CACHE_BYTES: usize = 64 << 20;

/// A stroke end touches the terrain when a terrain pixel lies within this
/// share of the image height below it (or a column beside it) in the view
/// before the edit ...
pub const TERRAIN_TOUCH_SHARE: f64 = 0.05;
/// ... and at least this many rows.
pub const TERRAIN_TOUCH_PX: f64 = 5.0;

/// Default of [`EditOptions::min_fit`] (`--min-fit`).
pub const DEFAULT_MIN_FIT: f64 = 0.9;

/// Default radius of the ground held fixed around each viewpoint, metres
/// (at least two cells; the sketch's `observer_radius_m` overrides it).
pub const OBSERVER_RADIUS_M: f64 = 100.0;

/// A view of the sketch set up on the DEM.
pub(super) struct ViewState<'a> {
    pub(super) spec: &'a ViewSpec,
    /// Where the DEM window read for the view (the box of the camera's
    /// wedge within the view distance, [`Scene::open_wedge`]) lies on the
    /// DEM grid, and the view's local frame (expressed for that window).
    /// The window's heights are [`Extracted::windows`], dropped once the
    /// strokes are placed: everything later renders from the view's
    /// terrain.
    pub(super) window_offset: (i64, i64),
    /// The ground held around the eye ([`ViewState::observer_cells`]),
    /// where the wedge's box does not cover it (behind the eye).
    pub(super) eye_ground: EyeGround,
    pub(super) frame: LocalFrame,
    pub(super) camera: Camera,
    pub(super) strokes: Vec<Stroke>,
    pub(super) before: RenderedView,
}

/// What every stage of one edit reads: the options, the sketch's name for
/// messages, the view distance in force and the progress spinner.
pub(super) struct Edit<'o> {
    pub(super) opts: &'o EditOptions,
    pub(super) sketch_name: String,
    /// [`EditOptions::max_distance_m`] when finite and positive.
    pub(super) max_d: Option<f64>,
    pub(super) pb: ProgressBar,
    /// The views' skylines are candidate features
    /// ([`crate::sketch::skyline`]); `false` on the run without them.
    pub(super) skyline: bool,
}

pub(super) fn secs(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// The caller's stage bar when it gave one, else progress on stderr: a
/// spinner with the current stage, hidden when stderr is not a terminal or
/// progress is off.
fn progress_bar(opts: &EditOptions) -> ProgressBar {
    if let Some(pb) = &opts.stage {
        return pb.clone();
    }
    let on = opts.progress;
    let target = if on {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let pb = ProgressBar::with_draw_target(None, target);
    if let Ok(style) = ProgressStyle::with_template("{spinner} [{elapsed}] {msg}") {
        pb.set_style(style);
    }
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

/// Run one edit: see the module documentation.
pub fn run(
    dem_path: &Path,
    sketch_path: &Path,
    opts: &EditOptions,
) -> Result<EditReport, EditError> {
    // (the outputs' directories before the DEM, as always)
    check_output_paths(opts)?;
    run_opened(Dem::open(dem_path)?, dem_path, sketch_path, opts)
}

/// [`run`] on `dem`, the DEM at `dem_path` opened already (by
/// [`super::guard::prepare_open`]): not opened a second time.
pub fn run_opened(
    dem: Dem,
    dem_path: &Path,
    sketch_path: &Path,
    opts: &EditOptions,
) -> Result<EditReport, EditError> {
    // On a worker thread of rayon's pool: the many parallel loops of an
    // edit (a few hundred, most of them short: the multigrid levels, the
    // silhouette columns) then split work between the workers directly
    // instead of each waking the pool from outside and waiting for it.
    if rayon::current_thread_index().is_none() {
        return rayon::join(|| run_opened(dem, dem_path, sketch_path, opts), || ()).0;
    }
    let t_all = Instant::now();
    let edit = Edit {
        opts,
        sketch_name: sketch_path.display().to_string(),
        max_d: opts.max_distance_m.filter(|d| d.is_finite() && *d > 0.0),
        pb: progress_bar(opts),
        skyline: true,
    };
    let mut timings = Timings::default();
    check_output_paths(opts)?;

    let t = Instant::now();
    let Loaded {
        sketch,
        dem,
        notes,
        prepared,
        scenes,
    } = load_views(
        &edit,
        dem.with_block_cache_budget(EDIT_BLOCK_CACHE_BYTES),
        sketch_path,
        &[],
    )?;
    timings.load = secs(t);

    let dem_name = dem_path.display().to_string();
    let (views, outcome) = all_passes(
        &edit,
        (&sketch, &dem, &dem_name, sketch_path),
        (scenes, prepared, notes),
        &mut timings,
    )?;
    if skyline_left_unfitted(&outcome) {
        // A skyline match that leaves a stroke unfitted stands against
        // the edit without the skylines (see `sketch::skyline`).
        let plain = Edit {
            opts,
            sketch_name: edit.sketch_name.clone(),
            max_d: edit.max_d,
            pb: edit.pb.clone(),
            skyline: false,
        };
        let reloaded = dem.reopened().map_err(EditError::from).and_then(|d| {
            load_views(
                &plain,
                d.with_block_cache_budget(EDIT_BLOCK_CACHE_BYTES),
                sketch_path,
                &[],
            )
        });
        if let Ok(Loaded {
            sketch: sketch2,
            dem: dem2,
            notes: notes2,
            prepared: prepared2,
            scenes: scenes2,
        }) = reloaded
        {
            let mut scratch = Timings::default();
            let other = all_passes(
                &plain,
                (&sketch2, &dem2, &dem_name, sketch_path),
                (scenes2, prepared2, notes2),
                &mut scratch,
            );
            // The retry's time is the edit's, whichever is kept.
            timings.add(&scratch);
            if let Ok((views2, mut outcome2)) = other {
                if fits_better(&outcome2, &outcome) {
                    outcome2
                        .notes
                        .push(skyline_dropped_note(&outcome2, &outcome));
                    let sources = Sources {
                        dem_path,
                        sketch_path,
                        dem: &dem2,
                        sketch: &sketch2,
                    };
                    return write_outputs(plain, &sources, &views2, outcome2, timings, t_all);
                }
            }
        }
    }
    let sources = Sources {
        dem_path,
        sketch_path,
        dem: &dem,
        sketch: &sketch,
    };
    write_outputs(edit, &sources, &views, outcome, timings, t_all)
}

/// The first pass ([`edit_pass`]) and, while one is kept and leaves a
/// stroke unfitted, the later ones ([`second_pass`]), up to
/// [`MAX_PASSES`].
fn all_passes<'s>(
    edit: &Edit,
    (sketch, dem, dem_name, sketch_path): (&'s SketchFile, &Dem, &str, &Path),
    loaded: (Vec<ViewScene>, Vec<Vec<Stroke>>, Vec<String>),
    timings: &mut Timings,
) -> Result<(Vec<ViewState<'s>>, Outcome), EditError> {
    let (views, outcome) = edit_pass(
        edit,
        (sketch, dem, dem_name),
        loaded,
        Vec::new(),
        timings,
        false,
    )?;
    let Some(mut outcome) = outcome else {
        return Err(EditError::Internal(
            "the first pass was dropped as a later one".into(),
        ));
    };
    let mut pass = 1;
    while pass < MAX_PASSES && needs_second_pass(sketch, &outcome) {
        let t = Instant::now();
        // The far rings of a long view lie beyond every pass's changes:
        // the later passes take the first's (when they serve, see `load_views`).
        let far: Vec<FarLayers> = views
            .iter()
            .map(|v| v.before.terrain.far_layers())
            .collect();
        pass += 1;
        let changed;
        (outcome, changed) = second_pass(edit, dem, sketch_path, outcome, &far, pass)?;
        timings.lowering += secs(t);
        if !changed {
            break;
        }
    }
    Ok((views, outcome))
}

/// Stages 2 to 5 on the loaded views: features, matching, deformation,
/// lowering and contour rounds (with the sketch's map-view corrections),
/// and the strokes measured on the result. `timings` gets their times.
/// `earlier`: per view, the pass before's last render, which the views'
/// renders take what they can from ([`render_and_extract`]; none for the
/// first pass).
/// `later`: a pass after the first, which the run drops when it changes no
/// cell ([`second_pass`]); such a pass stops as soon as that is known and
/// gives no outcome (`None`; the first pass always gives one).
/// When a stroke matched to a view's skyline is left unfitted, stages 3
/// to 5 run again without the skylines, and that outcome is kept if it
/// fits the strokes better (ties keep the skyline's).
fn edit_pass<'s>(
    edit: &Edit,
    (sketch, dem, dem_name): (&'s SketchFile, &Dem, &str),
    (scenes, prepared, notes): (Vec<ViewScene>, Vec<Vec<Stroke>>, Vec<String>),
    earlier: Vec<RenderedView>,
    timings: &mut Timings,
    later: bool,
) -> Result<(Vec<ViewState<'s>>, Option<Outcome>), EditError> {
    let t = Instant::now();
    let extracted = render_and_extract(edit, sketch, dem, scenes, prepared, earlier)?;
    let views = extracted.views;
    let features = scene_features(&views, &extracted.ridges, &sketch.options, edit.skyline);
    timings.features = secs(t);
    let found = (&views[..], &extracted.windows[..], &features);
    let Some(outcome) = match_and_fit(
        edit,
        (sketch, dem, dem_name),
        found,
        notes.clone(),
        timings,
        later,
    )?
    else {
        return Ok((views, None));
    };
    if !(edit.skyline && skyline_left_unfitted(&outcome)) {
        return Ok((views, Some(outcome)));
    }
    // A skyline match that leaves a stroke unfitted stands against the
    // match without the skyline (see `sketch::skyline`); the two are
    // compared whole (never dropped early).
    let plain = scene_features(&views, &extracted.ridges, &sketch.options, false);
    let mut scratch = Timings::default();
    let found = (&views[..], &extracted.windows[..], &plain);
    let other = match_and_fit(
        edit,
        (sketch, dem, dem_name),
        found,
        notes,
        &mut scratch,
        false,
    );
    let outcome = match other {
        Ok(Some(mut other)) if fits_better(&other, &outcome) => {
            other.notes.push(skyline_dropped_note(&other, &outcome));
            other
        }
        _ => outcome,
    };
    timings.add(&scratch);
    Ok((views, Some(outcome)))
}

/// Stages 3 to 5 on the rendered `views` and their `features`: matching,
/// deformation, lowering and contour rounds (with the sketch's map-view
/// corrections), and the strokes measured on the result. `later`: a pass
/// after the first, dropped when it changes no cell ([`second_pass`]): it
/// stops as soon as that is known and gives `None`, unless a stroke was
/// matched to a skyline (its outcome may then be compared with the match
/// without the skylines, see [`edit_pass`]).
fn match_and_fit(
    edit: &Edit,
    (sketch, dem, dem_name): (&SketchFile, &Dem, &str),
    (views, windows, features): (&[ViewState], &[HeightMap], &Features),
    mut notes: Vec<String>,
    timings: &mut Timings,
    later: bool,
) -> Result<Option<Outcome>, EditError> {
    let t = Instant::now();
    let map_only = sketch.corrections.is_some() && views.iter().all(|v| v.strokes.is_empty());
    let placed = match_strokes(
        edit,
        (&sketch.options, dem),
        (views, windows, map_only),
        features,
        &mut notes,
    )?;
    timings.matching = secs(t);

    let t = Instant::now();
    let (solver, deformation) = deform(edit, dem, dem_name, &sketch.options, views, &placed)?;
    timings.deformation = secs(t);

    let t = Instant::now();
    // (map-view corrections would change the terrain after the rounds:
    // such a pass is never dropped early)
    let on_skyline = placed
        .matched
        .views
        .iter()
        .flat_map(|m| &m.strokes)
        .any(|sm| sm.feature_id.is_some_and(crate::sketch::is_skyline));
    let discard_unchanged = later && sketch.corrections.is_none() && !on_skyline;
    let Some(mut rounds) = refine(
        edit,
        views,
        &solver,
        &placed,
        deformation,
        discard_unchanged,
    )?
    else {
        return Ok(None);
    };
    if rounds.kept_unedited {
        notes.push(
            "nothing changed by the strokes: no deformation fitted them better than the terrain as it is (each stroke's fit below is on the unedited terrain)"
                .to_string(),
        );
    }
    let corrections = apply_corrections(edit, dem, sketch, views, &placed, &mut rounds)?;
    let view_reports = measure_strokes(edit, views, features, &placed, &rounds);
    timings.lowering = secs(t);

    Ok(Some(Outcome {
        views: view_reports,
        notes,
        curve_constraints: placed.demands.curves.len(),
        lowering_constraints: rounds.lowering_constraints,
        matching: MatchingReport {
            nodes: placed.matched.nodes,
            node_budget: placed.matched.node_budget,
            stopped_early: placed.matched.stopped_early,
        },
        deformation: rounds.deformation,
        corrections,
        renders: rounds.rendered,
    }))
}

/// The strokes' summed fit (the fitted fraction of each stroke).
fn fit_score(o: &Outcome) -> f64 {
    o.views
        .iter()
        .flat_map(|v| &v.strokes)
        .map(|s| s.fit.fitted_fraction)
        .sum()
}

/// The strokes' summed fit counting only what is seen: per stroke the
/// smaller of its fitted and its visible fraction (a placed curve hidden
/// behind nearer terrain fits only where its silhouette happens to).
fn seen_fit_score(o: &Outcome) -> f64 {
    o.views
        .iter()
        .flat_map(|v| &v.strokes)
        .map(|s| s.fit.fitted_fraction.min(s.visible_fraction))
        .sum()
}

/// True when outcome `a` fits the strokes better than `b` by either
/// measure: the summed fit ([`fit_score`]) or the summed fit where the
/// placed curves are visible ([`seen_fit_score`]). The skyline's edit is
/// kept only where it is at least as good by both.
fn fits_better(a: &Outcome, b: &Outcome) -> bool {
    fit_score(a) > fit_score(b) + 1e-9 || seen_fit_score(a) > seen_fit_score(b) + 1e-9
}

/// The report's note when the edit without the skylines (`plain`) is
/// kept over the skyline's (`skyline`).
fn skyline_dropped_note(plain: &Outcome, skyline: &Outcome) -> String {
    format!(
        "a stroke matched to a view's skyline was left unfitted: matched without the skylines, the strokes' summed fit is {:.3} ({:.3} where visible) instead of {:.3} ({:.3})",
        fit_score(plain),
        seen_fit_score(plain),
        fit_score(skyline),
        seen_fit_score(skyline)
    )
}

/// True when a stroke was matched to a view's skyline feature
/// ([`crate::sketch::skyline`]) and some stroke is short of a full fit or
/// partly hidden.
fn skyline_left_unfitted(o: &Outcome) -> bool {
    let strokes = || o.views.iter().flat_map(|v| &v.strokes);
    strokes().any(|s| s.matched.feature_id.is_some_and(crate::sketch::is_skyline))
        && strokes().any(|s| s.fit.fitted_fraction.min(s.visible_fraction) < 1.0 - 1e-9)
}

/// A second pass is made when the first changed the terrain but left a
/// stroke short of a full fit, and the sketch has no map-view
/// corrections (which the first pass applied already).
fn needs_second_pass(sketch: &SketchFile, first: &Outcome) -> bool {
    sketch.corrections.is_none()
        && first.deformation.stats.changed_cells > 0
        && first
            .views
            .iter()
            .flat_map(|v| &v.strokes)
            .any(|s| s.fit.fitted_fraction < 1.0 - 1e-9)
}

/// The edit again, on the terrain the first pass made (read through an
/// overlay of `dem`, nothing written): where the first pass fitted a
/// stroke, the stroke now lies on a silhouette and is kept; the columns it
/// left unfitted are matched and placed again, against the terrain as it
/// now is, as editing the output again would. Without it an edit is not
/// its own fixed point: editing its output again with the same sketch
/// would move those columns (issue 11: on the fidelity suite, 3 of 126
/// tuned and 35 of 235 hold-out cases moved by more than 0.5 m). The
/// result is the first pass's deformation plus the second's, reported with
/// the first pass's matches and placements (the landform the strokes
/// asked for) and the final fit; it is kept only when it fits the strokes
/// at least as well as the first pass alone and the sum of the two changes
/// has no more spikes ([`find_spikes`]) than the first alone. `pass` numbers
/// it (2 for the second; `first` is then everything the passes before
/// made). Returns the outcome and whether this pass was kept: when it was,
/// the run makes another pass ([`MAX_PASSES`] in all at most), so that
/// the edit stops only where a pass, as a re-edit of its output would,
/// changes nothing.
fn second_pass(
    edit: &Edit,
    dem: &Dem,
    sketch_path: &Path,
    mut first: Outcome,
    far: &[FarLayers],
    pass: usize,
) -> Result<(Outcome, bool), EditError> {
    edit.pb
        .set_message(format!("pass {pass} over the strokes left unfitted"));
    let d1 = &quantized(dem, &first.deformation);
    // The pass before's last renders are of the terrain this pass starts
    // from: its views' renders take what they can from them.
    let earlier = std::mem::take(&mut first.renders);
    let run_second = || -> Result<Option<Outcome>, EditError> {
        let overlay = dem.reopened()?.with_overlay(d1.window, d1.edited().data);
        let Loaded {
            sketch,
            dem: dem2,
            notes,
            prepared,
            scenes,
        } = load_views(edit, overlay, sketch_path, far)?;
        let dem_name = dem.path.display().to_string();
        let mut scratch = Timings::default();
        let (_, second) = edit_pass(
            edit,
            (&sketch, &dem2, &dem_name),
            (scenes, prepared, notes),
            earlier,
            &mut scratch,
            true,
        )?;
        Ok(second)
    };
    // The first pass stands on its own: a second that cannot run (a stroke
    // end no longer on terrain, say) leaves it as it is.
    let second = match run_second() {
        Ok(Some(o)) => o,
        // A pass that changes no cell is dropped (below) whatever it
        // measured: it stopped as soon as that was known.
        Ok(None) => return Ok((first, false)),
        Err(e) => {
            let mut out = first;
            out.notes.push(format!("no {} pass: {e}", ordinal(pass)));
            return Ok((out, false));
        }
    };
    let score = fit_score;
    if score(&second) < score(&first) - 1e-9 || second.deformation.stats.changed_cells == 0 {
        return Ok((first, false));
    }
    let total = compose(dem, d1, &second.deformation)?;
    // Each pass's change is free of spikes, but their sum need not be
    // (issue 11, item 5): a pass that adds one is dropped.
    if find_spikes(&total).len() > find_spikes(d1).len() {
        return Ok((first, false));
    }
    let mut out = first;
    let (f1, f2) = (score(&out), score(&second));
    for (v1, v2) in out.views.iter_mut().zip(second.views) {
        for (s1, s2) in v1.strokes.iter_mut().zip(v2.strokes) {
            s1.fit = s2.fit;
            s1.visible_fraction = s2.visible_fraction;
            s1.status = s2.status;
            s1.reason = s2.reason;
        }
        v1.lowering_iterations += v2.lowering_iterations;
        v1.silhouettes_lowered += v2.silhouettes_lowered;
        v1.contour_iterations += v2.contour_iterations;
    }
    out.lowering_constraints += second.lowering_constraints;
    out.renders = second.renders;
    out.notes.push(format!(
        "a {} pass over the strokes the {} left unfitted, on the terrain it made, took their summed fit from {f1:.3} to {f2:.3}",
        ordinal(pass),
        if pass == 2 { "first" } else { "passes before" }
    ));
    out.deformation = total;
    Ok((out, true))
}

/// The most passes of one edit: the first and the later ones over the
/// strokes the passes before left unfitted ([`second_pass`]).
pub const MAX_PASSES: usize = 4;

/// "second", "third", ...: the name of pass `n` in the report's notes.
fn ordinal(n: usize) -> String {
    match n {
        1 => "first".to_string(),
        2 => "second".to_string(),
        3 => "third".to_string(),
        4 => "fourth".to_string(),
        n => format!("{n}th"),
    }
}

/// `d` with each changed cell's displacement made what the write stores:
/// the edited height quantized to `dem`'s sample type (an integer DEM
/// stores whole units), so that a second pass sees the terrain exactly as
/// editing the written output again would.
fn quantized(dem: &Dem, d: &Deformation) -> Deformation {
    let mut q = d.clone();
    let (st, v) = (dem.sample_type, &dem.vertical);
    for (m, &h) in q.displacement.iter_mut().zip(&d.base.data) {
        if *m != 0.0 && !m.is_nan() && !h.is_nan() {
            let stored = v.to_metres(st.quantize(v.to_raw(h as f64 + *m as f64)));
            *m = (stored - h as f64) as f32;
        }
    }
    q.stats.recount(&q.displacement);
    q
}

/// The deformation `a` followed by `b` (computed on the terrain `a` made)
/// as one deformation of `dem`: the union of their windows, the sum of
/// their displacements, either's constrained cells.
fn compose(dem: &Dem, a: &Deformation, b: &Deformation) -> Result<Deformation, EditError> {
    let (wa, wb) = (a.window, b.window);
    let (c0, r0) = (wa.col.min(wb.col), wa.row.min(wb.row));
    let (c1, r1) = (
        wa.col_end().max(wb.col_end()),
        wa.row_end().max(wb.row_end()),
    );
    let window = Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize);
    let base = dem.read_height_map(window)?;
    let mut displacement = vec![0.0f32; window.len()];
    let mut constrained = vec![false; window.len()];
    for d in [a, b] {
        let w = d.window;
        for r in 0..w.height {
            for c in 0..w.width {
                let k = r * w.width + c;
                let j = ((w.row - r0) as usize + r) * window.width + (w.col - c0) as usize + c;
                displacement[j] += d.displacement[k];
                constrained[j] |= d.constrained[k];
            }
        }
    }
    for (m, h) in displacement.iter_mut().zip(&base.data) {
        if h.is_nan() {
            *m = f32::NAN;
        }
    }
    let mut stats = a.stats.clone();
    stats.recount(&displacement);
    stats.constrained_cells = constrained.iter().filter(|c| **c).count();
    stats.max_abs_constraint_m = a
        .stats
        .max_abs_constraint_m
        .max(b.stats.max_abs_constraint_m);
    stats.cycles += b.stats.cycles;
    stats.solve_s += b.stats.solve_s;
    Ok(Deformation {
        window,
        displacement,
        base,
        affected_tiles: dem.tiles_touching(&window),
        constrained,
        stats,
    })
}

/// The DEM cells around a view's eye that its observer's fixed ground can
/// take ([`observer_reach`]), within the square of the view distance, with
/// their offset in the DEM grid.
pub(super) struct EyeGround {
    map: HeightMap,
    offset: (i64, i64),
    /// The grid of the square of the view distance around the eye (as
    /// reading it would georeference it) and its offset in the DEM's: CRS
    /// points are turned into cells on it, as when the view read the whole
    /// square (the same cells to the last bit, where a point lies on a
    /// line between cell centres).
    grid: crate::raster::GeoTransform,
    grid_offset: (i64, i64),
}

/// Per view: the DEM around its viewpoint, its camera and the ground
/// around its eye.
type ViewScene = (Scene, Camera, EyeGround);

/// The inputs of an edit, read and checked ([`load_views`]).
struct Loaded {
    sketch: SketchFile,
    dem: Dem,
    /// Notes for the report, so far from preparing the strokes.
    notes: Vec<String>,
    /// Per view: its strokes, prepared for matching.
    prepared: Vec<Vec<Stroke>>,
    /// Per view: the DEM around its viewpoint, its camera and the ground
    /// around its eye.
    scenes: Vec<ViewScene>,
}

/// Stage 1, `load`: reads the sketch and opens the DEM, prepares every
/// view's strokes, and sets up each view on the DEM: its viewpoint
/// resolved, its camera built, and the DEM read where the camera can see
/// within the maximum view distance ([`Scene::open_wedge_lod`]: the box of its
/// horizontal wedge, not the whole square around the eye), plus the cells
/// around the eye its fixed ground can take ([`EyeGround`]). Refuses a viewpoint
/// whose absolute altitude is not above the ground. Everything later
/// stages read comes from here; nothing is rendered yet. `far`: per view,
/// the far rings of an earlier pass, taken where they serve (the same eye,
/// no changed cell within their reach) instead of being read again.
fn load_views(
    edit: &Edit,
    dem: Dem,
    sketch_path: &Path,
    far: &[FarLayers],
) -> Result<Loaded, EditError> {
    let sketch_name = &edit.sketch_name;
    edit.pb.set_message("loading DEM and sketch");
    let mut sketch = SketchFile::from_path(sketch_path)?;
    sketch.split_map_feature_strokes();
    let mut notes = Vec::new();
    let mut prepared = Vec::new();
    for v in &sketch.views {
        let (strokes, n) = v.prepared_strokes(&sketch.options, sketch_name)?;
        notes.extend(n);
        prepared.push(strokes);
    }
    check_view_sizes(edit, &dem, &sketch)?;
    let mut scenes = Vec::new();
    for (i, v) in sketch.views.iter().enumerate() {
        let vp = v.eye();
        let view_err = |source| EditError::View {
            sketch: sketch_name.clone(),
            view: v.name.clone(),
            source,
        };
        let camera = v.pinhole().map_err(|e| view_err(e.into()))?;
        let scene = Scene::open_wedge_lod(
            &dem,
            &vp,
            edit.max_d,
            edit.opts.refraction,
            &camera,
            far.get(i),
        )
        .map_err(view_err)?;
        if let EyeHeightSpec::Absolute(a) = v.viewpoint.height() {
            if a <= scene.frame.ground {
                return Err(EditError::Unusable {
                    sketch: sketch_name.clone(),
                    message: format!(
                        "view \"{}\": viewpoint alt_m {a} is not above the ground ({:.2} m) at the viewpoint",
                        v.name, scene.frame.ground
                    ),
                });
            }
        }
        let eye_ground = eye_ground(
            &dem,
            &scene,
            &vp,
            edit.max_d,
            sketch.options.observer_radius_m,
        )
        .map_err(view_err)?;
        scenes.push((scene, camera, eye_ground));
    }
    Ok(Loaded {
        sketch,
        dem,
        notes,
        prepared,
        scenes,
    })
}

/// Bytes of memory an edit takes per cell of its views' windows, at most
/// (measured: 45 on a 45.8 M-cell view at 100 km): the window read, the
/// view's terrain and cast index before the edit, the terrains of the
/// rounds' renders kept (the best, the latest and the current one), the
/// ridge detection's arrays.
pub const EDIT_BYTES_PER_CELL: u64 = 48;

/// The size limits of the stages after the load, checked before reading
/// any height (issue 15: the deformation's window limit used to be hit only
/// at a re-solve, after seconds of work and gigabytes): the windows every
/// view reads ([`Scene::wedge_cells`]: its window and its far rings), their union (where the ridges are
/// detected: at most 2^30 cells) and the memory the edit will take over
/// them ([`EDIT_BYTES_PER_CELL`] per cell) against the memory budget
/// ([`crate::raster::geotiff::memory_budget`]).
fn check_view_sizes(edit: &Edit, dem: &Dem, sketch: &SketchFile) -> Result<(), EditError> {
    let mut windows = Vec::new();
    let mut ring_cells = 0u64;
    for v in &sketch.views {
        let view_err = |source| EditError::View {
            sketch: edit.sketch_name.clone(),
            view: v.name.clone(),
            source,
        };
        let camera = v.pinhole().map_err(|e| view_err(e.into()))?;
        let (w, rings) =
            Scene::wedge_cells(dem, &v.eye(), edit.max_d, edit.opts.refraction, &camera)
                .map_err(view_err)?;
        windows.push(w);
        ring_cells = ring_cells.saturating_add(rings);
    }
    let Some(first) = windows.first() else {
        return Ok(());
    };
    let (mut c0, mut r0, mut c1, mut r1) = (first.col, first.row, first.col_end(), first.row_end());
    for w in &windows {
        c0 = c0.min(w.col);
        r0 = r0.min(w.row);
        c1 = c1.max(w.col_end());
        r1 = r1.max(w.row_end());
    }
    let union = ((c1 - c0) as u64).saturating_mul((r1 - r0) as u64);
    // (a far ring's cell costs a terrain's, not a window's: counted as one)
    let cells: u64 = windows.iter().map(|w| w.len() as u64).sum::<u64>() + ring_cells;
    let bytes = cells.saturating_mul(EDIT_BYTES_PER_CELL);
    let budget = crate::raster::geotiff::memory_budget();
    let distance = match edit.max_d {
        Some(d) => format!("--max-distance {d} m"),
        None => "the whole DEM (no --max-distance)".to_string(),
    };
    let message = if union >= 1 << 30 {
        format!(
            "the views see {union} cells within {distance} (ridge detection handles at most 2^30): lower --max-distance"
        )
    } else if bytes > budget {
        format!(
            "the views see {cells} cells within {distance}: the edit would take about {} MB, over the memory budget of {} MB (DEMSKETCH_MEMORY_BUDGET_MB): lower --max-distance",
            bytes >> 20,
            budget >> 20
        )
    } else {
        return Ok(());
    };
    Err(EditError::Unusable {
        sketch: edit.sketch_name.clone(),
        message,
    })
}

/// The views rendered before the edit, and the ridges around them
/// ([`render_and_extract`]).
struct Extracted<'a> {
    views: Vec<ViewState<'a>>,
    /// Per view: the heights of its window ([`ViewState::window`]).
    windows: Vec<HeightMap>,
    ridges: RidgeNetwork,
}

/// Stage 2, `features` (first half): renders every view of `sketch` on its
/// scene before the edit (exact depth buffer and silhouettes) and, side by
/// side, detects one ridge network over what all views see
/// ([`ridge_network`]); a view's render takes from `earlier` (the pass
/// before's last render of it, when there is one) the silhouettes it
/// refined already ([`RenderedView::from_terrain_after`]: the same
/// render). Pairs each render with its view's window, frame,
/// camera and prepared strokes into a [`ViewState`], which every later
/// stage works on, and refuses strokes drawn in empty sky
/// ([`check_strokes_touch_terrain`]).
fn render_and_extract<'a>(
    edit: &Edit,
    sketch: &'a SketchFile,
    dem: &Dem,
    scenes: Vec<ViewScene>,
    prepared: Vec<Vec<Stroke>>,
    earlier: Vec<RenderedView>,
) -> Result<Extracted<'a>, EditError> {
    edit.pb
        .set_message("rendering views, silhouettes and ridges");
    // The ridges and the views' renders are independent: computed side by
    // side, each also parallel inside.
    let mut parts = Vec::new();
    let mut terrains = Vec::new();
    for (scene, camera, eye_ground) in scenes {
        let Scene {
            window,
            window_offset,
            frame,
            terrain,
            ..
        } = scene;
        parts.push((window, window_offset, frame, camera, eye_ground));
        terrains.push((terrain, camera));
    }
    let windows: Vec<(&HeightMap, (i64, i64))> = parts.iter().map(|p| (&p.0, p.1)).collect();
    let seen: Vec<Window> = parts
        .iter()
        .zip(&terrains)
        .map(|(p, (t, _))| Window::new(p.1 .0 + t.col0 as i64, p.1 .1 + t.row0 as i64, t.nx, t.ny))
        .collect();
    let (ridges, befores) = rayon::join(
        || ridge_network(dem, &windows, &seen),
        || {
            terrains
                .into_iter()
                .enumerate()
                .map(|(k, (t, c))| RenderedView::from_terrain_after(t, &c, earlier.get(k)))
                .collect::<Vec<_>>()
        },
    );
    let ridges = ridges?;
    let mut views: Vec<ViewState> = Vec::new();
    let mut heights = Vec::new();
    for (((v, (window, window_offset, frame, camera, eye_ground)), strokes), before) in
        sketch.views.iter().zip(parts).zip(prepared).zip(befores)
    {
        let before = before
            .map_err(|e| EditError::Internal(format!("view \"{}\": features: {e}", v.name)))?;
        views.push(ViewState {
            spec: v,
            window_offset,
            eye_ground,
            frame,
            camera,
            strokes,
            before,
        });
        heights.push(window);
    }
    for v in &views {
        check_strokes_touch_terrain(v, dem, edit.max_d, &edit.sketch_name)?;
    }
    Ok(Extracted {
        views,
        windows: heights,
        ridges,
    })
}

/// The terrain features each view offers the strokes ([`scene_features`]).
struct Features<'v> {
    /// Per view: its projection and its silhouettes and ridges as seen.
    scene_views: Vec<SceneView<'v>>,
    /// Per view: how many of each kind, for the report.
    counts: Vec<FeatureCounts>,
}

/// Stage 2, `features` (second half): each view's silhouettes and the
/// ridges it sees, as the features its strokes are matched against
/// ([`SceneView`]); multi-view sketches in one world frame, the first
/// view's. Features are cut where they come within the observer's fixed
/// ground: no deformation may move it, so no free stroke part may be
/// placed there. Also counts them per view for the report.
fn scene_features<'v>(
    views: &'v [ViewState],
    ridges: &RidgeNetwork,
    options: &SketchOptions,
    skyline: bool,
) -> Features<'v> {
    // Multi-view sketches are matched in one world frame: the first view's.
    let world = (views.len() > 1).then(|| views[0].frame);
    let scene_views: Vec<SceneView> = views
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let mut p = SceneProjection::new(v.camera, &v.before.terrain);
            if let Some(w) = world {
                p = p.in_world_frame(w);
            }
            SceneView::build(
                &v.spec.name,
                k,
                p,
                &v.before.silhouettes,
                ridges,
                &ViewFeatureOptions {
                    min_depth_m: v.observer_radius(options.observer_radius_m),
                    skyline,
                    ..ViewFeatureOptions::default()
                },
            )
        })
        .collect();
    let counts: Vec<FeatureCounts> = scene_views
        .iter()
        .map(|sv| {
            let sil = sv
                .features
                .iter()
                .filter(|f| f.kind == crate::sketch::FeatureKind::Silhouette)
                .count();
            FeatureCounts {
                silhouettes: sil,
                ridges: sv.features.len() - sil,
            }
        })
        .collect();
    Features {
        scene_views,
        counts,
    }
}

/// The strokes matched and placed on the terrain ([`match_strokes`]).
pub(super) struct Placed {
    /// The joint matching of all views (the stroke points as placed).
    pub(super) matched: SketchMatch,
    /// What the placed strokes ask of the terrain.
    pub(super) demands: Demands,
    /// Per view, per stroke: why it cannot be fitted whatever the
    /// deformation does ([`placement_issue`]), if anything.
    pub(super) issues: Vec<Vec<Option<&'static str>>>,
    /// Per view: the part of the view the re-renders compute.
    pub(super) regions: Vec<StrokeRegion>,
}

/// Stage 3, `matching`: matches the strokes of all views jointly to the
/// views' features ([`match_sketch`]), notes depth-order conflicts and an
/// exhausted node budget, then places the strokes in 3D and turns them
/// into constraints in the DEM's CRS ([`place_demands`]). Also finds the
/// strokes that cannot be fitted whatever the deformation does and the
/// image regions the later re-renders need. Fails when no stroke could be
/// placed at all.
fn match_strokes(
    edit: &Edit,
    (options, dem): (&SketchOptions, &Dem),
    (views, windows, map_only): (&[ViewState], &[HeightMap], bool),
    features: &Features,
    notes: &mut Vec<String>,
) -> Result<Placed, EditError> {
    edit.pb.set_message("matching strokes to terrain features");
    let scene_views = &features.scene_views;
    let inputs: Vec<ViewInput> = views
        .iter()
        .zip(scene_views)
        .map(|(v, sv)| sv.input(v.strokes.clone()))
        .collect();
    let mut matched = match_sketch(&inputs, options).map_err(|source| EditError::Match {
        sketch: edit.sketch_name.clone(),
        source,
    })?;
    for (v, m) in views.iter().zip(&matched.views) {
        for c in &m.ordering.conflicts {
            notes.push(format!(
                "view \"{}\": depth order: {}",
                v.spec.name, c.message
            ));
        }
    }
    if matched.stopped_early {
        notes.push(format!(
            "matching: branch-and-bound stopped after its budget of {} nodes; the assignment is the best found within it (raise options.node_budget to search further)",
            matched.node_budget
        ));
    }
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        trace_candidates(&matched);
    }
    let demands = place_demands(views, windows, scene_views, &mut matched.views, options);
    notes.extend(depth_notes(views, &demands.strokes));
    let issues: Vec<Vec<Option<&'static str>>> = scene_views
        .iter()
        .zip(&matched.views)
        .map(|(sv, m)| {
            m.strokes
                .iter()
                .map(|sm| {
                    let all = sv.projection.placed_to_dem(&sm.points);
                    placement_issue(dem, &sm.points, &all, edit.max_d)
                })
                .collect()
        })
        .collect();
    // The part of each view the re-renders compute.
    let regions: Vec<StrokeRegion> = views
        .iter()
        .zip(&demands.strokes)
        .map(|(v, cs)| StrokeRegion::new(cs, v.camera.width, v.camera.height))
        .collect();
    // A sketch whose only strokes are those of its map features' landforms
    // (`map_only`: taken out of the views) edits through those alone.
    if !map_only
        && demands
            .strokes
            .iter()
            .flatten()
            .all(|c| c.depths.is_empty())
    {
        return Err(EditError::Unusable {
            sketch: edit.sketch_name.clone(),
            message: "no stroke could be placed on the terrain".into(),
        });
    }
    Ok(Placed {
        matched,
        demands,
        issues,
        regions,
    })
}

/// Under `DEMSKETCH_DEBUG`: the best candidates of every stroke, with
/// their depths and costs, on stderr.
fn trace_candidates(matched: &SketchMatch) {
    for m in &matched.views {
        for (k, l) in m.lists.iter().enumerate() {
            for c in l.candidates.iter().take(6) {
                let d: Vec<f64> = c.points.iter().map(|p| p.depth).collect();
                eprintln!(
                    "stroke {k}: feature {} {:?} depth {:.0}..{:.0} cost {:.2} = dis {:.2} def {:.2} sam {:.2} ext {:.2} cov {:.2}",
                    c.feature_id % (1 << 40),
                    c.kind,
                    d.iter().cloned().fold(f64::INFINITY, f64::min),
                    d.iter().cloned().fold(0.0, f64::max),
                    c.costs.total,
                    c.costs.dissimilarity,
                    c.costs.deformation,
                    c.costs.sampling,
                    c.costs.extension,
                    c.coverage
                );
            }
        }
    }
}

/// Stage 4, `deformation`: the initial solve. Sets up the [`Solver`] every
/// later solve goes through (the DEM, the sketch's influence radius, the
/// cells held fixed) and deforms the DEM through the placed strokes'
/// curve constraints alone; the refinement rounds
/// ([`super::rounds::refine`]) start from this terrain.
fn deform<'a>(
    edit: &Edit,
    dem: &'a Dem,
    dem_name: &'a str,
    options: &SketchOptions,
    views: &[ViewState],
    placed: &'a Placed,
) -> Result<(Solver<'a>, Deformation), EditError> {
    edit.pb.set_message("deforming the DEM (multigrid)");
    let solver = Solver {
        dem,
        dem_name,
        opts: DeformOptions {
            influence_m: options.influence_m,
            ..DeformOptions::default()
        },
        fixed: &placed.demands.fixed,
        idle: views[0].eye_cell(),
    };
    let deformation = solver.solve(&placed.demands.curves, &[])?;
    Ok((solver, deformation))
}

/// After the refinement rounds, the sketch's map-view corrections (its
/// `corrections` member) on the terrain they gave
/// ([`crate::correct::in_sketch`]: in turn, not in one solve, and why);
/// the views are rendered again on the result, so the strokes are measured
/// on the terrain that is written.
fn apply_corrections(
    edit: &Edit,
    dem: &Dem,
    sketch: &SketchFile,
    views: &[ViewState],
    placed: &Placed,
    rounds: &mut Rounds,
) -> Result<Vec<crate::correct::FeatureReport>, EditError> {
    let Some(collection) = &sketch.corrections else {
        return Ok(Vec::new());
    };
    edit.pb.set_message("map-view corrections");
    let name = format!("{}: map_features", edit.sketch_name);
    // Landforms place their strokes on the views as the file gives them.
    let full = SketchFile {
        views: sketch
            .map_feature_views
            .clone()
            .unwrap_or_else(|| sketch.views.clone()),
        options: sketch.options.clone(),
        corrections: None,
        map_feature_views: None,
    };
    let (deformation, reports) = crate::correct::in_sketch::apply_after_edit(
        dem,
        collection,
        &name,
        (&full, &edit.sketch_name),
        &rounds.deformation,
        crate::correct::MAX_WINDOW_CELLS,
    )
    .map_err(|e| match e {
        crate::correct::CorrectError::Raster(r) => EditError::Raster(r),
        crate::correct::CorrectError::Internal(m) => EditError::Internal(m),
        crate::correct::CorrectError::Input(message) => EditError::Unusable {
            sketch: edit.sketch_name.clone(),
            message: message
                .strip_prefix(&format!("{}: ", edit.sketch_name))
                .unwrap_or(&message)
                .to_string(),
        },
    })?;
    rounds.rendered = views
        .iter()
        .zip(&placed.regions)
        .map(|(v, r)| render_edited(v, &deformation, Some(r)))
        .collect::<Result<_, _>>()?;
    rounds.deformation = deformation;
    Ok(reports)
}

/// Stage 5, `lowering` (last step): measures on the final terrain of the
/// refinement rounds how well each view shows each of its strokes (fit and
/// visibility, [`measure`]), decides each stroke's status against
/// `--min-fit` ([`stroke_outcome`]), and assembles the per-view reports
/// with the matching, the placement and the rounds' counts. The write
/// stage gates on these statuses.
fn measure_strokes(
    edit: &Edit,
    views: &[ViewState],
    features: &Features,
    placed: &Placed,
    rounds: &Rounds,
) -> Vec<ViewReport> {
    let demands = &placed.demands;
    let mut view_reports = Vec::new();
    for (((k, v), m), after) in views
        .iter()
        .enumerate()
        .zip(&placed.matched.views)
        .zip(&rounds.rendered)
    {
        let strokes = demands.strokes[k]
            .par_iter()
            .zip(&m.strokes)
            .zip(&placed.issues[k])
            .enumerate()
            .map(|(j, ((c, sm), issue))| {
                let (fit, visible) = measure(c, after);
                let cells = free_cells_across(c, after);
                let (status, reason) =
                    stroke_outcome(&fit, visible, *issue, cells, edit.opts.min_fit);
                let (lo, hi) = c.depths.iter().fold((f64::INFINITY, 0.0f64), |(a, b), d| {
                    (a.min(d.1), b.max(d.1))
                });
                StrokeReport {
                    id: c.id.clone(),
                    source_id: c.source_id.clone(),
                    matched: MatchReport {
                        kind: sm.kind,
                        feature_id: sm.feature_id,
                        cost: sm.costs.map(|c| c.total),
                        depth_rank: sm.depth_rank,
                        depth_m: [if lo.is_finite() { lo } else { 0.0 }, hi],
                    },
                    fit,
                    visible_fraction: visible,
                    status,
                    reason,
                    on_silhouette: demands.on_silhouette[k][j],
                    placement: demands.placement[k][j],
                    placed_curve: placed_curve(&features.scene_views[k], sm),
                }
            })
            .collect();
        view_reports.push(ViewReport {
            name: v.spec.name.clone(),
            eye_alt_m: v.frame.eye_alt,
            strokes,
            lowering_iterations: rounds.lowering_iterations[k],
            silhouettes_lowered: rounds.silhouettes_lowered[k],
            contour_iterations: rounds.contour_iterations[k],
            features: features.counts[k],
            matching_stopped_early: placed.matched.stopped_early,
        });
    }
    view_reports
}

/// A placed stroke's points in the DEM's CRS (absolute heights), for the
/// report: the finite ones, rounded to the millimetre.
fn placed_curve(sv: &SceneView, sm: &crate::sketch::StrokeMatch) -> Vec<[f64; 3]> {
    sv.projection
        .placed_to_dem(&sm.points)
        .into_iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .map(|p| p.map(|v| (v * 1000.0).round() / 1000.0))
        .collect()
}

/// Why a placed stroke cannot be fitted whatever the deformation does, if
/// anything: `points` its placed points, `dem_points` the same in the DEM's
/// CRS (absolute heights).
fn placement_issue(
    dem: &Dem,
    points: &[crate::sketch::PlacedPoint],
    dem_points: &[[f64; 3]],
    max_d: Option<f64>,
) -> Option<&'static str> {
    use crate::sketch::PointSource;
    let on_stroke = |p: &&crate::sketch::PlacedPoint| p.source != PointSource::Completion;
    if points.iter().filter(on_stroke).count() == 0 {
        return Some("could not be placed on the terrain");
    }
    if points
        .iter()
        .filter(on_stroke)
        .any(|p| p.pixel.is_none() || !(p.depth > 0.0))
    {
        return Some("behind the eye");
    }
    let outside = points.iter().zip(dem_points).any(|(p, q)| {
        on_stroke(&p)
            && match dem.geotransform.crs_to_pixel(q[0], q[1]) {
                Some((px, py)) if q.iter().all(|c| c.is_finite()) => {
                    !(px >= 0.0 && py >= 0.0 && px < dem.width as f64 && py < dem.height as f64)
                }
                _ => true,
            }
    });
    if outside {
        return Some("outside the DEM");
    }
    if let Some(d) = max_d {
        if points.iter().filter(on_stroke).any(|p| p.depth > d) {
            return Some("beyond --max-distance");
        }
    }
    None
}

/// Notes for the strokes whose `depth_m` (the author's distance) the
/// placement did not follow: placement does not use `depth_m` yet, it only
/// lifts the refusal of strokes drawn in empty sky
/// ([`check_strokes_touch_terrain`]); the report says where they went.
fn depth_notes(views: &[ViewState], curves: &[Vec<StrokeCurve>]) -> Vec<String> {
    let mut out = Vec::new();
    for (v, cs) in views.iter().zip(curves) {
        for c in cs {
            let Some(spec) = v.spec.strokes.get(c.stroke.source_index) else {
                continue;
            };
            let Some(d) = spec.depth_m else { continue };
            let [near, far] = d.range();
            let (lo, hi) = c.depths.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
                (a.min(p.1), b.max(p.1))
            });
            // Within 10 % of the range given counts as followed.
            if lo.is_finite() && lo >= 0.9 * near && hi <= 1.1 * far {
                continue;
            }
            out.push(format!(
                "view \"{}\" stroke \"{}\": placed at {:.0} to {:.0} m, not at its depth_m {near}..{far} m (placement does not use depth_m yet)",
                v.spec.name, c.id, if lo.is_finite() { lo } else { 0.0 }, hi
            ));
        }
    }
    out
}

/// Under this many DEM cells across, a stroke's free stretch is finer
/// than the DEM can draw at the depth it was placed: a bilinear cell shows
/// at most one bend of a silhouette.
const SUB_CELL_STRETCH_CELLS: f64 = 2.0;

/// How many DEM cells the free (not anchored) stretch of `c` spans at the
/// median depth it was placed, in `view`: `(cells, depth)`; `None` when
/// the stroke has no free stretch.
fn free_cells_across(c: &StrokeCurve, view: &RenderedView) -> Option<(f64, f64)> {
    let free: Vec<(f64, f64)> = c
        .depths
        .iter()
        .zip(&c.anchored)
        .filter(|(_, &a)| !a)
        .map(|(&d, _)| d)
        .filter(|d| d.0.is_finite() && d.1.is_finite() && d.1 > 0.0)
        .collect();
    let (first, last) = (free.first()?, free.last()?);
    let mut depths: Vec<f64> = free.iter().map(|d| d.1).collect();
    depths.sort_by(f64::total_cmp);
    let depth = depths[depths.len() / 2];
    let px = view.cell_px(depth);
    (px.is_finite() && px > 0.0).then(|| ((last.0 - first.0).abs() / px, depth))
}

/// A stroke's status and, when it is not fitted, why. `cells`: how many
/// DEM cells its free stretch spans at the depth it was placed
/// ([`free_cells_across`]).
fn stroke_outcome(
    fit: &super::fit::StrokeFit,
    visible: f64,
    issue: Option<&'static str>,
    cells: Option<(f64, f64)>,
    min_fit: f64,
) -> (StrokeStatus, Option<String>) {
    let f = fit.fitted_fraction;
    if f >= min_fit {
        return (StrokeStatus::Fitted, None);
    }
    let status = if f > 0.0 {
        StrokeStatus::Partial
    } else {
        StrokeStatus::Unfitted
    };
    let below = format!("fit {f:.2} below --min-fit {min_fit}");
    let reason = match issue {
        Some(i) => format!("{i}; {below}"),
        None if visible < min_fit.min(1.0) => {
            format!("hidden by nearer terrain (visible {visible:.2}); {below}")
        }
        None => match cells {
            Some((n, depth)) if n < SUB_CELL_STRETCH_CELLS => format!(
                "its free stretch spans {n:.1} DEM cells at the depth it was placed ({depth:.0} m): \
                 finer than the DEM can draw there; {below}"
            ),
            _ => below,
        },
    };
    (status, Some(reason))
}

/// Refuse a stroke (without `depth_m`) whose end points both lie in empty
/// sky in the view before the edit, with no terrain close under them
/// ([`TERRAIN_TOUCH_SHARE`]): nothing says how far it is. Names the
/// view and the stroke, and whether the terrain lies beyond
/// `--max-distance` or nowhere on the DEM.
fn check_strokes_touch_terrain(
    v: &ViewState,
    dem: &Dem,
    max_d: Option<f64>,
    sketch: &str,
) -> Result<(), EditError> {
    let depth = &v.before.depth;
    let (w, h) = (v.camera.width, v.camera.height);
    let touches = |p: [f64; 2]| -> bool {
        let i0 = (p[0].floor() as i64).clamp(0, w as i64 - 1);
        let j0 = (p[1].floor() as i64).clamp(0, h as i64 - 1);
        let rows = (TERRAIN_TOUCH_SHARE * h as f64)
            .max(TERRAIN_TOUCH_PX)
            .ceil() as i64;
        (i0 - 1..=i0 + 1).any(|i| {
            (j0 - 1..=j0 + rows)
                .any(|j| i >= 0 && j >= 0 && depth.depth_at(i as usize, j as usize).is_finite())
        }) || (j0 + rows >= h as i64
            // Under the image's lower border: the stroke is cut by the frame.
            && v.before.terrain_at_or_below(p, rows as f64).is_some())
    };
    for s in &v.spec.strokes {
        if s.depth_m.is_some() {
            continue;
        }
        let (Some(&a), Some(&b)) = (s.points.first(), s.points.last()) else {
            continue;
        };
        if touches(a) || touches(b) {
            continue;
        }
        // Would the DEM go on beyond --max-distance along the end's ray?
        let beyond = max_d.is_some_and(|d| {
            [a, b].iter().any(|p| {
                let r = v.camera.ray(p[0], p[1]);
                let n = r[0].hypot(r[1]);
                if n <= 0.0 {
                    return false;
                }
                let (x, y) = v.frame.en_to_crs(r[0] / n * d, r[1] / n * d);
                dem.geotransform.crs_to_pixel(x, y).is_some_and(|(px, py)| {
                    px >= 0.0 && py >= 0.0 && px < dem.width as f64 && py < dem.height as f64
                })
            })
        });
        let problem = match (beyond, max_d) {
            (true, Some(d)) => format!(
                "the rays through its end points hit no terrain within --max-distance {d} m (the DEM goes on beyond it): raise --max-distance, or give the stroke's depth_m"
            ),
            _ => "drawn in empty sky: the rays through its end points hit no terrain of the DEM; give the stroke's depth_m (distance from the eye, metres) to place it".to_string(),
        };
        return Err(EditError::Unusable {
            sketch: sketch.to_string(),
            message: format!("view \"{}\" stroke \"{}\": {problem}", v.spec.name, s.id),
        });
    }
    Ok(())
}

/// What the placed strokes ask of the terrain.
pub(super) struct Demands {
    /// Curve constraints: the stretches of placed strokes that do not lie
    /// on a silhouette already ([`super::on_silhouette`]).
    pub(super) curves: Vec<CurveConstraint>,
    /// Cells held at their input heights: under anchored stroke points and
    /// around every viewpoint. Applied after every other constraint, so
    /// nothing in the edit moves them.
    pub(super) fixed: Vec<CellConstraint>,
    /// Per view, per stroke: the placed stroke.
    pub(super) strokes: Vec<Vec<StrokeCurve>>,
    /// Per view, per stroke: share of its points on an existing silhouette.
    pub(super) on_silhouette: Vec<Vec<f64>>,
    /// Per view, per stroke: how its free stretches were placed.
    pub(super) placement: Vec<Vec<StretchPlacement>>,
}

/// Anchors the matched strokes where they already lie on a silhouette and
/// turns the rest into curve constraints in the DEM's CRS; adds the
/// observer's ground.
fn place_demands(
    views: &[ViewState],
    windows: &[HeightMap],
    scene_views: &[SceneView],
    matched: &mut [crate::sketch::ViewMatch],
    options: &SketchOptions,
) -> Demands {
    let mut d = Demands {
        curves: Vec::new(),
        fixed: Vec::new(),
        strokes: Vec::new(),
        on_silhouette: Vec::new(),
        placement: Vec::new(),
    };
    let mut held = Vec::new();
    for (((v, w), sv), m) in views
        .iter()
        .zip(windows)
        .zip(scene_views)
        .zip(matched.iter_mut())
    {
        let mut cs = Vec::new();
        let mut fractions = Vec::new();
        let mut placements = Vec::new();
        for (s, sm) in v.strokes.iter().zip(m.strokes.iter_mut()) {
            fractions.push(anchor_on_silhouettes(&v.before, &sv.projection, sm));
            placements.push(place_free_stretches(
                &v.before,
                &sv.projection,
                &sv.features,
                v.observer_radius(options.observer_radius_m),
                sm,
            ));
            if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
                for p in &sm.points {
                    if let Some(px) = p.pixel {
                        eprintln!(
                            "placed {} x {:.1} y {:.1} depth {:.0} {:?}",
                            s.id, px[0], px[1], p.depth, p.source
                        );
                    }
                }
            }
            let dem_points = sv.projection.placed_to_dem(&sm.points);
            let anchored: Vec<bool> = sm
                .points
                .iter()
                .map(|p| p.source == PointSource::Silhouette)
                .collect();
            let depths: Vec<f64> = sm.points.iter().map(|p| p.depth).collect();
            d.curves
                .extend(free_stretches(&dem_points, &depths, &anchored));
            for (p, _) in dem_points.iter().zip(&anchored).filter(|(_, &a)| a) {
                held.extend(v.stencil_cells(w, p[0], p[1]));
            }
            cs.push(StrokeCurve::new(s, sm));
        }
        d.strokes.push(cs);
        d.on_silhouette.push(fractions);
        d.placement.push(placements);
    }
    // Cells under anchored points are held, except next to a free
    // stretch: on a coarse DEM one cell spans many pixels of a stroke, and
    // holding it would keep the free stretch beside it from rising. There
    // the free stretch's own curve, which starts on the anchor, decides.
    if let Some(v) = views.first() {
        let near = cells_near_curves(v, &d.curves, ANCHOR_CLEARANCE_CELLS);
        d.fixed
            .extend(held.into_iter().filter(|c| !near.contains(&(c.col, c.row))));
    }
    for (v, w) in views.iter().zip(windows) {
        d.fixed
            .extend(v.observer_cells(w, options.observer_radius_m));
    }
    d
}

/// Anchored cells within this many cells of a free stretch are not held.
pub const ANCHOR_CLEARANCE_CELLS: i64 = 2;

/// The DEM cells (whole-DEM grid, through `v`'s window) within `reach`
/// cells of the curves' points and of the segments between them.
fn cells_near_curves(
    v: &ViewState,
    curves: &[CurveConstraint],
    reach: i64,
) -> std::collections::HashSet<(i64, i64)> {
    let gt = &v.eye_ground.grid;
    let mut near = std::collections::HashSet::new();
    let mut mark = |x: f64, y: f64| {
        if let Some((c, r)) = v.cell_of(x, y) {
            for dr in -reach..=reach + 1 {
                for dc in -reach..=reach + 1 {
                    near.insert((c + dc, r + dr));
                }
            }
        }
    };
    for curve in curves {
        for w in curve.points.windows(2) {
            let (a, b) = (w[0], w[1]);
            // Half-cell steps along the segment.
            let steps = gt
                .crs_to_pixel(a[0], a[1])
                .zip(gt.crs_to_pixel(b[0], b[1]))
                .map(|(p, q)| (2.0 * (q.0 - p.0).hypot(q.1 - p.1)).ceil() as usize)
                .unwrap_or(1)
                .clamp(1, 10_000);
            for k in 0..=steps {
                let t = k as f64 / steps as f64;
                mark(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
            }
        }
        if let [p] = curve.points.as_slice() {
            mark(p[0], p[1]);
        }
    }
    near
}

/// Neighbouring points of a placed stroke whose depths differ by more than
/// this fraction are not joined by a curve constraint: the stroke passes
/// from one landform to another there (a segment between them would be a
/// wall across the ground in between).
pub const DEPTH_BREAK: f64 = 0.15;

/// The stretches of a placed stroke (DEM CRS points, with their depths)
/// between anchored points, each with the anchored point on either side
/// where its depth continues the stretch, so that the curve meets the
/// terrain it continues; cut where the depth jumps ([`DEPTH_BREAK`]).
fn free_stretches(points: &[[f64; 3]], depths: &[f64], anchored: &[bool]) -> Vec<CurveConstraint> {
    let finite = |p: &[f64; 3]| p.iter().all(|c| c.is_finite());
    let joined = |i: usize, j: usize| {
        let (a, b) = (depths[i], depths[j]);
        (a - b).abs() <= DEPTH_BREAK * a.min(b)
    };
    let mut out = Vec::new();
    let n = points.len();
    let mut a = 0;
    while a < n {
        if anchored[a] {
            a += 1;
            continue;
        }
        let mut b = a;
        while b < n && !anchored[b] {
            b += 1;
        }
        let lo = if a > 0 && joined(a - 1, a) { a - 1 } else { a };
        let hi = if b < n && joined(b - 1, b) { b } else { b - 1 };
        let mut piece: Vec<[f64; 3]> = Vec::new();
        for k in lo..=hi {
            if k > lo && !joined(k - 1, k) {
                if piece.len() >= 2 {
                    out.push(CurveConstraint {
                        points: std::mem::take(&mut piece),
                    });
                }
                piece.clear();
            }
            if finite(&points[k]) {
                piece.push(points[k]);
            }
        }
        if piece.len() >= 2 {
            out.push(CurveConstraint { points: piece });
        }
        a = b;
    }
    out
}

/// The solves of one edit: the DEM, the options, and the cells held fixed
/// in every solve.
pub(super) struct Solver<'a> {
    dem: &'a Dem,
    dem_name: &'a str,
    opts: DeformOptions,
    fixed: &'a [CellConstraint],
    /// Window of the deformation when nothing needs to move.
    idle: Window,
}

impl Solver<'_> {
    /// `d` as the write will store it ([`quantized`]) when the DEM's
    /// sample type is an integer one; `None` on a floating-point DEM,
    /// which stores the heights as solved.
    pub(super) fn as_written(&self, d: &Deformation) -> Option<Deformation> {
        self.dem
            .sample_type
            .is_integer()
            .then(|| quantized(self.dem, d))
    }

    /// Deform the DEM through `curves` with the cells `cells` (then the
    /// fixed ones) held; no curve: no deformation at all.
    pub(super) fn solve(
        &self,
        curves: &[CurveConstraint],
        cells: &[CellConstraint],
    ) -> Result<Deformation, EditError> {
        let err = |e: DeformError| match e {
            DeformError::Raster(r) => EditError::Raster(r),
            source => EditError::Deform {
                dem: self.dem_name.to_string(),
                source,
            },
        };
        if curves.is_empty() {
            return Deformation::none(self.dem, self.idle).map_err(err);
        }
        let all: Vec<CellConstraint> = cells.iter().chain(self.fixed).copied().collect();
        deform_with_cells(self.dem, curves, &all, &self.opts).map_err(err)
    }
}

impl ViewState<'_> {
    /// The DEM cell under the eye, as a one-cell window.
    fn eye_cell(&self) -> Window {
        let (ex, ey) = self.frame.eye_pixel;
        Window::new(
            self.window_offset.0 + ex.floor() as i64,
            self.window_offset.1 + ey.floor() as i64,
            1,
            1,
        )
    }

    /// The cells of the bilinear stencil of DEM CRS point `(x, y)`, held
    /// at their input heights (`window`: the view's window's heights).
    fn stencil_cells(&self, window: &HeightMap, x: f64, y: f64) -> Vec<CellConstraint> {
        let Some((c0, r0)) = self.cell_of(x, y) else {
            return Vec::new();
        };
        [(c0, r0), (c0 + 1, r0), (c0, r0 + 1), (c0 + 1, r0 + 1)]
            .into_iter()
            .filter_map(|(c, r)| self.held_cell(window, c, r))
            .collect()
    }

    /// The DEM cell (whole-DEM grid) whose centre is the upper left one of
    /// the bilinear stencil of CRS point `(x, y)`, found on the grid of the
    /// square around the eye ([`EyeGround::grid`]).
    fn cell_of(&self, x: f64, y: f64) -> Option<(i64, i64)> {
        let (px, py) = self.eye_ground.grid.crs_to_pixel(x, y)?;
        let off = self.eye_ground.grid_offset;
        Some((
            (px - 0.5).floor() as i64 + off.0,
            (py - 0.5).floor() as i64 + off.1,
        ))
    }

    /// DEM cell `(col, row)` (whole-DEM grid) held at its input height;
    /// `None` outside the window and the eye's ground ([`EyeGround`]), or
    /// on nodata.
    fn held_cell(&self, window: &HeightMap, col: i64, row: i64) -> Option<CellConstraint> {
        let at = |map: &HeightMap, off: (i64, i64)| {
            let (x, y) = (col - off.0, row - off.1);
            (x >= 0 && y >= 0 && (x as usize) < map.width && (y as usize) < map.height)
                .then(|| map.get(x as usize, y as usize))
        };
        let h = at(window, self.window_offset)
            .or_else(|| at(&self.eye_ground.map, self.eye_ground.offset))??;
        Some(CellConstraint {
            col,
            row,
            height: h as f64,
        })
    }

    /// The radius of the observer's fixed ground: `radius_m` (the sketch's
    /// `observer_radius_m`), else [`OBSERVER_RADIUS_M`] and at least two
    /// cells.
    fn observer_radius(&self, radius_m: Option<f64>) -> f64 {
        observer_radius(&self.frame, radius_m)
    }

    /// The ground the observer stands on: every cell whose surface reaches
    /// within `radius_m` of the viewpoint (default 100 m, at least two
    /// cells), held at its input height.
    fn observer_cells(&self, window: &HeightMap, radius_m: Option<f64>) -> Vec<CellConstraint> {
        let Some((reach, nc, nr)) = observer_reach(&self.frame, radius_m) else {
            return Vec::new();
        };
        let (ex, ey) = self.frame.eye_pixel;
        let (c_eye, r_eye) = (ex.floor() as i64, ey.floor() as i64);
        let mut out = Vec::new();
        for r in r_eye - nr..=r_eye + nr {
            for c in c_eye - nc..=c_eye + nc {
                let (e, n) = self.frame.pixel_to_en(c as f64 + 0.5, r as f64 + 0.5);
                if e.hypot(n) > reach {
                    continue;
                }
                out.extend(self.held_cell(
                    window,
                    c + self.window_offset.0,
                    r + self.window_offset.1,
                ));
            }
        }
        out
    }
}

/// Metres per cell along the columns and rows of the grid `frame` is on.
fn cell_m(frame: &LocalFrame) -> (f64, f64) {
    let p = frame.p;
    (p[0][0].hypot(p[1][0]), p[0][1].hypot(p[1][1]))
}

/// See [`ViewState::observer_radius`].
fn observer_radius(frame: &LocalFrame, radius_m: Option<f64>) -> f64 {
    let (hx, hy) = cell_m(frame);
    radius_m.unwrap_or(OBSERVER_RADIUS_M.max(2.0 * hx.max(hy)))
}

/// How far the observer's fixed ground reaches ([`ViewState::observer_cells`]):
/// metres from the viewpoint, and cells across and down either side of the
/// eye's cell; `None` when nothing is held.
fn observer_reach(frame: &LocalFrame, radius_m: Option<f64>) -> Option<(f64, i64, i64)> {
    let (hx, hy) = cell_m(frame);
    let radius = observer_radius(frame, radius_m);
    if !(hx > 0.0 && hy > 0.0 && radius.is_finite()) {
        return None;
    }
    let reach = radius + hx.hypot(hy);
    Some((
        reach,
        (reach / hx).ceil() as i64 + 1,
        (reach / hy).ceil() as i64 + 1,
    ))
}

/// The cells around `scene`'s eye that its observer's fixed ground can take
/// ([`observer_reach`]), within the square of the view distance around the
/// viewpoint (the cells a view could hold before it read only its wedge):
/// read from `dem` (a few hundred cells by default).
fn eye_ground(
    dem: &Dem,
    scene: &Scene,
    vp: &crate::view::Viewpoint,
    max_d: Option<f64>,
    radius_m: Option<f64>,
) -> Result<EyeGround, crate::render::RenderError> {
    let square = Scene::window_of(dem, &scene.georef, vp.lon, vp.lat, max_d)?;
    let grid = dem
        .geotransform
        .offset(square.col as f64, square.row as f64);
    let empty = || EyeGround {
        map: scene.window.crop(0, 0, 0, 0),
        offset: (0, 0),
        grid,
        grid_offset: (square.col, square.row),
    };
    let Some((_, nc, nr)) = observer_reach(&scene.frame, radius_m) else {
        return Ok(empty());
    };
    let (ex, ey) = scene.frame.eye_pixel;
    let (c, r) = (
        scene.window_offset.0 + ex.floor() as i64,
        scene.window_offset.1 + ey.floor() as i64,
    );
    let around = Window::new(c - nc, r - nr, (2 * nc + 1) as usize, (2 * nr + 1) as usize);
    let Some(w) = around.intersect(&square) else {
        return Ok(empty());
    };
    Ok(EyeGround {
        map: dem.read_height_map(w)?,
        offset: (w.col, w.row),
        grid,
        grid_offset: (square.col, square.row),
    })
}

/// Fail early, before any work, when an output cannot be written: its
/// parent directory must exist (write-back checks the rest).
fn check_output_paths(opts: &EditOptions) -> Result<(), EditError> {
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

/// Ridge network of the DEM over the union of what the views see (their
/// terrains' extents, given as windows in the DEM grid) within the windows
/// read for them (with their offsets in the DEM grid): one network, so that
/// a ridge seen from two views is one feature; ridges beyond every view's
/// field of view could match no stroke.
fn ridge_network(
    dem: &Dem,
    windows: &[(&HeightMap, (i64, i64))],
    seen: &[Window],
) -> Result<RidgeNetwork, EditError> {
    let Some(first) = seen.first() else {
        return Ok(RidgeNetwork::default());
    };
    let (mut c0, mut r0, mut c1, mut r1) = (first.col, first.row, first.col_end(), first.row_end());
    for w in seen {
        c0 = c0.min(w.col);
        r0 = r0.min(w.row);
        c1 = c1.max(w.col_end());
        r1 = r1.max(w.row_end());
    }
    let union = Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize);
    // Within one window read already (always, for one view): cropped from
    // it; else read from the DEM.
    let inside = windows.iter().find(|(map, off)| {
        Window::new(off.0, off.1, map.width, map.height).intersect(&union) == Some(union)
    });
    // The whole of one window (one view whose terrain is all of its wedge's
    // box): the window itself, no copy.
    let map = match inside {
        Some((map, off))
            if (off.0, off.1, map.width, map.height)
                == (union.col, union.row, union.width, union.height) =>
        {
            std::borrow::Cow::Borrowed(*map)
        }
        Some((map, off)) => std::borrow::Cow::Owned(map.crop(
            (union.col - off.0) as usize,
            (union.row - off.1) as usize,
            union.width,
            union.height,
        )),
        None => std::borrow::Cow::Owned(dem.read_height_map(union)?),
    };
    detect_ridges(&map, &RidgeParams::default())
        .map_err(|e| EditError::Internal(format!("ridges: {e}")))
}

/// Render a view on the DEM with the deformation applied: only `region` of
/// it ([`StrokeRegion`]), or the whole view. The terrain is the view's
/// terrain before the edit with the deformation's cells patched in
/// ([`edited_terrain`]): the view's window is neither copied nor
/// triangulated again.
pub(super) fn render_edited(
    v: &ViewState,
    d: &Deformation,
    region: Option<&StrokeRegion>,
) -> Result<RenderedView, EditError> {
    render_edited_after(v, d, region, None)
}

/// [`render_edited`], taking from `earlier` (an earlier render of the
/// same region of the view) what the terrain's change since cannot reach
/// ([`RenderedView::rerender_terrain_region`]): the same render, for less.
pub(super) fn render_edited_after(
    v: &ViewState,
    d: &Deformation,
    region: Option<&StrokeRegion>,
    earlier: Option<&RenderedView>,
) -> Result<RenderedView, EditError> {
    let terrain = edited_terrain(&v.before.terrain, v.window_offset, d);
    match (region, earlier) {
        (Some(r), Some(e)) => RenderedView::rerender_terrain_region(terrain, &v.camera, r, e),
        (Some(r), None) => RenderedView::render_terrain_region(terrain, &v.camera, r),
        (None, _) => RenderedView::from_terrain(terrain, &v.camera),
    }
    .map_err(|e| EditError::Internal(format!("view \"{}\": features: {e}", v.spec.name)))
}

/// `terrain` (built over a window of the DEM at `offset`) with `H + M`
/// swapped in where the deformation changes a cell: the terrain the same
/// view would have on the edited DEM, to the bit
/// ([`LocalTerrain::with_heights`]).
pub(crate) fn edited_terrain(
    terrain: &crate::render::LocalTerrain,
    offset: (i64, i64),
    d: &Deformation,
) -> crate::render::LocalTerrain {
    let w = d.window;
    // The deformation's window in the terrain's grid, clipped at its origin.
    let (c0, r0) = ((w.col - offset.0).max(0), (w.row - offset.1).max(0));
    let (c1, r1) = (
        (w.col_end() - offset.0).max(0),
        (w.row_end() - offset.1).max(0),
    );
    let height = |c: usize, r: usize| -> Option<f32> {
        let (x, y) = (c as i64 + offset.0 - w.col, r as i64 + offset.1 - w.row);
        if x < 0 || y < 0 || x as usize >= w.width || y as usize >= w.height {
            return None;
        }
        let s = y as usize * w.width + x as usize;
        let (h, m) = (d.base.data[s], d.displacement[s]);
        (!h.is_nan() && m.is_finite() && m != 0.0).then(|| h + m)
    };
    terrain.with_heights(
        (c0 as usize, r0 as usize, c1 as usize, r1 as usize),
        &height,
    )
}

#[cfg(test)]
mod tests {
    use super::{free_stretches, stroke_outcome};
    use crate::edit::fit::StrokeFit;

    #[test]
    fn an_unfitted_stroke_placed_finer_than_a_cell_says_so() {
        let fit = StrokeFit {
            fitted_fraction: 0.41,
            mean_px: 1.1,
            max_px: 2.1,
            columns: 27,
        };
        let (_, reason) = stroke_outcome(&fit, 1.0, None, Some((0.3, 497.0)), 0.9);
        let reason = reason.unwrap_or_default();
        assert!(
            reason.starts_with("its free stretch spans 0.3 DEM cells"),
            "{reason}"
        );
        assert!(reason.ends_with("fit 0.41 below --min-fit 0.9"), "{reason}");
        // Two cells and more: the fit alone.
        let (_, reason) = stroke_outcome(&fit, 1.0, None, Some((3.0, 497.0)), 0.9);
        assert_eq!(reason.as_deref(), Some("fit 0.41 below --min-fit 0.9"));
        // Hidden comes first.
        let (_, reason) = stroke_outcome(&fit, 0.5, None, Some((0.3, 497.0)), 0.9);
        assert!(reason
            .unwrap_or_default()
            .starts_with("hidden by nearer terrain"));
    }

    fn pts(n: usize) -> Vec<[f64; 3]> {
        (0..n).map(|i| [i as f64, 0.0, 10.0]).collect()
    }

    #[test]
    fn free_stretches_take_the_anchors_beside_them_where_depth_continues() {
        let p = pts(6);
        let depths = [1000.0, 1000.0, 1010.0, 1020.0, 1030.0, 1030.0];
        let anchored = [true, true, false, false, true, true];
        let c = free_stretches(&p, &depths, &anchored);
        assert_eq!(c.len(), 1);
        assert_eq!(c[0].points, p[1..=4].to_vec());
    }

    #[test]
    fn free_stretches_break_where_the_depth_jumps() {
        let p = pts(6);
        // An anchor far behind, then a stretch that jumps in depth midway.
        let depths = [27000.0, 8000.0, 8100.0, 5000.0, 5050.0, 5100.0];
        let anchored = [true, false, false, false, false, false];
        let c = free_stretches(&p, &depths, &anchored);
        let lens: Vec<usize> = c.iter().map(|c| c.points.len()).collect();
        assert_eq!(lens, vec![2, 3]);
        assert_eq!(c[0].points[0], p[1], "no segment back to the far anchor");
    }

    #[test]
    fn a_stroke_all_on_silhouettes_asks_for_no_curve() {
        let p = pts(4);
        let c = free_stretches(&p, &[1.0e3; 4], &[true; 4]);
        assert!(c.is_empty());
    }
}
