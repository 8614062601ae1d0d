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
//! the output again changes nothing (`all_passes`). The later passes first
//! place again the near misses the passes before left (their looser
//! anchoring only on boundaries the view as drawn on showed,
//! [`TracedBoundaries`]; the terrain read in whole metres, the same for
//! every storage of the same heights, `in_whole_metres`), then run as a
//! re-edit of the output would, until one changes nothing.
//!
//! Each view's skyline is one of the candidate features
//! ([`crate::sketch::skyline`]). Where a stroke matched to a skyline is
//! left unfitted, stages 3 to 5 of the pass run again without the
//! skylines (`match_and_fit`), and so does the whole edit (all its
//! passes, in `run_opened`); the skyline's is kept only where the other
//! does not fit the strokes better, in all or where its placed curves
//! are visible (`fits_better`).
//!
//! A view that reaches far is first loaded with its exact terrain cut at
//! [`EDIT_EXACT_REACH_CELLS`] cells from the eye (the DEM's own cells
//! beyond, as a far layer); the edit is kept where every stroke is fitted
//! within the cut and every changed cell lies within it, else made again
//! without the cut (`run_opened`, `kept_within`).
//!
//! 6. `write` (`super::outputs::write_outputs`): affected tiles written
//!    back atomically, then the pictures and the report.
//!
//! Each stage has a file of its own: `load` (stages 1 and 2), `stages`
//! (3 and 4), `demands` (what the strokes ask of the terrain), `measure`
//! (stage 5's fit and notes), `passes` and `skyline_retry` (the passes,
//! and the match without the skylines), `observer` (the fixed ground)
//! and `options`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;

use super::fit::measure;
use super::on_silhouette::{anchor_on_silhouettes, TracedBoundaries};
use super::outputs::{write_outputs, Outcome, Sources};
use super::rendered_view::{RenderedView, StrokeCurve, StrokeRegion};
use super::report::{
    EditReport, FeatureCounts, MatchReport, MatchingReport, StrokeReport, StrokeStatus, Timings,
    ViewReport,
};
use super::rounds::{refine, Rounds};
use super::spikes::find_spikes;
use super::stretch_placement::{place_free_stretches, StretchPlacement};
use super::tangent_rise::match_behind_occluder;
use super::EditError;
use crate::deform::{
    deform_bounded, CellConstraint, CurveConstraint, DeformError, DeformOptions, Deformation,
};
use crate::features::{detect_ridges, RidgeNetwork, RidgeParams};
use crate::raster::{Dem, Destination, HeightMap, Window, WriteOptions};
use crate::render::{FarLayers, FarRingsToRead, Scene};
use crate::sketch::{
    match_sketch, PointSource, SceneProjection, SceneView, SketchFile, SketchMatch, SketchOptions,
    Stroke, ViewFeatureOptions, ViewInput, ViewSpec,
};
use crate::view::{Camera, LocalFrame};

mod demands;
mod load;
mod measure;
mod observer;
mod options;
mod passes;
mod skyline_retry;
mod stages;
pub use self::demands::*;
pub use self::load::*;
use self::measure::*;
use self::observer::*;
pub use self::options::*;
pub use self::passes::*;
use self::skyline_retry::*;
use self::stages::*;

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
    /// The views' exact terrain cut at this many cells from the eye
    /// ([`EDIT_EXACT_REACH_CELLS`]); `None`: each view's full exact reach.
    pub(super) exact_cells: Option<f64>,
    /// In the passes after the first, each view's boundaries as the
    /// sketcher drew on it (the first pass's unedited render), which the
    /// looser anchoring of a stroke's short gaps asks for
    /// ([`TracedBoundaries`]); `None` in the first pass.
    pub(super) traced: Option<std::sync::Arc<Vec<TracedBoundaries>>>,
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
    check_view_options(opts)?;
    check_output_paths(opts)?;
    run_opened(Dem::open(dem_path)?, dem_path, sketch_path, opts)
}

/// How far from the eye an edit's exact terrain reaches at first, in
/// cells of the DEM (15 km with 15 m cells, 30 km with 30 m cells), where
/// the view's level of detail would reach farther
/// ([`crate::render::LodPlan::new_within`]: between the two, a ring of the
/// DEM's own cells): the ridge network, the terrain the rounds change and
/// re-render, and the deformation's reach are confined to it. The edit is
/// kept where it fits every stroke on curves within it and changes no
/// cell beyond it, less [`EXACT_MARGIN_CELLS`] cells ([`kept_within`]);
/// otherwise it is made again with the view's whole exact reach.
pub const EDIT_EXACT_REACH_CELLS: f64 = 1000.0;

