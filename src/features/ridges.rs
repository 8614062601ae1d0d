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
//! Profile recognition runs in parallel by bands of rows (an AVX2 kernel where
//! the CPU has one) into a bitmap of candidates; from there on every
//! candidate has a compact id (its rank in row-major order, see
//! [`super::candidates`]) and the forest, pruning and tracing work on an 8-bit
//! adjacency mask per candidate. The forest is built strip by strip in
//! parallel (see [`super::spanning_forest`]); the walks of pruning run
//! alongside the ordered pruning pass (the one sequential step), which takes
//! them in order as they come; the lines are traced in parallel and their
//! vertices written into one buffer per network (a line holds a range of
//! it). The result does not depend on the number of threads.
//! `RIDGE_TIMING=1` prints the time of each stage on stderr.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex};

use rayon::prelude::*;

use super::candidates::{CandidateSet, BAND};
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
/// Its vertices are a range of the network's vertex arrays (one buffer for
/// all lines): see [`RidgeNetwork::line_points`] and
/// [`RidgeNetwork::line_pixels`].
#[derive(Debug, Clone, PartialEq)]
pub struct RidgeLine {
    /// Index of the line in [`RidgeNetwork::lines`].
    pub id: u32,
    /// Indices of the line's vertices in [`RidgeNetwork::points`] and
    /// [`RidgeNetwork::pixels`].
    pub vertices: std::ops::Range<usize>,
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
    /// Vertices of all lines, line after line, in CRS coordinates with the
    /// height: `[x, y, z]`.
    pub points: Vec<[f64; 3]>,
    /// The same vertices in DEM pixel space (cell centres at `col + 0.5, row + 0.5`).
    pub pixels: Vec<[f64; 2]>,
    /// Number of candidate cells found by profile recognition.
    pub candidate_cells: usize,
}

impl RidgeNetwork {
    /// Total length of all lines in metres.
    pub fn total_length_m(&self) -> f64 {
        self.lines.iter().map(|l| l.length_m).sum()
    }

    /// Vertices of `line` in CRS coordinates with the height.
    pub fn line_points(&self, line: &RidgeLine) -> &[[f64; 3]] {
        &self.points[line.vertices.clone()]
    }

