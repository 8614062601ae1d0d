//! The finest level of the hierarchy (the caller's grid, 5-point operator,
//! zero right-hand side) and the kernels that work on it.
//!
//! Storage is *red-black split*: the cells of colour `c = (i + j) & 1` of
//! row `j` are stored contiguously in `u[c]`, cell `(i, j)` at entry
//! `k = i >> 1`. A red update then reads only black values (and vice versa),
//! so every kernel is a contiguous, vectorisable loop, and a colour row can be
//! written while the other colour is read by other threads. Each colour array
//! has a ghost row above and below the grid and a ghost entry at both ends of
//! every row; ghosts (and the padding entry of odd-width rows) are always 0,
//! which is the boundary condition `M = 0` outside the grid, so no kernel
//! needs a boundary branch.
//!
//! Layout of one colour array: row `j` (`-1 ..= ny`) starts at
//! `(j + 1) * stride`, entry `k` (`-1 ..= w`) is at `+ k + 1`, with
//! `w = ceil(nx / 2)` and `stride = w + 2`. Within row `j` the colour-`c`
//! cells sit at `i = 2k + ((j + c) & 1)`; their west and east neighbours
//! (other colour, same row) are at padded positions `k + s` and `k + s + 1`
//! with `s = (j + c) & 1`, their north and south neighbours at `k + 1` of
//! the other colour's rows `j - 1` and `j + 1`.
//!
//! Fixed (Dirichlet) cells hold their values in `u` like any other cell.
//! The kernels treat a whole colour row as free and then put the row's
//! fixed cells back (a few per row: they are listed per colour row), which
//! keeps the kernels free of masks.

use rayon::prelude::*;

use super::coarse::{prolongate, CoarseLevel};
use crate::buffer_pool;

/// Below this many cells a level is processed on one thread: the rayon
/// hand-off costs more than it saves.
const PARALLEL_MIN_CELLS: usize = 1 << 15;

/// Rows per parallel band of the smoother (at least 3 for the band scheme).
const MIN_BAND_ROWS: usize = 8;

/// Rows per parallel task of [`Level::load`].
const LOAD_CHUNK: usize = 16;

/// The finest level: the unknown (the solution), the fixed cells and the
/// constant 5-point coefficients.
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
    /// Fixed cells of colour `c` in row `j`:
    /// `fixed_start[2 j + c] .. fixed_start[2 j + c + 1]`, each an entry
    /// `fixed_k` and its value `fixed_value`.
    fixed_start: Vec<u32>,
    fixed_k: Vec<u32>,
    fixed_value: Vec<f32>,
    /// Number of free cells.
    pub free_cells: usize,
    /// Row bands `[r0, r1)` of the parallel smoother.
    bands: Vec<(usize, usize)>,
}

/// What [`Level::load`] learnt about the caller's arrays.
pub(super) struct Intake {
    /// `||b||_2`: the 2-norm over free cells of the coupling to fixed
    /// neighbours (the residual of a zero guess), f32 per cell, f64 sums.
    pub b_norm: f64,
    /// Every free cell of the initial guess is 0.
    pub zero_guess: bool,
}

/// What to do with the residual rows of the finest level as they become
/// final during the last sweep of [`Level::smooth_visiting`]. Rows come as
/// `(E, O)`: the residual of the even and of the odd cells, padded (entry
/// `k` at `k + 1`, a leading zero, zeros past the row's end, `w + 2`
/// entries each), as [`Level::residual_halves`] gives them.
/// Writes the residual of row `j` into its two colour halves `(e, o)`
/// (see [`RowVisitor::finish`]).
pub(super) type RowResidual<'a> = dyn Fn(usize, &mut [f32], &mut [f32]) + Sync + 'a;

