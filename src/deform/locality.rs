//! Locality of an edit: the displacement falls to zero within an influence
//! distance `d` of the curves, so the window of the DEM an edit touches, and
//! the tiles under it, are known before anything is solved.
//!
//! - [`cell_size_m`]: metres per cell of a DEM grid (geographic DEMs use the
//!   WGS84 radii of curvature at the curves' latitude).
//! - [`default_influence_m`]: `d` when the user gives none: half the
//!   diagonal of the curves' bounding box, at least [`MIN_INFLUENCE_CELLS`]
//!   cells.
//! - [`affected_window`]: the curves' bounding box grown by `d` (plus the
//!   constraint reach and one cell), clipped to the DEM. Every cell within
//!   `d` of a curve lies inside it.
//! - [`influence_mask`]: which cells of the window the solver may change.
//!   A cell is free when its distance to the nearest constrained cell centre
//!   plus the constraint reach `r` (the cell diagonal) is at most `d`;
//!   constrained centres lie within `r` of a curve, so every free cell lies
//!   within `d` of a curve, and every cell farther than `d` from all curves
//!   is held at exactly 0. [`room_to_edge`]: how far inside that edge a
//!   cell lies (the bounded curves of [`super::deform_bounded`] hold a
//!   cell only where the room is at least their displacement there).
//!   Distances come from an exact Euclidean distance transform (Felzenszwalb
//!   and Huttenlocher's lower envelope of parabolas, separable, anisotropic
//!   cells), parallel over rows and columns.
//!
//! The mask, not the window, bounds the solve: the window edge is as far from
//! the curves as the mask's edge, so a cell outside the window would be held
//! at 0 anyway, and the solution is the one on the whole DEM grid (seam
//! consistency across tiles). At the DEM's own edges the solver holds `M = 0`
//! just outside the grid.

use rayon::prelude::*;

use super::constraints::{CellSize, ConstraintRaster, CurveConstraint};
use crate::raster::{Dem, GeoTransform, Window};

/// Floor of the default influence distance, in cells.
pub const MIN_INFLUENCE_CELLS: f64 = 8.0;

/// Fraction of the curves' bounding-box diagonal used as the default
/// influence distance.
pub const DEFAULT_INFLUENCE_FRACTION: f64 = 0.5;

const WGS84_A: f64 = 6_378_137.0;
const WGS84_E2: f64 = 0.006_694_379_990_141_316;

/// Metres per cell of a grid with geotransform `gt`. Projected CRSs are taken
/// to be in metres; for geographic CRSs (degrees, x = longitude) the sizes
/// are those at latitude `lat_deg` on the WGS84 ellipsoid (meridional and
/// prime-vertical radii of curvature). Rotation terms are folded into the
/// column and row lengths: pixel axes are treated as orthogonal.
pub fn cell_size_m(gt: &GeoTransform, geographic: bool, lat_deg: f64) -> CellSize {
    let g = gt.0;
    let (mx, my) = if geographic {
        let phi = lat_deg.to_radians();
        let s2 = phi.sin().powi(2);
        let w = (1.0 - WGS84_E2 * s2).sqrt();
        let n = WGS84_A / w;
        let m = WGS84_A * (1.0 - WGS84_E2) / (w * w * w);
        let deg = std::f64::consts::PI / 180.0;
        (n * phi.cos() * deg, m * deg)
    } else {
        (1.0, 1.0)
    };
    CellSize {
        hx: (g[1] * mx).hypot(g[4] * my),
        hy: (g[2] * mx).hypot(g[5] * my),
    }
}

/// Bounding box `[xmin, ymin, xmax, ymax]` of all curve points in the CRS.
pub fn curves_bbox(curves: &[CurveConstraint]) -> Option<[f64; 4]> {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in curves.iter().flat_map(|c| c.points.iter()) {
        b = [
            b[0].min(p[0]),
            b[1].min(p[1]),
            b[2].max(p[0]),
            b[3].max(p[1]),
        ];
    }
    (b[0] <= b[2] && b[1] <= b[3]).then_some(b)
}

/// Bounding box of the curve points in pixel coordinates of `dem`'s grid:
/// `[col_min, row_min, col_max, row_max]` (fractional).
fn pixel_bbox(dem: &Dem, curves: &[CurveConstraint]) -> Option<[f64; 4]> {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for p in curves.iter().flat_map(|c| c.points.iter()) {
        let (x, y) = dem.geotransform.crs_to_pixel(p[0], p[1])?;
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    }
    (b[0] <= b[2] && b[1] <= b[3]).then_some(b)
}