    /// Vertices of `line` in DEM pixel space.
    pub fn line_pixels(&self, line: &RidgeLine) -> &[[f64; 2]] {
        &self.pixels[line.vertices.clone()]
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

/// Number of set bits of each mask value: a cell's degree in the forest.
const DEGREE: [u8; 256] = {
    let mut t = [0u8; 256];
    let mut m = 0;
    while m < 256 {
        t[m] = (m as u8).count_ones() as u8;
        m += 1;
    }
    t
};

/// Degree of a cell with adjacency mask `m`.
#[inline(always)]
pub(super) fn degree(m: u8) -> u32 {
    DEGREE[m as usize] as u32
}

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

    let timing = std::env::var_os("RIDGE_TIMING").is_some();
    let t0 = std::time::Instant::now();
    let cand = profile_recognition(map, params);
    let t1 = std::time::Instant::now();
    let mut mask = spanning_forest(&cand, w, h);
    let t2 = std::time::Instant::now();
    let forest = Forest::new(&cand, w);
    prune(
        &forest,
        &mut mask,
        &metric,
        (min_branch, min_line),
        params.prune_passes,
    );
    let t3 = std::time::Instant::now();
    let mut net = trace(map, &forest, &mask, &metric, params.smooth_iterations);
    net.candidate_cells = cand.len();
    if timing {
        eprintln!(
            "ridges: profile {:?} forest {:?} prune {:?} trace {:?}",
            t1 - t0,
            t2 - t1,
            t3 - t2,
            t3.elapsed()
        );
    }
    Ok(net)
}

/// Profile recognition: the cells that are a crest of at least
/// `min_directions` of the four profiles through them, in parallel by bands
/// of rows.
fn profile_recognition(map: &HeightMap, p: &RidgeParams) -> CandidateSet {
    profile_recognition_with(map, p, true)
}

/// [`profile_recognition`], with the SIMD kernel where the CPU has one
/// (`simd`) or the portable one.
fn profile_recognition_with(map: &HeightMap, p: &RidgeParams, simd: bool) -> CandidateSet {
    let (w, h) = (map.width, map.height);
    let tq0 = std::time::Instant::now();
    let mut bits = vec![0u64; (w * h).div_ceil(64)];
    // `w` words hold the `BAND` rows of a band.
    let parts: Vec<(Vec<u32>, Vec<f32>)> = bits
        .par_chunks_mut(w)
        .enumerate()
        .map(|(band, words)| profile_band(map, p, band * BAND, words, simd))
        .collect();
    let tq1 = std::time::Instant::now();
    let c = CandidateSet::from_parts(bits, parts);
    if std::env::var_os("RIDGE_TIMING").is_some() {
        eprintln!("profile: bands {:?} set {:?}", tq1 - tq0, tq1.elapsed());
    }
    c
}

/// Profile recognition of the rows from `r0` (at most `BAND`), into the
/// band's bitmap words; returns the band's candidate cells and heights.
///
/// The rows around the current one sit in a ring of padded copies where
/// cells outside the DEM and NaN cells are `+inf`, so the lowest point of a
/// profile side is a plain minimum over fixed offsets (a side with no valid
/// cell stays `+inf` and never shows a drop, as before with NaN). A NaN
/// centre shows no drop either.
#[inline(never)]
fn profile_band(
    map: &HeightMap,
    p: &RidgeParams,
    r0: usize,
    words: &mut [u64],
    simd: bool,
) -> (Vec<u32>, Vec<f32>) {
    let (w, h) = (map.width, map.height);
    let hw = p.half_window;
    let r1 = (r0 + BAND).min(h);
    let w8 = w.next_multiple_of(8);
    let wp = w8 + 2 * hw;
    let slots = 2 * hw + 1;
    let mut ring = vec![f32::INFINITY; slots * wp];
    let fill = |ring: &mut [f32], r: isize| {
        let slot = r.rem_euclid(slots as isize) as usize;
        let row = &mut ring[slot * wp + hw..slot * wp + hw + w];
        if r < 0 || r >= h as isize {
            row.fill(f32::INFINITY);
        } else {
            let src = &map.data[r as usize * w..(r as usize + 1) * w];
            row.copy_from_slice(src);
            if has_nan(src) {
                for v in row.iter_mut().filter(|v| v.is_nan()) {
                    *v = f32::INFINITY;
                }
            }
        }
    };
    let (r0i, hwi) = (r0 as isize, hw as isize);
    for r in r0i - hwi..r0i + hwi {
        fill(&mut ring, r);
    }
    // Whole words of flags, so that the candidates are read 64 at a time.
    let mut bits = vec![0u8; w8.next_multiple_of(64) / 8];
    let mut own_centre = vec![f32::NAN; w8];
    let mut starts = Vec::with_capacity(8 * hw);
    // The band's candidates: cells and heights.
    let reserve = (r1 - r0) * w / 8;
    let (mut cells, mut heights) = (Vec::with_capacity(reserve), Vec::with_capacity(reserve));
    for r in r0..r1 {
        let ri = r as isize;
        fill(&mut ring, ri + hwi);
        starts.clear();
        for &(dx, dy) in &DIRS[..4] {
            for side in [1isize, -1] {
                for k in 1..=hwi {
                    let slot = (ri + side * k * dy).rem_euclid(slots as isize) as usize;
                    starts.push(slot * wp + (hwi + side * k * dx) as usize);
                }
            }
        }
        // The row itself, from the ring unless it holds NaN cells.
        let src = &map.data[r * w..(r + 1) * w];
        let centre = if has_nan(src) {
            own_centre[..w].copy_from_slice(src);
            &own_centre[..]
        } else {
            let at = r % slots * wp + hw;
            &ring[at..at + w8]
        };
        let row = ProfileRow {
            ring: &ring,
            starts: &starts,
            hw,
            centre,
            drop: p.min_drop_m,
            min_dirs: p.min_directions as i32,
        };
        row.flags(&mut bits, simd);
        append_bits(words, (r - r0) * w, &bits, w);
        for (j, word) in bits.chunks_exact(8).enumerate() {
            let mut word = u64::from_le_bytes(std::array::from_fn(|i| word[i]));
            while word != 0 {
                let col = 64 * j + word.trailing_zeros() as usize;
                word &= word - 1;
                if col < w {
                    cells.push((r * w + col) as u32);
                    heights.push(src[col]);
                }
            }
        }
    }
    (cells, heights)
}

/// Whether `v` holds a NaN (a branch-free pass that vectorises).
fn has_nan(v: &[f32]) -> bool {
    v.chunks(64).fold(false, |any, c| {
        any | c.iter().fold(false, |a, x| a | x.is_nan())
    })
}

/// The smaller of `a` and `b` (one `minps`; no NaN reaches it).
#[inline(always)]
fn lower(a: f32, b: f32) -> f32 {
    if b < a {
        b
    } else {
        a
    }
}

/// The rows around a row of profile recognition: `ring` holds padded rows,
/// `starts[(2 * dir + side) * hw + k - 1]` is where in `ring` the profile
/// point `k` cells from the row's first cell along direction `dir` (side 0)
/// or against it (side 1) lies, and every start leaves room for `centre.len()`
/// values.
struct ProfileRow<'a> {
    ring: &'a [f32],
    starts: &'a [usize],
    hw: usize,
    /// Heights of the row, a multiple of 8 long.
    centre: &'a [f32],
    drop: f32,
    min_dirs: i32,
}

