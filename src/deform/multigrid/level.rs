//! One level of the multigrid hierarchy and the kernels that work on it.
//!
//! Storage is *red-black split*: the cells of colour `c = (i + j) & 1` of
//! row `j` are stored contiguously in `u[c]`, cell `(i, j)` at entry
//! `k = i >> 1`. A red update then reads only black values (and vice versa),
//! so every kernel is a contiguous, vectorisable loop, and a colour row can be
//! written while the other colour is read by other threads. Each colour array
//! has a ghost row above and below the grid and a ghost entry at both ends of
//! every row; ghosts (and the padding entry of odd-width rows) are always 0,
//! which is the boundary condition `M = 0` outside the grid, and are never
//! free, so no kernel needs a boundary branch.
//!
//! Layout of one colour array: row `j` (`-1 ..= ny`) starts at
//! `(j + 1) * stride`, entry `k` (`-1 ..= w`) is at `+ k + 1`, with
//! `w = ceil(nx / 2)` and `stride = w + 2`. Within row `j` the colour-`c`
//! cells sit at `i = 2k + ((j + c) & 1)`; their west and east neighbours
//! (other colour, same row) are at padded positions `k + s` and `k + s + 1`
//! with `s = (j + c) & 1`, their north and south neighbours at `k + 1` of
//! the other colour's rows `j - 1` and `j + 1`.

use rayon::prelude::*;

use super::coarse::{prolongate, CoarseLevel};

/// Below this many cells a level is processed on one thread: the rayon
/// hand-off costs more than it saves.
const PARALLEL_MIN_CELLS: usize = 1 << 15;

/// Rows per parallel band of the smoother (at least 3 for the band scheme).
const MIN_BAND_ROWS: usize = 8;

/// One grid of the hierarchy: the unknown (solution on the finest level,
/// correction on coarser ones), its right-hand side, the free-cell mask and
/// the constant 5-point coefficients.
pub(super) struct Level {
    pub nx: usize,
    pub ny: usize,
    /// Entries per colour row (`ceil(nx / 2)`).
    pub w: usize,
    /// Padded colour row length (`w + 2`).
    pub stride: usize,
    /// `1 / hx^2` and `1 / hy^2` at this level's cell size.
    pub ax: f32,
    pub ay: f32,
    /// Diagonal `2 ax + 2 ay + c` of a cell away from constraints.
    pub diag: f32,
    /// `1 / diag`.
    pub inv_diag: f32,
    /// Unknown, split by colour.
    pub u: [Vec<f32>; 2],
    /// Right-hand side, split by colour; empty when the level has none
    /// (the finest level, whose right-hand side is zero), see [`Level::rhs_row`].
    pub rhs: [Vec<f32>; 2],
    /// One zero padded row, read instead of `rhs` when `rhs` is empty.
    zero_row: Vec<f32>,
    /// 1 where the cell is a free unknown, 0 where it is fixed, padding or ghost.
    pub mask: [Vec<u8>; 2],
    /// Number of free cells.
    pub free_cells: usize,
    /// Row bands `[r0, r1)` of the parallel smoother.
    bands: Vec<(usize, usize)>,
}

/// Raw pointers to the two colour arrays of a level's unknown, shared by the
/// smoother's threads.
///
/// Soundness: the smoother's band schedule (see [`Level::smooth`]) never
/// lets one thread write a colour row while another thread reads or writes
/// that same colour row, and row slices made from these pointers live only
/// for the update of one row.
#[derive(Clone, Copy)]
struct SharedColours {
    ptr: [*mut f32; 2],
    stride: usize,
}

// SAFETY: see the type's documentation; access is row-disjoint by schedule.
unsafe impl Send for SharedColours {}
unsafe impl Sync for SharedColours {}

impl SharedColours {
    /// Colour `c` row `j` (`j` in `-1 ..= ny`), whole padded row.
    ///
    /// # Safety
    /// No other thread may write this colour row while the slice lives.
    unsafe fn row(&self, c: usize, j: isize) -> &[f32] {
        let start = ((j + 1) as usize) * self.stride;
        std::slice::from_raw_parts(self.ptr[c].add(start), self.stride)
    }

    /// Colour `c` row `j`, whole padded row, mutable.
    ///
    /// # Safety
    /// No other thread may read or write this colour row while the slice lives.
    #[allow(clippy::mut_from_ref)]
    unsafe fn row_mut(&self, c: usize, j: isize) -> &mut [f32] {
        let start = ((j + 1) as usize) * self.stride;
        std::slice::from_raw_parts_mut(self.ptr[c].add(start), self.stride)
    }
}

