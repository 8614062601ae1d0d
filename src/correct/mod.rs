//! Corrections in map view (`demsketch correct`): the corrections GIS
//! analysts make from an orthophoto or a map rather than from a viewpoint —
//! lakes flattened to one level, rivers flat across and never rising
//! downstream (hydro-flattening, Maquettier section IV), and control curves
//! with heights the terrain must follow (Maquettier section III), and hard
//! and soft breaklines ([`breakline`]), and landforms from silhouette
//! strokes of a sketch view and noise regions ([`landform`], Gain et al.
//! 2009; `--sketch`). They come
//! as GeoJSON features drawn in a GIS ([`geojson_input`]), are applied one
//! after the other, in file order, to one seamless window of the DEM
//! ([`grid`]) with the project's multigrid solver ([`water`] blends the
//! shores of [`lake`]s and [`river`]s; [`control_curve`] uses the edit's
//! constraint rasteriser), and go back through the same atomic write-back
//! as an edit (only changed tiles rewritten, cells no correction reached
//! bit-identical). [`report`] says what each feature did, [`pictures`]
//! draws the run. Nothing is written
//! when any feature is invalid or fails.

pub mod breakline;
pub mod control_curve;
pub mod curve_fit;
pub mod geojson_input;
pub mod grid;
pub mod in_sketch;
pub mod lake;
pub mod landform;
pub mod pictures;
pub mod report;
pub mod river;
pub mod sparse_lsq;
pub mod spike_easing;
pub mod water;
pub mod wavelet_noise;

use std::path::{Path, PathBuf};
use std::time::Instant;

use geo::BoundingRect;

use crate::deform::locality::{affected_window, cell_size_m};
use crate::edit::report::StagedFile;
use crate::raster::provenance::sha256_hex;
use crate::raster::{
    Dem, Destination, Provenance, ProvenanceRecord, RasterError, Window, WriteOptions,
};

pub use geojson_input::{Correction, CorrectionKind};
pub use report::{CorrectReport, FeatureReport};

/// Options of [`run`].
#[derive(Debug, Clone)]
pub struct CorrectOptions {
    pub destination: Destination,
    /// Write the report (JSON) here.
    pub report: Option<PathBuf>,
    /// Compute everything, write only the report (and the water mask).
    pub dry_run: bool,
    /// Also write the water cells (1) of lakes and rivers, 0 elsewhere, as
    /// a Byte raster on the grid of the corrected window.
    pub water_mask: Option<PathBuf>,
    /// Write the pictures of [`pictures`] into this directory (on dry runs
    /// too), once the DEM is written.
    pub renders: Option<PathBuf>,
    pub write: WriteOptions,
    /// Largest window, in cells.
    pub max_window_cells: usize,
    /// The sketch file whose views and strokes the landforms and noise
    /// regions name (`--sketch`).
    pub sketch: Option<PathBuf>,
}

/// The largest window a correction may solve over by default, in cells
/// (2^26, about 8200 x 8200).
pub const MAX_WINDOW_CELLS: usize = 1 << 26;

impl CorrectOptions {
    pub fn new(destination: Destination) -> Self {
        CorrectOptions {
            destination,
            report: None,
            dry_run: false,
            water_mask: None,
            renders: None,
            write: WriteOptions::default(),
            max_window_cells: MAX_WINDOW_CELLS,
            sketch: None,
        }
    }
}