impl ProfileRow<'_> {
    /// Candidate flags of the row into `bits` (bit `i` of byte `j`: cell
    /// `8 j + i`), with SIMD where the CPU has it and `simd` is set.
    fn flags(&self, bits: &mut [u8], simd: bool) {
        assert!(self.centre.len() % 8 == 0 && bits.len() * 8 >= self.centre.len());
        assert!(self.starts.len() == 8 * self.hw);
        assert!(self
            .starts
            .iter()
            .all(|&s| s + self.centre.len() <= self.ring.len()));
        #[cfg(target_arch = "x86_64")]
        if simd && std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2; the asserts above keep every
            // load inside `ring`, `centre` and every store inside `bits`.
            unsafe {
                match self.hw {
                    1 => self.flags_avx2::<1>(bits),
                    2 => self.flags_avx2::<2>(bits),
                    3 => self.flags_avx2::<3>(bits),
                    4 => self.flags_avx2::<4>(bits),
                    _ => self.flags_avx2_any(bits),
                }
            }
            return;
        }
        self.flags_portable(bits)
    }

    fn flags_portable(&self, bits: &mut [u8]) {
        let (ring, starts, hw) = (self.ring, self.starts, self.hw);
        for (o, (z, byte)) in self.centre.chunks_exact(8).zip(bits).enumerate() {
            let o = o * 8;
            let mut count = [0i32; 8];
            for dir in 0..4 {
                let mut a = [f32::INFINITY; 8];
                let mut b = [f32::INFINITY; 8];
                for k in 0..hw {
                    let sa = &ring[starts[2 * dir * hw + k] + o..][..8];
                    let sb = &ring[starts[(2 * dir + 1) * hw + k] + o..][..8];
                    for i in 0..8 {
                        a[i] = lower(a[i], sa[i]);
                        b[i] = lower(b[i], sb[i]);
                    }
                }
                for i in 0..8 {
                    count[i] += (z[i] - a[i] > self.drop && z[i] - b[i] > self.drop) as i32;
                }
            }
            *byte = (0..8).fold(0u8, |m, i| m | ((count[i] >= self.min_dirs) as u8) << i);
        }
    }

    /// [`Self::flags_portable`] with 8 cells per AVX2 register, for
    /// `hw == HW`.
    ///
    /// # Safety
    /// The CPU must support AVX2 and the bounds asserted in [`Self::flags`]
    /// must hold.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn flags_avx2<const HW: usize>(&self, bits: &mut [u8]) {
        use std::arch::x86_64::*;
        let ring = self.ring.as_ptr();
        let at: [[*const f32; HW]; 8] =
            std::array::from_fn(|ds| std::array::from_fn(|k| ring.add(self.starts[ds * HW + k])));
        let centre = self.centre.as_ptr();
        let drop = _mm256_set1_ps(self.drop);
        let below = _mm256_set1_epi32(self.min_dirs - 1);
        for (j, byte) in bits.iter_mut().take(self.centre.len() / 8).enumerate() {
            let o = 8 * j;
            let z = _mm256_loadu_ps(centre.add(o));
            let mut count = _mm256_setzero_si256();
            for dir in 0..4 {
                let side = |s: &[*const f32; HW]| {
                    let mut m = _mm256_loadu_ps(s[0].add(o));
                    for p in &s[1..] {
                        m = _mm256_min_ps(m, _mm256_loadu_ps(p.add(o)));
                    }
                    _mm256_cmp_ps::<_CMP_GT_OQ>(_mm256_sub_ps(z, m), drop)
                };
                let crest = _mm256_and_ps(side(&at[2 * dir]), side(&at[2 * dir + 1]));
                // A true lane is -1.
                count = _mm256_sub_epi32(count, _mm256_castps_si256(crest));
            }
            let hit = _mm256_cmpgt_epi32(count, below);
            *byte = _mm256_movemask_ps(_mm256_castsi256_ps(hit)) as u8;
        }
    }

    /// [`Self::flags_avx2`] for any `hw`.
    ///
    /// # Safety
    /// As [`Self::flags_avx2`].
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn flags_avx2_any(&self, bits: &mut [u8]) {
        use std::arch::x86_64::*;
        let (ring, starts, hw) = (self.ring.as_ptr(), self.starts, self.hw);
        let centre = self.centre.as_ptr();
        let drop = _mm256_set1_ps(self.drop);
        let below = _mm256_set1_epi32(self.min_dirs - 1);
        for (j, byte) in bits.iter_mut().take(self.centre.len() / 8).enumerate() {
            let o = 8 * j;
            let z = _mm256_loadu_ps(centre.add(o));
            let mut count = _mm256_setzero_si256();
            for dir in 0..4 {
                let side = |s: usize| {
                    let mut m = _mm256_set1_ps(f32::INFINITY);
                    for &st in &starts[(2 * dir + s) * hw..(2 * dir + s + 1) * hw] {
                        m = _mm256_min_ps(m, _mm256_loadu_ps(ring.add(st + o)));
                    }
                    _mm256_cmp_ps::<_CMP_GT_OQ>(_mm256_sub_ps(z, m), drop)
                };
                let crest = _mm256_and_ps(side(0), side(1));
                count = _mm256_sub_epi32(count, _mm256_castps_si256(crest));
            }
            let hit = _mm256_cmpgt_epi32(count, below);
            *byte = _mm256_movemask_ps(_mm256_castsi256_ps(hit)) as u8;
        }
    }
}

