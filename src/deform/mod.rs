//! Deformation: turns placed 3D curve constraints into a displacement field
//! `M` and the corrected DEM `H' = H + M` (section 6 of Tassé et al. 2014).
//! The displacement is diffused by a multigrid solver ([`multigrid`]) so that
//! the terrain's own small-scale detail is preserved.
//!
//! [`deform`] is one edit, a pure function of the DEM, the curves and the
//! options (the lowering step of the pipeline calls it again with the old
//! and the new curves together):
//!
//! 1. [`plan`]: the cell size in metres, the influence distance `d` and the
//!    affected window (the curves' bounding box grown by `d`, clipped to the
//!    DEM) and the tiles under it, all before any pixel is read
//!    ([`locality`]).
//! 2. The window is read through the tile layer as one seamless array
//!    across tile boundaries, so the edit is solved as if the affected tiles
//!    were one raster (seam consistency).
//! 3. The curves are rasterised as displacement constraints
//!    `delta = z - H(x, y)` with sub-cell accuracy ([`constraints`]).
//! 4. Cells farther than `d` from every curve, and nodata cells, are held at
//!    `M = 0`; the multigrid solver diffuses the constraints over the rest
//!    (Laplace, or screened Poisson with [`DeformOptions::screening`]) to the
//!    stated relative residual. Held cells and *bounded* curves
//!    ([`deform_bounded`]: the edit's feature completion beyond a stroke's
//!    ends) act only within `d` of the curves; they never widen it.
//! 5. [`Deformation::write_values`] gives `H + M` where `M != 0` and NaN
//!    (keep) elsewhere, for [`crate::raster::Dem::write_back`]: cells beyond
//!    the influence distance come out bit-identical and tiles without a
//!    changed cell are not rewritten.

pub mod constraints;
pub mod locality;
pub mod multigrid;

pub use constraints::{CellConstraint, CellSize, ConstraintRaster, CurveConstraint};

use std::time::Instant;

use crate::raster::{Dem, HeightMap, RasterError, Window};
use multigrid::{MultigridError, MultigridOptions};

/// Options of [`deform`].
#[derive(Debug, Clone, PartialEq)]
pub struct DeformOptions {
    /// Distance in metres beyond which the displacement is exactly 0. `None`:
    /// [`locality::default_influence_m`] (half the diagonal of the curves'
    /// bounding box, at least 8 cells).
    pub influence_m: Option<f64>,
    /// Relative residual `||b - A m|| / ||b||` the solver must reach (see
    /// [`multigrid`]). Default `1e-5`.
    pub tolerance: f64,
    /// Screening coefficient `c` (1/m^2) of `Laplace(M) - c M = 0`; 0 (the
    /// default) is the paper's Laplace diffusion. `c > 0` makes the
    /// displacement decay over about `1 / sqrt(c)` metres inside the
    /// influence distance.
    pub screening: f64,
    /// Most V-cycles before the solve is declared not converged. Default 100.
    pub max_cycles: usize,
    /// Largest affected window, in cells. Default 2^25 (about 5800 x 5800;
    /// a solve needs about 40 bytes per cell).
    pub max_window_cells: usize,
}

impl Default for DeformOptions {
    fn default() -> Self {
        DeformOptions {
            influence_m: None,
            tolerance: 1e-5,
            screening: 0.0,
            max_cycles: 100,
            max_window_cells: 1 << 25,
        }
    }
}

/// What [`plan`] decides before reading any pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct DeformPlan {
    /// The affected window in the DEM grid.
    pub window: Window,
    /// Indices into the DEM's tiles of the tiles the window touches.
    pub affected_tiles: Vec<usize>,
    /// The influence distance in metres.
    pub influence_m: f64,
    /// Cell size in metres used for distances and the solver.
    pub cell: CellSize,
}

/// Numbers about one deformation.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DeformStats {
    /// Cells holding a displacement constraint.
    pub constrained_cells: usize,
    /// Cells the solver was free to change (within the influence distance,
    /// valid, not constrained).
    pub free_cells: usize,
    /// Cells with `M != 0`.
    pub changed_cells: usize,
    /// Largest `|M|`, metres.
    pub max_abs_displacement_m: f64,
    /// Largest `|delta|` of a constraint, metres.
    pub max_abs_constraint_m: f64,
    /// The influence distance used, metres.
    pub influence_m: f64,
    /// Cell size in metres.
    pub cell_size_m: CellSize,
    /// V-cycles the solver ran.
    pub cycles: usize,
    /// Relative residual reached.
    pub relative_residual: f64,
    /// Multigrid levels.
    pub levels: usize,
    /// Wall-clock seconds: reading the window, rasterising the constraints
    /// and the influence mask, solving.
    pub read_s: f64,
    pub constraints_s: f64,
    pub solve_s: f64,
}

