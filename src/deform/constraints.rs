//! Rasterisation of placed 3D curves into displacement constraints
//! (section 6.1 of Tassé et al. 2014): each curve point `p = (x, y, z)` asks
//! for the displacement `delta = z - H(x, y)`, and these displacements are
//! set on the cells of the DEM grid near the curve, where the multigrid
//! solver holds them fixed while it diffuses them into the map `M`.
//!
//! # Rule
//!
//! The edited terrain is read between cell centres by bilinear
//! interpolation, so a curve point `q` is governed by the (up to) four cells
//! whose bilinear weight at `q` is positive: the cells whose centre lies
//! less than one cell from `q` along both axes. The constrained set is the
//! union of these stencils over the whole curve: **every valid cell whose
//! centre is within less than one cell of the curve in the L-infinity sense**
//! (`|x_c - x_q| < 1` and `|y_c - y_q| < 1` in pixel units for some curve
//! point `q`). Its value is taken at the curve point `q*` **closest** to the
//! centre (Euclidean distance in metres): `delta_c = z(q*) - H(q*)`, with `z`
//! interpolated linearly along the polyline segment and `H` interpolated
//! bilinearly between cell centres. When several curves or segments come
//! near a cell, the closest point wins; exact ties go to the earlier curve /
//! segment, so the result is a deterministic function of the curves.
//!
//! # What is exact
//!
//! Along a straight segment the closest point of a centre is an affine
//! function of the centre, so if `delta` varies linearly along the segment
//! (the curve's `z` is linear there and `H` is linear along it, e.g. on a
//! planar terrain), the constrained values are samples of one affine function
//! of the plane, and bilinear interpolation reproduces affine functions:
//! since every stencil cell of every curve point is constrained, the edited
//! terrain `H' = H + M`, interpolated bilinearly, passes **exactly** through
//! `z(q)` at every curve point, whatever the curve's direction or slope (no
//! gaps, no staircase). In general the error is second order: it is bounded
//! by the variation of `delta`'s derivative within about one cell (terrain
//! curvature along the curve, curve bends), and it is larger within a cell
//! of a curve's two end points, where the closest point sticks to the end
//! point.
//!
//! The constrained set along a curve is a band two to four cells wide, so it
//! is 4-connected (no gaps on steep or diagonal curves, no diagonal leaks for
//! the 5-point solver). Across the band `M` is constant along the normal to
//! the curve. Curves closer to each other than about two cells compete for
//! the cells between them (the nearer one wins).
//!
//! Nodata cells are never constrained. Where the bilinear stencil of `q*`
//! touches nodata (or the window's edge), `H(q*)` is the bilinear weighting
//! renormalised over the valid corners; a curve point with no valid corner
//! gives no constraint.
//!
//! Distances are measured in metres on the grid with cell sizes
//! `hx x hy` ([`CellSize`]), so the rule is the same on geographic DEMs
//! whose cells are not square in metres.

use crate::raster::HeightMap;

/// A placed 3D curve: a polyline of points `[x, y, z]` in the DEM's CRS
/// (`x`, `y`) and its vertical datum (`z`, absolute metres). One point is a
/// point constraint.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CurveConstraint {
    pub points: Vec<[f64; 3]>,
}

/// A height prescribed on one cell of the DEM grid (`col`, `row` in the
/// whole DEM's pixel space): the edited terrain `H' = H + M` is held at
/// `height` (absolute metres) there. The edit pipeline uses these to put the
/// mesh vertices around a placed stroke exactly where the stroke needs them
/// (see `edit::contour`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CellConstraint {
    pub col: i64,
    pub row: i64,
    pub height: f64,
}

/// Size of one grid cell in metres: `hx` along a row (between columns), `hy`
/// along a column (between rows).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CellSize {
    pub hx: f64,
    pub hy: f64,
}

impl CellSize {
    /// The largest distance in metres between a constrained cell's centre
    /// and its curve: less than one cell along both axes, so less than the
    /// cell diagonal `hypot(hx, hy)`.
    pub fn constraint_reach(&self) -> f64 {
        self.hx.hypot(self.hy)
    }
}