/// ORs the first `n` flags of `bits` (8 per byte) into `words` from bit
/// `offset` on.
fn append_bits(words: &mut [u64], offset: usize, bits: &[u8], n: usize) {
    for (j, &b) in bits.iter().take(n.div_ceil(8)).enumerate() {
        let valid = (n - 8 * j).min(8);
        let b = (b as u64) & ((1u64 << valid) - 1);
        if b == 0 {
            continue;
        }
        let o = offset + 8 * j;
        let (word, shift) = (o >> 6, o & 63);
        words[word] |= b << shift;
        if shift > 56 {
            let spill = b >> (64 - shift);
            if spill != 0 {
                words[word + 1] |= spill;
            }
        }
    }
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

/// Moving along the forest: cell offsets of the mask directions and the
/// candidates' ids, cells and heights.
struct Forest<'a> {
    cand: &'a CandidateSet,
    off: [isize; 8],
}

impl<'a> Forest<'a> {
    fn new(cand: &'a CandidateSet, w: usize) -> Self {
        Forest {
            cand,
            off: std::array::from_fn(|d| DIRS[d].1 * w as isize + DIRS[d].0),
        }
    }

    /// The cell and candidate id one step from `cell` along direction `d`
    /// (which must lead to a candidate).
    #[inline]
    fn step(&self, cell: usize, d: usize) -> (usize, usize) {
        let n = (cell as isize + self.off[d]) as usize;
        (n, self.cand.id(n) as usize)
    }
}

/// Ids whose mask satisfies `keep`, in order (scanned in parallel).
fn select(mask: &[u8], keep: impl Fn(u8) -> bool + Sync) -> Vec<u32> {
    const CHUNK: usize = 1 << 16;
    let parts: Vec<Vec<u32>> = mask
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(k, chunk)| {
            let base = (k * CHUNK) as u32;
            let mut v = Vec::new();
            for (i, &m) in chunk.iter().enumerate() {
                if keep(m) {
                    v.push(base + i as u32);
                }
            }
            v
        })
        .collect();
    parts.concat()
}

/// Mask of a candidate id in a leaf's walk record: leaf id, end id << 30,
/// bit 60: one step, bit 62: the end is a branch point (else a leaf), bit
/// 63: too short.
const ID: u64 = (1 << 30) - 1;

/// Whether a walk record's end still has the degree class (branch point or
/// leaf) it had when walked: then the walk is unchanged.
#[inline]
fn same_class(walk: u64, end_degree: u32) -> bool {
    let branch = walk >> 62 & 1 == 1;
    (end_degree == 1 && !branch) || (end_degree >= 3 && branch)
}

/// Walks from leaves along the forest, with the pruning lengths.
struct LeafWalker<'a> {
    forest: &'a Forest<'a>,
    /// Metres of one step along each direction.
    step: [f64; 8],
    min_branch: f64,
    min_line: f64,
    /// A walk this long is kept whatever its end.
    enough: f64,
}