pub(super) trait RowVisitor: Sync {
    /// State of one band.
    type State: Send;
    /// The black residual is taken as 0 (see [`Level::residual_halves`]).
    const RED_ONLY: bool;
    /// State of band `[r0, r1)`.
    fn start(&self, r0: usize, r1: usize) -> Self::State;
    /// Row `j` is final: `fill(e, o)` writes its residual. Called with
    /// increasing `j` within a band, while the sweep goes on elsewhere.
    fn row<F: FnOnce(&mut [f32], &mut [f32])>(&self, state: &mut Self::State, j: usize, fill: F);
    /// After the sweep: `residual(j, e, o)` writes the residual of any row
    /// (the band's edge rows were not given to `row`).
    fn finish(&self, state: &mut Self::State, r0: usize, r1: usize, residual: &RowResidual);
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
    unsafe fn row<'a>(self, c: usize, j: isize) -> &'a [f32] {
        let start = ((j + 1) as usize) * self.stride;
        std::slice::from_raw_parts(self.ptr[c].add(start), self.stride)
    }

    /// Colour `c` row `j`, whole padded row, mutable.
    ///
    /// # Safety
    /// No other thread may read or write this colour row while the slice lives.
    unsafe fn row_mut<'a>(self, c: usize, j: isize) -> &'a mut [f32] {
        let start = ((j + 1) as usize) * self.stride;
        std::slice::from_raw_parts_mut(self.ptr[c].add(start), self.stride)
    }
}

/// Gauss-Seidel values of the first `out.len()` entries of one colour row:
/// `(ax (west + east) + ay (north + south)) / diag` (times the precomputed
/// inverse diagonal: no division per cell).
#[inline(always)]
fn relax_row_kernel(
    out: &mut [f32],
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
    for k in 0..w {
        out[k] = (ax * (west[k] + east[k]) + ay * (north[k] + south[k])) * inv_diag;
    }
}

/// Residual of the first `out.len()` entries of one colour row whose values
/// are `u`: `ax (west + east) + ay (north + south) - diag u`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn residual_row_kernel(
    out: &mut [f32],
    u: &[f32],
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
    for k in 0..w {
        out[k] = ax * (west[k] + east[k]) + ay * (north[k] + south[k]) - diag * u[k];
    }
}

/// Sum of squares in f64 (four independent accumulators so it vectorises).
#[inline(always)]
fn sum_squares_kernel(values: &[f32]) -> f64 {
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

/// `even[k] = row[2k]`, `odd[k] = row[2k + 1]` for every cell of `row`.
#[inline(always)]
fn deinterleave_kernel(row: &[f32], even: &mut [f32], odd: &mut [f32]) {
    let pairs = row.chunks_exact(2);
    if let [last] = pairs.remainder() {
        even[row.len() / 2] = *last;
    }
    for ((p, e), o) in pairs.zip(even.iter_mut()).zip(odd.iter_mut()) {
        *e = p[0];
        *o = p[1];
    }
}

/// The inverse of [`deinterleave_kernel`].
#[inline(always)]
fn interleave_kernel(row: &mut [f32], even: &[f32], odd: &[f32]) {
    let n = row.len();
    let mut pairs = row.chunks_exact_mut(2);
    for ((p, &e), &o) in (&mut pairs).zip(even).zip(odd) {
        p[0] = e;
        p[1] = o;
    }
    if let [last] = pairs.into_remainder() {
        *last = even[n / 2];
    }
}

/// One row of [`Level::load`]: splits `vals` into `even`/`odd` entries and
/// returns (free cells, sum of `b^2` over the row, whether a free value is
/// nonzero, whether a value is not finite); `b` is scratch of `vals.len()`
/// entries. `up`/`dn` are the rows
/// above and below (zeros and no fixed cells outside the grid).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn load_row_kernel(
    vals: &[f32],
    fix: &[bool],
    up: (&[f32], &[bool]),
    dn: (&[f32], &[bool]),
    even: &mut [f32],
    odd: &mut [f32],
    b: &mut [f32],
    coef: (f32, f32),
) -> (usize, f64, bool, bool) {
    let (ax, ay) = coef;
    let nx = vals.len();
    deinterleave_kernel(vals, even, odd);
    let mut free = 0usize;
    let mut nonzero = 0u32;
    let mut bad = 0u32;
    for (&v, &f) in vals.iter().zip(fix) {
        free += usize::from(!f);
        nonzero |= u32::from(!f & (v != 0.0));
        bad |= u32::from(!v.is_finite());
    }
    // b: the free cells' coupling to fixed neighbours (0 on fixed cells).
    let fv = |v: f32, f: bool| if f { v } else { 0.0 };
    let vertical = |i: usize| fv(up.0[i], up.1[i]) + fv(dn.0[i], dn.1[i]);
    let free_only = |v: f32, f: bool| if f { 0.0 } else { v };
    if nx == 1 {
        b[0] = free_only(ay * vertical(0), fix[0]);
    } else {
        b[0] = free_only(ax * fv(vals[1], fix[1]) + ay * vertical(0), fix[0]);
        let last = ax * fv(vals[nx - 2], fix[nx - 2]) + ay * vertical(nx - 1);
        b[nx - 1] = free_only(last, fix[nx - 1]);
        let (west, east) = (&vals[..nx - 2], &vals[2..]);
        let (west_fixed, east_fixed) = (&fix[..nx - 2], &fix[2..]);
        let (u, uf) = (&up.0[1..nx - 1], &up.1[1..nx - 1]);
        let (d, df) = (&dn.0[1..nx - 1], &dn.1[1..nx - 1]);
        let own = &fix[1..nx - 1];
        for (k, o) in b[1..nx - 1].iter_mut().enumerate() {
            let horizontal = fv(west[k], west_fixed[k]) + fv(east[k], east_fixed[k]);
            let s = ax * horizontal + ay * (fv(u[k], uf[k]) + fv(d[k], df[k]));
            *o = free_only(s, own[k]);
        }
    }
    (free, sum_squares_kernel(&b[..nx]), nonzero != 0, bad != 0)
}