/// [`EDIT_EXACT_REACH_CELLS`], or the cells `DEMSKETCH_EXACT_CUT_CELLS`
/// gives (for checking the cut where the fidelity suite's views reach:
/// their DEMs' cells of 30 m and more keep them within the default).
fn exact_reach_cells() -> f64 {
    std::env::var("DEMSKETCH_EXACT_CUT_CELLS")
        .ok()
        .and_then(|v| v.parse::<f64>().ok())
        .filter(|c| c.is_finite() && *c > EXACT_MARGIN_CELLS)
        .unwrap_or(EDIT_EXACT_REACH_CELLS)
}

/// Cells kept between the farthest changed cell or placed point and the
/// exact terrain's edge (the ring beyond overlaps the exact terrain by
/// two of its cells).
pub const EXACT_MARGIN_CELLS: f64 = 8.0;

/// [`run`] on `dem`, the DEM at `dem_path` opened already (by
/// [`super::guard::prepare_open`]): not opened a second time.
///
/// First with the exact terrain cut at [`EDIT_EXACT_REACH_CELLS`] cells;
/// where the edit does not keep within it (checked before anything is
/// written, [`kept_within`]),
/// the whole edit again with each view's full exact reach, as without
/// the cut.
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
    check_view_options(opts)?;
    check_output_paths(opts)?;
    let first = run_within(
        dem,
        dem_path,
        sketch_path,
        opts,
        Some(exact_reach_cells()),
        t_all,
    );
    // (an error is the edit's outcome: it may come after a write)
    let dem = match first? {
        Attempt::Done(report) => return Ok(report),
        Attempt::Beyond(dem) => dem,
    };
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        eprintln!("exact cut: the edit does not keep within it; made again without");
    }
    match run_within(dem, dem_path, sketch_path, opts, None, t_all)? {
        Attempt::Done(report) => Ok(report),
        Attempt::Beyond(_) => Err(EditError::Internal(
            "an edit without a cut refused its changes".into(),
        )),
    }
}

/// What [`run_within`] made of an edit.
enum Attempt {
    /// The edit, written.
    Done(EditReport),
    /// The exact terrain was cut and the edit does not keep within the cut
    /// (nothing written): the DEM, to make it again.
    Beyond(Dem),
}

/// The edit of [`run_opened`] with the exact terrain cut at `exact_cells`
/// cells (`None`: each view's full exact reach): [`Attempt::Beyond`] when
/// it was cut and does not keep within the cut (nothing written).
fn run_within(
    dem: Dem,
    dem_path: &Path,
    sketch_path: &Path,
    opts: &EditOptions,
    exact_cells: Option<f64>,
    t_all: Instant,
) -> Result<Attempt, EditError> {
    let edit = Edit {
        opts,
        sketch_name: sketch_path.display().to_string(),
        max_d: crate::view::distance_limit(opts.max_distance_m),
        pb: progress_bar(opts),
        skyline: true,
        exact_cells,
        traced: None,
    };
    let mut timings = Timings::default();

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
            exact_cells,
            traced: None,
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
                    if !kept_within(exact_cells, &views2, &outcome2) {
                        return Ok(Attempt::Beyond(dem));
                    }
                    outcome2
                        .notes
                        .push(skyline_dropped_note(&outcome2, &outcome));
                    let sources = Sources {
                        dem_path,
                        sketch_path,
                        dem: &dem2,
                        sketch: &sketch2,
                    };
                    return write_outputs(plain, &sources, &views2, outcome2, timings, t_all)
                        .map(Attempt::Done);
                }
            }
        }
    }
    if !kept_within(exact_cells, &views, &outcome) {
        return Ok(Attempt::Beyond(dem));
    }
    let sources = Sources {
        dem_path,
        sketch_path,
        dem: &dem,
        sketch: &sketch,
    };
    write_outputs(edit, &sources, &views, outcome, timings, t_all).map(Attempt::Done)
}