impl LeafWalker<'_> {
    /// The end of the walk from `leaf` (the first cell of degree other than
    /// 2), the walked length and whether the end is the leaf's neighbour, or
    /// `None` when the walk grows long enough to be kept before its end.
    #[inline]
    fn walk(&self, mask: &[u8], leaf: usize) -> Option<(usize, f64, bool)> {
        let (mut c, mut d) = (
            self.forest.cand.cells[leaf] as usize,
            mask[leaf].trailing_zeros() as usize,
        );
        let mut len = 0.0;
        let mut first = true;
        loop {
            let (nc, nid) = self.forest.step(c, d);
            len += self.step[d];
            let m = mask[nid];
            if degree(m) != 2 {
                return Some((nid, len, first));
            }
            first = false;
            if len >= self.enough {
                return None;
            }
            d = (m & !(1 << ((d + 4) % 8))).trailing_zeros() as usize;
            c = nc;
        }
    }

    /// Whether a walk of `len` ending at a cell of degree `end_degree` is
    /// pruned.
    #[inline]
    fn too_short(&self, len: f64, end_degree: u32) -> bool {
        if end_degree >= 3 {
            len < self.min_branch
        } else {
            len < self.min_line
        }
    }

    /// Removes the walk from `leaf` to its end.
    fn remove(&self, mask: &mut [u8], leaf: usize) {
        let (mut c, mut id, mut d) = (
            self.forest.cand.cells[leaf] as usize,
            leaf,
            mask[leaf].trailing_zeros() as usize,
        );
        loop {
            let (nc, nid) = self.forest.step(c, d);
            let m = mask[nid];
            let back = (d + 4) % 8;
            mask[id] &= !(1 << d);
            mask[nid] &= !(1 << back);
            if degree(m) != 2 {
                return;
            }
            d = (m & !(1 << back)).trailing_zeros() as usize;
            (c, id) = (nc, nid);
        }
    }

    /// Removes the recorded walk `walk` (directly when its end is the leaf's
    /// neighbour).
    #[inline]
    fn remove_walk(&self, mask: &mut [u8], walk: u64) {
        let (leaf, end) = ((walk & ID) as usize, (walk >> 30 & ID) as usize);
        if walk >> 60 & 1 == 1 {
            let d = mask[leaf].trailing_zeros() as usize;
            mask[leaf] &= !(1 << d);
            mask[end] &= !(1 << ((d + 4) % 8));
        } else {
            self.remove(mask, leaf);
        }
    }

    /// The record of the walk from `leaf` to `end` of length `len`.
    #[inline]
    fn record(&self, mask: &[u8], leaf: usize, (end, len, one_step): (usize, f64, bool)) -> u64 {
        let end_degree = degree(mask[end]);
        leaf as u64
            | (end as u64) << 30
            | (one_step as u64) << 60
            | ((end_degree >= 3) as u64) << 62
            | (self.too_short(len, end_degree) as u64) << 63
    }

    /// Walks from `leaf` and removes the walk when it is too short; returns
    /// the walk's record when it reached its end and was kept.
    fn settle(&self, mask: &mut [u8], leaf: usize) -> Option<u64> {
        let walk = self.record(mask, leaf, self.walk(mask, leaf)?);
        if walk >> 63 == 1 {
            self.remove(mask, leaf);
            None
        } else {
            Some(walk)
        }
    }
}

