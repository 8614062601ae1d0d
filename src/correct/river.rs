//! Rivers (hydro-flattening practice): from a centreline and a width, a
//! water surface that is flat across the river and never rises downstream.
//! Stations every half cell along the centreline take the lower of the two
//! bank heights (the DEM sampled bilinearly one cell beyond each bank); the
//! surface is the lower convex hull of their running minimum from the
//! source to the outlet (never above a bank, non-increasing, and linear in
//! the arc length between a few kinks). Every cell whose centre is within
//! half the width of the centreline gets the surface at the arc length of
//! its nearest centreline point, so it is affine across a straight reach
//! and the bilinear surface is flat along its normals.
//!
//! **Bends.** At a vertex where the centreline turns by `theta`, the
//! normals of the two segments cross on the inner side: a cell near the
//! inner bank is nearest to the upstream segment at arc length
//! `s_v - d tan(theta / 2)` or to the downstream one at
//! `s_v + d tan(theta / 2)` (`d` its distance from the centreline), so on a
//! sloping surface the heights across the bend jumped along the bisector
//! (up to 0.6 m on the Vinschgau valley fixture). No sloping surface can be
//! flat along cross-sections whose direction turns (a bilinear surface flat
//! along two directions is level), so the river is *level* over each bend:
//! from `a = w/2 max(tan(theta / 2), sin theta) + 2 cells` before the
//! vertex to as far after it. `w/2 tan(theta / 2)` is where the normals of
//! the two segments meet the inner bank; `w/2 sin theta` is how far along
//! the other segment the cells of a segment's normal at the vertex lie, so
//! the level reach holds the normals of both segments at the vertex, their
//! bisector and the fan of the outer side; the two cells keep every
//! bilinear stencil of those sections in it. Overlapping bends merge.
//! The hull is taken in the arc length with these level reaches removed
//! (`u`), so the surface stays continuous, non-increasing and never above a
//! bank, is exactly level through each bend and linear in `s` between the
//! kinks the report lists (`surface_knots_m`: the hull's bends and the ends
//! of the level reaches). The banks are blended as for lakes
//! ([`super::water::flatten_and_blend`]).
//!
//! The flow runs as [`Flow`] says: in the line's order (`downstream: true`
//! or `"end"`, or `flow: "line"`), against it (`downstream: false` or
//! `"start"`), or, when neither property is given (or with `flow: "auto"`),
//! from the higher end (current DEM height at the end points) to the lower,
//! as the corrections table of DESIGN.md says.

use super::grid::Grid;
use super::water::{self, Change};

/// Which way a river centreline flows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    /// The line is drawn downstream: its last vertex is the outlet.
    Line,
    /// The line is drawn upstream: its first vertex is the outlet.
    Reversed,
    /// The end with the lower DEM height is the outlet.
    Heights,
}

/// What a river did.
#[derive(Debug, Clone, PartialEq)]
pub struct RiverResult {
    /// Water surface at the source and at the outlet, metres.
    pub surface_start_m: f64,
    pub surface_end_m: f64,
    /// True when the centreline was reversed (by the heights or by
    /// `downstream`).
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

/// A piecewise linear function through `knots` (`[x, z]`, increasing `x`),
/// constant beyond its ends.
fn piecewise(knots: &[[f64; 2]], x: f64) -> f64 {
    let k = knots.partition_point(|v| v[0] <= x);
    if k == 0 {
        return knots[0][1];
    }
    if k >= knots.len() {
        return knots[knots.len() - 1][1];
    }
    let (a, b) = (knots[k - 1], knots[k]);
    let t = if b[0] > a[0] {
        (x - a[0]) / (b[0] - a[0])
    } else {
        0.0
    };
    a[1] + t * (b[1] - a[1])
}

/// Arc-length intervals `[s0, s1]` (sorted, disjoint) where the surface is
/// level, and the map from the arc length `s` to the arc length without
/// them `u`.
#[derive(Debug, Clone, Default)]
struct LevelReaches(Vec<[f64; 2]>);

impl LevelReaches {
    /// The level reach of every bend of `pts` (see the module
    /// documentation), merged where they overlap and clamped to the line.
    fn at_bends(grid: &Grid, pts: &[[f64; 2]], width_m: f64) -> LevelReaches {
        let (hx, hy) = (grid.cell.hx, grid.cell.hy);
        let margin = 2.0 * hx.max(hy);
        let mut total = 0.0;
        let mut raw: Vec<[f64; 2]> = Vec::new();
        let dir = |a: [f64; 2], b: [f64; 2]| {
            let (dx, dy) = ((b[0] - a[0]) * hx, (b[1] - a[1]) * hy);
            dy.atan2(dx)
        };
        for k in 0..pts.len().saturating_sub(1) {
            let len = grid.metres(pts[k], pts[k + 1]);
            if k > 0 && len > 0.0 {
                // The previous segment of non-zero length.
                if let Some(j) = (0..k)
                    .rev()
                    .find(|&j| grid.metres(pts[j], pts[j + 1]) > 0.0)
                {
                    let mut theta = dir(pts[k], pts[k + 1]) - dir(pts[j], pts[j + 1]);
                    theta = (theta + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
                        - std::f64::consts::PI;
                    let theta = theta.abs().min(170f64.to_radians());
                    if theta > 1e-9 {
                        let a = 0.5 * width_m * (0.5 * theta).tan().max(theta.sin()) + margin;
                        raw.push([total - a, total + a]);
                    }
                }
            }
            total += len;
        }
        let mut merged: Vec<[f64; 2]> = Vec::new();
        for r in raw {
            let r = [r[0].max(0.0), r[1].min(total)];
            if r[1] <= r[0] {
                continue;
            }
            match merged.last_mut() {
                Some(m) if r[0] <= m[1] => m[1] = m[1].max(r[1]),
                _ => merged.push(r),
            }
        }
        LevelReaches(merged)
    }

    /// The arc length without the level reaches before `s` (constant over
    /// each level reach).
    fn u(&self, s: f64) -> f64 {
        let mut removed = 0.0;
        for r in &self.0 {
            if s <= r[0] {
                break;
            }
            if s < r[1] {
                return r[0] - removed;
            }
            removed += r[1] - r[0];
        }
        s - removed
    }
}

/// The water surface along the river: the hull's knots in `u` and the
/// level reaches.
struct Profile {
    /// `[u, z]`: the surface is linear in `u` between them.
    hull: Vec<[f64; 2]>,
    level: LevelReaches,
    /// Arc length of the outlet.
    length: f64,
}

impl Profile {
    /// The surface at arc length `s`.
    fn at(&self, s: f64) -> f64 {
        piecewise(&self.hull, self.level.u(s))
    }