/// Why a correction run failed. Nothing was written.
#[derive(Debug, thiserror::Error)]
pub enum CorrectError {
    /// Bad input (the message is one line naming the file).
    #[error("{0}")]
    Input(String),
    #[error("{0}")]
    Raster(#[from] RasterError),
    /// The program's fault.
    #[error("{0}")]
    Internal(String),
}

impl CorrectError {
    /// True when the input is at fault (exit code 1).
    pub fn is_user_error(&self) -> bool {
        match self {
            CorrectError::Input(_) => true,
            CorrectError::Raster(e) => e.is_user_error(),
            CorrectError::Internal(_) => false,
        }
    }
}

/// Margin in DEM pixels around a correction's geometry that it may change.
fn margin_px(c: &Correction, cell: crate::deform::CellSize, default_blend: f64) -> [f64; 2] {
    let m = match &c.kind {
        CorrectionKind::Lake { blend_m, .. } | CorrectionKind::RiverArea { blend_m, .. } => {
            blend_m.unwrap_or(default_blend)
        }
        CorrectionKind::River {
            width_m, blend_m, ..
        } => 0.5 * width_m + blend_m.unwrap_or(default_blend) + cell.hx.max(cell.hy),
        CorrectionKind::ControlCurve { .. }
        | CorrectionKind::Breakline { .. }
        | CorrectionKind::Landform { .. }
        | CorrectionKind::NoiseRegion { .. } => 0.0,
    };
    [m / cell.hx + 3.0, m / cell.hy + 3.0]
}

/// The window of `dem` a correction may change.
fn feature_window(
    dem: &Dem,
    c: &Correction,
    cell: crate::deform::CellSize,
    default_blend: f64,
    influence: Option<f64>,
) -> Option<Window> {
    let b = match &c.kind {
        CorrectionKind::Lake { area, .. } | CorrectionKind::RiverArea { area, .. } => {
            let r = area.bounding_rect()?;
            [r.min().x, r.min().y, r.max().x, r.max().y]
        }
        CorrectionKind::Landform { placed, .. } | CorrectionKind::NoiseRegion { placed, .. } => {
            let r = placed.as_ref()?.boundary.bounding_rect()?;
            [r.min().x, r.min().y, r.max().x, r.max().y]
        }
        CorrectionKind::River { centreline, .. } => {
            let xs = centreline.iter().map(|p| p[0]);
            let ys = centreline.iter().map(|p| p[1]);
            [
                xs.clone().fold(f64::INFINITY, f64::min),
                ys.clone().fold(f64::INFINITY, f64::min),
                xs.fold(f64::NEG_INFINITY, f64::max),
                ys.fold(f64::NEG_INFINITY, f64::max),
            ]
        }
        CorrectionKind::ControlCurve {
            points, sections, ..
        } => {
            let curves = control_curve::curves(points, sections);
            return affected_window(dem, &curves, cell, influence.unwrap_or(0.0));
        }
        CorrectionKind::Breakline { points, hard, .. } => {
            let curves = control_curve::curves(points, &[]);
            let support = if *hard {
                breakline::support_m(cell)
            } else {
                0.0
            };
            return affected_window(dem, &curves, cell, influence.unwrap_or(0.0) + support);
        }
    };
    let g = margin_px(c, cell, default_blend);
    let (w, h) = (dem.width as f64, dem.height as f64);
    let c0 = (b[0] - g[0]).floor().clamp(0.0, w);
    let r0 = (b[1] - g[1]).floor().clamp(0.0, h);
    let c1 = (b[2] + g[0]).ceil().clamp(0.0, w);
    let r1 = (b[3] + g[1]).ceil().clamp(0.0, h);
    let win = Window::new(c0 as i64, r0 as i64, (c1 - c0) as usize, (r1 - r0) as usize);
    (!win.is_empty()).then_some(win)
}

fn union(a: Window, b: Window) -> Window {
    let (c0, r0) = (a.col.min(b.col), a.row.min(b.row));
    let (c1, r1) = (a.col_end().max(b.col_end()), a.row_end().max(b.row_end()));
    Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize)
}

/// A planned set of corrections on one DEM: the features, each one's
/// influence distance, and the window they may change (nothing read yet).
#[derive(Debug, Clone)]
pub struct Plan {
    pub corrections: Vec<Correction>,
    influences: Vec<Option<f64>>,
    /// The union of the features' windows, in the DEM grid.
    pub window: Window,
    /// Cell size in metres.
    pub cell: crate::deform::CellSize,
    default_blend: f64,
}