/// Whether an edit made with the exact terrain cut at `exact_cells` cells
/// (`None`: not cut) may be kept: every stroke fitted, on a placed curve within
/// the cut of its view, and every cell it changed within the cut of
/// every view ([`changes_within`]), each less [`EXACT_MARGIN_CELLS`]
/// cells. (A stroke not fitted, or fitted farther, might fit otherwise
/// with the features and terrain beyond the cut.)
fn kept_within(exact_cells: Option<f64>, views: &[ViewState], outcome: &Outcome) -> bool {
    let Some(cells) = exact_cells else {
        return true;
    };
    // (no view cut: the edit is the one without the cut)
    let cut = |v: &ViewState| {
        v.before
            .terrain
            .far_layer_sizes()
            .first()
            .is_some_and(|l| l.0 == 1)
    };
    if !views.iter().any(cut) {
        return true;
    }
    let strokes_within = views.iter().zip(&outcome.views).all(|(v, report)| {
        let limit = (cells - EXACT_MARGIN_CELLS) * frame_cell_m(&v.frame);
        report.strokes.iter().all(|s| {
            s.status == StrokeStatus::Fitted
                && !s.first_curve().is_empty()
                && s.first_depth_m()
                    .iter()
                    .all(|d| d.is_finite() && *d <= limit)
        })
    });
    views.len() == outcome.views.len()
        && strokes_within
        && changes_within(views, &outcome.deformation, cells)
}

/// The longer side of a cell of `frame`'s grid, metres.
fn frame_cell_m(frame: &LocalFrame) -> f64 {
    let p = frame.p;
    p[0][0].hypot(p[1][0]).max(p[0][1].hypot(p[1][1]))
}