dispatch!(relax_row, relax_row_avx2, relax_row_kernel,
    (out: &mut [f32], same: &[f32], north: &[f32], south: &[f32], inv_diag: f32, s: usize, coef: (f32, f32)));
dispatch!(residual_row, residual_row_avx2, residual_row_kernel,
    (out: &mut [f32], u: &[f32], same: &[f32], north: &[f32], south: &[f32], diag: f32, s: usize, coef: (f32, f32)));
dispatch!(pub(super) sum_squares, sum_squares_avx2, sum_squares_kernel, (values: &[f32]) -> f64);
dispatch!(pub(super) deinterleave, deinterleave_avx2, deinterleave_kernel,
    (row: &[f32], even: &mut [f32], odd: &mut [f32]));
dispatch!(pub(super) interleave, interleave_avx2, interleave_kernel,
    (row: &mut [f32], even: &[f32], odd: &[f32]));
dispatch!(load_row, load_row_avx2, load_row_kernel,
    (vals: &[f32], fix: &[bool], up: (&[f32], &[bool]), dn: (&[f32], &[bool]), even: &mut [f32], odd: &mut [f32], b: &mut [f32], coef: (f32, f32)) -> (usize, f64, bool, bool));

impl Drop for Level {
    fn drop(&mut self) {
        for u in &mut self.u {
            buffer_pool::recycle_f32(std::mem::take(u));
        }
    }
}