/// Plans `corrections` on `dem`: influence distances and the window,
/// before reading pixels. `name` (the features' file) starts the messages.
pub fn plan(
    dem: &Dem,
    corrections: Vec<Correction>,
    name: &str,
    max_window_cells: usize,
) -> Result<Plan, CorrectError> {
    let centre = dem
        .geotransform
        .pixel_to_crs(dem.width as f64 / 2.0, dem.height as f64 / 2.0);
    let lat = if dem.crs.geographic { centre.1 } else { 0.0 };
    let cell = cell_size_m(
        &dem.geotransform,
        dem.crs.geographic,
        lat.clamp(-89.9, 89.9),
    );
    let default_blend = 2.0 * cell.hx.max(cell.hy);
    let mut influences = Vec::new();
    let mut window: Option<Window> = None;
    for c in &corrections {
        let infl = match &c.kind {
            CorrectionKind::ControlCurve {
                points,
                influence_m,
                sections,
                ..
            } => Some(influence_m.unwrap_or_else(|| {
                let curves = control_curve::curves(points, sections);
                crate::deform::locality::default_influence_m(dem, &curves, cell)
            })),
            CorrectionKind::Breakline { influence_m, .. } => {
                Some(influence_m.unwrap_or_else(|| breakline::default_influence_m(cell)))
            }
            _ => None,
        };
        influences.push(infl);
        let w = feature_window(dem, c, cell, default_blend, infl).ok_or_else(|| {
            CorrectError::Input(format!("{name}: {}: lies outside the DEM", c.label()))
        })?;
        window = Some(window.map_or(w, |u| union(u, w)));
    }
    let window = window.ok_or_else(|| CorrectError::Input(format!("{name}: no features")))?;
    if window.len() > max_window_cells {
        return Err(CorrectError::Input(format!(
            "{name}: the corrections span {} x {} cells, more than the limit of {} cells",
            window.width, window.height, max_window_cells
        )));
    }
    Ok(Plan {
        corrections,
        influences,
        window,
        cell,
        default_blend,
    })
}

impl Plan {
    /// Applies every correction, in order, to `grid` (which covers at
    /// least [`Plan::window`]); messages start with `name`.
    pub fn apply(
        &self,
        dem: &Dem,
        grid: &mut grid::Grid,
        name: &str,
    ) -> Result<Vec<FeatureReport>, CorrectError> {
        let mut reports = Vec::new();
        for (c, infl) in self.corrections.iter().zip(&self.influences) {
            let r = apply_one(dem, grid, c, self.default_blend, *infl).map_err(|e| match e {
                ApplyError::User(m) => CorrectError::Input(format!("{name}: {}: {m}", c.label())),
                ApplyError::Internal(m) => {
                    CorrectError::Internal(format!("{name}: {}: {m}", c.label()))
                }
            })?;
            reports.push(r);
        }
        Ok(reports)
    }
}

/// The window of `dem` that the corrections of `features` (GeoJSON) may
/// change, as [`run`] would plan it: every feature read and checked
/// against the DEM, nothing else read.
pub fn footprint(dem: &Dem, features: &Path) -> Result<Window, CorrectError> {
    let mut corrections = geojson_input::read(features, dem).map_err(CorrectError::Input)?;
    let name = features.display().to_string();
    landform::resolve(dem, None, &mut corrections, &name, LANDFORM_HINT_BATCH)
        .map_err(CorrectError::Input)?;
    Ok(plan(dem, corrections, &name, MAX_WINDOW_CELLS)?.window)
}

/// Applies the corrections of `features` (GeoJSON) to `dem_path` and writes
/// the result (see the module documentation): the features read and
/// planned ([`planned`]), solved on the window's grid, the DEM written
/// with its provenance ([`write_corrected`]), then the report.
pub fn run(
    dem_path: &Path,
    features: &Path,
    opts: &CorrectOptions,
) -> Result<CorrectReport, CorrectError> {
    let t0 = Instant::now();
    let (dem, plan, fname) = planned(dem_path, features, opts)?;
    let (window, cell) = (plan.window, plan.cell);
    // (the report's file is made before anything is solved: a path that
    // cannot be written fails first)
    let staged_report = match &opts.report {
        Some(p) => Some(StagedFile::create(p).map_err(|e| report_error(p, e))?),
        None => None,
    };
    let t_plan = t0.elapsed().as_secs_f64();
    let mut grid = grid::Grid::new(window, cell, dem.read_height_map(window)?);

    let t1 = Instant::now();
    let reports = plan.apply(&dem, &mut grid, &fname)?;
    let t_solve = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let (changed_cells, tiles_written) =
        write_corrected(dem_path, features, opts, &dem, &plan, &grid)?;
    let output = match &opts.destination {
        Destination::InPlace => dem_path.display().to_string(),
        Destination::Path(p) => p.display().to_string(),
    };
    let report = CorrectReport {
        dem: dem_path.display().to_string(),
        features: features.display().to_string(),
        output,
        written: !opts.dry_run,
        window: [
            window.col,
            window.row,
            window.width as i64,
            window.height as i64,
        ],
        cell_size_m: [cell.hx, cell.hy],
        changed_cells,
        tiles_written: tiles_written
            .iter()
            .map(|p| p.display().to_string())
            .collect(),
        corrections: reports,
        timings_s: report::Timings {
            plan: t_plan,
            solve: t_solve,
            write: t2.elapsed().as_secs_f64(),
            total: t0.elapsed().as_secs_f64(),
        },
    };
    if let (Some(staged), Some(path)) = (staged_report, &opts.report) {
        let mut text = serde_json::to_string_pretty(&report)
            .map_err(|e| CorrectError::Internal(format!("report: {e}")))?;
        text.push('\n');
        staged
            .commit(text.as_bytes())
            .map_err(|e| report_error(path, e))?;
    }
    Ok(report)
}