/// Gauss-Seidel update of one colour row: for every free entry,
/// `u = (rhs + ax (west + east) + ay (north + south)) / diag` (times the
/// precomputed inverse diagonal: no division per cell).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn relax_row_kernel(
    out: &mut [f32],
    mask: &[u8],
    rhs: &[f32],
    same: &[f32],
    north: &[f32],
    south: &[f32],
    inv_diag: f32,
    s: usize,
    coef: (f32, f32),
) {
    let (ax, ay) = coef;
    let w = out.len();
    let west = &same[s..s + w];
    let east = &same[s + 1..s + 1 + w];
    let north = &north[1..1 + w];
    let south = &south[1..1 + w];
    let mask = &mask[..w];
    let rhs = &rhs[..w];
    for k in 0..w {
        let new = (rhs[k] + ax * (west[k] + east[k]) + ay * (north[k] + south[k])) * inv_diag;
        out[k] = if mask[k] != 0 { new } else { out[k] };
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn relax_row_avx2(
    out: &mut [f32],
    mask: &[u8],
    rhs: &[f32],
    same: &[f32],
    north: &[f32],
    south: &[f32],
    inv_diag: f32,
    s: usize,
    coef: (f32, f32),
) {
    relax_row_kernel(out, mask, rhs, same, north, south, inv_diag, s, coef)
}

/// Residual of one colour row: `rhs + ax (west + east) + ay (north + south)
/// - diag u` on free entries, 0 elsewhere.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn residual_row_kernel(
    out: &mut [f32],
    u: &[f32],
    mask: &[u8],
    rhs: &[f32],
    same: &[f32],
    north: &[f32],
    south: &[f32],
    diag: f32,
    s: usize,
    coef: (f32, f32),
) {
    let (ax, ay) = coef;
    let w = out.len();
    let west = &same[s..s + w];
    let east = &same[s + 1..s + 1 + w];
    let north = &north[1..1 + w];
    let south = &south[1..1 + w];
    let u = &u[..w];
    let mask = &mask[..w];
    let rhs = &rhs[..w];
    for k in 0..w {
        let r = rhs[k] + ax * (west[k] + east[k]) + ay * (north[k] + south[k]) - diag * u[k];
        out[k] = if mask[k] != 0 { r } else { 0.0 };
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn residual_row_avx2(
    out: &mut [f32],
    u: &[f32],
    mask: &[u8],
    rhs: &[f32],
    same: &[f32],
    north: &[f32],
    south: &[f32],
    diag: f32,
    s: usize,
    coef: (f32, f32),
) {
    residual_row_kernel(out, u, mask, rhs, same, north, south, diag, s, coef)
}

/// Whether the AVX2/FMA versions of the kernels may be used on this CPU.
#[inline]
fn have_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[allow(clippy::too_many_arguments)]
#[inline]
fn relax_row(
    out: &mut [f32],
    mask: &[u8],
    rhs: &[f32],
    same: &[f32],
    north: &[f32],
    south: &[f32],
    inv_diag: f32,
    s: usize,
    coef: (f32, f32),
    avx2: bool,
) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the CPU supports AVX2 and FMA (checked by `have_avx2`).
        unsafe { relax_row_avx2(out, mask, rhs, same, north, south, inv_diag, s, coef) };
        return;
    }
    let _ = avx2;
    relax_row_kernel(out, mask, rhs, same, north, south, inv_diag, s, coef)
}

#[allow(clippy::too_many_arguments)]
#[inline]
fn residual_row(
    out: &mut [f32],
    u: &[f32],
    mask: &[u8],
    rhs: &[f32],
    same: &[f32],
    north: &[f32],
    south: &[f32],
    diag: f32,
    s: usize,
    coef: (f32, f32),
    avx2: bool,
) {
    #[cfg(target_arch = "x86_64")]
    if avx2 {
        // SAFETY: the CPU supports AVX2 and FMA (checked by `have_avx2`).
        unsafe { residual_row_avx2(out, u, mask, rhs, same, north, south, diag, s, coef) };
        return;
    }
    let _ = avx2;
    residual_row_kernel(out, u, mask, rhs, same, north, south, diag, s, coef)
}

/// Sum of squares in f64 (four independent accumulators so it vectorises).
#[inline]
pub(super) fn sum_squares(values: &[f32]) -> f64 {
    let mut acc = [0.0f64; 4];
    let mut chunks = values.chunks_exact(4);
    for ch in &mut chunks {
        for l in 0..4 {
            let v = ch[l] as f64;
            acc[l] += v * v;
        }
    }
    let mut total = acc[0] + acc[1] + acc[2] + acc[3];
    for &v in chunks.remainder() {
        total += (v as f64) * (v as f64);
    }
    total
}

impl Level {
    /// An empty level of `nx x ny` cells of size `hx x hy` with screening `c`.
    /// `with_rhs` false gives a level whose right-hand side is identically
    /// zero and not stored (the finest level).
    pub fn new(nx: usize, ny: usize, hx: f64, hy: f64, screening: f64, with_rhs: bool) -> Level {
        let w = nx.div_ceil(2);
        let stride = w + 2;
        let len = (ny + 2) * stride;
        let ax = 1.0 / (hx * hx);
        let ay = 1.0 / (hy * hy);
        let diag = 2.0 * ax + 2.0 * ay + screening;
        let threads = rayon::current_num_threads().max(1);
        let bands = if nx * ny < PARALLEL_MIN_CELLS || ny < 2 * MIN_BAND_ROWS {
            vec![(0, ny)]
        } else {
            // A few bands per thread for load balance.
            let count = (threads * 4).min(ny / MIN_BAND_ROWS).max(1);
            (0..count)
                .map(|b| (b * ny / count, (b + 1) * ny / count))
                .collect()
        };
        Level {
            nx,
            ny,
            w,
            stride,
            ax: ax as f32,
            ay: ay as f32,
            diag: diag as f32,
            inv_diag: (1.0 / diag) as f32,
            u: [vec![0.0; len], vec![0.0; len]],
            rhs: if with_rhs {
                [vec![0.0; len], vec![0.0; len]]
            } else {
                [Vec::new(), Vec::new()]
            },
            zero_row: vec![0.0; stride],
            mask: [vec![0; len], vec![0; len]],
            free_cells: 0,
            bands,
        }
    }

    /// Offset of colour row `j` (`-1 ..= ny`) in a colour array.
    #[inline]
    pub fn row_start(&self, j: isize) -> usize {
        ((j + 1) as usize) * self.stride
    }

    /// Right-hand side of colour `c`, entries `0 .. w` of row `j`.
    #[inline]
    pub fn rhs_row(&self, c: usize, j: isize) -> &[f32] {
        if self.rhs[c].is_empty() {
            &self.zero_row[..self.w]
        } else {
            let start = self.row_start(j) + 1;
            &self.rhs[c][start..start + self.w]
        }
    }

    /// Whether this level is large enough to use several threads.
    #[inline]
    pub fn parallel(&self) -> bool {
        self.nx * self.ny >= PARALLEL_MIN_CELLS
    }

    /// Gauss-Seidel update of colour `c` in row `j`.
    ///
    /// # Safety
    /// The caller guarantees that no other thread touches colour `c` row `j`
    /// and that no other thread writes colour `1 - c` rows `j - 1 ..= j + 1`.
    #[inline]
    unsafe fn relax_colour_row(&self, shared: SharedColours, c: usize, j: usize, avx2: bool) {
        let jj = j as isize;
        let s = (j + c) & 1;
        let other = 1 - c;
        let start = self.row_start(jj) + 1;
        let out = &mut shared.row_mut(c, jj)[1..1 + self.w];
        relax_row(
            out,
            &self.mask[c][start..start + self.w],
            self.rhs_row(c, jj),
            shared.row(other, jj),
            shared.row(other, jj - 1),
            shared.row(other, jj + 1),
            self.inv_diag,
            s,
            (self.ax, self.ay),
            avx2,
        );
    }

    /// `sweeps` red-black Gauss-Seidel sweeps, parallel over row bands.
    ///
    /// One sweep is one pass over memory: within a band, red row `j` is
    /// updated and then black row `j - 1`, whose red neighbours are final.
    /// Black rows at band edges need red values of the neighbouring band and
    /// are updated in a second phase after all bands finished their red rows.
    /// Phase 1 writes red rows of the band and black rows strictly inside it,
    /// and reads black rows `r0 - 1 ..= r1`: the edge rows, which nobody
    /// writes in phase 1. Phase 2 writes only black edge rows and reads red
    /// rows, which nobody writes in phase 2.
    pub fn smooth(&mut self, sweeps: usize) {
        if self.free_cells == 0 || sweeps == 0 {
            return;
        }
        let avx2 = have_avx2();
        let shared = SharedColours {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            stride: self.stride,
        };
        let this: &Level = self;
        let phase1 = |&(r0, r1): &(usize, usize)| {
            for j in r0..r1 {
                // SAFETY: band schedule documented above.
                unsafe { this.relax_colour_row(shared, 0, j, avx2) };
                if j >= r0 + 2 {
                    unsafe { this.relax_colour_row(shared, 1, j - 1, avx2) };
                }
            }
        };
        let phase2 = |&(r0, r1): &(usize, usize)| {
            // SAFETY: band schedule documented above.
            unsafe { this.relax_colour_row(shared, 1, r0, avx2) };
            if r1 - 1 > r0 {
                unsafe { this.relax_colour_row(shared, 1, r1 - 1, avx2) };
            }
        };
        for _ in 0..sweeps {
            if this.bands.len() > 1 {
                this.bands.par_iter().for_each(phase1);
                this.bands.par_iter().for_each(phase2);
            } else {
                this.bands.iter().for_each(phase1);
                this.bands.iter().for_each(phase2);
            }
        }
    }

    /// Residual of colour `c` row `j` into `out` (length `w`).
    #[inline]
    fn residual_colour_row(&self, out: &mut [f32], c: usize, j: usize, avx2: bool) {
        let jj = j as isize;
        let other = 1 - c;
        let start = self.row_start(jj);
        let up = self.row_start(jj - 1);
        let down = self.row_start(jj + 1);
        let st = self.stride;
        residual_row(
            out,
            &self.u[c][start + 1..start + 1 + self.w],
            &self.mask[c][start + 1..start + 1 + self.w],
            self.rhs_row(c, jj),
            &self.u[other][start..start + st],
            &self.u[other][up..up + st],
            &self.u[other][down..down + st],
            self.diag,
            (j + c) & 1,
            (self.ax, self.ay),
            avx2,
        );
    }

    /// Squared 2-norm of the residual over the whole level (f64 sums).
    pub fn residual_norm_squared(&self) -> f64 {
        let avx2 = have_avx2();
        let row_sum = |j: usize, buf: &mut Vec<f32>| {
            buf.resize(self.w, 0.0);
            let mut total = 0.0;
            for c in 0..2 {
                self.residual_colour_row(buf, c, j, avx2);
                total += sum_squares(buf);
            }
            total
        };
        if self.parallel() {
            (0..self.ny)
                .into_par_iter()
                .map_init(Vec::new, |buf, j| row_sum(j, buf))
                .sum()
        } else {
            let mut buf = Vec::new();
            (0..self.ny).map(|j| row_sum(j, &mut buf)).sum()
        }
    }
}

impl Level {
    /// Residual of row `j` split by column parity into `e` (even columns)
    /// and `o` (odd columns), padded: entry `k` at `k + 1`, a leading zero,
    /// zeros past the row's end (`e` and `o` have at least `w + 2` entries).
    /// In red-black storage the even cells of row `j` have colour `j & 1`.
    pub fn residual_halves(&self, j: usize, e: &mut [f32], o: &mut [f32]) {
        let w = self.w;
        let avx2 = have_avx2();
        let even = j & 1;
        for (c, out) in [(even, &mut *e), (1 - even, &mut *o)] {
            out[0] = 0.0;
            out[w + 1..].fill(0.0);
            self.residual_colour_row(&mut out[1..1 + w], c, j, avx2);
        }
    }

    /// `u += P coarse.u` on the free cells (fixed cells have zero weights
    /// anyway; the mask also keeps the padding entries at 0).
    pub fn prolongate_from(&mut self, coarse: &CoarseLevel) {
        let (w, ny, st) = (self.w, self.ny, self.stride);
        let shared = SharedColours {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            stride: st,
        };
        let mask = &self.mask;
        let add_row = |fj: usize, even: &[f32], odd: &[f32]| {
            let c = fj & 1;
            let start = (fj + 1) * st + 1;
            for (colour, corr) in [(c, even), (1 - c, odd)] {
                // SAFETY: each call of the closure below owns fine rows
                // 2 cj and 2 cj + 1.
                let row = unsafe { &mut shared.row_mut(colour, fj as isize)[1..1 + w] };
                let m = &mask[colour][start..start + w];
                for ((u, &m), &v) in row.iter_mut().zip(m).zip(corr) {
                    *u += if m != 0 { v } else { 0.0 };
                }
            }
        };
        let parallel = self.parallel();
        prolongate(coarse, parallel, |cj, [e0, o0, e1, o1]| {
            add_row(2 * cj, e0, o0);
            if 2 * cj + 1 < ny {
                add_row(2 * cj + 1, e1, o1);
            }
        });
    }
}