impl Level {
    /// An empty `nx x ny` level of cells of size `hx x hy` with screening `c`.
    pub fn new(nx: usize, ny: usize, hx: f64, hy: f64, screening: f64) -> Level {
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
            u: [buffer_pool::zeroed_f32(len), buffer_pool::zeroed_f32(len)],
            fixed_start: vec![0; 2 * ny + 1],
            fixed_k: Vec::new(),
            fixed_value: Vec::new(),
            free_cells: 0,
            bands,
        }
    }

    /// Whether this level is large enough to use several threads.
    #[inline]
    pub fn parallel(&self) -> bool {
        self.nx * self.ny >= PARALLEL_MIN_CELLS
    }

    /// Number of cells of colour `c` in row `j` (the even cells of row `j`
    /// have colour `j & 1`).
    #[inline]
    fn count(&self, c: usize, j: usize) -> usize {
        if c == j & 1 {
            self.w
        } else {
            self.nx / 2
        }
    }

    /// Fixed cells of colour `c` in row `j`: index range into `fixed_k`.
    #[inline]
    fn fixed_of(&self, c: usize, j: usize) -> std::ops::Range<usize> {
        self.fixed_start[2 * j + c] as usize..self.fixed_start[2 * j + c + 1] as usize
    }

    /// Puts the fixed values of colour `c` row `j` back into `row` (its
    /// entries `0 .. w`).
    #[inline]
    fn restore_fixed(&self, c: usize, j: usize, row: &mut [f32]) {
        for f in self.fixed_of(c, j) {
            row[self.fixed_k[f] as usize] = self.fixed_value[f];
        }
    }

    /// Copies the caller's natural-layout arrays in (the fixed values, and
    /// the initial guess on free cells), lists the fixed cells and counts
    /// the free ones, and computes `||b||` and whether the guess is zero in
    /// the same pass. Fails with the first cell `(i, j)` (in row order)
    /// whose value is not finite.
    pub fn load(&mut self, fixed: &[bool], values: &[f32]) -> Result<Intake, (usize, usize)> {
        let (nx, ny, st) = (self.nx, self.ny, self.stride);
        let coef = (self.ax, self.ay);
        let zero_values = vec![0.0f32; nx];
        let none_fixed = vec![false; nx];
        let row_of = |j: isize| -> (&[f32], &[bool]) {
            if j < 0 || j as usize >= ny {
                (&zero_values, &none_fixed)
            } else {
                let r = j as usize * nx..(j as usize + 1) * nx;
                (&values[r.clone()], &fixed[r])
            }
        };
        let chunk = LOAD_CHUNK * st;
        let end = (ny + 1) * st;
        let [u0, u1] = &mut self.u;
        type Part = (usize, f64, bool, Option<usize>, Vec<u32>, Vec<(u32, f32)>);
        let parts: Vec<Part> = u0[st..end]
            .par_chunks_mut(chunk)
            .zip(u1[st..end].par_chunks_mut(chunk))
            .enumerate()
            .map(|(t, (u0, u1))| {
                let mut b = vec![0.0f32; nx];
                let (mut free, mut b_sq, mut nonzero) = (0, 0.0, false);
                let mut bad_row = None;
                // Per colour row: the number of fixed cells, then the cells.
                let mut counts = Vec::with_capacity(2 * LOAD_CHUNK);
                let mut cells = Vec::new();
                for (m, (r0, r1)) in u0.chunks_mut(st).zip(u1.chunks_mut(st)).enumerate() {
                    let j = t * LOAD_CHUNK + m;
                    let (vals, fix) = row_of(j as isize);
                    let (even, odd) = if j & 1 == 0 { (r0, r1) } else { (r1, r0) };
                    let (f, s, z, bad) = load_row(
                        vals,
                        fix,
                        row_of(j as isize - 1),
                        row_of(j as isize + 1),
                        &mut even[1..],
                        &mut odd[1..],
                        &mut b,
                        coef,
                    );
                    free += f;
                    b_sq += s;
                    nonzero |= z;
                    if bad && bad_row.is_none() {
                        bad_row = Some(j);
                    }
                    // Fixed cells of colour 0, then colour 1; cell i has
                    // colour (i + j) & 1 and entry i >> 1.
                    let before = cells.len();
                    for c in 0..2 {
                        let start = cells.len();
                        let parity = (j + c) & 1;
                        for (n, block) in fix.chunks(32).enumerate() {
                            if !block.iter().fold(false, |a, &f| a | f) {
                                continue;
                            }
                            for (d, &f) in block.iter().enumerate() {
                                let i = 32 * n + d;
                                if f && i & 1 == parity {
                                    cells.push(((i >> 1) as u32, vals[i]));
                                }
                            }
                        }
                        counts.push((cells.len() - start) as u32);
                    }
                    debug_assert_eq!(cells.len() - before, nx - f);
                }
                (free, b_sq, nonzero, bad_row, counts, cells)
            })
            .collect();
        if let Some(j) = parts.iter().find_map(|p| p.3) {
            let row = &values[j * nx..(j + 1) * nx];
            let i = row.iter().position(|v| !v.is_finite()).unwrap_or(0);
            return Err((i, j));
        }
        let mut free = 0;
        let mut b_sq = 0.0;
        let mut nonzero = false;
        self.fixed_k.clear();
        self.fixed_value.clear();
        self.fixed_start.clear();
        self.fixed_start.push(0);
        for (f, s, z, _, counts, cells) in parts {
            free += f;
            b_sq += s;
            nonzero |= z;
            let mut total = *self.fixed_start.last().unwrap_or(&0);
            for n in counts {
                total += n;
                self.fixed_start.push(total);
            }
            for (k, v) in cells {
                self.fixed_k.push(k);
                self.fixed_value.push(v);
            }
        }
        self.free_cells = free;
        Ok(Intake {
            b_norm: b_sq.sqrt(),
            zero_guess: !nonzero,
        })
    }

    /// Copies the level back to the caller's natural-layout array. Fixed
    /// cells hold the caller's values unchanged, so whole rows are copied.
    pub fn store(&self, values: &mut [f32]) {
        let (nx, st) = (self.nx, self.stride);
        let (u0, u1) = (&self.u[0], &self.u[1]);
        values.par_chunks_mut(nx).enumerate().for_each(|(j, vals)| {
            let start = (j + 1) * st + 1;
            let (r0, r1) = (&u0[start..start + self.w], &u1[start..start + self.w]);
            let (even, odd) = if j & 1 == 0 { (r0, r1) } else { (r1, r0) };
            interleave(vals, even, odd);
        });
    }

    /// Sets every free cell to 0.
    pub fn zero_free(&mut self) {
        let shared = SharedColours {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            stride: self.stride,
        };
        let this: &Level = self;
        (0..this.ny).into_par_iter().for_each(|j| {
            for c in 0..2 {
                // SAFETY: each task owns row j of both colours.
                let row = unsafe { &mut shared.row_mut(c, j as isize)[1..1 + this.w] };
                row.fill(0.0);
                this.restore_fixed(c, j, row);
            }
        });
    }

    /// Gauss-Seidel update of colour `c` in row `j`.
    ///
    /// # Safety
    /// The caller guarantees that no other thread touches colour `c` row `j`
    /// and that no other thread writes colour `1 - c` rows `j - 1 ..= j + 1`.
    #[inline]
    unsafe fn relax_colour_row(&self, shared: SharedColours, c: usize, j: usize) {
        let jj = j as isize;
        let other = 1 - c;
        let row = &mut shared.row_mut(c, jj)[1..1 + self.w];
        relax_row(
            &mut row[..self.count(c, j)],
            shared.row(other, jj),
            shared.row(other, jj - 1),
            shared.row(other, jj + 1),
            self.inv_diag,
            (j + c) & 1,
            (self.ax, self.ay),
        );
        self.restore_fixed(c, j, row);
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
        let shared = SharedColours {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            stride: self.stride,
        };
        // SAFETY: `shared` points into `self.u`, which nothing else accesses.
        unsafe { self.sweeps(shared, sweeps) };
    }

    /// Phase 2 of a sweep (see [`Level::smooth`]).
    ///
    /// # Safety
    /// `shared` points into `self.u`; nothing else accesses it meanwhile.
    unsafe fn phase2(&self, shared: SharedColours) {
        let phase2 = |&(r0, r1): &(usize, usize)| {
            // SAFETY: band schedule documented on `smooth`.
            unsafe { self.relax_colour_row(shared, 1, r0) };
            if r1 - 1 > r0 {
                unsafe { self.relax_colour_row(shared, 1, r1 - 1) };
            }
        };
        if self.bands.len() > 1 {
            self.bands.par_iter().for_each(phase2);
        } else {
            self.bands.iter().for_each(phase2);
        }
    }

    /// Phase 1 of a sweep over band `[r0, r1)`, calling `after(j)` once
    /// red row `j` and black row `j - 1` are done.
    ///
    /// # Safety
    /// As for [`Level::phase2`], and only the band schedule runs meanwhile.
    #[inline]
    unsafe fn phase1(
        &self,
        shared: SharedColours,
        r0: usize,
        r1: usize,
        mut after: impl FnMut(usize),
    ) {
        for j in r0..r1 {
            // SAFETY: band schedule documented on `smooth`.
            self.relax_colour_row(shared, 0, j);
            if j >= r0 + 2 {
                self.relax_colour_row(shared, 1, j - 1);
            }
            after(j);
        }
    }

    /// `sweeps` plain sweeps.
    ///
    /// # Safety
    /// As for [`Level::phase2`].
    unsafe fn sweeps(&self, shared: SharedColours, sweeps: usize) {
        for _ in 0..sweeps {
            let phase1 =
                |&(r0, r1): &(usize, usize)| unsafe { self.phase1(shared, r0, r1, |_| {}) };
            if self.bands.len() > 1 {
                self.bands.par_iter().for_each(phase1);
            } else {
                self.bands.iter().for_each(phase1);
            }
            self.phase2(shared);
        }
    }

    /// `sweeps >= 1` sweeps like [`Level::smooth`], handing the residual of
    /// every row to `visitor` as the row becomes final in the last sweep:
    /// rows `r0 + 2 ..= r1 - 3` of each band `[r0, r1)` during the band's
    /// pass (two rows behind the sweep, while they are in cache), the
    /// band's remaining edge rows in a third parallel phase after the
    /// sweep. Returns the bands' final states.
    pub fn smooth_visiting<V: RowVisitor>(&mut self, sweeps: usize, visitor: &V) -> Vec<V::State> {
        assert!(sweeps >= 1);
        let shared = SharedColours {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            stride: self.stride,
        };
        let this: &Level = self;
        // SAFETY (all blocks below): `shared` points into `self.u`, which
        // only the band schedule touches. A residual read in phase 1 covers
        // rows j - 3 ..= j - 1 of the visiting band, final and written by
        // nobody else; phase 3 only reads.
        let residual = |j: usize, e: &mut [f32], o: &mut [f32]| unsafe {
            this.residual_halves_shared(shared, j, e, o, V::RED_ONLY)
        };
        unsafe { this.sweeps(shared, sweeps - 1) };
        let phase1 = |&(r0, r1): &(usize, usize)| -> V::State {
            let mut state = visitor.start(r0, r1);
            unsafe {
                this.phase1(shared, r0, r1, |j| {
                    if j >= r0 + 4 {
                        let r = j - 2;
                        visitor.row(&mut state, r, |e, o| residual(r, e, o));
                    }
                })
            };
            state
        };
        let states: Vec<V::State> = if this.bands.len() > 1 {
            this.bands.par_iter().map(phase1).collect()
        } else {
            this.bands.iter().map(phase1).collect()
        };
        unsafe { this.phase2(shared) };
        let phase3 = |(mut state, &(r0, r1)): (V::State, &(usize, usize))| {
            visitor.finish(&mut state, r0, r1, &residual);
            state
        };
        if this.bands.len() > 1 {
            states
                .into_par_iter()
                .zip(this.bands.par_iter())
                .map(phase3)
                .collect()
        } else {
            states
                .into_iter()
                .zip(this.bands.iter())
                .map(phase3)
                .collect()
        }
    }

    /// Read-only view of `self.u` for the residual functions.
    #[inline]
    fn reader(&self) -> SharedColours {
        SharedColours {
            ptr: [
                self.u[0].as_ptr() as *mut f32,
                self.u[1].as_ptr() as *mut f32,
            ],
            stride: self.stride,
        }
    }

    /// Residual of colour `c` row `j` into `out` (length `w`; 0 at fixed
    /// cells and past the row's end).
    ///
    /// # Safety
    /// `shared` points into `self.u` and nobody writes rows `j - 1 ..= j + 1`
    /// meanwhile; it is only read.
    #[inline]
    unsafe fn residual_colour_row(
        &self,
        shared: SharedColours,
        out: &mut [f32],
        c: usize,
        j: usize,
    ) {
        let other = 1 - c;
        let jj = j as isize;
        let n = self.count(c, j);
        residual_row(
            &mut out[..n],
            &shared.row(c, jj)[1..1 + self.w],
            shared.row(other, jj),
            shared.row(other, jj - 1),
            shared.row(other, jj + 1),
            self.diag,
            (j + c) & 1,
            (self.ax, self.ay),
        );
        out[n..].fill(0.0);
        for f in self.fixed_of(c, j) {
            out[self.fixed_k[f] as usize] = 0.0;
        }
    }

    /// Squared 2-norm of the residual over the whole level (f64 sums).
    pub fn residual_norm_squared(&self) -> f64 {
        let shared = self.reader();
        let row_sum = |j: usize, buf: &mut Vec<f32>| {
            buf.resize(self.w, 0.0);
            let mut total = 0.0;
            for c in 0..2 {
                // SAFETY: `shared` reads `self.u`, borrowed shared here.
                unsafe { self.residual_colour_row(shared, buf, c, j) };
                total += sum_squares(buf);
            }
            total
        };
        if self.parallel() {
            (0..self.ny)
                .into_par_iter()
                .with_min_len(8)
                .map_init(Vec::new, |buf, j| row_sum(j, buf))
                .sum()
        } else {
            let mut buf = Vec::new();
            (0..self.ny).map(|j| row_sum(j, &mut buf)).sum()
        }
    }

    /// Residual of row `j` split by column parity into `e` (even columns)
    /// and `o` (odd columns), padded: entry `k` at `k + 1`, a leading zero,
    /// zeros past the row's end (`e` and `o` have at least `w + 2` entries).
    /// In red-black storage the even cells of row `j` have colour `j & 1`.
    ///
    /// `red_only`: the black residual is taken as 0. Right after a red-black
    /// sweep the black cells were just solved for from their final red
    /// neighbours, so their residual is 0 up to rounding (the restricted
    /// residual changes by about 1e-10 relative on the benchmark layout).
    pub fn residual_halves(&self, j: usize, e: &mut [f32], o: &mut [f32], red_only: bool) {
        // SAFETY: `reader` reads `self.u`, borrowed shared here.
        unsafe { self.residual_halves_shared(self.reader(), j, e, o, red_only) }
    }

    /// [`Level::residual_halves`] through `shared`.
    ///
    /// # Safety
    /// As for [`Level::residual_colour_row`].
    unsafe fn residual_halves_shared(
        &self,
        shared: SharedColours,
        j: usize,
        e: &mut [f32],
        o: &mut [f32],
        red_only: bool,
    ) {
        let w = self.w;
        let even = j & 1;
        for (c, out) in [(even, &mut *e), (1 - even, &mut *o)] {
            if red_only && c == 1 {
                out.fill(0.0);
                continue;
            }
            out[0] = 0.0;
            out[w + 1..].fill(0.0);
            self.residual_colour_row(shared, &mut out[1..1 + w], c, j);
        }
    }

    /// `u += P coarse.u` on the free cells (fixed cells have zero weights;
    /// they are put back anyway).
    ///
    /// `before_sweep`: a red-black sweep follows, whose red update does not
    /// read the red values it replaces, so only black cells are corrected
    /// (the result after the sweep is the same).
    pub fn prolongate_from(&mut self, coarse: &CoarseLevel, before_sweep: bool) {
        let (w, ny, st) = (self.w, self.ny, self.stride);
        let shared = SharedColours {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            stride: st,
        };
        let this: &Level = self;
        let add_row = |fj: usize, even: &[f32], odd: &[f32]| {
            let c = fj & 1;
            for (colour, corr) in [(c, even), (1 - c, odd)] {
                if before_sweep && colour == 0 {
                    continue;
                }
                // SAFETY: each call of the closure below owns fine rows
                // 2 cj and 2 cj + 1.
                let row = unsafe { &mut shared.row_mut(colour, fj as isize)[1..1 + w] };
                let n = this.count(colour, fj);
                for (u, &v) in row[..n].iter_mut().zip(corr) {
                    *u += v;
                }
                this.restore_fixed(colour, fj, row);
            }
        };
        let parallel = this.parallel();
        prolongate(coarse, parallel, |cj, [e0, o0, e1, o1]| {
            add_row(2 * cj, e0, o0);
            if 2 * cj + 1 < ny {
                add_row(2 * cj + 1, e1, o1);
            }
        });
    }
}