/// The DEM opened, the features of `features` read and checked against
/// it, the landforms placed on the views of the sketch they name
/// (`--sketch`), and their window planned: nothing solved yet. Also the
/// features file's name, which starts every message about a feature.
fn planned(
    dem_path: &Path,
    features: &Path,
    opts: &CorrectOptions,
) -> Result<(Dem, Plan, String), CorrectError> {
    let dem = Dem::open(dem_path)?;
    let mut corrections = geojson_input::read(features, &dem).map_err(CorrectError::Input)?;
    let fname = features.display().to_string();
    let sketch = match &opts.sketch {
        Some(p) => Some(
            crate::sketch::SketchFile::from_path(p)
                .map_err(|e| CorrectError::Input(e.to_string()))?,
        ),
        None => None,
    };
    let sketch_name = opts
        .sketch
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_default();
    landform::resolve(
        &dem,
        sketch.as_ref().map(|s| (s, sketch_name.as_str())),
        &mut corrections,
        &fname,
        LANDFORM_HINT_CORRECT,
    )
    .map_err(CorrectError::Input)?;
    let plan = plan(&dem, corrections, &fname, opts.max_window_cells)?;
    Ok((dem, plan, fname))
}

/// Writes what the corrections made of `grid`: the pictures staged first
/// (`--renders`), the DEM (or, on a dry run, the check that it could be
/// written) with the provenance of `features`, the water mask, then the
/// pictures committed. The changed cells and the tiles written.
fn write_corrected(
    dem_path: &Path,
    features: &Path,
    opts: &CorrectOptions,
    dem: &Dem,
    plan: &Plan,
    grid: &grid::Grid,
) -> Result<(usize, Vec<PathBuf>), CorrectError> {
    let window = plan.window;
    let staged_renders = match &opts.renders {
        Some(dir) => {
            let pics = pictures::pictures(dem, grid, &plan.corrections)
                .map_err(|e| CorrectError::Internal(format!("pictures: {e}")))?;
            Some(
                crate::edit::StagedDir::create(dir, &pics)
                    .map_err(|e| CorrectError::Input(e.to_string()))?,
            )
        }
        None => None,
    };
    let values = grid.write_values();
    let (provenance, wopts) = provenance_of(dem_path, features, &opts.write);
    let written = if opts.dry_run {
        (dem.check_write_back(window, &values)?, Vec::new())
    } else {
        let w = dem.write_back_with(window, &values, &opts.destination, &provenance, &wopts)?;
        (w.changed_cells, w.tiles_written)
    };
    if let Some(path) = &opts.water_mask {
        write_water_mask(path, dem, grid)?;
    }
    if let Some(s) = staged_renders {
        s.commit().map_err(|e| CorrectError::Input(e.to_string()))?;
    }
    Ok(written)
}

/// The provenance a correction writes (its id names the features file
/// and the start of its SHA-256), and `write` with the record of the
/// input DEM, the features' hash and the parameters.
fn provenance_of(
    dem_path: &Path,
    features: &Path,
    write: &WriteOptions,
) -> (Provenance, WriteOptions) {
    let bytes = std::fs::read(features).unwrap_or_default();
    let hash = sha256_hex(&bytes);
    let provenance = Provenance {
        edit_id: format!(
            "correct {}:{}",
            features
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            &hash[..16]
        ),
    };
    let mut wopts = write.clone();
    wopts.record = ProvenanceRecord {
        input: Some(dem_path.display().to_string()),
        sketch_sha256: Some(hash),
        parameters: Some(format!("--features {}", features.display())),
    };
    (provenance, wopts)
}

