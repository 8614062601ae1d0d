//! Control curves (Maquettier section III, positional constraints): a 3D
//! polyline the corrected DEM must pass through. The curve is rasterised
//! into displacement constraints by the deformation's own rule
//! ([`crate::deform::constraints::rasterise`]: every cell in the bilinear
//! stencil of a curve point), the displacement is diffused by the multigrid
//! over the cells within the influence distance
//! ([`crate::deform::locality::influence_mask`]) and is exactly 0 beyond
//! it, so those cells stay bit-identical. This is the edit pipeline's solve
//! applied to the current heights of the correction run, so it composes
//! with the lakes and rivers before it. Cross-sections attached to the
//! curve (section III-B) are fitted after it and then together with it,
//! the curve weighing more, as the paper solves its two least-squares
//! problems in turn (see [`apply`]); the joint fit is solved directly
//! ([`super::sparse_lsq`]).
//!
//! What a bilinear DEM can follow: where the surface read bilinearly passes
//! through a straight, sloping curve segment at every point, each cell
//! square the segment crosses must be planar (the bilinear twist term would
//! bend the profile) and consecutive squares hinge on their shared cells, so
//! all the cells under one straight segment lie on one plane: the cross
//! slope under a segment is a single number, and at a bend the two
//! segments' planes must share the cells of the bend. Cross-sections that
//! ask for other cross slopes can then be met only to within a few cell
//! sizes times the slopes' differences. On the bundled 250 m fixture the
//! embankment with five sections of `tests/correct_control_curve.rs` cannot
//! be met better than 0.06 m on the curve and 0.12 m on the sections by
//! any cell heights (a minimax fit over every cell under them); the same
//! curve and sections on the fixture resampled to 62.5 m cells are met
//! within 0.05 and 0.1 m (the errors fall as the square of the cell size).

use crate::deform::locality::{affected_window, default_influence_m, influence_mask};
use crate::deform::multigrid::{self, MultigridError, MultigridOptions};
use crate::deform::{constraints, CurveConstraint};
use crate::raster::Dem;

use super::grid::Grid;

/// What a control curve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CurveResult {
    /// The influence distance used, metres.
    pub influence_m: f64,
    /// Cells whose height changed.
    pub cells_changed: usize,
    /// Largest `|new - old|`, metres.
    pub max_abs_dz_m: f64,
    /// Largest `|DEM - z|` along the curve afterwards (bilinear, every
    /// half cell), metres.
    pub max_curve_error_m: f64,
    /// Largest `|DEM - z|` along the cross-sections afterwards, metres.
    pub max_section_error_m: f64,
}