/// Displacement constraints on a window (the grid of the `HeightMap` they
/// were rasterised on), row-major.
#[derive(Debug, Clone)]
pub struct ConstraintRaster {
    pub width: usize,
    pub height: usize,
    /// True on constrained cells.
    pub constrained: Vec<bool>,
    /// `delta` on constrained cells, 0 elsewhere.
    pub delta: Vec<f32>,
    /// Number of constrained cells.
    pub count: usize,
    /// Largest `|delta|`, metres (0 when nothing is constrained).
    pub max_abs_delta: f64,
}

/// A cell near a curve and the closest point of one segment to its centre.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    cell: usize,
    /// Squared distance centre to closest point, m^2.
    d2: f64,
    /// The cell is in the bilinear stencil of some point of the segment.
    member: bool,
    /// Closest point in window pixel coordinates and its curve height.
    qx: f64,
    qy: f64,
    z: f64,
}

/// Rasterises `curves` (CRS coordinates) as displacement constraints on the
/// grid of `base` (heights `H`, NaN = nodata, with the window's
/// geotransform) following the rule of the module documentation. Points
/// outside the window are allowed: only cells inside it are constrained.
/// Curves must have finite coordinates (the caller checks).
pub fn rasterise(base: &HeightMap, curves: &[CurveConstraint], cell: CellSize) -> ConstraintRaster {
    resolve(base, curve_candidates(base, curves, cell))
}

/// [`rasterise`] of `curves`, and of `curves` followed by `extra`, with
/// the candidates of `curves` found once: the two rasters are those of
/// `rasterise(base, curves, cell)` and `rasterise(base, &[curves,
/// extra].concat(), cell)`, to the bit (the candidates of a list of
/// curves are those of its curves in turn).
pub fn rasterise_with(
    base: &HeightMap,
    curves: &[CurveConstraint],
    extra: &[CurveConstraint],
    cell: CellSize,
) -> (ConstraintRaster, ConstraintRaster) {
    let own = curve_candidates(base, curves, cell);
    let mut all = own.clone();
    all.extend(curve_candidates(base, extra, cell));
    (resolve(base, own), resolve(base, all))
}

/// The candidate cells of `curves` on the grid of `base`, curve by curve
/// and segment by segment.
fn curve_candidates(
    base: &HeightMap,
    curves: &[CurveConstraint],
    cell: CellSize,
) -> Vec<Candidate> {
    let (w, h) = (base.width, base.height);
    let mut cands: Vec<Candidate> = Vec::new();
    for curve in curves {
        // Window pixel coordinates of the vertices.
        let px: Vec<[f64; 3]> = curve
            .points
            .iter()
            .filter_map(|p| {
                base.geotransform
                    .crs_to_pixel(p[0], p[1])
                    .map(|(x, y)| [x, y, p[2]])
            })
            .collect();
        match px.len() {
            0 => {}
            1 => segment_candidates(px[0], px[0], w, h, cell, &mut cands),
            _ => {
                for s in px.windows(2) {
                    segment_candidates(s[0], s[1], w, h, cell, &mut cands);
                }
            }
        }
    }
    cands
}

/// The constraints of the candidates `cands` (in curve order): per cell,
/// the closest candidate.
fn resolve(base: &HeightMap, mut cands: Vec<Candidate>) -> ConstraintRaster {
    let (w, h) = (base.width, base.height);
    // Per cell, the closest candidate; the stable sort keeps curve order
    // among exact ties, and the first of a tie wins.
    cands.sort_by_key(|c| c.cell);
    let mut constrained = vec![false; w * h];
    let mut delta = vec![0f32; w * h];
    let mut count = 0;
    let mut max_abs_delta = 0f64;
    let mut i = 0;
    while i < cands.len() {
        let mut best = cands[i];
        let mut member = best.member;
        let mut j = i + 1;
        while j < cands.len() && cands[j].cell == best.cell {
            if cands[j].d2 < best.d2 {
                best = cands[j];
            }
            member |= cands[j].member;
            j += 1;
        }
        i = j;
        if !member || base.data[best.cell].is_nan() {
            continue;
        }
        let Some(hq) = bilinear_valid(base, best.qx, best.qy) else {
            continue;
        };
        let d = best.z - hq;
        if !d.is_finite() {
            continue;
        }
        constrained[best.cell] = true;
        delta[best.cell] = d as f32;
        count += 1;
        max_abs_delta = max_abs_delta.max(d.abs());
    }
    ConstraintRaster {
        width: w,
        height: h,
        constrained,
        delta,
        count,
        max_abs_delta,
    }
}