/// The default influence distance in metres: [`DEFAULT_INFLUENCE_FRACTION`]
/// of the diagonal of the curves' bounding box, at least
/// [`MIN_INFLUENCE_CELLS`] cells (of the larger cell side).
pub fn default_influence_m(dem: &Dem, curves: &[CurveConstraint], cell: CellSize) -> f64 {
    let floor = MIN_INFLUENCE_CELLS * cell.hx.max(cell.hy);
    match pixel_bbox(dem, curves) {
        Some(b) => {
            let diag = ((b[2] - b[0]) * cell.hx).hypot((b[3] - b[1]) * cell.hy);
            (DEFAULT_INFLUENCE_FRACTION * diag).max(floor)
        }
        None => floor,
    }
}

/// The window of `dem` an edit with these curves and influence distance can
/// change: the curves' pixel bounding box grown by `influence_m` plus the
/// constraint reach and one cell, clipped to the DEM. `None` when it misses
/// the DEM.
pub fn affected_window(
    dem: &Dem,
    curves: &[CurveConstraint],
    cell: CellSize,
    influence_m: f64,
) -> Option<Window> {
    let b = pixel_bbox(dem, curves)?;
    let r = cell.constraint_reach();
    let gx = (influence_m + r) / cell.hx + 1.0;
    let gy = (influence_m + r) / cell.hy + 1.0;
    let c0 = (b[0] - gx).floor();
    let r0 = (b[1] - gy).floor();
    let c1 = (b[2] + gx).ceil();
    let r1 = (b[3] + gy).ceil();
    // Clip in f64 first so absurd coordinates cannot overflow.
    let (w, h) = (dem.width as f64, dem.height as f64);
    let (c0, c1) = (c0.clamp(0.0, w), c1.clamp(0.0, w));
    let (r0, r1) = (r0.clamp(0.0, h), r1.clamp(0.0, h));
    let win = Window::new(c0 as i64, r0 as i64, (c1 - c0) as usize, (r1 - r0) as usize);
    (!win.is_empty()).then_some(win)
}

/// Which cells of the constraint window may take a nonzero displacement
/// (free or constrained): see the module documentation. Constrained cells
/// are always inside.
pub fn influence_mask(c: &ConstraintRaster, cell: CellSize, influence_m: f64) -> Vec<bool> {
    let d2 = squared_distance_to_constraints(c, cell);
    mask_of_distances(&d2, c, cell, influence_m)
}

/// [`influence_mask`] from the squared distances `d2` of
/// [`squared_distance_to_constraints`] of `c`.
pub fn mask_of_distances(
    d2: &[f32],
    c: &ConstraintRaster,
    cell: CellSize,
    influence_m: f64,
) -> Vec<bool> {
    d2.par_iter()
        .zip(c.constrained.par_iter())
        .map(|(&d2, &k)| k || room_to_edge(d2, cell, influence_m) >= 0.0)
        .collect()
}

/// How far, in metres, a cell at squared distance `d2` from the nearest
/// constrained cell centre lies inside the edge of the influence
/// (negative: beyond it). [`influence_mask`] holds the cells where it is
/// at least 0.
pub fn room_to_edge(d2: f32, cell: CellSize, influence_m: f64) -> f64 {
    influence_m - ((d2 as f64).sqrt() * (1.0 + 1e-6) + cell.constraint_reach())
}