impl DeformStats {
    /// `changed_cells` and `max_abs_displacement_m` counted again from
    /// `displacement` (`M`, NaN on nodata), after it was built or combined
    /// outside the solver.
    pub fn recount(&mut self, displacement: &[f32]) {
        self.changed_cells = displacement
            .iter()
            .filter(|m| **m != 0.0 && !m.is_nan())
            .count();
        self.max_abs_displacement_m = displacement
            .iter()
            .filter(|m| !m.is_nan())
            .fold(0f64, |a, m| a.max(m.abs() as f64));
    }

    /// The figures of a deformation that solved nothing: cell size and
    /// influence distance, every count and time zero.
    pub fn unsolved(cell_size_m: CellSize, influence_m: f64) -> DeformStats {
        DeformStats {
            constrained_cells: 0,
            free_cells: 0,
            changed_cells: 0,
            max_abs_displacement_m: 0.0,
            max_abs_constraint_m: 0.0,
            influence_m,
            cell_size_m,
            cycles: 0,
            relative_residual: 0.0,
            levels: 0,
            read_s: 0.0,
            constraints_s: 0.0,
            solve_s: 0.0,
        }
    }
}

/// The result of [`deform`] on the affected window.
#[derive(Debug, Clone)]
pub struct Deformation {
    /// Affected window in the DEM grid.
    pub window: Window,
    /// `M` on the window, row-major: exactly 0 beyond the influence distance,
    /// NaN on nodata.
    pub displacement: Vec<f32>,
    /// `H` on the window (NaN = nodata).
    pub base: HeightMap,
    /// Indices into the DEM's tiles of the tiles the window touches.
    pub affected_tiles: Vec<usize>,
    /// Constrained cells of the window, row-major.
    pub constrained: Vec<bool>,
    pub stats: DeformStats,
}

impl Deformation {
    /// `H + M` on the window (nodata stays NaN; cells with `M == 0` keep
    /// their input value exactly).
    pub fn edited(&self) -> HeightMap {
        let mut out = self.base.clone();
        for (h, &m) in out.data.iter_mut().zip(&self.displacement) {
            if !h.is_nan() && m != 0.0 && !m.is_nan() {
                *h += m;
            }
        }
        out
    }

    /// Values for [`Dem::write_back`] over [`Deformation::window`]: `H + M`
    /// (in f64) where `M != 0`, NaN (keep) where `M == 0` or on nodata.
    pub fn write_values(&self) -> Vec<f64> {
        self.base
            .data
            .iter()
            .zip(&self.displacement)
            .map(|(&h, &m)| {
                if h.is_nan() || m.is_nan() || m == 0.0 {
                    f64::NAN
                } else {
                    h as f64 + m as f64
                }
            })
            .collect()
    }
}

impl Deformation {
    /// No deformation at all, over `window` of `dem` (an edit whose
    /// strokes all lie where the terrain already shows them): `M = 0`
    /// everywhere, so [`Deformation::write_values`] keeps every cell.
    pub fn none(dem: &Dem, window: Window) -> Result<Deformation, DeformError> {
        let base = dem.read_height_map(window)?;
        // (Nothing is solved: the cell size is only reported.)
        let cell = locality::cell_size_m(&dem.geotransform, dem.crs.geographic, 0.0);
        let displacement = base
            .data
            .iter()
            .map(|h| if h.is_nan() { f32::NAN } else { 0.0 })
            .collect();
        Ok(Deformation {
            window,
            displacement,
            affected_tiles: Vec::new(),
            constrained: vec![false; window.len()],
            stats: DeformStats::unsolved(cell, 0.0),
            base,
        })
    }
}