/// Pruning passes: leaf branches shorter than `min_branch` that end at a
/// branch point are removed, as are isolated lines shorter than `min_line`.
///
/// Leaves are visited in cell order, one after another (a removal changes
/// the branch point's degree, which the next walks see). A walk stops as
/// soon as it is long enough to be kept whatever its end. Removals create no
/// new leaves (a branch point keeps degree 2 or more) and never touch a
/// chain whose walk stopped that way, so later passes only revisit the
/// leaves that reached their end and were kept, and walk again only those
/// whose end changed class: the result is that of walking every leaf in
/// every pass.
///
/// The walks of the first pass are made on a copy of the unpruned forest,
/// in parallel with the ordered pass that consumes them in order. In the
/// ordered pass, a leaf's chain is still intact
/// (only its own removal or that of the leaf at its other end would touch
/// it), so its walk is unchanged as long as its end is still a branch point
/// or still a leaf; otherwise it is walked again.
#[inline(never)]
fn prune(
    forest: &Forest,
    mask: &mut [u8],
    metric: &Metric,
    (min_branch, min_line): (f64, f64),
    passes: usize,
) {
    if passes == 0 {
        return;
    }
    let y0 = metric.gt[3];
    let walker = LeafWalker {
        forest,
        step: std::array::from_fn(|k| metric.step_m(DIRS[k].0 as f64, DIRS[k].1 as f64, y0)),
        min_branch,
        min_line,
        enough: min_branch.max(min_line),
    };
    let t0 = std::time::Instant::now();
    // Records of the walks of the leaves that reach their end, by chunks of
    // ids, made on a copy of the unpruned forest: one job walks the chunks
    // in order while the other runs the ordered pass over the chunks walked
    // so far (and walks a chunk itself when the next one is not there yet).
    const CHUNK: usize = 1 << 14;
    let unpruned = mask.to_vec();
    let chunks = unpruned.len().div_ceil(CHUNK);
    let walk_chunk = |k: usize| -> Vec<u64> {
        let mut walks = Vec::new();
        let chunk = &unpruned[k * CHUNK..((k + 1) * CHUNK).min(unpruned.len())];
        for (i, _) in chunk.iter().enumerate().filter(|(_, &m)| degree(m) == 1) {
            let leaf = k * CHUNK + i;
            if let Some(end) = walker.walk(&unpruned, leaf) {
                walks.push(walker.record(&unpruned, leaf, end));
            }
        }
        walks
    };
    let claimed = AtomicUsize::new(0);
    let walked: Mutex<Vec<Option<Vec<u64>>>> = Mutex::new((0..chunks).map(|_| None).collect());
    let ready = Condvar::new();
    // The lock never sees a panic while held (no code in it can panic).
    let lock = || walked.lock().unwrap_or_else(|e| e.into_inner());
    let claim_and_walk = || {
        let k = claimed.fetch_add(1, Ordering::Relaxed);
        if k < chunks {
            let walks = walk_chunk(k);
            lock()[k] = Some(walks);
            ready.notify_all();
        }
        k < chunks
    };
    // The leaves to visit in the next pass, with their walks.
    let mut revisit: Vec<u64> = Vec::new();
    let mut nwalks = 0;
    let ordered = |mask: &mut [u8], revisit: &mut Vec<u64>, nwalks: &mut usize| {
        for k in 0..chunks {
            let walks = loop {
                let mut slots = lock();
                if let Some(walks) = slots[k].take() {
                    break walks;
                }
                if claimed.load(Ordering::Relaxed) < chunks {
                    drop(slots);
                    claim_and_walk();
                } else {
                    while slots[k].is_none() {
                        slots = ready.wait(slots).unwrap_or_else(|e| e.into_inner());
                    }
                }
            };
            *nwalks += walks.len();
            for &walk in &walks {
                let (leaf, end) = ((walk & ID) as usize, (walk >> 30 & ID) as usize);
                if degree(mask[leaf]) != 1 {
                    continue;
                }
                if same_class(walk, degree(mask[end])) {
                    if walk >> 63 == 1 {
                        walker.remove_walk(mask, walk);
                    } else {
                        revisit.push(walk);
                    }
                } else if let Some(walk) = walker.settle(mask, leaf) {
                    revisit.push(walk);
                }
            }
        }
    };
    rayon::join(
        || while claim_and_walk() {},
        || ordered(mask, &mut revisit, &mut nwalks),
    );
    let t2 = std::time::Instant::now();
    let nrevisit = revisit.len();
    // A kept walk whose end kept its class is kept again.
    for _ in 1..passes {
        let mut kept = 0;
        for k in 0..revisit.len() {
            let walk = revisit[k];
            let (leaf, end) = ((walk & ID) as usize, (walk >> 30 & ID) as usize);
            if degree(mask[leaf]) != 1 {
                continue;
            }
            let walk = if same_class(walk, degree(mask[end])) {
                walk
            } else if let Some(walk) = walker.settle(mask, leaf) {
                walk
            } else {
                continue;
            };
            revisit[kept] = walk;
            kept += 1;
        }
        revisit.truncate(kept);
    }
    if std::env::var_os("RIDGE_TIMING").is_some() {
        eprintln!(
            "prune: walks and ordered pass {:?} ({nwalks} walks, {nrevisit} kept) later passes {:?}",
            t2 - t0,
            t2.elapsed()
        );
    }
}