/// Adds the cell constraints `cells` (whole-DEM pixel coordinates) to
/// `cons`, rasterised on `base`, the window `window` of the DEM: each cell
/// inside the window and not nodata is constrained to `delta = height - H`,
/// replacing what the curves asked there. When a cell is listed twice the
/// last entry wins. Only cells within the curves' influence (`within`,
/// [`super::locality::influence_mask`] of the curves alone) or on a curve
/// are taken: a held or lowered cell never extends the region an edit may
/// change (issue 11 item 4: cells beyond the influence distance of the
/// curves stay bit-identical).
pub fn apply_cells(
    cons: &mut ConstraintRaster,
    base: &HeightMap,
    window: crate::raster::Window,
    cells: &[CellConstraint],
    within: &[bool],
) {
    for c in cells {
        let (x, y) = (c.col - window.col, c.row - window.row);
        if x < 0 || y < 0 || x as usize >= cons.width || y as usize >= cons.height {
            continue;
        }
        let k = y as usize * cons.width + x as usize;
        if !within[k] && !cons.constrained[k] {
            continue;
        }
        let h = base.data[k];
        let d = c.height - h as f64;
        if h.is_nan() || !d.is_finite() {
            continue;
        }
        if !cons.constrained[k] {
            cons.constrained[k] = true;
            cons.count += 1;
        }
        cons.delta[k] = d as f32;
        cons.max_abs_delta = cons.max_abs_delta.max(d.abs());
    }
}

/// Drops the constraints of `cons` on cells outside `within` (within an
/// influence mask, [`super::locality::influence_mask`]), and counts the
/// rest again: the cells of curves that act only within the influence of
/// others (a stroke's feature completion beyond its ends).
pub fn keep_within(cons: &mut ConstraintRaster, within: &[bool]) {
    let mut count = 0;
    let mut max_abs_delta = 0f64;
    for ((k, d), &w) in cons
        .constrained
        .iter_mut()
        .zip(cons.delta.iter_mut())
        .zip(within)
    {
        if !*k {
            continue;
        }
        if !w {
            *k = false;
            *d = 0.0;
            continue;
        }
        count += 1;
        max_abs_delta = max_abs_delta.max(d.abs() as f64);
    }
    cons.count = count;
    cons.max_abs_delta = max_abs_delta;
}

