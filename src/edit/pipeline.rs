//! The edit pipeline, stage by stage (timings in the report use these
//! names):
//!
//! 1. `load`: open the DEM (tile layer), read and validate the sketch,
//!    resolve every view's viewpoint (PROJ) and read the DEM window within
//!    the maximum view distance ([`Scene::open`]).
//! 2. `features`: render each view (exact depth buffer), extract its
//!    silhouettes, and the ridge network of the DEM around all views.
//! 3. `matching`: strokes of all views matched jointly
//!    ([`match_sketch`]), placed in 3D, converted to the DEM's CRS.
//! 4. `deformation`: displacement constraints diffused by multigrid,
//!    `H' = H + M` on the affected window.
//! 5. `lowering`: each view re-rendered on the edited terrain; protruding
//!    silhouettes lowered by the paper's `h` as new constraints, and the
//!    mesh vertices that decide the contour along strokes that do not fit
//!    yet put on the strokes' sight surfaces ([`super::contour`]); re-solve
//!    with the union, repeat until neither asks for more (or the iteration
//!    limits); fit and visibility measured on the final terrain.
//! 6. `write`: affected tiles written back atomically, then the pictures
//!    and the report.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;

use super::contour::contour_constraints;
use super::fit::measure;
use super::lowering::find_protruding;
use super::on_silhouette::anchor_on_silhouettes;
use super::rendered_view::{RenderedView, StrokeCurve, StrokeRegion};
use super::renders::{encode_png, height_change_map, view_picture, Picture};
use super::report::{
    DeformationReport, EditReport, FeatureCounts, MatchReport, MatchingReport, StagedFile,
    StrokeReport, StrokeStatus, Timings,
};
use super::spikes::flatten_spikes;
use super::stretch_placement::{place_free_stretches, StretchPlacement};
use super::EditError;
use crate::deform::{
    deform_with_cells, CellConstraint, CurveConstraint, DeformError, DeformOptions, Deformation,
};
use crate::features::{detect_ridges, RidgeNetwork, RidgeParams};
use crate::raster::{Dem, Destination, HeightMap, Provenance, Window};
use crate::render::Scene;
use crate::sketch::{
    match_sketch, EyeHeightSpec, PointSource, SceneProjection, SceneView, SketchFile, Stroke,
    ViewFeatureOptions, ViewInput, ViewSpec,
};
use crate::view::{Camera, EyeHeight, LocalFrame, Viewpoint};

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
    /// A stroke is fitted when at least this share of its columns is
    /// (`fitted_fraction`); below it, nothing is written
    /// ([`EditError::BelowMinFit`]) unless `allow_partial`.
    pub min_fit: f64,
    /// Write the edit even when a stroke's fit is below `min_fit`.
    pub allow_partial: bool,
    /// Compute everything and write the report and pictures, but not the
    /// DEM. Fails as a real run would (bad heights, fit below `min_fit`).
    pub dry_run: bool,
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
            min_fit: DEFAULT_MIN_FIT,
            allow_partial: false,
            dry_run: false,
        }
    }
}

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

/// A cell constraint counts as new when its height moved by more than this
/// (metres).
const CELL_CHANGE_M: f64 = 0.01;

/// A view of the sketch set up on the DEM.
struct ViewState<'a> {
    spec: &'a ViewSpec,
    /// The DEM window read around the viewpoint, where it lies on the DEM
    /// grid, and the view's local frame (resolved on that window).
    window: HeightMap,
    window_offset: (i64, i64),
    frame: LocalFrame,
    camera: Camera,
    strokes: Vec<Stroke>,
    before: RenderedView,
}

