//! Ridge lines of a DEM by the profile-recognition and polygon-breaking
//! algorithm (PPA, Chang & Sinha 2007) as Tassé et al. use it in section 5.1:
//! profile recognition marks the cells that are likely to lie on a ridge,
//! adjacent candidates are joined by segments, a maximum-height spanning forest
//! (Kruskal on the segments, highest first) replaces polygon breaking (which
//! deletes the lowest segment of every cycle and yields the same forest), short
//! branches are pruned and the remaining lines are smoothed. The result is a
//! graph of 3D polylines (CRS x, y and height z) between end points and branch
//! points, which the sketch matcher uses as candidate features alongside the
//! view silhouettes.
//!
//! Every pass is linear in the number of cells except the sort of the candidate
//! segments; profile recognition and segment construction run in parallel by
//! rows (rayon), the forest, pruning and tracing work on an 8-bit adjacency
//! mask per cell.

use rayon::prelude::*;

use super::spanning_forest::spanning_forest;
use super::FeatureError;
use crate::raster::HeightMap;

/// Parameters of ridge detection. Lengths are in metres on the ground.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RidgeParams {
    /// Half length of the profiles, in cells (Chang's window is `2 * half_window + 1`).
    pub half_window: usize,
    /// A cell is a candidate when at least this many of the four profile
    /// directions (E-W, N-S and the two diagonals) show it as a local crest.
    pub min_directions: u8,
    /// A profile marks its centre when each side holds a point lower than the
    /// centre by more than this (metres).
    pub min_drop_m: f32,
    /// Branches that end in a leaf and are shorter than this are pruned
    /// (metres; `None`: 3 cells).
    pub min_branch_m: Option<f64>,
    /// Number of pruning passes.
    pub prune_passes: usize,
    /// Connected lines shorter than this are dropped (metres; `None`: 5 cells).
    pub min_line_m: Option<f64>,
    /// Iterations of the [1 2 1]/4 smoothing of line vertices (end points stay).
    pub smooth_iterations: usize,
}

impl Default for RidgeParams {
    fn default() -> Self {
        RidgeParams {
            half_window: 3,
            min_directions: 2,
            min_drop_m: 0.0,
            min_branch_m: None,
            prune_passes: 3,
            min_line_m: None,
            smooth_iterations: 2,
        }
    }
}

/// One ridge line between two graph nodes (end points or branch points).
#[derive(Debug, Clone, PartialEq)]
pub struct RidgeLine {
    /// Index of the line in [`RidgeNetwork::lines`].
    pub id: u32,
    /// Vertices in CRS coordinates with the height: `[x, y, z]`.
    pub points: Vec<[f64; 3]>,
    /// The same vertices in DEM pixel space (cell centres at `col + 0.5, row + 0.5`).
    pub pixels: Vec<[f64; 2]>,
    /// 3D length in metres (horizontal metres computed on the ellipsoid's local
    /// scale for geographic CRSs).
    pub length_m: f64,
    /// Node ids of the first and last vertex.
    pub nodes: [u32; 2],
}

/// An end point or branch point of the ridge graph.
#[derive(Debug, Clone, PartialEq)]
pub struct RidgeNode {
    pub id: u32,
    /// DEM cell `(col, row)`.
    pub cell: [u32; 2],
    /// CRS coordinates and height.
    pub point: [f64; 3],
    /// Number of ridge lines meeting here (1: end point, >= 3: branch point).
    pub degree: u8,
}

/// The ridge graph of a DEM.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RidgeNetwork {
    pub lines: Vec<RidgeLine>,
    pub nodes: Vec<RidgeNode>,
    /// Number of candidate cells found by profile recognition.
    pub candidate_cells: usize,
}

impl RidgeNetwork {
    /// Total length of all lines in metres.
    pub fn total_length_m(&self) -> f64 {
        self.lines.iter().map(|l| l.length_m).sum()
    }
}

/// Neighbour directions of the adjacency mask: bit `d` links a cell to the
/// cell at `DIRS[d]` (dx, dy); the opposite direction is `(d + 4) % 8`.
pub(super) const DIRS: [(isize, isize); 8] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
    (-1, -1),
    (0, -1),
    (1, -1),
];

/// Detect the ridge network of `map`.
pub fn detect_ridges(map: &HeightMap, params: &RidgeParams) -> Result<RidgeNetwork, FeatureError> {
    let (w, h) = (map.width, map.height);
    if params.half_window == 0 || params.min_directions == 0 || params.min_directions > 4 {
        return Err(FeatureError::InvalidParameter(format!(
            "ridge half_window must be >= 1 and min_directions in 1..=4 (got {} and {})",
            params.half_window, params.min_directions
        )));
    }
    if map.data.len() != w * h {
        return Err(FeatureError::InvalidInput(format!(
            "height map holds {} values for {} x {} cells",
            map.data.len(),
            w,
            h
        )));
    }
    if (w * h) as u64 * 4 >= u32::MAX as u64 {
        return Err(FeatureError::TooLarge(format!(
            "ridge detection handles at most 2^30 cells, got {w} x {h}"
        )));
    }
    if w < 2 || h < 2 {
        return Ok(RidgeNetwork::default());
    }
    let metric = Metric::new(map);
    let cell_m = metric.cell_m();
    let min_branch = params.min_branch_m.unwrap_or(3.0 * cell_m);
    let min_line = params.min_line_m.unwrap_or(5.0 * cell_m);

    let cand = profile_recognition(map, params);
    let candidate_cells = cand.par_iter().filter(|&&c| c).count();
    let mut mask = spanning_forest(&map.data, &cand, w, h);
    drop(cand);
    for _ in 0..params.prune_passes {
        prune(&mut mask, w, &metric, min_branch, min_line);
    }
    let mut net = trace(map, &mask, &metric, params.smooth_iterations);
    net.candidate_cells = candidate_cells;
    Ok(net)
}

