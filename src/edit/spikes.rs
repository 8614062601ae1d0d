//! No spikes in the change field (issue 11, item 5): no cell's change may
//! exceed, or fall below, the changes of all its 8 neighbours by more than
//! half a cell size.
//!
//! Harmonic diffusion of curve constraints keeps the change smooth between
//! curves, but at the apex of a sharp stroke (a peak drawn over a few cells
//! of a coarse DEM) the constrained cell stands alone above neighbours that
//! the curve itself pulls down, and a cell held at its input height (the
//! observer's ground, a stroke lying on a silhouette already) can stand
//! alone below raised neighbours. Such a cell is not moved: the cell
//! beside it farthest from the nearest eye is brought to within half a cell
//! of it instead. Seen from the sketch's views that neighbour lies behind
//! the apex, under the line of sight that grazes it, so the silhouette the
//! user drew is unchanged (the pipeline measures the fit afterwards). Only
//! where no neighbour behind it may move is a nearer one used, and only
//! where every neighbour is held does the cell itself give way.

use rayon::prelude::*;

use crate::deform::Deformation;

/// Cells whose change is more than half a cell above, or below, the changes
/// of all their valid neighbours: `(column, row)` in the deformation's
/// window.
pub fn find_spikes(d: &Deformation) -> Vec<(usize, usize)> {
    let limit = 0.5 * d.stats.cell_size_m.hx.min(d.stats.cell_size_m.hy);
    let (w, h) = (d.window.width, d.window.height);
    // Rows side by side, collected in row order.
    (0..h)
        .into_par_iter()
        .flat_map_iter(|r| {
            (0..w)
                .filter(move |&c| {
                    excess(d, c, r).is_some_and(|(above, below)| above > limit || below > limit)
                })
                .map(move |c| (c, r))
        })
        .collect()
}

/// How far the change at `(c, r)` lies above the largest, and below the
/// smallest, change of its valid neighbours (`None`: nodata, or no valid
/// neighbour).
fn excess(d: &Deformation, c: usize, r: usize) -> Option<(f64, f64)> {
    let (w, h) = (d.window.width, d.window.height);
    let m = d.displacement[r * w + c];
    if m.is_nan() {
        return None;
    }
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for (dc, dr) in NEIGHBOURS {
        let (x, y) = (c as i64 + dc, r as i64 + dr);
        if x < 0 || y < 0 || x as usize >= w || y as usize >= h {
            continue;
        }
        let v = d.displacement[y as usize * w + x as usize];
        if !v.is_nan() {
            lo = lo.min(v);
            hi = hi.max(v);
        }
    }
    hi.is_finite().then_some(((m - hi) as f64, (lo - m) as f64))
}