/// Squared distance in m^2 from every cell centre of the window to the
/// nearest constrained cell centre (infinity when none), by a separable
/// exact Euclidean distance transform: columns first (in parallel blocks of
/// columns, so reads stay cache-friendly), then rows.
pub fn squared_distance_to_constraints(c: &ConstraintRaster, cell: CellSize) -> Vec<f32> {
    const BLOCK: usize = 16;
    let (w, h) = (c.width, c.height);
    if w == 0 || h == 0 {
        return Vec::new();
    }
    // Pass 1: along each column (spacing hy); block-local column-major.
    let blocks: Vec<Vec<f32>> = (0..w.div_ceil(BLOCK))
        .into_par_iter()
        .map(|bi| {
            let c0 = bi * BLOCK;
            let nc = BLOCK.min(w - c0);
            let mut out = vec![0f32; nc * h];
            let mut f = vec![0f64; h];
            let mut d = vec![0f64; h];
            for k in 0..nc {
                for (row, fv) in f.iter_mut().enumerate() {
                    *fv = if c.constrained[row * w + c0 + k] {
                        0.0
                    } else {
                        f64::INFINITY
                    };
                }
                edt_1d(&f, cell.hy, &mut d);
                for (o, v) in out[k * h..(k + 1) * h].iter_mut().zip(&d) {
                    *o = *v as f32;
                }
            }
            out
        })
        .collect();
    // Pass 2: along each row (spacing hx).
    let mut d2 = vec![0f32; w * h];
    d2.par_chunks_mut(w).enumerate().for_each(|(row, out_row)| {
        let f: Vec<f64> = (0..w)
            .map(|col| blocks[col / BLOCK][(col % BLOCK) * h + row] as f64)
            .collect();
        let mut d = vec![0.0; w];
        edt_1d(&f, cell.hx, &mut d);
        for (o, v) in out_row.iter_mut().zip(d) {
            *o = v as f32;
        }
    });
    d2
}

/// One-dimensional squared distance transform of sampled function `f`
/// (infinity = no seed) on points spaced `h` apart:
/// `out[p] = min_q ((p - q) h)^2 + f[q]` (Felzenszwalb and Huttenlocher).
fn edt_1d(f: &[f64], h: f64, out: &mut [f64]) {
    let n = f.len();
    let mut v: Vec<usize> = Vec::with_capacity(n);
    let mut z: Vec<f64> = Vec::with_capacity(n + 1);
    for q in 0..n {
        if !f[q].is_finite() {
            continue;
        }
        let xq = q as f64 * h;
        loop {
            match v.last() {
                None => {
                    v.push(q);
                    z.clear();
                    z.push(f64::NEG_INFINITY);
                    break;
                }
                Some(&p) => {
                    let xp = p as f64 * h;
                    let s = ((f[q] + xq * xq) - (f[p] + xp * xp)) / (2.0 * (xq - xp));
                    if s <= *z.last().unwrap_or(&f64::NEG_INFINITY) {
                        v.pop();
                        z.pop();
                        continue;
                    }
                    v.push(q);
                    z.push(s);
                    break;
                }
            }
        }
    }
    if v.is_empty() {
        out.iter_mut().for_each(|o| *o = f64::INFINITY);
        return;
    }
    let mut k = 0;
    for (p, o) in out.iter_mut().enumerate() {
        let xp = p as f64 * h;
        while k + 1 < v.len() && z[k + 1] < xp {
            k += 1;
        }
        let xq = v[k] as f64 * h;
        *o = (xp - xq) * (xp - xq) + f[v[k]];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edt_matches_brute_force() {
        let (w, h) = (37, 23);
        let cell = CellSize { hx: 2.0, hy: 3.0 };
        let mut constrained = vec![false; w * h];
        for (c, r) in [(3, 4), (20, 20), (36, 0), (10, 11), (11, 11)] {
            constrained[r * w + c] = true;
        }
        let raster = ConstraintRaster {
            width: w,
            height: h,
            constrained: constrained.clone(),
            delta: vec![0.0; w * h],
            count: 5,
            max_abs_delta: 0.0,
        };
        let d2 = squared_distance_to_constraints(&raster, cell);
        for r in 0..h {
            for c in 0..w {
                let mut best = f64::INFINITY;
                for rr in 0..h {
                    for cc in 0..w {
                        if constrained[rr * w + cc] {
                            let dx = (c as f64 - cc as f64) * cell.hx;
                            let dy = (r as f64 - rr as f64) * cell.hy;
                            best = best.min(dx * dx + dy * dy);
                        }
                    }
                }
                assert!((d2[r * w + c] as f64 - best).abs() <= 1e-4 * best.max(1.0));
            }
        }
    }

    #[test]
    fn geographic_cell_size() {
        // 3 arc-second cells at 37 N: about 74 m by 92.5 m.
        let gt = GeoTransform::north_up(-113.0, 37.5, 1.0 / 1200.0, 1.0 / 1200.0);
        let c = cell_size_m(&gt, true, 37.0);
        assert!((c.hx - 74.1).abs() < 0.3, "{c:?}");
        assert!((c.hy - 92.5).abs() < 0.3, "{c:?}");
    }
}