/// Trace the forest into lines between nodes, smooth them and convert them
/// to CRS coordinates. Each line is traced from its node of lower cell index
/// (in parallel over the nodes; the walk from the other end is dropped), so
/// the lines come in the order of their first node and direction. The walks
/// count the vertices of each line first; the lines then write their
/// vertices in parallel into their ranges of one buffer.
#[inline(never)]
fn trace(
    map: &HeightMap,
    forest: &Forest,
    mask: &[u8],
    metric: &Metric,
    smooth: usize,
) -> RidgeNetwork {
    let w = map.width;
    let gt = &map.geotransform;
    let cand = forest.cand;
    let t0 = std::time::Instant::now();
    let node_ids = select(mask, |m| m != 0 && degree(m) != 2);
    let nodes: Vec<RidgeNode> = node_ids
        .par_iter()
        .enumerate()
        .map(|(i, &id)| {
            let c = cand.cells[id as usize] as usize;
            let (col, row) = (c % w, c / w);
            let (x, y) = gt.pixel_to_crs(col as f64 + 0.5, row as f64 + 0.5);
            RidgeNode {
                id: i as u32,
                cell: [col as u32, row as u32],
                point: [x, y, cand.heights[id as usize] as f64],
                degree: degree(mask[id as usize]) as u8,
            }
        })
        .collect();
    // The lines, walked from both ends and kept from the lower one, with
    // the steps of the kept walks, by chunks of nodes.
    const CHUNK: usize = 1024;
    let walked: Vec<ChunkLines> = node_ids
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(k, chunk)| {
            let mut out = ChunkLines::default();
            for (i, &id) in chunk.iter().enumerate() {
                let (m, cell) = (mask[id as usize], cand.cells[id as usize] as usize);
                for d0 in (0..8).filter(|d| m & (1 << d) != 0) {
                    let mark = out.ids.len();
                    let (mut c, mut d) = (cell, d0);
                    let end = loop {
                        let (nc, nid) = forest.step(c, d);
                        out.ids.push(nid as u32);
                        out.dirs.push(d as u8);
                        let m = mask[nid];
                        if degree(m) != 2 {
                            break nid;
                        }
                        d = (m & !(1 << ((d + 4) % 8))).trailing_zeros() as usize;
                        c = nc;
                    };
                    if end > id as usize {
                        let first = ((k * CHUNK + i) as u32) << 3 | d0 as u32;
                        let count = (out.ids.len() - mark + 1) as u32;
                        out.lines.push((first, count, end as u32));
                    } else {
                        out.ids.truncate(mark);
                        out.dirs.truncate(mark);
                    }
                }
            }
            out
        })
        .collect();
    let t1 = std::time::Instant::now();
    let mut lines = Vec::with_capacity(walked.iter().map(|c| c.lines.len()).sum());
    let (mut line_bounds, mut vertex_bounds) = (vec![0usize], vec![0usize]);
    let mut vertices = 0usize;
    for chunk in &walked {
        for &(first, count, _) in &chunk.lines {
            let next = vertices + count as usize;
            lines.push(RidgeLine {
                id: lines.len() as u32,
                vertices: vertices..next,
                length_m: 0.0,
                nodes: [first >> 3, u32::MAX],
            });
            vertices = next;
        }
        line_bounds.push(lines.len());
        vertex_bounds.push(vertices);
    }
    let mut points = vec![[0.0f64; 3]; vertices];
    let mut pixels = vec![[0.0f64; 2]; vertices];
    let t2 = std::time::Instant::now();
    // The lines of each chunk, filled in parallel from the recorded steps.
    let heights = &cand.heights;
    walked
        .par_iter()
        .zip(split_at(&mut lines, &line_bounds))
        .zip(split_at(&mut points, &vertex_bounds))
        .zip(split_at(&mut pixels, &vertex_bounds))
        .for_each(|(((walked, lines), points), pixels)| {
            let base = lines.first().map_or(0, |l| l.vertices.start);
            let mut step = 0;
            for (line, &(first, _, end)) in lines.iter_mut().zip(&walked.lines) {
                let range = line.vertices.start - base..line.vertices.end - base;
                let id = node_ids[(first >> 3) as usize] as usize;
                let cell = cand.cells[id] as usize;
                let (mut col, mut row) = ((cell % w) as isize, (cell / w) as isize);
                let px = &mut points[range.clone()];
                px[0] = [col as f64 + 0.5, row as f64 + 0.5, heights[id] as f64];
                let n = px.len() - 1;
                let steps = walked.ids[step..step + n]
                    .iter()
                    .zip(&walked.dirs[step..step + n]);
                for (p, (&nid, &d)) in px[1..].iter_mut().zip(steps) {
                    let (dx, dy) = DIRS[d as usize];
                    (col, row) = (col + dx, row + dy);
                    *p = [
                        col as f64 + 0.5,
                        row as f64 + 0.5,
                        heights[nid as usize] as f64,
                    ];
                }
                step += n;
                line.nodes[1] = node_ids.binary_search(&end).map_or(u32::MAX, |j| j as u32);
                line.length_m = polyline(map, metric, smooth, px, &mut pixels[range]);
            }
        });
    if std::env::var_os("RIDGE_TIMING").is_some() {
        eprintln!(
            "trace: nodes and walks {:?} ranges {:?} lines {:?}",
            t1 - t0,
            t2 - t1,
            t2.elapsed()
        );
    }
    RidgeNetwork {
        lines,
        nodes,
        points,
        pixels,
        candidate_cells: 0,
    }
}

/// `s` cut into the consecutive pieces `bounds[i]..bounds[i + 1]`.
fn split_at<'a, T>(mut s: &'a mut [T], bounds: &[usize]) -> Vec<&'a mut [T]> {
    let mut parts = Vec::with_capacity(bounds.len().saturating_sub(1));
    for b in bounds.windows(2) {
        let (part, rest) = std::mem::take(&mut s).split_at_mut(b[1] - b[0]);
        parts.push(part);
        s = rest;
    }
    parts
}