/// The 8 neighbours of a cell, `(column, row)` offsets.
pub(crate) const NEIGHBOURS: [(i64, i64); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

/// Removes the spikes of `d` (see the module documentation): `eyes` are the
/// viewpoints in the window's pixel space, `held(c, r)` tells which cells
/// may not change. Returns how many cells were changed; spikes that have
/// no free neighbour stay (and [`find_spikes`] still reports them).
pub fn flatten_spikes(
    d: &mut Deformation,
    eyes: &[(f64, f64)],
    held: &dyn Fn(usize, usize) -> bool,
) -> usize {
    let cell = d.stats.cell_size_m;
    let limit = 0.5 * cell.hx.min(cell.hy);
    let w = d.window.width;
    let mut changed = 0;
    // Each pass can only move neighbours towards a spike; a few passes
    // settle what one pass's changes start.
    for _ in 0..32 {
        let spikes = find_spikes(d);
        if spikes.is_empty() {
            break;
        }
        let mut moved = false;
        for (c, r) in spikes {
            let Some((above, below)) = excess(d, c, r) else {
                continue;
            };
            let m = d.displacement[r * w + c];
            // Neighbours, farthest from the nearest eye first.
            let dist = |x: f64, y: f64| {
                eyes.iter()
                    .map(|e| ((x - e.0) * cell.hx).hypot((y - e.1) * cell.hy))
                    .fold(f64::INFINITY, f64::min)
            };
            let here = dist(c as f64 + 0.5, r as f64 + 0.5);
            let mut order: Vec<(f64, usize)> = NEIGHBOURS
                .iter()
                .filter_map(|&(dc, dr)| {
                    let (x, y) = (c as i64 + dc, r as i64 + dr);
                    if x < 0 || y < 0 || x as usize >= w || y as usize >= d.window.height {
                        return None;
                    }
                    let (x, y) = (x as usize, y as usize);
                    let k = y * w + x;
                    if d.displacement[k].is_nan() || held(x, y) {
                        return None;
                    }
                    Some((dist(x as f64 + 0.5, y as f64 + 0.5), k))
                })
                .collect();
            // Behind the apex first (the farthest from the eyes); one
            // nearer only when none behind it may move.
            order.sort_by(|a, b| (b.0 >= here).cmp(&(a.0 >= here)).then(b.0.total_cmp(&a.0)));
            // (Within 0.9 of the limit: the written values are rounded to
            // the DEM's sample type.)
            let (k, target) = match order.first() {
                Some(&(_, k)) if above > limit => (k, m - (0.9 * limit) as f32),
                Some(&(_, k)) if below > limit => (k, m + (0.9 * limit) as f32),
                // Every neighbour is held: the apex itself comes down (or
                // the pit up) to within half a cell of them.
                None if above > limit => (r * w + c, m - (above - 0.9 * limit) as f32),
                None if below > limit => (r * w + c, m + (below - 0.9 * limit) as f32),
                _ => continue,
            };
            d.displacement[k] = target;
            changed += 1;
            moved = true;
        }
        if !moved {
            break;
        }
    }
    if changed > 0 {
        let mut n = 0;
        let mut max_abs = 0f64;
        for &v in &d.displacement {
            if !v.is_nan() && v != 0.0 {
                n += 1;
                max_abs = max_abs.max(v.abs() as f64);
            }
        }
        d.stats.changed_cells = n;
        d.stats.max_abs_displacement_m = max_abs;
    }
    changed
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deform::{CellSize, DeformStats};
    use crate::raster::{Crs, GeoTransform, HeightMap, Window};

    fn deformation(w: usize, h: usize, m: Vec<f32>) -> Deformation {
        let cell = CellSize { hx: 10.0, hy: 10.0 };
        Deformation {
            window: Window::new(0, 0, w, h),
            displacement: m,
            base: HeightMap {
                width: w,
                height: h,
                data: vec![100.0; w * h],
                geotransform: GeoTransform([0.0, 10.0, 0.0, 0.0, 0.0, -10.0]),
                crs: Crs {
                    epsg: None,
                    wkt: String::new(),
                    proj: None,
                    geographic: false,
                },
            },
            affected_tiles: Vec::new(),
            constrained: vec![false; w * h],
            stats: DeformStats::unsolved(cell, 100.0),
        }
    }

    #[test]
    fn a_lone_apex_gets_a_neighbour_behind_it_and_is_kept() {
        // 5 x 5, apex +40 m in the middle (half a cell is 5 m), eye at the
        // left edge: the neighbour farthest from it (to the right) rises.
        let mut m = vec![0.0f32; 25];
        m[12] = 40.0;
        let mut d = deformation(5, 5, m);
        assert_eq!(find_spikes(&d), vec![(2, 2)]);
        let n = flatten_spikes(&mut d, &[(0.0, 2.5)], &|_, _| false);
        assert!(n >= 1);
        assert!(find_spikes(&d).is_empty(), "{:?}", d.displacement);
        assert_eq!(d.displacement[12], 40.0, "the apex itself is kept");
        let right = [8usize, 13, 18];
        assert!(right.iter().any(|&k| d.displacement[k] >= 35.0));
    }

    #[test]
    fn a_held_pit_is_filled_around_not_moved() {
        let mut m = vec![30.0f32; 25];
        m[12] = 0.0;
        let mut d = deformation(5, 5, m);
        assert_eq!(find_spikes(&d), vec![(2, 2)]);
        flatten_spikes(&mut d, &[(2.5, 0.0)], &|c, r| (c, r) == (2, 2));
        assert_eq!(d.displacement[12], 0.0);
        assert!(find_spikes(&d).is_empty(), "{:?}", d.displacement);
    }

    #[test]
    fn an_apex_whose_neighbours_behind_are_held_gets_a_nearer_one() {
        let mut m = vec![0.0f32; 25];
        m[12] = 40.0;
        let mut d = deformation(5, 5, m);
        // everything right of the apex is held; the eye is at the left
        flatten_spikes(&mut d, &[(0.0, 2.5)], &|c, _| c >= 3);
        assert!(find_spikes(&d).is_empty(), "{:?}", d.displacement);
        assert_eq!(d.displacement[12], 40.0, "the apex itself is kept");
    }

    #[test]
    fn an_apex_among_held_cells_comes_down_itself() {
        let mut m = vec![0.0f32; 25];
        m[12] = 40.0;
        let mut d = deformation(5, 5, m);
        flatten_spikes(&mut d, &[(0.0, 2.5)], &|c, r| (c, r) != (2, 2));
        assert!(find_spikes(&d).is_empty(), "{:?}", d.displacement);
        assert!(d.displacement[12] <= 5.0, "{}", d.displacement[12]);
    }
}