/// Profile recognition: `true` for cells that are a crest of at least
/// `min_directions` of the four profiles through them.
fn profile_recognition(map: &HeightMap, p: &RidgeParams) -> Vec<bool> {
    let (w, h) = (map.width, map.height);
    let data = &map.data;
    let hw = p.half_window;
    let drop = p.min_drop_m;
    let mut cand = vec![false; w * h];
    cand.par_chunks_mut(w).enumerate().for_each_init(
        || (vec![0f32; w], vec![0f32; w], vec![0u8; w]),
        |(min_a, min_b, count), (row, out)| {
            count.iter_mut().for_each(|c| *c = 0);
            let centre = &data[row * w..(row + 1) * w];
            for &(dx, dy) in &DIRS[..4] {
                min_a.iter_mut().for_each(|v| *v = f32::NAN);
                min_b.iter_mut().for_each(|v| *v = f32::NAN);
                for k in 1..=hw as isize {
                    // side A: (col + k dx, row + k dy); side B: (col - k dx, row - k dy)
                    for (side, s) in [(&mut *min_a, 1isize), (&mut *min_b, -1isize)] {
                        let r = row as isize + s * k * dy;
                        if r < 0 || r >= h as isize {
                            continue;
                        }
                        let src = &data[r as usize * w..(r as usize + 1) * w];
                        let off = s * k * dx;
                        let (c0, c1) = if off >= 0 {
                            (0usize, w.saturating_sub(off as usize))
                        } else {
                            ((-off) as usize, w)
                        };
                        if c0 >= c1 {
                            continue;
                        }
                        let src = &src[(c0 as isize + off) as usize..(c1 as isize + off) as usize];
                        for (m, &v) in side[c0..c1].iter_mut().zip(src) {
                            *m = m.min(v);
                        }
                    }
                }
                for ((c, &z), (&a, &b)) in count
                    .iter_mut()
                    .zip(centre)
                    .zip(min_a.iter().zip(min_b.iter()))
                {
                    *c += (z - a > drop && z - b > drop) as u8;
                }
            }
            for (o, &c) in out.iter_mut().zip(count.iter()) {
                *o = c >= p.min_directions;
            }
        },
    );
    cand
}

/// Horizontal metres per pixel step, and 3D lengths.
struct Metric {
    gt: [f64; 6],
    geographic: bool,
}

impl Metric {
    fn new(map: &HeightMap) -> Self {
        Metric {
            gt: map.geotransform.0,
            geographic: map.crs.geographic,
        }
    }

    /// Metres per CRS unit in x and y at CRS latitude `y` (1 for projected CRSs).
    fn scale(&self, y: f64) -> (f64, f64) {
        if self.geographic {
            let lat = y.to_radians();
            (111_320.0 * lat.cos(), 110_574.0)
        } else {
            (1.0, 1.0)
        }
    }

    /// Mean cell size in metres.
    fn cell_m(&self) -> f64 {
        let g = &self.gt;
        let (sx, sy) = self.scale(g[3]);
        let a = (g[1] * sx).hypot(g[4] * sy);
        let b = (g[2] * sx).hypot(g[5] * sy);
        (a * b).sqrt()
    }

    /// Horizontal metres of one step `(dx, dy)` in pixels at CRS latitude `y`.
    fn step_m(&self, dx: f64, dy: f64, y: f64) -> f64 {
        let g = &self.gt;
        let (sx, sy) = self.scale(y);
        let (a, b) = ((dx * g[1] + dy * g[2]) * sx, (dx * g[4] + dy * g[5]) * sy);
        (a * a + b * b).sqrt()
    }
}

fn neighbour(c: usize, d: usize, w: usize) -> usize {
    let (dx, dy) = DIRS[d];
    (c as isize + dy * w as isize + dx) as usize
}

/// Walk from `start` out along direction `d` until a cell whose degree is not
/// 2. Returns the cells visited (start included) and the walked length.
fn walk(mask: &[u8], w: usize, metric: &Metric, start: usize, mut d: usize) -> (Vec<usize>, f64) {
    let mut path = vec![start];
    let mut len = 0.0;
    let mut c = start;
    let y0 = metric.gt[3];
    let step: [f64; 8] =
        std::array::from_fn(|k| metric.step_m(DIRS[k].0 as f64, DIRS[k].1 as f64, y0));
    loop {
        let n = neighbour(c, d, w);
        len += step[d];
        path.push(n);
        c = n;
        let m = mask[c];
        if m.count_ones() != 2 {
            break;
        }
        let back = (d + 4) % 8;
        let rest = m & !(1 << back);
        d = rest.trailing_zeros() as usize;
    }
    (path, len)
}