/// Whether every cell `deformation` changes (non-zero displacement) lies,
/// with its four corners, within `cells` cells less
/// [`EXACT_MARGIN_CELLS`] of each view's eye: where the view's exact
/// terrain, which the rounds change and re-render, holds it, and no far
/// layer (the DEM as it was) stands over it.
pub(super) fn changes_within(views: &[ViewState], deformation: &Deformation, cells: f64) -> bool {
    let w = deformation.window;
    if w.width == 0 {
        return true;
    }
    views.iter().all(|v| {
        let limit = (cells - EXACT_MARGIN_CELLS) * frame_cell_m(&v.frame);
        let (ox, oy) = v.window_offset;
        // The window's corners well within: so is every corner of its
        // cells (the cells' corners lie in the parallelogram of the
        // window's, in a disc; the margin covers the rounding of each).
        let (x0, y0) = ((w.col - ox) as f64, (w.row - oy) as f64);
        let (x1, y1) = (x0 + w.width as f64, y0 + w.height as f64);
        if [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
            .iter()
            .all(|&(x, y)| {
                let (e, n) = v.frame.pixel_to_en(x, y);
                e.hypot(n) <= limit * (1.0 - 1e-9)
            })
        {
            return true;
        }
        deformation
            .displacement
            .chunks(w.width)
            .enumerate()
            .all(|(r, row)| {
                let py = (w.row + r as i64 - oy) as f64;
                row.iter().enumerate().all(|(c, &m)| {
                    if m == 0.0 || m.is_nan() {
                        return true;
                    }
                    let px = (w.col + c as i64 - ox) as f64;
                    [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                        .iter()
                        .all(|&(a, b)| {
                            let (e, n) = v.frame.pixel_to_en(px + a, py + b);
                            e.hypot(n) <= limit
                        })
                })
            })
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
/// A view's scene, camera and fixed ground, and its far rings where they
/// are still to be read ([`Scene::open_wedge_lod_deferred`]: read beside
/// the ridges' detection, [`render_and_extract`]).
type ViewScene = (Scene, Camera, EyeGround, Option<FarRingsToRead>);

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

/// The views rendered before the edit, and the ridges around them
/// ([`render_and_extract`]).
struct Extracted<'a> {
    views: Vec<ViewState<'a>>,
    /// Per view: the heights of its window ([`ViewState::window`]).
    windows: Vec<HeightMap>,
    /// Per view: what its terrain covers of the DEM grid.
    seen: Vec<Window>,
    ridges: RidgeNetwork,
}

/// A ridge network and what it was detected from ([`ridge_network`]): the
/// views' windows (their heights, at their offsets in the DEM grid) and
/// what each view's terrain covers. A later pass that reads the same
/// (to the bit) takes the network as it is. The windows are the pass's
/// own, kept instead of dropped (no copy).
pub(super) struct RidgesOf {
    windows: Vec<(HeightMap, (i64, i64))>,
    seen: Vec<Window>,
    ridges: RidgeNetwork,
}

impl RidgesOf {
    /// Whether `windows` and `seen` are what these ridges were detected
    /// from, to the bit (the same windows, offsets, georeferencing and
    /// heights, nodata included).
    fn detected_from(&self, windows: &[(&HeightMap, (i64, i64))], seen: &[Window]) -> bool {
        self.seen == seen
            && self.windows.len() == windows.len()
            && self
                .windows
                .iter()
                .zip(windows)
                .all(|((a, oa), (b, ob))| oa == ob && same_heights(a, b))
    }

    /// `ridges` with what they were detected from: the views' `windows`
    /// (moved, not copied) at their offsets and their terrains' extents
    /// `seen` ([`Extracted`]), for a later pass ([`Seen`]).
    fn of(
        ridges: RidgeNetwork,
        windows: Vec<HeightMap>,
        seen: Vec<Window>,
        views: &[ViewState],
    ) -> RidgesOf {
        let windows = windows
            .into_iter()
            .zip(views)
            .map(|(w, v)| (w, v.window_offset))
            .collect();
        RidgesOf {
            windows,
            seen,
            ridges,
        }
    }
}

/// Whether two height maps are the same to the bit: size, georeferencing
/// and every height (nodata included).
fn same_heights(a: &HeightMap, b: &HeightMap) -> bool {
    (a.width, a.height) == (b.width, b.height)
        && a.geotransform == b.geotransform
        && a.crs == b.crs
        && a.data.len() == b.data.len()
        && a.data
            .iter()
            .zip(&b.data)
            .all(|(p, q)| p.to_bits() == q.to_bits())
}

/// What a pass rendered of the terrain it read: its views' whole renders
/// and its ridge network. A later pass that reads the same terrain again
/// (after a pass not kept, or dropped) takes them as they are.
pub(super) struct Seen {
    pub(super) renders: Vec<RenderedView>,
    pub(super) ridges: RidgesOf,
}

/// The terrain features each view offers the strokes ([`scene_features`]).
struct Features<'v> {
    /// Per view: its projection and its silhouettes and ridges as seen.
    scene_views: Vec<SceneView<'v>>,
    /// Per view: how many of each kind, for the report.
    counts: Vec<FeatureCounts>,
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

/// What the placed strokes ask of the terrain.
pub(super) struct Demands {
    /// Curve constraints: the stretches of placed strokes that do not lie
    /// on a silhouette already ([`super::on_silhouette`]), the strokes'
    /// own points only. They define the edit's influence.
    pub(super) curves: Vec<CurveConstraint>,
    /// The parts of those stretches that the feature completion adds
    /// beyond the strokes' ends (each from the stroke's end point on):
    /// they act only within the influence of `curves`
    /// ([`crate::deform::deform_bounded`]).
    pub(super) completions: Vec<CurveConstraint>,
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

/// The solves of one edit: the DEM, the options, and the cells held fixed
/// in every solve.
pub(super) struct Solver<'a> {
    dem: &'a Dem,
    dem_name: &'a str,
    opts: DeformOptions,
    fixed: &'a [CellConstraint],
    /// Curves that act only within the influence of the solved curves
    /// (the strokes' feature completion), in every solve.
    bounded: &'a [CurveConstraint],
    /// Window of the deformation when nothing needs to move.
    idle: Window,
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
    let camera = &v.camera;
    match (region, earlier) {
        // From the earlier render where that can keep something, else
        // from the unedited view where that can, else as before.
        (Some(r), e) => {
            match e.filter(|e| RenderedView::rerender_keeps_some(&terrain, camera, r, e)) {
                Some(e) => RenderedView::rerender_terrain_region(terrain, camera, r, e),
                None => match unedited_region(v, r, &terrain) {
                    Some(before) => before.and_then(|before| {
                        RenderedView::rerender_terrain_region(terrain, camera, r, &before)
                    }),
                    None => match e {
                        Some(e) => RenderedView::rerender_terrain_region(terrain, camera, r, e),
                        None => RenderedView::render_terrain_region(terrain, camera, r),
                    },
                },
            }
        }
        (None, _) => RenderedView::from_terrain(terrain, camera),
    }
    .map_err(|e| EditError::Internal(format!("view \"{}\": features: {e}", v.spec.name)))
}

/// The render of `region` of view `v`'s terrain before the edit, taken
/// from its whole render ([`RenderedView::region_of`]), where a re-render
/// of `terrain` from it can take some of it
/// ([`RenderedView::rerender_keeps_some`]): a terrain that differs from
/// the unedited one in a few cells only (a later pass whose change rounds
/// to almost nothing on an integer DEM), while it differs a little
/// everywhere from the rounds' last render. `None`: no such render.
fn unedited_region(
    v: &ViewState,
    region: &StrokeRegion,
    terrain: &crate::render::LocalTerrain,
) -> Option<Result<RenderedView, crate::features::FeatureError>> {
    let before = &v.before;
    if before.region.is_some()
        || before.camera != v.camera
        || !RenderedView::change_keeps_some(terrain, &v.camera, &before.terrain)
    {
        return None;
    }
    let unedited = before.terrain.with_heights((0, 0, 0, 0), &|_, _| None);
    before.region_of(unedited, region)
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
        (!h.is_nan() && m.is_finite() && m != 0.0).then_some(h + m)
    };
    terrain.with_heights(
        (c0 as usize, r0 as usize, c1 as usize, r1 as usize),
        &height,
    )
}

#[cfg(test)]
mod tests {
    use super::{stroke_curves, stroke_outcome, RidgesOf};
    use crate::deform::CurveConstraint;
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

    /// The curves of a stroke without feature completion.
    fn free_stretches(p: &[[f64; 3]], depths: &[f64], anchored: &[bool]) -> Vec<CurveConstraint> {
        let c = stroke_curves(p, depths, anchored, &vec![false; p.len()]);
        assert!(c.completion.is_empty());
        c.own
    }

    #[test]
    fn the_completion_beyond_a_strokes_ends_is_its_own_curve_from_the_end_point() {
        let p = pts(7);
        let depths = [1000.0, 1010.0, 1020.0, 1030.0, 1040.0, 1050.0, 1060.0];
        let anchored = [false, false, false, false, false, true, true];
        let completion = [true, true, false, false, false, false, false];
        let c = stroke_curves(&p, &depths, &anchored, &completion);
        assert_eq!(c.own.len(), 1);
        assert_eq!(c.own[0].points, p[2..=5].to_vec());
        assert_eq!(c.completion.len(), 1);
        assert_eq!(c.completion[0].points, p[0..=2].to_vec());
        // Completion at both ends of a stroke free throughout.
        let completion = [true, false, false, false, false, true, true];
        let c = stroke_curves(&p, &depths, &[false; 7], &completion);
        assert_eq!(c.own[0].points, p[1..=4].to_vec());
        let parts: Vec<_> = c.completion.iter().map(|c| c.points.clone()).collect();
        assert_eq!(parts, vec![p[0..=1].to_vec(), p[4..=6].to_vec()]);
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

    /// A later pass takes the ridges a pass before detected only where it
    /// reads the very windows they were detected from (to the bit, nodata
    /// included), at the same offsets, for the same extents.
    #[test]
    fn ridges_are_taken_only_for_the_same_heights() {
        use crate::features::{detect_ridges, RidgeParams};
        use crate::raster::{Crs, GeoTransform, HeightMap, Window};
        let (w, h) = (40, 30);
        let data: Vec<f32> = (0..w * h)
            .map(|i| {
                let (c, r) = ((i % w) as f32, (i / w) as f32);
                if i == 7 {
                    f32::NAN
                } else {
                    100.0 - (c - 20.0).abs() * 3.0 + r * 0.5
                }
            })
            .collect();
        let map = HeightMap {
            width: w,
            height: h,
            data,
            geotransform: GeoTransform([500_000.0, 30.0, 0.0, 4_000_000.0, 0.0, -30.0]),
            crs: Crs {
                epsg: None,
                wkt: String::new(),
                proj: None,
                geographic: false,
            },
        };
        let ridges = detect_ridges(&map, &RidgeParams::default()).unwrap();
        let seen = vec![Window::new(3, 4, w - 2, h - 5)];
        let earlier = RidgesOf {
            windows: vec![(map.clone(), (2, 4))],
            seen: seen.clone(),
            ridges,
        };
        let same = map.clone();
        assert!(earlier.detected_from(&[(&same, (2, 4))], &seen));
        // Another offset, another view's extent, more views.
        assert!(!earlier.detected_from(&[(&same, (2, 5))], &seen));
        assert!(!earlier.detected_from(&[(&same, (2, 4))], &[Window::new(3, 4, w - 2, h - 6)]));
        assert!(!earlier.detected_from(&[(&same, (2, 4)), (&same, (2, 4))], &seen));
        // Other heights: one moved a millimetre, one row less, another
        // georeferencing.
        let mut moved = map.clone();
        moved.data[w * 10 + 20] += 0.001;
        assert!(!earlier.detected_from(&[(&moved, (2, 4))], &seen));
        let cropped = map.crop(0, 0, w, h - 1);
        assert!(!earlier.detected_from(&[(&cropped, (2, 4))], &seen));
        let mut shifted = map.clone();
        shifted.geotransform = GeoTransform([500_030.0, 30.0, 0.0, 4_000_000.0, 0.0, -30.0]);
        assert!(!earlier.detected_from(&[(&shifted, (2, 4))], &seen));
    }
}