/// The lines that start at a chunk of nodes, as walked.
#[derive(Default)]
struct ChunkLines {
    /// Per line: its first node (index) << 3 | direction, its vertex count
    /// and the candidate id of its last vertex.
    lines: Vec<(u32, u32, u32)>,
    /// Candidate ids of the vertices after the first, line after line.
    ids: Vec<u32>,
    /// The direction of the step to each of these vertices.
    dirs: Vec<u8>,
}

/// Smooths the line of pixel vertices `points` (with heights) in place,
/// copies the pixel coordinates into `pixels`, converts `points` to CRS
/// coordinates and returns the line's length in metres.
#[inline(never)]
fn polyline(
    map: &HeightMap,
    metric: &Metric,
    smooth: usize,
    points: &mut [[f64; 3]],
    pixels: &mut [[f64; 2]],
) -> f64 {
    smooth_polyline(points, smooth);
    for (p, q) in points.iter_mut().zip(pixels.iter_mut()) {
        *q = [p[0], p[1]];
        (p[0], p[1]) = map.geotransform.pixel_to_crs(p[0], p[1]);
    }
    pixels
        .windows(2)
        .zip(points.windows(2))
        .map(|(a, b)| {
            let hm = metric.step_m(a[1][0] - a[0][0], a[1][1] - a[0][1], b[0][1]);
            hm.hypot(b[1][2] - b[0][2])
        })
        .sum()
}

/// [1 2 1]/4 smoothing of interior vertices, `iterations` times, in place.
fn smooth_polyline(p: &mut [[f64; 3]], iterations: usize) {
    if p.len() < 3 {
        return;
    }
    for _ in 0..iterations {
        let mut prev = p[0];
        for i in 1..p.len() - 1 {
            let cur = p[i];
            for k in 0..3 {
                p[i][k] = 0.25 * prev[k] + 0.5 * cur[k] + 0.25 * p[i + 1][k];
            }
            prev = cur;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::{Crs, GeoTransform};

    fn random_map(w: usize, h: usize, seed: u64) -> HeightMap {
        let mut s = seed;
        let data = (0..w * h)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                // Coarse values make ties; a few NaN cells.
                match s % 97 {
                    0 => f32::NAN,
                    v => (v % 23) as f32,
                }
            })
            .collect();
        HeightMap {
            width: w,
            height: h,
            data,
            geotransform: GeoTransform::north_up(0.0, 0.0, 30.0, 30.0),
            crs: Crs {
                epsg: None,
                wkt: String::new(),
                proj: None,
                geographic: false,
            },
        }
    }

    /// Profile recognition by its definition, cell by cell.
    fn reference(map: &HeightMap, p: &RidgeParams) -> Vec<bool> {
        let (w, h) = (map.width as isize, map.height as isize);
        let at = |c: isize, r: isize| {
            (c >= 0 && r >= 0 && c < w && r < h)
                .then(|| map.data[(r * w + c) as usize])
                .filter(|v| !v.is_nan())
        };
        let mut out = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let z = map.data[(r * w + c) as usize];
                let mut n = 0;
                for &(dx, dy) in &DIRS[..4] {
                    let low = |s: isize| {
                        (1..=p.half_window as isize)
                            .filter_map(|k| at(c + s * k * dx, r + s * k * dy))
                            .reduce(f32::min)
                    };
                    let crest = [low(1), low(-1)]
                        .iter()
                        .all(|m| m.is_some_and(|m| z - m > p.min_drop_m));
                    n += crest as u8;
                }
                out.push(n >= p.min_directions);
            }
        }
        out
    }

    #[test]
    fn profile_recognition_follows_its_definition() {
        for (w, h, seed) in [(70, 150, 1), (9, 200, 2), (130, 66, 3), (64, 64, 4)] {
            let map = random_map(w, h, seed);
            for hw in 1..=5 {
                for (min_directions, min_drop_m) in [(1, 0.0), (2, 0.0), (3, 2.5), (4, -1.0)] {
                    let p = RidgeParams {
                        half_window: hw,
                        min_directions,
                        min_drop_m,
                        ..RidgeParams::default()
                    };
                    let want = reference(&map, &p);
                    for simd in [true, false] {
                        let set = profile_recognition_with(&map, &p, simd);
                        let got: Vec<bool> = (0..w * h)
                            .map(|c| set.before(c + 1) > set.before(c))
                            .collect();
                        assert!(
                            got == want,
                            "{w} x {h}, hw {hw}, {min_directions} directions, drop {min_drop_m}, simd {simd}"
                        );
                    }
                }
            }
        }
    }
}
