//! Rivers (hydro-flattening practice): from a centreline and a width, a
//! water surface that is flat across the river and never rises downstream.
//! Stations every half cell along the centreline take the lower of the two
//! bank heights (the DEM sampled bilinearly one cell beyond each bank); the
//! surface is the lower convex hull of their running minimum from the
//! source to the outlet (never above a bank, non-increasing, and linear in
//! the arc length between a few kinks). Every
//! cell whose centre is within half the width of the centreline gets the
//! surface at the arc length of its nearest centreline point (interpolated
//! linearly between stations, so it is affine across a straight reach and
//! the bilinear surface is flat along its normals); the banks are blended
//! as for lakes ([`super::water::flatten_and_blend`]).
//!
//! The flow runs in the line's order, or with `flow: "auto"` from the higher
//! end (current DEM height at the end points) to the lower.

use super::grid::Grid;
use super::water::{self, Change};

/// What a river did.
#[derive(Debug, Clone, PartialEq)]
pub struct RiverResult {
    /// Water surface at the source and at the outlet, metres.
    pub surface_start_m: f64,
    pub surface_end_m: f64,
    /// True when the centreline was reversed (`flow: "auto"`).
    pub reversed: bool,
    /// `[arc length from the source, surface]` in metres where the surface
    /// profile bends (first and last: the ends); linear in between.
    pub knots: Vec<[f64; 2]>,
    pub change: Change,
}

/// Why a river could not be applied (a user error).
#[derive(Debug, thiserror::Error)]
pub enum RiverError {
    #[error("no valid DEM height along the river to take the surface from")]
    NoHeights,
    #[error("no cell centre lies within half the width of the centreline over valid DEM cells")]
    NoCells,
    #[error("blend solver: {0}")]
    Solver(#[from] crate::deform::multigrid::MultigridError),
}

/// Arc length (metres) of stations and the water surface there.
struct Profile {
    s: Vec<f64>,
    z: Vec<f64>,
    /// The hull's vertices `[s, z]`: the surface is linear between them.
    knots: Vec<[f64; 2]>,
}

impl Profile {
    fn at(&self, s: f64) -> f64 {
        let k = self.s.partition_point(|&v| v <= s);
        if k == 0 {
            return self.z[0];
        }
        if k >= self.s.len() {
            return self.z[self.z.len() - 1];
        }
        let (s0, s1) = (self.s[k - 1], self.s[k]);
        let t = if s1 > s0 { (s - s0) / (s1 - s0) } else { 0.0 };
        self.z[k - 1] + t * (self.z[k] - self.z[k - 1])
    }
}

/// The centreline in window pixel space, upstream first.
fn oriented(grid: &Grid, line: &[[f64; 2]], flow_auto: bool) -> (Vec<[f64; 2]>, bool) {
    let mut pts: Vec<[f64; 2]> = line.iter().map(|&p| grid.local(p)).collect();
    let mut reversed = false;
    if flow_auto {
        let first = grid.bilinear(pts[0]);
        let last = grid.bilinear(pts[pts.len() - 1]);
        if let (Some(a), Some(b)) = (first, last) {
            if a < b {
                pts.reverse();
                reversed = true;
            }
        }
    }
    (pts, reversed)
}

/// Stations along the centreline and the running minimum of the bank
/// heights there.
fn profile(grid: &Grid, pts: &[[f64; 2]], width_m: f64) -> Option<Profile> {
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let offset = 0.5 * width_m + hx.max(hy);
    let (mut s, mut z) = (Vec::new(), Vec::new());
    let mut s0 = 0.0;
    for (k, seg) in pts.windows(2).enumerate() {
        let (a, b) = (seg[0], seg[1]);
        let len = grid.metres(a, b);
        if len == 0.0 {
            continue;
        }
        let (tx, ty) = ((b[0] - a[0]) * hx / len, (b[1] - a[1]) * hy / len);
        let (nx, ny) = (-ty, tx);
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / 0.5).ceil().max(1.0) as usize;
        let last = k + 2 == pts.len();
        for j in 0..n + usize::from(last) {
            let t = j as f64 / n as f64;
            let c = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
            let side = |sign: f64| {
                grid.bilinear([
                    c[0] + sign * nx * offset / hx,
                    c[1] + sign * ny * offset / hy,
                ])
            };
            let bank = match (side(1.0), side(-1.0)) {
                (Some(l), Some(r)) => Some(l.min(r)),
                (l, r) => l.or(r).or_else(|| grid.bilinear(c)),
            };
            s.push(s0 + t * len);
            z.push(bank.unwrap_or(f64::NAN));
        }
        s0 += len;
    }
    let first = z.iter().copied().find(|v| !v.is_nan())?;
    let mut run = first;
    for v in z.iter_mut() {
        if !v.is_nan() {
            run = run.min(*v);
        }
        *v = run;
    }
    Some(lower_hull(Profile {
        s,
        z,
        knots: Vec::new(),
    }))
}