/// Why a control curve could not be applied (a user error).
#[derive(Debug, thiserror::Error)]
pub enum CurveError {
    #[error("the curve passes over no valid DEM cell")]
    NothingConstrained,
    #[error("solver: {0}")]
    Solver(#[from] MultigridError),
    #[error("{0}")]
    Fit(#[from] super::sparse_lsq::LsqError),
}

/// The influence distance of a curve: the given one, else the edit's default.
pub fn influence_for(dem: &Dem, grid: &Grid, points: &[[f64; 3]], given: Option<f64>) -> f64 {
    given.unwrap_or_else(|| {
        let curve = CurveConstraint {
            points: points.to_vec(),
        };
        default_influence_m(dem, &[curve], grid.cell)
    })
}

/// The curve and its cross-sections as the deformation's curves.
pub fn curves(points: &[[f64; 3]], sections: &[Vec<[f64; 3]>]) -> Vec<CurveConstraint> {
    std::iter::once(points)
        .chain(sections.iter().map(|s| s.as_slice()))
        .map(|p| CurveConstraint { points: p.to_vec() })
        .collect()
}

/// The heights of the cells in the bilinear stencil of `curve` (not yet
/// `decided`) fitted so that the bilinear surface passes through it
/// ([`super::curve_fit`]); they are marked `decided` and written to
/// `target`. Returns how many cells it constrained.
fn fit_curve(
    hm: &crate::raster::HeightMap,
    curve: &CurveConstraint,
    cell: crate::deform::CellSize,
    decided: &mut [bool],
    target: &mut [f64],
) -> Result<usize, CurveError> {
    let curves = std::slice::from_ref(curve);
    let cons = constraints::rasterise(hm, curves, cell);
    // The rasteriser run on a zero surface gives the curve's height at each
    // cell's closest curve point: the fit's start.
    let mut zero = hm.clone();
    for h in zero.data.iter_mut().filter(|h| !h.is_nan()) {
        *h = 0.0;
    }
    let at_curve = constraints::rasterise(&zero, curves, cell);
    let n = hm.data.len();
    let keep: Vec<bool> = (0..n)
        .map(|i| cons.constrained[i] && at_curve.constrained[i] && !decided[i])
        .collect();
    let h0: Vec<f64> = (0..n).map(|i| at_curve.delta[i] as f64).collect();
    let gt = hm.geotransform;
    let local: Vec<[f64; 3]> = curve
        .points
        .iter()
        .filter_map(|p| gt.crs_to_pixel(p[0], p[1]).map(|(x, y)| [x, y, p[2]]))
        .collect();
    let (fitted, _) = super::curve_fit::fit(hm.width, hm.height, &keep, &h0, &[(&local, 1.0)])?;
    let mut count = 0;
    for i in 0..n {
        if keep[i] {
            decided[i] = true;
            target[i] = fitted[i];
            count += 1;
        }
    }
    Ok(count)
}

/// Weight of the control curve's samples against a cross-section's in the
/// joint fit: the curve's constraints come first (the paper solves them
/// first; the weight makes the joint least squares nearly lexicographic).
const CURVE_WEIGHT: f64 = 1e3;

/// The second least-squares problem: every stencil cell of the curve and
/// its cross-sections, started from the first fits (`target`), fitted to
/// the curve (weight [`CURVE_WEIGHT`]) and the cross-sections together, so
/// that the cells next to the curve also follow the sections' slopes.
fn refit_together(
    hm: &crate::raster::HeightMap,
    all: &[CurveConstraint],
    decided: &[bool],
    target: &mut [f64],
) -> Result<(), CurveError> {
    let gt = hm.geotransform;
    let local: Vec<Vec<[f64; 3]>> = all
        .iter()
        .map(|c| {
            c.points
                .iter()
                .filter_map(|p| gt.crs_to_pixel(p[0], p[1]).map(|(x, y)| [x, y, p[2]]))
                .collect()
        })
        .collect();
    let lines: Vec<(&[[f64; 3]], f64)> = local
        .iter()
        .enumerate()
        .map(|(k, l)| (l.as_slice(), if k == 0 { CURVE_WEIGHT } else { 1.0 }))
        .collect();
    let (fitted, _) = super::curve_fit::fit(hm.width, hm.height, decided, target, &lines)?;
    for (i, &d) in decided.iter().enumerate() {
        if d {
            target[i] = fitted[i];
        }
    }
    Ok(())
}

/// Deforms the current heights so that they pass through the curve, then
/// through its cross-sections (Maquettier section III-B): the cells under
/// the control curve are fitted first; the cells under each cross-section
/// not already fitted next, by the same least-squares fit; then all of
/// them together, the curve's samples weighing [`CURVE_WEIGHT`] times a
/// section's (so the cells beside the curve take the sections' slopes
/// without the curve giving way); the other cells within the influence distance of any
/// of them take the displacement that minimises the discrete Laplacian
/// energy (the multigrid's harmonic solve, the paper's term against high
/// curvature), and cells beyond it keep their heights exactly.
pub fn apply(
    dem: &Dem,
    grid: &mut Grid,
    points: &[[f64; 3]],
    sections: &[Vec<[f64; 3]>],
    influence_m: f64,
) -> Result<CurveResult, CurveError> {
    let all = curves(points, sections);
    let cell = grid.cell;
    let win = affected_window(dem, &all, cell, influence_m)
        .and_then(|w| w.intersect(&grid.window))
        .ok_or(CurveError::NothingConstrained)?;
    let (cells_changed, max_abs) = solve_in(grid, &all, win, true, |cons, _| {
        influence_mask(cons, cell, influence_m)
    })?;
    Ok(CurveResult {
        influence_m,
        cells_changed,
        max_abs_dz_m: max_abs,
        max_curve_error_m: curve_error(grid, points),
        max_section_error_m: sections
            .iter()
            .map(|s| curve_error(grid, s))
            .fold(0.0, f64::max),
    })
}

/// The solve of [`apply`] over `win` (DEM grid, inside the grid's window):
/// the curves `all` (the first is the control curve, the others its
/// cross-sections) fitted (with `fit`; else the cells of their stencils
/// take the rasteriser's heights, the curve's at the closest point), then
/// the cells `inside` says may move (a mask
/// over `win`, given the curves' constraint raster and the window's
/// heights) diffused harmonically, every other cell kept. Returns the
/// cells changed and the largest `|dz|`. The landforms of
/// [`super::landform`] solve through it with their boundary as the mask.
pub fn solve_in(
    grid: &mut Grid,
    all: &[CurveConstraint],
    win: crate::raster::Window,
    fit: bool,
    inside: impl FnOnce(&constraints::ConstraintRaster, &crate::raster::HeightMap) -> Vec<bool>,
) -> Result<(usize, f64), CurveError> {
    let cell = grid.cell;
    let (lc, lr) = (
        (win.col - grid.window.col) as usize,
        (win.row - grid.window.row) as usize,
    );
    let hm = grid.current().crop(lc, lr, win.width, win.height);
    let cons = constraints::rasterise(&hm, all, cell);
    let n = win.len();
    let mut decided = vec![false; n];
    let mut target = vec![0f64; n];
    // The control curve first, then the cross-sections.
    if !fit {
        if !cons.constrained.iter().any(|&c| c) {
            return Err(CurveError::NothingConstrained);
        }
    } else if fit_curve(&hm, &all[0], cell, &mut decided, &mut target)? == 0 {
        return Err(CurveError::NothingConstrained);
    }
    if fit && all.len() > 1 {
        for c in &all[1..] {
            fit_curve(&hm, c, cell, &mut decided, &mut target)?;
        }
        refit_together(&hm, all, &decided, &mut target)?;
    }
    let inside = inside(&cons, &hm);
    let mut fixed = vec![true; n];
    for i in 0..n {
        if !cons.constrained[i] && inside[i] && !hm.data[i].is_nan() {
            fixed[i] = false;
        }
    }
    let opts = MultigridOptions {
        tolerance: 1e-6,
        max_cycles: 300,
        ..MultigridOptions::default()
    };
    let mut values: Vec<f32> = (0..n)
        .map(|i| {
            if decided[i] {
                (target[i] - hm.data[i] as f64) as f32
            } else if cons.constrained[i] {
                cons.delta[i]
            } else {
                0.0
            }
        })
        .collect();
    multigrid::solve(
        win.width,
        win.height,
        cell.hx,
        cell.hy,
        &fixed,
        &mut values,
        &opts,
    )?;
    let (mut cells_changed, mut max_abs) = (0, 0f64);
    for r in 0..win.height {
        for c in 0..win.width {
            let m = values[r * win.width + c];
            let i = (r + lr) * grid.width() + c + lc;
            if m == 0.0 || m.is_nan() || grid.values[i].is_nan() {
                continue;
            }
            grid.values[i] += m as f64;
            cells_changed += 1;
            max_abs = max_abs.max(m.abs() as f64);
        }
    }
    Ok((cells_changed, max_abs))
}

/// Largest `|DEM - z|` along the curve (bilinear on the current heights,
/// every half cell; points over nodata are skipped).
pub fn curve_error(grid: &Grid, points: &[[f64; 3]]) -> f64 {
    let gt = grid.geotransform();
    let px: Vec<[f64; 3]> = points
        .iter()
        .filter_map(|p| gt.crs_to_pixel(p[0], p[1]).map(|(x, y)| [x, y, p[2]]))
        .collect();
    let mut worst = 0f64;
    let mut check = |x: f64, y: f64, z: f64| {
        if let Some(h) = grid.bilinear([x, y]) {
            worst = worst.max((h - z).abs());
        }
    };
    if px.len() == 1 {
        check(px[0][0], px[0][1], px[0][2]);
    }
    for seg in px.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / 0.5).ceil().max(1.0) as usize;
        for k in 0..=n {
            let t = k as f64 / n as f64;
            check(
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            );
        }
    }
    worst
}