/// The report's path cannot be written: a user error naming it.
fn report_error(path: &Path, e: impl std::fmt::Display) -> CorrectError {
    CorrectError::Input(format!("{}: cannot write the report: {e}", path.display()))
}

/// The water mask (`--water-mask`): Byte, 1 on water cells, 0 elsewhere,
/// on the window's grid with the DEM's CRS.
fn write_water_mask(path: &Path, dem: &Dem, grid: &grid::Grid) -> Result<(), CorrectError> {
    let spec = crate::raster::output_format::RasterSpec {
        width: grid.width(),
        height: grid.height(),
        geotransform: Some(grid.geotransform().0),
        crs: dem.crs.gdal_definition(),
        nodata: None,
        description: Some("water cells of demsketch correct (1 = water)".into()),
        format: None,
        creation_options: Vec::new(),
    };
    let band: Vec<u8> = grid.water.iter().map(|&w| u8::from(w)).collect();
    crate::raster::output_format::write_raster(path, &spec, vec![band])?;
    Ok(())
}

/// What a landform without a sketch is told, for `correct`.
pub const LANDFORM_HINT_CORRECT: &str =
    "give the sketch file with --sketch (demsketch correct DEM --features F --sketch S)";
/// ... in a batch manifest's corrections.
const LANDFORM_HINT_BATCH: &str =
    "a batch applies landforms only through `demsketch correct --sketch`";

enum ApplyError {
    User(String),
    Internal(String),
}

fn solver_error(e: crate::deform::multigrid::MultigridError) -> ApplyError {
    ApplyError::Internal(format!("solver: {e}"))
}

fn apply_one(
    dem: &Dem,
    grid: &mut grid::Grid,
    c: &Correction,
    default_blend: f64,
    influence: Option<f64>,
) -> Result<FeatureReport, ApplyError> {
    let mut r = FeatureReport::new(c);
    match &c.kind {
        CorrectionKind::Lake {
            area,
            level_m,
            blend_m,
        } => {
            let blend = blend_m.unwrap_or(default_blend);
            let res = lake::apply(grid, area, *level_m, blend).map_err(|e| match e {
                lake::LakeError::Solver(s) => solver_error(s),
                e => ApplyError::User(e.to_string()),
            })?;
            r.blend_m = Some(blend);
            r.level_m = Some(res.level_m);
            r.level_from_shoreline = Some(res.level_from_shore);
            r.water_cells = Some(res.change.water_cells);
            r.cells_changed = res.change.cells_changed;
            r.max_abs_dz_m = res.change.max_abs_dz_m;
        }
        CorrectionKind::River {
            centreline,
            width_m,
            blend_m,
            flow,
        } => {
            let blend = blend_m.unwrap_or(default_blend);
            let res =
                river::apply(grid, centreline, *width_m, *flow, blend).map_err(river_error)?;
            river_report(&mut r, &res, blend);
        }
        CorrectionKind::RiverArea { area, blend_m } => {
            let blend = blend_m.unwrap_or(default_blend);
            let res = river::apply_polygon(grid, area, blend).map_err(river_error)?;
            river_report(&mut r, &res, blend);
        }
        CorrectionKind::ControlCurve {
            points, sections, ..
        } => {
            let infl =
                influence.unwrap_or_else(|| control_curve::influence_for(dem, grid, points, None));
            let res =
                control_curve::apply(dem, grid, points, sections, infl).map_err(curve_error)?;
            r.influence_m = Some(res.influence_m);
            r.max_curve_error_m = Some(res.max_curve_error_m);
            if !sections.is_empty() {
                r.cross_sections = Some(sections.len());
                r.max_section_error_m = Some(res.max_section_error_m);
            }
            r.cells_changed = res.cells_changed;
            r.max_abs_dz_m = res.max_abs_dz_m;
        }
        CorrectionKind::Landform {
            silhouette, placed, ..
        } => {
            let res = landform::apply_landform(dem, grid, c.index, silhouette, placed.as_ref())
                .map_err(landform_error)?;
            landform_report(dem, &mut r, &res, placed.as_ref());
        }
        CorrectionKind::NoiseRegion {
            stroke,
            amplitude_m,
            placed,
            ..
        } => {
            let res = landform::apply_noise_region(
                dem,
                grid,
                c.index,
                stroke,
                *amplitude_m,
                placed.as_ref(),
            )
            .map_err(landform_error)?;
            landform_report(dem, &mut r, &res, None);
        }
        CorrectionKind::Breakline { points, hard, .. } => {
            let infl = influence.unwrap_or_else(|| breakline::default_influence_m(grid.cell));
            r.hard = Some(*hard);
            r.influence_m = Some(infl);
            if *hard {
                let res = breakline::apply_hard(grid, points, infl).map_err(|e| match e {
                    breakline::BreaklineError::Triangulation(m) => ApplyError::Internal(m),
                    e => ApplyError::User(e.to_string()),
                })?;
                r.band_cells = Some(res.band_cells);
                r.cells_changed = res.cells_changed;
                r.max_abs_dz_m = res.max_abs_dz_m;
            } else {
                let res =
                    control_curve::apply(dem, grid, points, &[], infl).map_err(curve_error)?;
                r.max_curve_error_m = Some(res.max_curve_error_m);
                r.cells_changed = res.cells_changed;
                r.max_abs_dz_m = res.max_abs_dz_m;
            }
        }
    }
    Ok(r)
}