    /// `[s, z]` where the surface bends: the ends, the hull's knots and the
    /// ends of the level reaches, increasing `s`.
    fn knots(&self) -> Vec<[f64; 2]> {
        let mut s: Vec<f64> = vec![0.0, self.length];
        for r in &self.level.0 {
            s.extend_from_slice(r);
        }
        // Hull knots strictly inside a stretch of `u` map back to one `s`.
        for k in &self.hull {
            let mut removed = 0.0;
            let mut inside_level = false;
            for r in &self.level.0 {
                let u0 = r[0] - removed;
                if k[0] < u0 {
                    break;
                }
                if k[0] == u0 {
                    inside_level = true;
                    break;
                }
                removed += r[1] - r[0];
            }
            if !inside_level {
                s.push(k[0] + removed);
            }
        }
        s.retain(|v| (0.0..=self.length).contains(v));
        s.sort_by(f64::total_cmp);
        s.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        s.into_iter().map(|v| [v, self.at(v)]).collect()
    }
}

/// The centreline in window pixel space, upstream first.
fn oriented(grid: &Grid, line: &[[f64; 2]], flow: Flow) -> (Vec<[f64; 2]>, bool) {
    let mut pts: Vec<[f64; 2]> = line.iter().map(|&p| grid.local(p)).collect();
    let mut reversed = false;
    if flow == Flow::Reversed {
        pts.reverse();
        reversed = true;
    } else if flow == Flow::Heights {
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

/// Stations along the centreline, the running minimum of the bank heights
/// there, and the surface below them.
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
    let level = LevelReaches::at_bends(grid, pts, width_m);
    // Stations in `u`; those of one level reach share a `u` and keep the
    // lowest (the running minimum's last) so the hull is a function.
    let mut pts_u: Vec<[f64; 2]> = Vec::with_capacity(s.len());
    for (&si, &zi) in s.iter().zip(&z) {
        let u = level.u(si);
        match pts_u.last_mut() {
            Some(p) if p[0] == u => p[1] = p[1].min(zi),
            _ => pts_u.push([u, zi]),
        }
    }
    Some(Profile {
        hull: lower_hull(&pts_u),
        level,
        length: s0,
    })
}

/// The lower convex hull of a non-increasing sequence `[x, z]` (increasing
/// `x`): piecewise linear with few kinks, never above the points, and
/// non-increasing (a convex function whose last point is its minimum).
fn lower_hull(p: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut hull: Vec<[f64; 2]> = Vec::new();
    for &q in p {
        while hull.len() >= 2 {
            let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
            let cross = (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]);
            if cross <= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        hull.push(q);
    }
    hull
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
    flow: Flow,
    blend_m: f64,
) -> Result<RiverResult, RiverError> {
    let (pts, reversed) = oriented(grid, line, flow);
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
        surface_start_m: prof.at(0.0),
        surface_end_m: prof.at(prof.length),
        reversed,
        knots: prof.knots(),
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
    let stations: Vec<[f64; 2]> = bank
        .iter()
        .enumerate()
        .map(|(k, &z)| [k as f64 * step, z])
        .collect();
    let prof = Profile {
        hull: lower_hull(&stations),
        level: LevelReaches::default(),
        length: (n - 1) as f64 * step,
    };
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
        surface_start_m: prof.at(0.0),
        surface_end_m: prof.at(prof.length),
        reversed,
        knots: prof.knots(),
        change,
    })
}