fn secs(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// Progress on stderr: a spinner with the current stage, hidden when stderr
/// is not a terminal or progress is off.
fn progress_bar(on: bool) -> ProgressBar {
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
    // On a worker thread of rayon's pool: the many parallel loops of an
    // edit (a few hundred, most of them short: the multigrid levels, the
    // silhouette columns) then split work between the workers directly
    // instead of each waking the pool from outside and waiting for it.
    if rayon::current_thread_index().is_none() {
        return rayon::join(|| run(dem_path, sketch_path, opts), || ()).0;
    }
    let t_all = Instant::now();
    let pb = progress_bar(opts.progress);
    let mut timings = Timings::default();
    let sketch_name = sketch_path.display().to_string();

    check_output_paths(opts)?;

    // 1. Load.
    pb.set_message("loading DEM and sketch");
    let t = Instant::now();
    let sketch = SketchFile::from_path(sketch_path)?;
    let dem = Dem::open(dem_path)?;
    let mut notes = Vec::new();
    let mut prepared = Vec::new();
    for v in &sketch.views {
        let (strokes, n) = v.prepared_strokes(&sketch.options, &sketch_name)?;
        notes.extend(n);
        prepared.push(strokes);
    }
    let max_d = opts.max_distance_m.filter(|d| d.is_finite() && *d > 0.0);
    let mut scenes = Vec::new();
    for v in &sketch.views {
        let vp = Viewpoint {
            lon: v.viewpoint.lon,
            lat: v.viewpoint.lat,
            height: match v.viewpoint.height() {
                EyeHeightSpec::AboveSurface(h) => EyeHeight::AboveSurface(h),
                EyeHeightSpec::Absolute(a) => EyeHeight::Absolute(a),
            },
        };
        let view_err = |source| EditError::View {
            sketch: sketch_name.clone(),
            view: v.name.clone(),
            source,
        };
        let camera = Camera::new(
            v.camera.width as usize,
            v.camera.height as usize,
            v.camera.heading_deg,
            v.camera.pitch_deg,
            v.camera.roll_deg,
            v.camera.hfov_deg,
        )
        .map_err(|e| view_err(e.into()))?;
        let scene =
            Scene::open_in_view(&dem, &vp, max_d, opts.refraction, &camera).map_err(view_err)?;
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
        scenes.push((scene, camera));
    }
    timings.load = secs(t);

    // 2. Features: render every view, silhouettes, ridges around all views.
    pb.set_message("rendering views, silhouettes and ridges");
    let t = Instant::now();
    // The ridges and the views' renders are independent: computed side by
    // side, each also parallel inside.
    let mut parts = Vec::new();
    let mut terrains = Vec::new();
    for (scene, camera) in scenes {
        let Scene {
            window,
            window_offset,
            frame,
            terrain,
            ..
        } = scene;
        parts.push((window, window_offset, frame, camera));
        terrains.push((terrain, camera));
    }
    let windows: Vec<(&HeightMap, (i64, i64))> = parts.iter().map(|p| (&p.0, p.1)).collect();
    let seen: Vec<Window> = parts
        .iter()
        .zip(&terrains)
        .map(|(p, (t, _))| Window::new(p.1 .0 + t.col0 as i64, p.1 .1 + t.row0 as i64, t.nx, t.ny))
        .collect();
    let (ridges, befores) = rayon::join(
        || ridge_network(&dem, &windows, &seen),
        || {
            terrains
                .into_iter()
                .map(|(t, c)| RenderedView::from_terrain(t, &c))
                .collect::<Vec<_>>()
        },
    );
    let ridges = ridges?;
    let mut views: Vec<ViewState> = Vec::new();
    for (((v, (window, window_offset, frame, camera)), strokes), before) in
        sketch.views.iter().zip(parts).zip(prepared).zip(befores)
    {
        let before = before
            .map_err(|e| EditError::Internal(format!("view \"{}\": features: {e}", v.name)))?;
        views.push(ViewState {
            spec: v,
            window,
            window_offset,
            frame,
            camera,
            strokes,
            before,
        });
    }
    for v in &views {
        check_strokes_touch_terrain(v, &dem, max_d, &sketch_name)?;
    }
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
                &ridges,
                &ViewFeatureOptions::default(),
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
    timings.features = secs(t);

    // 3. Matching, all views jointly.
    pb.set_message("matching strokes to terrain features");
    let t = Instant::now();
    let inputs: Vec<ViewInput> = views
        .iter()
        .zip(&scene_views)
        .map(|(v, sv)| sv.input(v.strokes.clone()))
        .collect();
    let mut matched =
        match_sketch(&inputs, &sketch.options).map_err(|source| EditError::Match {
            sketch: sketch_name.clone(),
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
    let demands = place_demands(&views, &scene_views, &mut matched.views, &sketch.options);
    let curves = demands.strokes;
    let on_silhouette = demands.on_silhouette;
    let placement = demands.placement;
    let fixed = demands.fixed;
    let mut constraints = demands.curves;
    notes.extend(depth_notes(&views, &curves));
    let placement_issues: Vec<Vec<Option<&'static str>>> = scene_views
        .iter()
        .zip(&matched.views)
        .map(|(sv, m)| {
            m.strokes
                .iter()
                .map(|sm| {
                    let all = sv.projection.placed_to_dem(&sm.points);
                    placement_issue(&dem, &sm.points, &all, max_d)
                })
                .collect()
        })
        .collect();
    // The part of each view the re-renders compute.
    let regions: Vec<StrokeRegion> = views
        .iter()
        .zip(&curves)
        .map(|(v, cs)| StrokeRegion::new(cs, v.camera.width, v.camera.height))
        .collect();
    if curves.iter().flatten().all(|c| c.depths.is_empty()) {
        return Err(EditError::Unusable {
            sketch: sketch_name,
            message: "no stroke could be placed on the terrain".into(),
        });
    }
    timings.matching = secs(t);

    // 4. Deformation.
    pb.set_message("deforming the DEM (multigrid)");
    let t = Instant::now();
    let dopts = DeformOptions {
        influence_m: sketch.options.influence_m,
        ..DeformOptions::default()
    };
    let dem_name = dem_path.display().to_string();
    let solver = Solver {
        dem: &dem,
        dem_name: &dem_name,
        opts: &dopts,
        fixed: &fixed,
        idle: views[0].eye_cell(),
    };
    let user_constraints = constraints.len();
    let mut deformation = solver.solve(&constraints, &[])?;
    timings.deformation = secs(t);

    // 5. Lowering protruding silhouettes (section 6.2) and making every
    //    stroke the occluding contour ([`contour`]): each round re-renders
    //    every view on the current terrain, collects the new constraints of
    //    all views and solves once; it stops when no view asks for more, or
    //    when a round stops helping (the best terrain so far is kept).
    pb.set_message("lowering protruding silhouettes");
    let t = Instant::now();
    let mut iterations = vec![0usize; views.len()];
    let mut lowered = vec![0usize; views.len()];
    let mut contour_rounds = vec![0usize; views.len()];
    let mut cells: BTreeMap<(i64, i64), f64> = BTreeMap::new();
    let mut rendered: Vec<RenderedView> = Vec::new();
    let mut best: Option<(f64, Deformation)> = None;
    let mut stalled = 0;
    loop {
        rendered.clear();
        for (k, v) in views.iter().enumerate() {
            rendered.push(render_edited(v, &deformation, max_d, Some(&regions[k]))?);
        }
        let score = fit_score(&curves, &rendered);
        if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
            eprintln!(
                "round: fit score {score:.3} (best {:?}), lowering {:?}, contour {:?}",
                best.as_ref().map(|b| b.0),
                iterations,
                contour_rounds
            );
        }
        match &best {
            Some((b, _)) if score <= *b + 1e-9 => {
                stalled += 1;
                if score < *b - 1e-9 || stalled >= 2 {
                    break;
                }
            }
            _ => {
                stalled = 0;
                best = Some((score, deformation.clone()));
            }
        }
        let mut changed = false;
        for (k, (v, after)) in views.iter().zip(&rendered).enumerate() {
            if iterations[k] < opts.max_lowering_iterations {
                let protruding = find_protruding(after, &curves[k]);
                if !protruding.is_empty() {
                    for p in &protruding {
                        if !p.lowered.is_empty() {
                            constraints.push(CurveConstraint {
                                points: p.lowered.clone(),
                            });
                        }
                    }
                    lowered[k] += protruding.len();
                    iterations[k] += 1;
                    changed = true;
                }
            }
            if contour_rounds[k] < opts.max_contour_iterations {
                let mut moved = false;
                let mut round: BTreeMap<(i64, i64), f64> = BTreeMap::new();
                let known = |col: i64, row: i64| cells.contains_key(&(col, row));
                for c in contour_constraints(after, &curves[k], v.window_offset, &known) {
                    let h = round.entry((c.col, c.row)).or_insert(c.height);
                    *h = h.min(c.height);
                }
                for (&(col, row), &height) in &round {
                    let old = cells.insert((col, row), height);
                    moved |= old.is_none_or(|h| (h - height).abs() > CELL_CHANGE_M);
                }
                if moved {
                    contour_rounds[k] += 1;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
        pb.set_message(format!(
            "lowering protruding silhouettes, fitting contours: round {}",
            iterations
                .iter()
                .chain(&contour_rounds)
                .max()
                .copied()
                .unwrap_or(0)
        ));
        let cell_list: Vec<CellConstraint> = cells
            .iter()
            .map(|(&(col, row), &height)| CellConstraint { col, row, height })
            .collect();
        deformation = solver.solve(&constraints, &cell_list)?;
    }
    // The best round's terrain, if a later one did worse.
    if let Some((b, d)) = best {
        if fit_score(&curves, &rendered) < b - 1e-9 {
            deformation = d;
            rendered.clear();
            for (k, v) in views.iter().enumerate() {
                rendered.push(render_edited(v, &deformation, max_d, Some(&regions[k]))?);
            }
        }
    }
    // No spikes: a lone apex (or pit) of the change field gets a
    // neighbour behind it within half a cell.
    if flatten_final_spikes(&views, &mut deformation, &fixed) > 0 {
        rendered.clear();
        for (k, v) in views.iter().enumerate() {
            rendered.push(render_edited(v, &deformation, max_d, Some(&regions[k]))?);
        }
    }
    // Fit and visibility on the final terrain.
    let mut view_reports = Vec::new();
    let mut after_views = Vec::new();
    for (((k, v), m), after) in views.iter().enumerate().zip(&matched.views).zip(rendered) {
        let strokes = curves[k]
            .par_iter()
            .zip(&m.strokes)
            .zip(&placement_issues[k])
            .enumerate()
            .map(|(j, ((c, sm), issue))| {
                let (fit, visible) = measure(c, &after);
                let (status, reason) = stroke_outcome(&fit, visible, *issue, opts.min_fit);
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
                    on_silhouette: on_silhouette[k][j],
                    placement: placement[k][j],
                }
            })
            .collect();
        view_reports.push(super::report::ViewReport {
            name: v.spec.name.clone(),
            eye_alt_m: v.frame.eye_alt,
            strokes,
            lowering_iterations: iterations[k],
            silhouettes_lowered: lowered[k],
            contour_iterations: contour_rounds[k],
            features: counts[k],
            matching_stopped_early: matched.stopped_early,
        });
        after_views.push(after);
    }
    timings.lowering = secs(t);

    // 6. Write: pictures staged first, then the DEM, then pictures and report.
    pb.set_message("writing corrected tiles");
    let t = Instant::now();
    let pictures = if opts.renders.is_some() {
        // The rounds rendered only around the strokes: the pictures show
        // the whole view.
        let whole = views
            .iter()
            .map(|v| render_edited(v, &deformation, max_d, None))
            .collect::<Result<Vec<_>, _>>()?;
        pictures(&views, &whole, &deformation)?
    } else {
        Vec::new()
    };
    let staged_report = match &opts.report {
        Some(p) => Some(StagedFile::create(p).map_err(|e| EditError::Write {
            path: p.display().to_string(),
            message: e.to_string(),
        })?),
        None => None,
    };
    let staged_renders = match &opts.renders {
        Some(dir) => Some(StagedDir::create(dir, &pictures)?),
        None => None,
    };
    let provenance = Provenance {
        edit_id: format!(
            "{}:{}",
            sketch_path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            content_hash(&sketch)
        ),
    };
    let values = deformation.write_values();
    // Honest outcome: the worst stroke below the minimum fit stops the
    // write (the report and pictures still come, to show why).
    let worst = view_reports
        .iter()
        .flat_map(|v| v.strokes.iter().map(move |s| (v, s)))
        .filter(|(_, s)| s.status != StrokeStatus::Fitted)
        .min_by(|a, b| a.1.fit.fitted_fraction.total_cmp(&b.1.fit.fitted_fraction));
    let below = worst.filter(|_| !opts.allow_partial).map(|(v, s)| {
        (
            v.name.clone(),
            s.id.clone(),
            s.fit.fitted_fraction,
            s.reason.clone().unwrap_or_default(),
        )
    });
    let write = below.is_none() && !opts.dry_run;
    let written = if write {
        dem.write_back(deformation.window, &values, &opts.destination, &provenance)?
    } else {
        // Not written: what a real run would change (a dry run fails as the
        // real run would on heights the DEM cannot store).
        let changed = match dem.check_write_back(deformation.window, &values) {
            Ok(n) => n,
            Err(e) if below.is_none() => return Err(e.into()),
            Err(e) => {
                notes.push(format!("the write-back would also fail: {e}"));
                0
            }
        };
        crate::raster::WriteReport {
            tiles_written: Vec::new(),
            tiles_unchanged: Vec::new(),
            changed_cells: changed,
        }
    };
    if let Some((view, stroke, fit, _)) = &below {
        notes.push(format!(
            "nothing written: view \"{view}\" stroke \"{stroke}\" fitted {fit:.2}, below --min-fit {} (--allow-partial writes anyway)",
            opts.min_fit
        ));
    } else if opts.dry_run {
        notes.push("dry run: nothing written".into());
    }
    if let Some(s) = staged_renders {
        s.commit()?;
    }
    timings.write = secs(t);
    timings.total = secs(t_all);

    let max_abs = deformation.stats.max_abs_displacement_m;
    let w = deformation.window;
    let report = EditReport {
        dem: dem_path.display().to_string(),
        sketch: sketch_name,
        output: match &opts.destination {
            Destination::InPlace => dem_path.display().to_string(),
            Destination::Path(p) => p.display().to_string(),
        },
        views: view_reports,
        tiles_written: written
            .tiles_written
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        tiles_unchanged: written
            .tiles_unchanged
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        changed_cells: written.changed_cells,
        max_abs_displacement_m: max_abs,
        deformation: DeformationReport {
            window: [w.col, w.row, w.width as i64, w.height as i64],
            curve_constraints: user_constraints,
            lowering_constraints: constraints.len() - user_constraints,
            influence_m: deformation.stats.influence_m,
            solver: serde_json::to_value(&deformation.stats).unwrap_or_default(),
        },
        timings_s: timings,
        notes,
        written: write,
        dry_run: opts.dry_run,
        min_fit: opts.min_fit,
        matching: MatchingReport {
            nodes: matched.nodes,
            node_budget: matched.node_budget,
            stopped_early: matched.stopped_early,
        },
    };
    if let (Some(staged), Some(path)) = (staged_report, &opts.report) {
        let mut text = serde_json::to_string_pretty(&report)
            .map_err(|e| EditError::Internal(format!("report: {e}")))?;
        text.push('\n');
        staged
            .commit(text.as_bytes())
            .map_err(|e| EditError::Write {
                path: path.display().to_string(),
                message: e.to_string(),
            })?;
    }
    pb.finish_and_clear();
    if let Some((view, stroke, fit, reason)) = below {
        return Err(EditError::BelowMinFit {
            sketch: report.sketch.clone(),
            view,
            stroke,
            fit,
            min_fit: opts.min_fit,
            reason,
            report: Box::new(report),
        });
    }
    Ok(report)
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

/// A stroke's status and, when it is not fitted, why.
fn stroke_outcome(
    fit: &super::fit::StrokeFit,
    visible: f64,
    issue: Option<&'static str>,
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
        None => below,
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
        })
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
struct Demands {
    /// Curve constraints: the stretches of placed strokes that do not lie
    /// on a silhouette already ([`super::on_silhouette`]).
    curves: Vec<CurveConstraint>,
    /// Cells held at their input heights: under anchored stroke points and
    /// around every viewpoint. Applied after every other constraint, so
    /// nothing in the edit moves them.
    fixed: Vec<CellConstraint>,
    /// Per view, per stroke: the placed stroke.
    strokes: Vec<Vec<StrokeCurve>>,
    /// Per view, per stroke: share of its points on an existing silhouette.
    on_silhouette: Vec<Vec<f64>>,
    /// Per view, per stroke: how its free stretches were placed.
    placement: Vec<Vec<StretchPlacement>>,
}

/// Anchors the matched strokes where they already lie on a silhouette and
/// turns the rest into curve constraints in the DEM's CRS; adds the
/// observer's ground.
fn place_demands(
    views: &[ViewState],
    scene_views: &[SceneView],
    matched: &mut [crate::sketch::ViewMatch],
    options: &crate::sketch::SketchOptions,
) -> Demands {
    let mut d = Demands {
        curves: Vec::new(),
        fixed: Vec::new(),
        strokes: Vec::new(),
        on_silhouette: Vec::new(),
        placement: Vec::new(),
    };
    let mut held = Vec::new();
    for ((v, sv), m) in views.iter().zip(scene_views).zip(matched.iter_mut()) {
        let mut cs = Vec::new();
        let mut fractions = Vec::new();
        let mut placements = Vec::new();
        for (s, sm) in v.strokes.iter().zip(m.strokes.iter_mut()) {
            fractions.push(anchor_on_silhouettes(&v.before, &sv.projection, sm));
            placements.push(place_free_stretches(
                &v.before,
                &sv.projection,
                &sv.features,
                sm,
            ));
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
                held.extend(v.stencil_cells(p[0], p[1]));
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
    for v in views {
        d.fixed.extend(v.observer_cells(options.observer_radius_m));
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
    let gt = &v.window.geotransform;
    let mut near = std::collections::HashSet::new();
    let mut mark = |x: f64, y: f64| {
        if let Some((px, py)) = gt.crs_to_pixel(x, y) {
            let (c, r) = (
                (px - 0.5).floor() as i64 + v.window_offset.0,
                (py - 0.5).floor() as i64 + v.window_offset.1,
            );
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

/// [`flatten_spikes`] on the final deformation, with the viewpoints as
/// eyes and the constrained and fixed cells held.
fn flatten_final_spikes(
    views: &[ViewState],
    deformation: &mut Deformation,
    fixed: &[CellConstraint],
) -> usize {
    let gt = &deformation.base.geotransform;
    let eyes: Vec<(f64, f64)> = views
        .iter()
        .filter_map(|v| gt.crs_to_pixel(v.frame.eye_crs.0, v.frame.eye_crs.1))
        .collect();
    let w = deformation.window;
    let fixed: std::collections::HashSet<(i64, i64)> =
        fixed.iter().map(|c| (c.col, c.row)).collect();
    let constrained = deformation.constrained.clone();
    let held = |c: usize, r: usize| {
        constrained[r * w.width + c] || fixed.contains(&(w.col + c as i64, w.row + r as i64))
    };
    flatten_spikes(deformation, &eyes, &held)
}

/// Share of the strokes' columns fitted, summed over all views' strokes:
/// what a round of lowering or contour fitting must improve.
fn fit_score(curves: &[Vec<StrokeCurve>], rendered: &[RenderedView]) -> f64 {
    curves
        .iter()
        .zip(rendered)
        .map(|(cs, view)| {
            cs.par_iter()
                .map(|c| measure(c, view).0.fitted_fraction)
                .sum::<f64>()
        })
        .sum()
}

/// The solves of one edit: the DEM, the options, and the cells held fixed
/// in every solve.
struct Solver<'a> {
    dem: &'a Dem,
    dem_name: &'a str,
    opts: &'a DeformOptions,
    fixed: &'a [CellConstraint],
    /// Window of the deformation when nothing needs to move.
    idle: Window,
}

impl Solver<'_> {
    /// Deform the DEM through `curves` with the cells `cells` (then the
    /// fixed ones) held; no curve: no deformation at all.
    fn solve(
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
        deform_with_cells(self.dem, curves, &all, self.opts).map_err(err)
    }
}

impl ViewState<'_> {
    /// Metres per cell of the view's window along its columns and rows.
    fn cell_m(&self) -> (f64, f64) {
        let p = self.frame.p;
        (p[0][0].hypot(p[1][0]), p[0][1].hypot(p[1][1]))
    }

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
    /// at their input heights.
    fn stencil_cells(&self, x: f64, y: f64) -> Vec<CellConstraint> {
        let Some((px, py)) = self.window.geotransform.crs_to_pixel(x, y) else {
            return Vec::new();
        };
        let (c0, r0) = ((px - 0.5).floor() as i64, (py - 0.5).floor() as i64);
        let mut out = Vec::with_capacity(4);
        for (c, r) in [(c0, r0), (c0 + 1, r0), (c0, r0 + 1), (c0 + 1, r0 + 1)] {
            if c < 0 || r < 0 {
                continue;
            }
            if let Some(h) = self.window.get(c as usize, r as usize) {
                out.push(CellConstraint {
                    col: c + self.window_offset.0,
                    row: r + self.window_offset.1,
                    height: h as f64,
                });
            }
        }
        out
    }

    /// The ground the observer stands on: every cell whose surface reaches
    /// within `radius_m` of the viewpoint (default 100 m, at least two
    /// cells), held at its input height.
    fn observer_cells(&self, radius_m: Option<f64>) -> Vec<CellConstraint> {
        let (hx, hy) = self.cell_m();
        let radius = radius_m.unwrap_or(OBSERVER_RADIUS_M.max(2.0 * hx.max(hy)));
        if !(hx > 0.0 && hy > 0.0 && radius.is_finite()) {
            return Vec::new();
        }
        let reach = radius + hx.hypot(hy);
        let (ex, ey) = self.frame.eye_pixel;
        let (nc, nr) = (
            (reach / hx).ceil() as i64 + 1,
            (reach / hy).ceil() as i64 + 1,
        );
        let (c_eye, r_eye) = (ex.floor() as i64, ey.floor() as i64);
        let mut out = Vec::new();
        for r in r_eye - nr..=r_eye + nr {
            for c in c_eye - nc..=c_eye + nc {
                if c < 0 || r < 0 {
                    continue;
                }
                let (e, n) = self.frame.pixel_to_en(c as f64 + 0.5, r as f64 + 0.5);
                if e.hypot(n) > reach {
                    continue;
                }
                if let Some(h) = self.window.get(c as usize, r as usize) {
                    out.push(CellConstraint {
                        col: c + self.window_offset.0,
                        row: r + self.window_offset.1,
                        height: h as f64,
                    });
                }
            }
        }
        out
    }
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
    let map = match inside {
        Some((map, off)) => map.crop(
            (union.col - off.0) as usize,
            (union.row - off.1) as usize,
            union.width,
            union.height,
        ),
        None => dem.read_height_map(union)?,
    };
    detect_ridges(&map, &RidgeParams::default())
        .map_err(|e| EditError::Internal(format!("ridges: {e}")))
}

/// Render a view on the DEM with the deformation applied: only `region` of
/// it ([`StrokeRegion`]), or the whole view.
fn render_edited(
    v: &ViewState,
    d: &Deformation,
    max_d: Option<f64>,
    region: Option<&StrokeRegion>,
) -> Result<RenderedView, EditError> {
    let edited = edited_window(&v.window, v.window_offset, d);
    match region {
        Some(r) => RenderedView::render_region(&edited, &v.frame, &v.camera, max_d, r),
        None => RenderedView::render(&edited, &v.frame, &v.camera, max_d),
    }
    .map_err(|e| EditError::Internal(format!("view \"{}\": features: {e}", v.spec.name)))
}

/// `map` (a window of the DEM at `offset`) with `H + M` swapped in where the
/// deformation's window overlaps it.
pub(crate) fn edited_window(map: &HeightMap, offset: (i64, i64), d: &Deformation) -> HeightMap {
    let mut out = map.clone();
    let mw = Window::new(offset.0, offset.1, map.width, map.height);
    let Some(ov) = mw.intersect(&d.window) else {
        return out;
    };
    for r in ov.row..ov.row_end() {
        let src = ((r - d.window.row) as usize) * d.window.width;
        let dst = ((r - offset.1) as usize) * map.width;
        for c in ov.col..ov.col_end() {
            let s = src + (c - d.window.col) as usize;
            let t = dst + (c - offset.0) as usize;
            let (h, m) = (d.base.data[s], d.displacement[s]);
            if !h.is_nan() && m.is_finite() && m != 0.0 {
                out.data[t] = h + m;
            }
        }
    }
    out
}

/// Before/after views with the strokes, and the height-change map.
fn pictures(
    views: &[ViewState],
    after: &[RenderedView],
    d: &Deformation,
) -> Result<Vec<Picture>, EditError> {
    let enc = |w, h, rgb: &[u8]| encode_png(w, h, rgb).map_err(|e| EditError::Internal(e));
    let mut out = Vec::new();
    for (v, a) in views.iter().zip(after) {
        let strokes: Vec<Vec<[f64; 2]>> = v.spec.strokes.iter().map(|s| s.points.clone()).collect();
        let (w, h) = (v.camera.width, v.camera.height);
        let name = sanitize(&v.spec.name);
        out.push(Picture {
            name: format!("{name}_before.png"),
            png: enc(w, h, &view_picture(&v.before, &strokes))?,
        });
        out.push(Picture {
            name: format!("{name}_after.png"),
            png: enc(w, h, &view_picture(a, &strokes))?,
        });
    }
    let (gx, gy) = d.base.geotransform.pixel_size();
    let cell_m = if d.base.crs.geographic {
        let lat = d.base.geotransform.0[3].to_radians();
        (
            gx.abs() * 111_320.0 * lat.cos().max(0.01),
            gy.abs() * 110_540.0,
        )
    } else {
        (gx.abs(), gy.abs())
    };
    let (w, h, rgb) = height_change_map(
        d.window.width,
        d.window.height,
        cell_m,
        &d.base.data,
        &d.displacement,
    );
    out.push(Picture {
        name: "height_change.png".into(),
        png: enc(w, h, &rgb)?,
    });
    Ok(out)
}

/// A file-name-safe version of a view name.
fn sanitize(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if s.is_empty() {
        "view".into()
    } else {
        s
    }
}

/// A short hash of the sketch content (FNV-1a of its JSON), for provenance.
fn content_hash(sketch: &SketchFile) -> String {
    let text = serde_json::to_string(sketch).unwrap_or_default();
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// Pictures written into a staging directory beside the target, moved into
/// the target directory on commit; removed if dropped uncommitted.
struct StagedDir {
    target: PathBuf,
    stage: PathBuf,
    names: Vec<String>,
    done: bool,
}

impl StagedDir {
    fn create(target: &Path, pictures: &[Picture]) -> Result<StagedDir, EditError> {
        let werr = |p: &Path, e: std::io::Error| EditError::Write {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        if target.exists() && !target.is_dir() {
            return Err(EditError::Write {
                path: target.display().to_string(),
                message: "exists and is not a directory".into(),
            });
        }
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "renders".into());
        let stage = target.with_file_name(format!(".{name}.demsketch-{}.tmp", std::process::id()));
        std::fs::create_dir_all(&stage).map_err(|e| werr(&stage, e))?;
        let mut staged = StagedDir {
            target: target.to_path_buf(),
            stage,
            names: Vec::new(),
            done: false,
        };
        for p in pictures {
            let path = staged.stage.join(&p.name);
            std::fs::write(&path, &p.png).map_err(|e| werr(&path, e))?;
            staged.names.push(p.name.clone());
        }
        Ok(staged)
    }

    fn commit(mut self) -> Result<(), EditError> {
        let werr = |p: &Path, e: std::io::Error| EditError::Write {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        if !self.target.exists() {
            std::fs::rename(&self.stage, &self.target).map_err(|e| werr(&self.target, e))?;
        } else {
            for n in &self.names {
                let to = self.target.join(n);
                std::fs::rename(self.stage.join(n), &to).map_err(|e| werr(&to, e))?;
            }
            let _ = std::fs::remove_dir(&self.stage);
        }
        self.done = true;
        Ok(())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_dir_all(&self.stage);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::free_stretches;

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