fn remove_path(mask: &mut [u8], w: usize, path: &[usize]) {
    for p in path.windows(2) {
        let (a, b) = (p[0], p[1]);
        for d in 0..8 {
            if mask[a] & (1 << d) != 0 && neighbour(a, d, w) == b {
                mask[a] &= !(1 << d);
                mask[b] &= !(1 << ((d + 4) % 8));
            }
        }
    }
}

/// One pruning pass: leaf branches shorter than `min_branch` that end at a
/// branch point are removed, as are isolated lines shorter than `min_line`.
fn prune(mask: &mut [u8], w: usize, metric: &Metric, min_branch: f64, min_line: f64) {
    let leaves: Vec<usize> = mask
        .par_iter()
        .enumerate()
        .filter_map(|(i, m)| (m.count_ones() == 1).then_some(i))
        .collect();
    for leaf in leaves {
        let m = mask[leaf];
        if m.count_ones() != 1 {
            continue;
        }
        let (path, len) = walk(mask, w, metric, leaf, m.trailing_zeros() as usize);
        let end = mask[*path.last().unwrap_or(&leaf)].count_ones();
        let too_short = if end >= 3 {
            len < min_branch
        } else {
            len < min_line
        };
        if too_short {
            remove_path(mask, w, &path);
        }
    }
}

/// Trace the forest into lines between nodes, smooth them and convert them
/// to CRS coordinates.
fn trace(map: &HeightMap, mask: &[u8], metric: &Metric, smooth: usize) -> RidgeNetwork {
    let w = map.width;
    let gt = &map.geotransform;
    let mut net = RidgeNetwork::default();
    let node_cells: Vec<usize> = mask
        .par_iter()
        .enumerate()
        .filter_map(|(i, m)| (*m != 0 && m.count_ones() != 2).then_some(i))
        .collect();
    let mut ids = std::collections::HashMap::with_capacity(node_cells.len());
    for &c in &node_cells {
        let id = net.nodes.len() as u32;
        ids.insert(c, id);
        let (col, row) = (c % w, c / w);
        let (x, y) = gt.pixel_to_crs(col as f64 + 0.5, row as f64 + 0.5);
        net.nodes.push(RidgeNode {
            id,
            cell: [col as u32, row as u32],
            point: [x, y, map.data[c] as f64],
            degree: mask[c].count_ones() as u8,
        });
    }
    let mut done = vec![0u8; mask.len()];
    for &c in &node_cells {
        for d in 0..8 {
            if mask[c] & (1 << d) == 0 || done[c] & (1 << d) != 0 {
                continue;
            }
            let (path, _) = walk(mask, w, metric, c, d);
            let last = *path.last().unwrap_or(&c);
            // mark the final edge from the far end so it is not traced again
            let prev = path[path.len() - 2];
            for e in 0..8 {
                if mask[last] & (1 << e) != 0 && neighbour(last, e, w) == prev {
                    done[last] |= 1 << e;
                }
            }
            done[c] |= 1 << d;
            let mut px: Vec<[f64; 3]> = path
                .iter()
                .map(|&p| {
                    [
                        (p % w) as f64 + 0.5,
                        (p / w) as f64 + 0.5,
                        map.data[p] as f64,
                    ]
                })
                .collect();
            smooth_polyline(&mut px, smooth);
            let points: Vec<[f64; 3]> = px
                .iter()
                .map(|p| {
                    let (x, y) = gt.pixel_to_crs(p[0], p[1]);
                    [x, y, p[2]]
                })
                .collect();
            let length_m = px
                .windows(2)
                .zip(points.windows(2))
                .map(|(a, b)| {
                    let hm = metric.step_m(a[1][0] - a[0][0], a[1][1] - a[0][1], b[0][1]);
                    hm.hypot(a[1][2] - a[0][2])
                })
                .sum();
            let (na, nb) = (
                ids.get(&c).copied().unwrap_or(u32::MAX),
                ids.get(&last).copied().unwrap_or(u32::MAX),
            );
            net.lines.push(RidgeLine {
                id: net.lines.len() as u32,
                pixels: px.iter().map(|p| [p[0], p[1]]).collect(),
                points,
                length_m,
                nodes: [na, nb],
            });
        }
    }
    net
}

/// [1 2 1]/4 smoothing of interior vertices, `iterations` times.
fn smooth_polyline(p: &mut [[f64; 3]], iterations: usize) {
    if p.len() < 3 {
        return;
    }
    let mut tmp = p.to_vec();
    for _ in 0..iterations {
        for i in 1..p.len() - 1 {
            for k in 0..3 {
                tmp[i][k] = 0.25 * p[i - 1][k] + 0.5 * p[i][k] + 0.25 * p[i + 1][k];
            }
        }
        p.copy_from_slice(&tmp);
    }
}