/// Why [`deform`] failed.
#[derive(Debug, thiserror::Error)]
pub enum DeformError {
    #[error("no curve constraints given")]
    NoCurves,
    #[error("curve {index} has no points")]
    EmptyCurve { index: usize },
    #[error("curve {curve} point {point} has a non-finite coordinate")]
    NonFinite { curve: usize, point: usize },
    #[error("invalid deformation option: {0}")]
    BadOption(String),
    #[error("{}: the curves lie outside the DEM", .path.display())]
    OffDem { path: std::path::PathBuf },
    #[error("{}: no curve passes over a valid DEM cell (all outside the DEM or over nodata)", .path.display())]
    NothingConstrained { path: std::path::PathBuf },
    #[error("{}: the affected window {width} x {height} exceeds the limit of {max} cells; lower influence_m", .path.display())]
    WindowTooLarge {
        path: std::path::PathBuf,
        width: usize,
        height: usize,
        max: usize,
    },
    #[error("{0}")]
    Raster(#[from] RasterError),
    #[error("deformation solver: {0}")]
    Solver(#[from] MultigridError),
}

fn check_inputs(curves: &[CurveConstraint], opts: &DeformOptions) -> Result<(), DeformError> {
    if curves.is_empty() {
        return Err(DeformError::NoCurves);
    }
    for (ci, c) in curves.iter().enumerate() {
        if c.points.is_empty() {
            return Err(DeformError::EmptyCurve { index: ci });
        }
        if let Some(pi) = c
            .points
            .iter()
            .position(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Err(DeformError::NonFinite {
                curve: ci,
                point: pi,
            });
        }
    }
    if let Some(d) = opts.influence_m {
        if !(d.is_finite() && d > 0.0) {
            return Err(DeformError::BadOption(format!(
                "influence_m {d} must be positive and finite"
            )));
        }
    }
    if !(opts.tolerance.is_finite() && opts.tolerance > 0.0) {
        return Err(DeformError::BadOption(format!(
            "tolerance {} must be positive and finite",
            opts.tolerance
        )));
    }
    if !(opts.screening.is_finite() && opts.screening >= 0.0) {
        return Err(DeformError::BadOption(format!(
            "screening {} must be >= 0 and finite",
            opts.screening
        )));
    }
    Ok(())
}

/// The affected window, tiles, influence distance and cell size of an edit
/// with these curves, before reading any pixel.
pub fn plan(
    dem: &Dem,
    curves: &[CurveConstraint],
    opts: &DeformOptions,
) -> Result<DeformPlan, DeformError> {
    check_inputs(curves, opts)?;
    let bbox = locality::curves_bbox(curves).ok_or(DeformError::NoCurves)?;
    let lat = (0.5 * (bbox[1] + bbox[3])).clamp(-89.9, 89.9);
    let cell = locality::cell_size_m(&dem.geotransform, dem.crs.geographic, lat);
    if !(cell.hx.is_finite() && cell.hy.is_finite() && cell.hx > 0.0 && cell.hy > 0.0) {
        return Err(DeformError::BadOption(format!(
            "{}: cell size {} x {} m is not usable",
            dem.path.display(),
            cell.hx,
            cell.hy
        )));
    }
    let influence_m = opts
        .influence_m
        .unwrap_or_else(|| locality::default_influence_m(dem, curves, cell));
    let window = locality::affected_window(dem, curves, cell, influence_m).ok_or_else(|| {
        DeformError::OffDem {
            path: dem.path.clone(),
        }
    })?;
    if window.len() > opts.max_window_cells {
        return Err(DeformError::WindowTooLarge {
            path: dem.path.clone(),
            width: window.width,
            height: window.height,
            max: opts.max_window_cells,
        });
    }
    Ok(DeformPlan {
        affected_tiles: dem.tiles_touching(&window),
        window,
        influence_m,
        cell,
    })
}

/// Deforms `dem` so that it passes through `curves` (see the module
/// documentation). Reads only the affected window; writes nothing.
pub fn deform(
    dem: &Dem,
    curves: &[CurveConstraint],
    opts: &DeformOptions,
) -> Result<Deformation, DeformError> {
    deform_with_cells(dem, curves, &[], opts)
}

/// [`deform`] with, in addition to the curves, heights prescribed on single
/// DEM cells ([`CellConstraint`]): such a cell is held at its height,
/// whatever the curves ask there (see [`constraints::apply_cells`]). The
/// affected window and the influence are the curves' alone; cells beyond
/// the curves' influence distance, or on nodata, are ignored (they stay
/// exactly as they are).
pub fn deform_with_cells(
    dem: &Dem,
    curves: &[CurveConstraint],
    cells: &[CellConstraint],
    opts: &DeformOptions,
) -> Result<Deformation, DeformError> {
    deform_bounded(dem, curves, &[], cells, opts)
}

/// [`deform_with_cells`] with, in addition, curves that act only within
/// the influence of `curves` (`bounded`: the edit's feature completion,
/// which carries a stroke's ends down to the ground beyond what was
/// drawn). The window, the default and the mask of the influence are
/// those of `curves` alone; `bounded` is rasterised with them (the
/// nearest curve point decides a cell, whichever list it is in), and its
/// constraints on cells beyond the influence of `curves`, or too high
/// above the terrain for the room left to the influence's edge
/// ([`BOUNDED_FALL`]), are dropped ([`constraints::keep_within`]): no
/// cell farther than the influence distance from `curves` changes, and
/// the edge does not become a wall. With no `bounded` curve this is
/// [`deform_with_cells`].
pub fn deform_bounded(
    dem: &Dem,
    curves: &[CurveConstraint],
    bounded: &[CurveConstraint],
    cells: &[CellConstraint],
    opts: &DeformOptions,
) -> Result<Deformation, DeformError> {
    let plan = plan(dem, curves, opts)?;
    check_bounded(bounded, curves.len())?;
    let t0 = Instant::now();
    let base = dem.read_height_map(plan.window)?;
    let t1 = Instant::now();
    let (mut cons, inside) = constrain(&base, curves, bounded, &plan);
    // Held and lowered cells, like the bounded curves, act only within the
    // curves' influence.
    constraints::apply_cells(&mut cons, &base, plan.window, cells, &inside);
    if cons.count == 0 {
        return Err(DeformError::NothingConstrained {
            path: dem.path.clone(),
        });
    }
    let n = plan.window.len();
    let mut fixed = vec![true; n];
    let mut values = vec![0f32; n];
    let mut free_cells = 0;
    for i in 0..n {
        if cons.constrained[i] {
            values[i] = cons.delta[i];
        } else if inside[i] && !base.data[i].is_nan() {
            fixed[i] = false;
            free_cells += 1;
        }
    }
    let t2 = Instant::now();
    let mg = MultigridOptions {
        tolerance: opts.tolerance,
        max_cycles: opts.max_cycles,
        screening: opts.screening,
        ..MultigridOptions::default()
    };
    let solved = multigrid::solve(
        plan.window.width,
        plan.window.height,
        plan.cell.hx,
        plan.cell.hy,
        &fixed,
        &mut values,
        &mg,
    )?;
    let t3 = Instant::now();
    let mut changed_cells = 0;
    let mut max_abs = 0f64;
    for (v, &h) in values.iter_mut().zip(&base.data) {
        if h.is_nan() {
            *v = f32::NAN;
        } else if *v != 0.0 {
            changed_cells += 1;
            max_abs = max_abs.max(v.abs() as f64);
        }
    }
    Ok(Deformation {
        window: plan.window,
        displacement: values,
        affected_tiles: plan.affected_tiles,
        constrained: cons.constrained,
        stats: DeformStats {
            constrained_cells: cons.count,
            free_cells,
            changed_cells,
            max_abs_displacement_m: max_abs,
            max_abs_constraint_m: cons.max_abs_delta,
            influence_m: plan.influence_m,
            cell_size_m: plan.cell,
            cycles: solved.cycles,
            relative_residual: solved.relative_residual,
            levels: solved.levels,
            read_s: (t1 - t0).as_secs_f64(),
            constraints_s: (t2 - t1).as_secs_f64(),
            solve_s: (t3 - t2).as_secs_f64(),
        },
        base,
    })
}

/// The constraints of `curves` and `bounded` on the window `base` of
/// `plan`, and the influence mask of `curves` alone; the bounded curves'
/// constraints beyond it are dropped.
fn constrain(
    base: &HeightMap,
    curves: &[CurveConstraint],
    bounded: &[CurveConstraint],
    plan: &DeformPlan,
) -> (ConstraintRaster, Vec<bool>) {
    let (cell, d) = (plan.cell, plan.influence_m);
    if bounded.is_empty() {
        let own = constraints::rasterise(base, curves, cell);
        let d2 = locality::squared_distance_to_constraints(&own, cell);
        let inside = locality::mask_of_distances(&d2, &own, cell, d);
        return (own, inside);
    }
    // (the curves' candidate cells found once for both rasters)
    let (own, mut cons) = constraints::rasterise_with(base, curves, bounded, cell);
    let d2 = locality::squared_distance_to_constraints(&own, cell);
    let inside = locality::mask_of_distances(&d2, &own, cell, d);
    let keep: Vec<bool> = (0..cons.delta.len())
        .map(|i| {
            own.constrained[i]
                || (inside[i]
                    && cons.delta[i].abs() as f64
                        <= BOUNDED_FALL * locality::room_to_edge(d2[i], cell, d))
        })
        .collect();
    constraints::keep_within(&mut cons, &keep);
    (cons, inside)
}

/// A bounded curve holds a cell only where the terrain can come back to
/// its own height before the edge of the influence at a mean slope of at
/// most this (1: 45 degrees): `|delta| <= BOUNDED_FALL * room`, the room
/// being the cell's distance to that edge. A completion still high above
/// the ground where it leaves the influence is let go before it, so the
/// edge is not a wall.
pub const BOUNDED_FALL: f64 = 1.0;

/// The bounded curves must have points, all finite (numbered after the
/// `first` influence-defining curves in the errors).
fn check_bounded(bounded: &[CurveConstraint], first: usize) -> Result<(), DeformError> {
    for (k, c) in bounded.iter().enumerate() {
        if c.points.is_empty() {
            return Err(DeformError::EmptyCurve { index: first + k });
        }
        if let Some(pi) = c
            .points
            .iter()
            .position(|p| !p.iter().all(|v| v.is_finite()))
        {
            return Err(DeformError::NonFinite {
                curve: first + k,
                point: pi,
            });
        }
    }
    Ok(())
}