/// A river's outcome in its feature's report.
fn river_report(r: &mut FeatureReport, res: &river::RiverResult, blend: f64) {
    r.blend_m = Some(blend);
    r.surface_start_m = Some(res.surface_start_m);
    r.surface_end_m = Some(res.surface_end_m);
    r.reversed = Some(res.reversed);
    r.surface_knots_m = Some(res.knots.clone());
    r.water_cells = Some(res.change.water_cells);
    r.cells_changed = res.change.cells_changed;
    r.max_abs_dz_m = res.change.max_abs_dz_m;
}

fn river_error(e: river::RiverError) -> ApplyError {
    match e {
        river::RiverError::Solver(s) => solver_error(s),
        e => ApplyError::User(e.to_string()),
    }
}

/// A control curve's (or soft breakline's) failure: the solver's and the
/// fit's are the program's, the rest the feature's.
fn curve_error(e: control_curve::CurveError) -> ApplyError {
    match e {
        control_curve::CurveError::Solver(s) => solver_error(s),
        control_curve::CurveError::Fit(f) => ApplyError::Internal(f.to_string()),
        e => ApplyError::User(e.to_string()),
    }
}

fn landform_error(e: landform::LandformError) -> ApplyError {
    match e {
        landform::LandformError::Curve(
            c @ (control_curve::CurveError::Solver(_) | control_curve::CurveError::Fit(_)),
        ) => curve_error(c),
        landform::LandformError::NotPlaced => ApplyError::Internal(e.to_string()),
        e => ApplyError::User(e.to_string()),
    }
}

/// The report of a landform (with its placement) or a noise region.
fn landform_report(
    dem: &Dem,
    r: &mut FeatureReport,
    res: &landform::LandformResult,
    placed: Option<&landform::Placed>,
) {
    r.cells_changed = res.cells_changed;
    r.max_abs_dz_m = res.max_abs_dz_m;
    r.max_curve_error_m = res.max_curve_error_m;
    let mut noise = report::NoiseReport {
        bands: res.spectrum.bands.clone(),
        detail_energy_ratio: res.spectrum.detail_energy_ratio,
        noise_sigma_m: res.noise_sigma_m,
        noise_rms_m: res.noise_rms_m,
    };
    if !noise.detail_energy_ratio.is_finite() {
        noise.detail_energy_ratio = 0.0;
    }
    r.noise = Some(noise);
    if let Some(p) = placed {
        let (boundary, shadow) = landform::geojson_of(dem, p);
        r.landform = Some(report::LandformReport {
            silhouette_points: p.curve.len(),
            both_ends_on_terrain: p.both_ends,
            default_boundary: p.default_boundary,
            shoulders_m: p.default_boundary.then_some(p.shoulders_m),
            peak_m: p
                .curve
                .iter()
                .map(|q| q[2])
                .fold(f64::NEG_INFINITY, f64::max),
            boundary,
            shadow,
        });
    }
}