/// Pushes every cell whose centre lies within [`CellSize::constraint_reach`]
/// of the segment `a b` (window pixel coordinates and heights), with its
/// closest point on the segment and whether it is in the bilinear stencil of
/// a segment point. Long segments are cut into pieces of a few cells so that
/// only cells near the segment are visited; the closest point of the whole
/// segment is the closest over its pieces, and heights are interpolated along
/// the whole segment so the pieces agree.
fn segment_candidates(
    a: [f64; 3],
    b: [f64; 3],
    w: usize,
    h: usize,
    cell: CellSize,
    out: &mut Vec<Candidate>,
) {
    let (dxp, dyp) = (b[0] - a[0], b[1] - a[1]);
    let reach = cell.constraint_reach();
    let (rpx, rpy) = (reach / cell.hx, reach / cell.hy);
    // Only the part of the segment within reach of the window matters
    // (Liang-Barsky clip to the grown window), so far-away points cost
    // nothing.
    let Some((ta, tb)) = clip_param(
        a,
        dxp,
        dyp,
        [
            -rpx - 1.0,
            -rpy - 1.0,
            w as f64 + rpx + 1.0,
            h as f64 + rpy + 1.0,
        ],
    ) else {
        return;
    };
    let len_px = (tb - ta) * dxp.abs().max(dyp.abs());
    let pieces = (len_px / 4.0).ceil().max(1.0) as usize;
    // Metric coordinates: x * hx, y * hy.
    let (ax, ay) = (a[0] * cell.hx, a[1] * cell.hy);
    let (ex, ey) = (dxp * cell.hx, dyp * cell.hy);
    let len2 = ex * ex + ey * ey;
    let reach2 = reach * reach;
    for k in 0..pieces {
        let t0 = ta + (tb - ta) * (k as f64 / pieces as f64);
        let t1 = ta + (tb - ta) * ((k + 1) as f64 / pieces as f64);
        let (x0, x1) = (a[0] + t0 * dxp, a[0] + t1 * dxp);
        let (y0, y1) = (a[1] + t0 * dyp, a[1] + t1 * dyp);
        // Cells whose centre (c + 0.5) may lie within reach of the piece.
        let c_lo = (x0.min(x1) - rpx - 0.5).ceil().max(0.0);
        let c_hi = (x0.max(x1) + rpx - 0.5).floor().min(w as f64 - 1.0);
        let r_lo = (y0.min(y1) - rpy - 0.5).ceil().max(0.0);
        let r_hi = (y0.max(y1) + rpy - 0.5).floor().min(h as f64 - 1.0);
        if !(c_lo <= c_hi && r_lo <= r_hi) {
            continue;
        }
        for row in r_lo as usize..=r_hi as usize {
            let cy = row as f64 + 0.5;
            let py = cy * cell.hy;
            for col in c_lo as usize..=c_hi as usize {
                let cx = col as f64 + 0.5;
                let px = cx * cell.hx;
                let t = if len2 > 0.0 {
                    (((px - ax) * ex + (py - ay) * ey) / len2).clamp(t0, t1)
                } else {
                    0.0
                };
                let (qx, qy) = (ax + t * ex, ay + t * ey);
                let d2 = (px - qx) * (px - qx) + (py - qy) * (py - qy);
                if d2 >= reach2 {
                    continue;
                }
                out.push(Candidate {
                    cell: row * w + col,
                    d2,
                    member: in_stencil(a, dxp, dyp, t0, t1, cx, cy),
                    qx: a[0] + t * dxp,
                    qy: a[1] + t * dyp,
                    z: a[2] + t * (b[2] - a[2]),
                });
            }
        }
    }
}