/// The lower convex hull of the running minimum, sampled back at the
/// stations: piecewise linear with few kinks (so the surface is affine in
/// the arc length over long reaches, and flat across them), never above the
/// running minimum (so never above a bank), and non-increasing (a convex
/// function whose last point is its minimum).
fn lower_hull(p: Profile) -> Profile {
    let mut hull: Vec<usize> = Vec::new();
    for i in 0..p.s.len() {
        while hull.len() >= 2 {
            let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
            let cross =
                (p.s[b] - p.s[a]) * (p.z[i] - p.z[a]) - (p.z[b] - p.z[a]) * (p.s[i] - p.s[a]);
            if cross <= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        hull.push(i);
    }
    let knots = Profile {
        s: hull.iter().map(|&i| p.s[i]).collect(),
        z: hull.iter().map(|&i| p.z[i]).collect(),
        knots: Vec::new(),
    };
    let z = p.s.iter().map(|&s| knots.at(s)).collect();
    Profile {
        s: p.s,
        z,
        knots: knots
            .s
            .iter()
            .zip(&knots.z)
            .map(|(&s, &z)| [s, z])
            .collect(),
    }
}

/// Distance (metres) from `p` to the polyline and the arc length of the
/// nearest point.
fn nearest(grid: &Grid, pts: &[[f64; 2]], p: [f64; 2]) -> (f64, f64) {
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let (mut best, mut best_s, mut s0) = (f64::INFINITY, 0.0, 0.0);
    for seg in pts.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        let (dx, dy) = ((b[0] - a[0]) * hx, (b[1] - a[1]) * hy);
        let (px, py) = ((p[0] - a[0]) * hx, (p[1] - a[1]) * hy);
        let l2 = dx * dx + dy * dy;
        let t = if l2 > 0.0 {
            ((px * dx + py * dy) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = (px - t * dx).hypot(py - t * dy);
        if d < best {
            best = d;
            best_s = s0 + t * l2.sqrt();
        }
        s0 += l2.sqrt();
    }
    (best, best_s)
}

/// Flattens the river and blends its banks.
pub fn apply(
    grid: &mut Grid,
    line: &[[f64; 2]],
    width_m: f64,
    flow_auto: bool,
    blend_m: f64,
) -> Result<RiverResult, RiverError> {
    let (pts, reversed) = oriented(grid, line, flow_auto);
    let prof = profile(grid, &pts, width_m).ok_or(RiverError::NoHeights)?;
    let half = 0.5 * width_m;
    let (gx, gy) = (half / grid.cell.hx + 1.0, half / grid.cell.hy + 1.0);
    let (w, h) = (grid.width() as f64, grid.height() as f64);
    let xs = pts.iter().map(|p| p[0]);
    let ys = pts.iter().map(|p| p[1]);
    let c0 = (xs.clone().fold(f64::INFINITY, f64::min) - gx)
        .floor()
        .clamp(0.0, w) as usize;
    let c1 = (xs.fold(f64::NEG_INFINITY, f64::max) + gx)
        .ceil()
        .clamp(0.0, w) as usize;
    let r0 = (ys.clone().fold(f64::INFINITY, f64::min) - gy)
        .floor()
        .clamp(0.0, h) as usize;
    let r1 = (ys.fold(f64::NEG_INFINITY, f64::max) + gy)
        .ceil()
        .clamp(0.0, h) as usize;
    // Candidates: the cells near some segment (its bounding box grown by
    // half the width), so long winding rivers do not test their whole box.
    let bw = c1.saturating_sub(c0);
    let mut candidate = vec![false; bw * r1.saturating_sub(r0)];
    for seg in pts.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        let sc0 = ((a[0].min(b[0]) - gx).floor().max(c0 as f64) as usize).min(c1);
        let sc1 = ((a[0].max(b[0]) + gx).ceil().max(0.0) as usize).min(c1);
        let sr0 = ((a[1].min(b[1]) - gy).floor().max(r0 as f64) as usize).min(r1);
        let sr1 = ((a[1].max(b[1]) + gy).ceil().max(0.0) as usize).min(r1);
        for r in sr0..sr1 {
            for c in sc0..sc1 {
                candidate[(r - r0) * bw + (c - c0)] = true;
            }
        }
    }
    let mut water = Vec::new();
    for r in r0..r1 {
        for c in c0..c1 {
            let i = r * grid.width() + c;
            if !candidate[(r - r0) * bw + (c - c0)] || grid.values[i].is_nan() {
                continue;
            }
            let (d, s) = nearest(grid, &pts, [c as f64 + 0.5, r as f64 + 0.5]);
            if d <= half {
                water.push((i, prof.at(s)));
            }
        }
    }
    if water.is_empty() {
        return Err(RiverError::NoCells);
    }
    let change = water::flatten_and_blend(grid, &water, blend_m)?;
    Ok(RiverResult {
        surface_start_m: prof.z[0],
        surface_end_m: prof.z[prof.z.len() - 1],
        reversed,
        knots: prof.knots,
        change,
    })
}

/// The axis of a river polygon: its principal direction in metres (unit,
/// pixel-space components scaled by the cell size) and its centroid.
fn principal_axis(grid: &Grid, ring: &[[f64; 2]]) -> ([f64; 2], [f64; 2]) {
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let n = ring.len() as f64;
    let (mx, my) = (
        ring.iter().map(|p| p[0]).sum::<f64>() / n,
        ring.iter().map(|p| p[1]).sum::<f64>() / n,
    );
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in ring {
        let (dx, dy) = ((p[0] - mx) * hx, (p[1] - my) * hy);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    ([angle.cos(), angle.sin()], [mx, my])
}

/// Flattens a river given as a polygon (a straight-ish reach): the flow
/// runs along the polygon's principal axis from its higher end to its
/// lower; stations every half cell along the axis take the lowest
/// shoreline height among the outline points that project within half a
/// cell of them; the surface is the lower hull of their running minimum,
/// and every cell whose centre is inside the polygon gets the surface at
/// its projection on the axis (so the water is flat along the axis's
/// normals). Winding rivers are better given as a centreline.
pub fn apply_polygon(
    grid: &mut Grid,
    area: &geo::MultiPolygon<f64>,
    blend_m: f64,
) -> Result<RiverResult, RiverError> {
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let mut outline: Vec<[f64; 2]> = Vec::new();
    for poly in &area.0 {
        let ring: Vec<[f64; 2]> = poly
            .exterior()
            .coords()
            .map(|c| grid.local([c.x, c.y]))
            .collect();
        for seg in ring.windows(2) {
            let (a, b) = (seg[0], seg[1]);
            let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / 0.5).ceil().max(1.0) as usize;
            for k in 0..n {
                let t = k as f64 / n as f64;
                outline.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
            }
        }
    }
    if outline.len() < 3 {
        return Err(RiverError::NoCells);
    }
    let (u, m) = principal_axis(grid, &outline);
    let along = |p: [f64; 2]| (p[0] - m[0]) * hx * u[0] + (p[1] - m[1]) * hy * u[1];
    let samples: Vec<(f64, f64)> = outline
        .iter()
        .filter_map(|&p| grid.bilinear(p).map(|h| (along(p), h)))
        .collect();
    if samples.is_empty() {
        return Err(RiverError::NoHeights);
    }
    let t0 = samples.iter().map(|s| s.0).fold(f64::INFINITY, f64::min);
    let t1 = samples
        .iter()
        .map(|s| s.0)
        .fold(f64::NEG_INFINITY, f64::max);
    let step = 0.5 * hx.min(hy);
    let n = ((t1 - t0) / step).ceil().max(1.0) as usize + 1;
    let mut bank = vec![f64::NAN; n];
    for &(t, h) in &samples {
        let k = (((t - t0) / step).round() as usize).min(n - 1);
        bank[k] = if bank[k].is_nan() { h } else { bank[k].min(h) };
    }
    // Upstream is the end whose first tenth of the banks is higher.
    let tenth = (n / 10).max(1);
    let mean = |v: &[f64]| {
        let ok: Vec<f64> = v.iter().copied().filter(|x| !x.is_nan()).collect();
        ok.iter().sum::<f64>() / ok.len().max(1) as f64
    };
    let reversed = mean(&bank[..tenth]) < mean(&bank[n - tenth..]);
    if reversed {
        bank.reverse();
    }
    let first = bank
        .iter()
        .copied()
        .find(|v| !v.is_nan())
        .ok_or(RiverError::NoHeights)?;
    let mut run = first;
    for v in bank.iter_mut() {
        if !v.is_nan() {
            run = run.min(*v);
        }
        *v = run;
    }
    let prof = lower_hull(Profile {
        s: (0..n).map(|k| k as f64 * step).collect(),
        z: bank,
        knots: Vec::new(),
    });
    let span = (n - 1) as f64 * step;
    let cells = super::lake::cells_inside(grid, area);
    if cells.is_empty() {
        return Err(RiverError::NoCells);
    }
    let w = grid.width();
    let water: Vec<(usize, f64)> = cells
        .into_iter()
        .map(|i| {
            let t = along([(i % w) as f64 + 0.5, (i / w) as f64 + 0.5]) - t0;
            let s = if reversed { span - t } else { t };
            (i, prof.at(s))
        })
        .collect();
    let change = water::flatten_and_blend(grid, &water, blend_m)?;
    Ok(RiverResult {
        surface_start_m: prof.z[0],
        surface_end_m: prof.z[prof.z.len() - 1],
        reversed,
        knots: prof.knots,
        change,
    })
}