/// The parameter range `[ta, tb]` within `[0, 1]` of the points
/// `a + t (dx, dy)` inside the box `[x0, y0, x1, y1]`, if any.
fn clip_param(a: [f64; 3], dx: f64, dy: f64, b: [f64; 4]) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    for (p, d, min, max) in [(a[0], dx, b[0], b[2]), (a[1], dy, b[1], b[3])] {
        if d == 0.0 {
            if p < min || p > max {
                return None;
            }
        } else {
            let (u, v) = ((min - p) / d, (max - p) / d);
            lo = lo.max(u.min(v));
            hi = hi.min(u.max(v));
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// True when some point `a + t (dx, dy)`, `t` in `[t0, t1]`, lies less than
/// one pixel from `(cx, cy)` along both axes, i.e. the cell centred there
/// has a positive bilinear weight at that point.
fn in_stencil(a: [f64; 3], dx: f64, dy: f64, t0: f64, t1: f64, cx: f64, cy: f64) -> bool {
    // The open interval of t where |a + t d - c| < 1 along one axis.
    let axis = |a: f64, d: f64, c: f64| -> (f64, f64) {
        if d == 0.0 {
            if (a - c).abs() < 1.0 {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                (f64::INFINITY, f64::NEG_INFINITY)
            }
        } else {
            let (u, v) = ((c - 1.0 - a) / d, (c + 1.0 - a) / d);
            (u.min(v), u.max(v))
        }
    };
    let (xl, xh) = axis(a[0], dx, cx);
    let (yl, yh) = axis(a[1], dy, cy);
    let lo = t0.max(xl).max(yl);
    let hi = t1.min(xh).min(yh);
    if lo > hi {
        return false;
    }
    // The midpoint of a non-empty intersection satisfies the strict
    // inequalities unless the intersection is a single boundary point.
    let t = 0.5 * (lo + hi);
    (a[0] + t * dx - cx).abs() < 1.0 && (a[1] + t * dy - cy).abs() < 1.0
}

/// Bilinear height at window pixel coordinates `(px, py)` (cell centres at
/// +0.5), with the weights renormalised over the corners that are valid and
/// inside the grid; `None` when no corner with positive weight is valid.
pub fn bilinear_valid(map: &HeightMap, px: f64, py: f64) -> Option<f64> {
    let x = px - 0.5;
    let y = py - 0.5;
    let (c0, r0) = (x.floor(), y.floor());
    let (fx, fy) = (x - c0, y - r0);
    let mut sum = 0.0;
    let mut wsum = 0.0;
    for (dc, dr, wgt) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        if wgt <= 0.0 {
            continue;
        }
        let (c, r) = (c0 as i64 + dc, r0 as i64 + dr);
        if c < 0 || r < 0 || c as usize >= map.width || r as usize >= map.height {
            continue;
        }
        let v = map.data[r as usize * map.width + c as usize];
        if v.is_nan() {
            continue;
        }
        sum += wgt * v as f64;
        wsum += wgt;
    }
    (wsum > 0.0).then(|| sum / wsum)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::{Crs, GeoTransform};

    fn plane(w: usize, h: usize) -> HeightMap {
        let mut data = vec![0f32; w * h];
        for r in 0..h {
            for c in 0..w {
                data[r * w + c] = (100.0 + 2.0 * c as f64 - 3.0 * r as f64) as f32;
            }
        }
        HeightMap {
            width: w,
            height: h,
            data,
            geotransform: GeoTransform::north_up(0.0, 0.0, 1.0, 1.0),
            crs: Crs {
                epsg: None,
                wkt: String::new(),
                proj: None,
                geographic: false,
            },
        }
    }

    #[test]
    fn point_constraint_covers_its_bilinear_stencil() {
        let m = plane(10, 10);
        // CRS y goes down with rows (north-up, origin at 0): pixel (4.3, 5.8).
        let curve = CurveConstraint {
            points: vec![[4.3, -5.8, 500.0]],
        };
        let c = rasterise(&m, &[curve], CellSize { hx: 1.0, hy: 1.0 });
        assert_eq!(c.count, 4);
        for (col, row) in [(3, 5), (4, 5), (3, 6), (4, 6)] {
            let k = row * 10 + col;
            assert!(c.constrained[k], "cell {col},{row}");
        }
        let hq = 100.0 + 2.0 * (4.3 - 0.5) - 3.0 * (5.8 - 0.5);
        assert!((c.delta[5 * 10 + 4] as f64 - (500.0 - hq)).abs() < 1e-4);
    }

    #[test]
    fn far_away_points_are_clipped() {
        let m = plane(10, 10);
        // A segment from far outside through the grid's row 5 centre line.
        let curve = CurveConstraint {
            points: vec![[-1e12, -5.5, 100.0], [1e12, -5.5, 100.0]],
        };
        let c = rasterise(&m, &[curve], CellSize { hx: 1.0, hy: 1.0 });
        // Only row 5 (rows 4 and 6 are a whole cell away).
        assert_eq!(c.count, 10);
        assert!((0..10).all(|col| c.constrained[5 * 10 + col]));
    }

    #[test]
    fn nodata_is_never_constrained_and_renormalises() {
        let mut m = plane(6, 6);
        m.data[2 * 6 + 2] = f32::NAN;
        let curve = CurveConstraint {
            points: vec![[2.5, -2.5, 0.0], [2.5, -2.5, 0.0]],
        };
        let c = rasterise(&m, &[curve], CellSize { hx: 1.0, hy: 1.0 });
        // The point is the centre of a nodata cell; its neighbours' centres
        // are a whole cell away (zero bilinear weight): nothing constrained.
        assert_eq!(c.count, 0);
        // Halfway between the nodata cell and the one below: only that one counts.
        assert_eq!(bilinear_valid(&m, 2.5, 3.0), Some(100.0 + 4.0 - 9.0));
    }
}
