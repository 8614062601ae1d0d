//! Coarse levels of the hierarchy: Galerkin 9-point operators (see
//! `galerkin.rs`), four-colour Gauss-Seidel smoothing, and the transfers
//! (`P` and `R = P^T`) between a level and the next coarser one.
//!
//! The unknown and the right-hand side of a coarse level are stored split
//! by column parity: point `(i, j)` is entry `k = i >> 1` of row `j` of
//! array `a = i & 1`. A four-colour Gauss-Seidel colour (row parity, column
//! parity) then updates one contiguous half row from contiguous half rows
//! of the other array and of the rows above and below, so every sweep is
//! one vectorised pass per colour. Each array has a ghost row above and
//! below the grid and a ghost entry at both ends of every row; ghosts (and
//! the padding entry of the odd columns of odd-width levels) stay 0.
//! Row `j` (`-1 ..= ny`) starts at `(j + 1) * hs`, entry `k` at `+ k + 1`,
//! with `hw = ceil(nx / 2)` and `hs = hw + 2`.
//!
//! Most points are *regular*: they share the level's constant stencil and
//! interpolation weights, and are handled by the constant-coefficient
//! kernels. The others (near a constraint, dead, or at the edge) are the
//! level's *special* points, listed row by row; every kernel first treats a
//! whole row as regular and then redoes its special points one by one with
//! their own stencil or weights. Dead points (no free fine point under
//! them) are special points with a zero stencil and a zero inverse
//! diagonal, so they keep a zero correction.
//!
//! The transfers are written against the fine level's residual and
//! correction rows split by column parity (`E` even, `O` odd columns), which
//! is both this module's storage and the red-black storage of the finest
//! level (`level.rs`), so the same kernels serve every level.

use rayon::prelude::*;

use super::galerkin::{constant_coarse, galerkin, BlockWeights, StencilSource};
use super::level::{deinterleave, interleave, sum_squares};
use crate::buffer_pool;

/// Below this many points a level is processed on one thread.
const PARALLEL_MIN_POINTS: usize = 1 << 14;

/// Index map entry of regular points (others hold their special index).
const REGULAR: u32 = u32::MAX;

/// Coarse rows per parallel task of the transfers.
const ROW_CHUNK: usize = 8;

/// Coarse rows per parallel task of the regular-point map in the setup.
const BUILD_CHUNK: usize = 32;

/// Distance in fine points over which an irregular fine stencil makes the
/// coarse points around it special.
const NEAR: usize = 2;

/// One coarse level.
pub(super) struct CoarseLevel {
    pub nx: usize,
    pub ny: usize,
    /// Padded half-row stride (`ceil(nx / 2) + 2`).
    pub hs: usize,
    /// Correction (unknown), split by column parity.
    pub u: [Vec<f32>; 2],
    /// Right-hand side, split by column parity.
    pub rhs: [Vec<f32>; 2],
    /// `REGULAR` or the special index of point `(i, j)` at `i + nx j`.
    idx: Vec<u32>,
    /// Special points, row by row: those of row `j` are
    /// `sp_row[j] .. sp_row[j + 1]`, the even columns first, the odd ones
    /// from `sp_odd[j]` on, each in increasing order.
    sp_row: Vec<u32>,
    sp_odd: Vec<u32>,
    sp_col: Vec<u32>,
    /// Stencil and inverse diagonal (both 0 for dead points).
    sp_stencil: Vec<[f32; 9]>,
    sp_inv: Vec<f32>,
    /// Interpolation weights from the point into the finer level.
    sp_block: Vec<BlockWeights>,
    /// Restriction weights onto the point, in the order of
    /// [`restrict_kernel`]'s `r` (0 for dead points).
    sp_restrict: Vec<[f32; 9]>,
    /// The constant stencil of regular points (f32 and f64), its inverse
    /// diagonal, and their interpolation weights.
    pub reg: [f32; 9],
    pub reg64: [f64; 9],
    reg_inv: f32,
    reg_block: BlockWeights,
    /// Number of live (not dead) points.
    pub live: usize,
    /// Row bands `[r0, r1)` of the parallel smoother.
    bands: Vec<(usize, usize)>,
}

impl StencilSource for CoarseLevel {
    #[inline]
    fn stencil(&self, i: isize, j: isize) -> [f64; 9] {
        if i < 0 || j < 0 || i as usize >= self.nx || j as usize >= self.ny {
            return [0.0; 9];
        }
        match self.idx[j as usize * self.nx + i as usize] {
            REGULAR => self.reg64,
            n => self.sp_stencil[n as usize].map(f64::from),
        }
    }

    fn irregular_row(&self, j: usize, out: &mut [u8]) {
        let ids = &self.idx[j * self.nx..(j + 1) * self.nx];
        for (o, &id) in out.iter_mut().zip(ids) {
            *o = u8::from(id != REGULAR);
        }
    }
}

/// Raw pointers to the two parity arrays of a level's unknown, shared by
/// the smoother's threads.
///
/// Soundness: in each phase of [`CoarseLevel::smooth`] a thread writes only
/// rows of one parity that no other thread touches and reads rows of the
/// other parity, which nobody writes in that phase; row slices made from
/// these pointers live only for the update of one row.
#[derive(Clone, Copy)]
struct SharedHalves {
    ptr: [*mut f32; 2],
    hs: usize,
}

// SAFETY: see the type's documentation; access is row-disjoint by schedule.
unsafe impl Send for SharedHalves {}
unsafe impl Sync for SharedHalves {}

impl SharedHalves {
    /// Padded half row at storage row `j` (`= grid row + 1`) of parity `a`.
    ///
    /// # Safety
    /// No other thread may write this half row while the slice lives.
    #[inline]
    unsafe fn row<'a>(self, a: usize, j: usize) -> &'a [f32] {
        std::slice::from_raw_parts(self.ptr[a].add(j * self.hs), self.hs)
    }

    /// Padded half row at storage row `j` (`= grid row + 1`), mutable.
    ///
    /// # Safety
    /// No other thread may read or write this half row while the slice lives.
    #[inline]
    unsafe fn row_mut<'a>(self, a: usize, j: usize) -> &'a mut [f32] {
        std::slice::from_raw_parts_mut(self.ptr[a].add(j * self.hs), self.hs)
    }
}

/// The padded half rows around one half row of parity `a`: the same
/// parity's rows above and below (`same_up`, `same_dn`) and the other
/// parity's rows above, at and below. Entry `k` of the half row has its
/// west and east neighbours at `other[k + a]` and `other[k + a + 1]`, its
/// north and south neighbours at `same_*[k + 1]`.
#[derive(Clone, Copy)]
struct Around<'a> {
    same_up: &'a [f32],
    same_dn: &'a [f32],
    other_up: &'a [f32],
    other: &'a [f32],
    other_dn: &'a [f32],
    a: usize,
}

impl Around<'_> {
    /// Off-centre part of `s . u` at entry `k` (centre excluded).
    #[inline(always)]
    fn off_centre(&self, s: &[f32; 9], k: usize) -> f32 {
        let (a, p) = (self.a, k + 1);
        (s[0] * self.other_up[k + a] + s[1] * self.same_up[p] + s[2] * self.other_up[k + a + 1])
            + (s[3] * self.other[k + a] + s[5] * self.other[k + a + 1])
            + (s[6] * self.other_dn[k + a]
                + s[7] * self.same_dn[p]
                + s[8] * self.other_dn[k + a + 1])
    }
}

/// Constant-stencil Gauss-Seidel values of the first `out.len()` entries of
/// a half row: `out[k] = (rhs[k] - off-centre s . u) * inv`.
#[inline(always)]
fn relax_half_kernel(out: &mut [f32], rhs: &[f32], nb: Around, s: &[f32; 9], inv: f32) {
    let n = out.len();
    let a = nb.a;
    let (ou, oc, od) = (
        &nb.other_up[a..a + n + 1],
        &nb.other[a..a + n + 1],
        &nb.other_dn[a..a + n + 1],
    );
    let (su, sd) = (&nb.same_up[1..n + 1], &nb.same_dn[1..n + 1]);
    let rhs = &rhs[..n];
    for k in 0..n {
        let north = s[0] * ou[k] + s[1] * su[k] + s[2] * ou[k + 1];
        let middle = s[3] * oc[k] + s[5] * oc[k + 1];
        let south = s[6] * od[k] + s[7] * sd[k] + s[8] * od[k + 1];
        out[k] = (rhs[k] - (north + middle + south)) * inv;
    }
}

/// Constant-stencil residual `rhs - s . u` of the first `out.len()` entries
/// of a half row whose own values are `centre` (padded).
#[inline(always)]
fn residual_half_kernel(out: &mut [f32], centre: &[f32], rhs: &[f32], nb: Around, s: &[f32; 9]) {
    let n = out.len();
    let a = nb.a;
    let (ou, oc, od) = (
        &nb.other_up[a..a + n + 1],
        &nb.other[a..a + n + 1],
        &nb.other_dn[a..a + n + 1],
    );
    let (su, sd) = (&nb.same_up[1..n + 1], &nb.same_dn[1..n + 1]);
    let (c, rhs) = (&centre[1..n + 1], &rhs[..n]);
    for k in 0..n {
        let north = s[0] * ou[k] + s[1] * su[k] + s[2] * ou[k + 1];
        let middle = s[3] * oc[k] + s[4] * c[k] + s[5] * oc[k + 1];
        let south = s[6] * od[k] + s[7] * sd[k] + s[8] * od[k + 1];
        out[k] = rhs[k] - (north + middle + south);
    }
}

/// Constant-weight restriction of one coarse row: `out[ci]` from the fine
/// residual half rows of fine rows `2 cj - 1` (`s`), `2 cj` (`c`) and
/// `2 cj + 1` (`n`), each as `(E, O)` padded with one leading zero (entry
/// `ci` at `ci + 1`).
#[inline(always)]
fn restrict_kernel(
    out: &mut [f32],
    s: (&[f32], &[f32]),
    c: (&[f32], &[f32]),
    n: (&[f32], &[f32]),
    r: &BlockWeights,
) {
    let m = out.len();
    let (es, os) = (&s.0[1..m + 1], &s.1[..m + 1]);
    let (ec, oc) = (&c.0[1..m + 1], &c.1[..m + 1]);
    let (en, on) = (&n.0[1..m + 1], &n.1[..m + 1]);
    for k in 0..m {
        let row_c = r[0] * ec[k] + r[1] * oc[k + 1] + r[2] * oc[k];
        let row_n = r[3] * en[k] + r[5] * on[k + 1] + r[6] * on[k];
        let row_s = r[4] * es[k] + r[7] * os[k + 1] + r[8] * os[k];
        out[k] = row_c + row_n + row_s;
    }
}

/// Constant-weight prolongation of one coarse row pair: corrections of the
/// fine half rows `(E, O)` of fine rows `2 cj` (`row0`) and `2 cj + 1`
/// (`row1`) from coarse rows `cj` (`uc`) and `cj + 1` (`un`), natural layout
/// with one trailing zero.
#[inline(always)]
fn prolong_kernel(
    row0: (&mut [f32], &mut [f32]),
    row1: (&mut [f32], &mut [f32]),
    uc: &[f32],
    un: &[f32],
    r: &BlockWeights,
) {
    let m = row0.0.len();
    let (uc, un) = (&uc[..m + 1], &un[..m + 1]);
    let (e0, o0) = (&mut row0.0[..m], &mut row0.1[..m]);
    let (e1, o1) = (&mut row1.0[..m], &mut row1.1[..m]);
    for k in 0..m {
        e0[k] = r[0] * uc[k];
        o0[k] = r[1] * uc[k] + r[2] * uc[k + 1];
        e1[k] = r[3] * uc[k] + r[4] * un[k];
        o1[k] = (r[5] * uc[k] + r[6] * uc[k + 1]) + (r[7] * un[k] + r[8] * un[k + 1]);
    }
}

dispatch!(relax_half, relax_half_avx2, relax_half_kernel,
    (out: &mut [f32], rhs: &[f32], nb: Around, s: &[f32; 9], inv: f32));
dispatch!(residual_half, residual_half_avx2, residual_half_kernel,
    (out: &mut [f32], centre: &[f32], rhs: &[f32], nb: Around, s: &[f32; 9]));
dispatch!(restrict_regular, restrict_regular_avx2, restrict_kernel,
    (out: &mut [f32], s: (&[f32], &[f32]), c: (&[f32], &[f32]), n: (&[f32], &[f32]), r: &BlockWeights));
dispatch!(prolong_regular, prolong_regular_avx2, prolong_kernel,
    (row0: (&mut [f32], &mut [f32]), row1: (&mut [f32], &mut [f32]), uc: &[f32], un: &[f32], r: &BlockWeights));

/// Row bands of the smoother: one band below [`PARALLEL_MIN_POINTS`],
/// otherwise a few bands per thread (at least 8 rows each).
fn smoother_bands(nx: usize, ny: usize) -> Vec<(usize, usize)> {
    if nx * ny < PARALLEL_MIN_POINTS || ny < 16 {
        return vec![(0, ny)];
    }
    let count = (rayon::current_num_threads().max(1) * 4).min(ny / 8).max(1);
    (0..count)
        .map(|b| (b * ny / count, (b + 1) * ny / count))
        .collect()
}

/// Number of points of column parity `a` in a row of `nx` points.
#[inline]
fn half_len(nx: usize, a: usize) -> usize {
    (nx + 1 - a) / 2
}

impl Drop for CoarseLevel {
    fn drop(&mut self) {
        for v in self.u.iter_mut().chain(&mut self.rhs) {
            buffer_pool::recycle_f32(std::mem::take(v));
        }
        buffer_pool::recycle_u32(std::mem::take(&mut self.idx));
    }
}

impl CoarseLevel {
    /// Whether this level is large enough to use several threads.
    #[inline]
    pub fn parallel(&self) -> bool {
        self.nx * self.ny >= PARALLEL_MIN_POINTS
    }

    /// Offset of padded half row `j` (`-1 ..= ny`).
    #[inline]
    fn row_start(&self, j: isize) -> usize {
        (j + 1) as usize * self.hs
    }

    /// Special points of row `j`: index range.
    #[inline]
    fn specials(&self, j: usize) -> std::ops::Range<usize> {
        self.sp_row[j] as usize..self.sp_row[j + 1] as usize
    }

    /// Special points of row `j` in columns of parity `a`: index range.
    #[inline]
    fn specials_of(&self, j: usize, a: usize) -> std::ops::Range<usize> {
        let (start, odd, end) = (self.sp_row[j], self.sp_odd[j], self.sp_row[j + 1]);
        if a == 0 {
            start as usize..odd as usize
        } else {
            odd as usize..end as usize
        }
    }

    /// The coarse level under a finer level given by `src` (`fnx x fny`
    /// points, constant stencil `fine_reg`).
    pub fn build<S: StencilSource + ?Sized>(
        src: &S,
        fnx: usize,
        fny: usize,
        fine_reg: [f64; 9],
    ) -> CoarseLevel {
        let nx = fnx.div_ceil(2);
        let ny = fny.div_ceil(2);
        let hw = nx.div_ceil(2);
        let hs = hw + 2;
        let len = (ny + 2) * hs;
        let (reg64, reg_block) = constant_coarse(fine_reg);
        let reg_diag = reg64[4];

        // Regular points: no irregular fine point (nor the edge) within 2
        // fine points of (2 ci, 2 cj) in either direction. That is exact: the
        // Galerkin stencil of (ci, cj) and the interpolation weights that the
        // transfers use around it depend only on the fine stencils within 2
        // fine points (see `galerkin.rs`). Rows are done in chunks, each
        // with its own window of dilated fine rows.
        let mut idx = buffer_pool::overwritten_u32(nx * ny);
        // Per task: dilated fine rows, one fine row and its scratch, and
        // the vertical union of one coarse row.
        let scratch = || (Vec::new(), vec![0u8; fnx], vec![0u8; fnx], vec![0u8; nx]);
        let chunk_cols: Vec<Vec<(u32, u32)>> = idx
            .par_chunks_mut(BUILD_CHUNK * nx)
            .enumerate()
            .map_init(scratch, |(near, irr, dilate, any), (t, rows)| {
                let cj0 = t * BUILD_CHUNK;
                let mut cols = Vec::new();
                // near[r][ci]: an irregular fine point within NEAR columns
                // of 2 ci in fine row fj0 + r.
                let fj0 = (2 * cj0).saturating_sub(NEAR);
                let fj1 = (2 * (cj0 + rows.len() / nx - 1) + NEAR).min(fny - 1);
                near.clear();
                near.resize((fj1 + 1 - fj0) * nx, 0u8);
                for (r, out) in near.chunks_mut(nx).enumerate() {
                    src.irregular_row(fj0 + r, irr);
                    dilate_columns(irr, dilate, out);
                }
                for (m, row) in rows.chunks_mut(nx).enumerate() {
                    let cj = cj0 + m;
                    let fj = 2 * cj;
                    if fj >= NEAR && fj + NEAR < fny {
                        any.fill(0);
                        for r in fj - NEAR..=fj + NEAR {
                            let nr = &near[(r - fj0) * nx..(r - fj0 + 1) * nx];
                            for (a, &v) in any.iter_mut().zip(nr) {
                                *a |= v;
                            }
                        }
                    } else {
                        any.fill(1);
                    }
                    for (id, &a) in row.iter_mut().zip(any.iter()) {
                        *id = if a != 0 { 0 } else { REGULAR }; // numbered below
                    }
                    // Special points of the row: even columns, then odd.
                    for parity in 0..2 {
                        for (ci, &a) in any.iter().enumerate().skip(parity).step_by(2) {
                            if a != 0 {
                                cols.push((ci as u32, cj as u32));
                            }
                        }
                    }
                }
                cols
            })
            .collect();
        // Number the special points row by row.
        let count: usize = chunk_cols.iter().map(Vec::len).sum();
        let mut sp_col = Vec::with_capacity(count);
        let mut sp_rowid = Vec::with_capacity(count);
        let mut sp_row = vec![0u32; ny + 1];
        let mut sp_odd = vec![0u32; ny];
        for cols in &chunk_cols {
            for &(ci, cj) in cols {
                sp_col.push(ci);
                sp_rowid.push(cj);
                sp_row[cj as usize + 1] += 1;
                sp_odd[cj as usize] += u32::from(ci & 1 == 0);
            }
        }
        drop(chunk_cols);
        for j in 0..ny {
            sp_row[j + 1] += sp_row[j];
            sp_odd[j] += sp_row[j];
        }
        idx.par_chunks_mut(nx).enumerate().for_each(|(cj, row)| {
            for n in sp_row[cj]..sp_row[cj + 1] {
                row[sp_col[n as usize] as usize] = n;
            }
        });
        // Interpolation weights of the special points, then their Galerkin
        // stencils (which read the weights of their neighbours).
        let sp_block: Vec<BlockWeights> = sp_col
            .par_iter()
            .zip(&sp_rowid)
            .map(|(&ci, &cj)| super::galerkin::block_weights(src, ci as isize, cj as isize))
            .collect();
        let block_at = |i: isize, j: isize| -> BlockWeights {
            if i < 0 || j < 0 || i as usize >= nx || j as usize >= ny {
                return [0.0; 9];
            }
            match idx[j as usize * nx + i as usize] {
                REGULAR => reg_block,
                n => sp_block[n as usize],
            }
        };
        let (sp_stencil, sp_inv): (Vec<[f32; 9]>, Vec<f32>) = sp_col
            .par_iter()
            .zip(&sp_rowid)
            .map(|(&ci, &cj)| {
                let st = galerkin(src, block_at, ci as isize, cj as isize);
                if st[4] <= 1e-9 * reg_diag {
                    ([0.0f32; 9], 0.0f32)
                } else {
                    (st.map(|v| v as f32), (1.0 / st[4]) as f32)
                }
            })
            .unzip();
        // Restriction weights of the special points (zero for dead ones).
        let sp_restrict: Vec<[f32; 9]> = sp_col
            .par_iter()
            .zip(&sp_rowid)
            .zip(&sp_inv)
            .map(|((&ci, &cj), &inv)| {
                if inv == 0.0 {
                    return [0.0; 9];
                }
                let (i, j) = (ci as isize, cj as isize);
                let (bc, bw, bs, bsw) = (
                    block_at(i, j),
                    block_at(i - 1, j),
                    block_at(i, j - 1),
                    block_at(i - 1, j - 1),
                );
                [
                    bc[0], bc[1], bw[2], bc[3], bs[4], bc[5], bw[6], bs[7], bsw[8],
                ]
            })
            .collect();
        let dead = sp_inv.iter().filter(|&&v| v == 0.0).count();
        CoarseLevel {
            nx,
            ny,
            hs,
            u: [buffer_pool::zeroed_f32(len), buffer_pool::zeroed_f32(len)],
            rhs: [buffer_pool::zeroed_f32(len), buffer_pool::zeroed_f32(len)],
            idx,
            sp_row,
            sp_odd,
            sp_col,
            sp_stencil,
            sp_inv,
            sp_block,
            sp_restrict,
            reg: reg64.map(|v| v as f32),
            reg64,
            reg_inv: (1.0 / reg64[4]) as f32,
            reg_block,
            live: nx * ny - dead,
            bands: smoother_bands(nx, ny),
        }
    }

    /// The half rows around half row `j` of parity `a`, read through `sh`.
    ///
    /// # Safety
    /// No other thread may write the other parity's rows `j - 1 ..= j + 1`
    /// or this parity's rows `j - 1` and `j + 1` while the result lives.
    #[inline]
    unsafe fn around_shared(&self, sh: SharedHalves, a: usize, j: usize) -> Around<'_> {
        let o = 1 - a;
        Around {
            same_up: sh.row(a, j),
            same_dn: sh.row(a, j + 2),
            other_up: sh.row(o, j),
            other: sh.row(o, j + 1),
            other_dn: sh.row(o, j + 2),
            a,
        }
    }

    /// The half rows around half row `j` of parity `a`.
    #[inline]
    fn around(&self, a: usize, j: usize) -> Around<'_> {
        let o = 1 - a;
        let hs = self.hs;
        let row = |p: usize, r: usize| &self.u[p][r * hs..(r + 1) * hs];
        Around {
            same_up: row(a, j),
            same_dn: row(a, j + 2),
            other_up: row(o, j),
            other: row(o, j + 1),
            other_dn: row(o, j + 2),
            a,
        }
    }

    /// Gauss-Seidel update of row `j`: even columns, then odd columns. The
    /// constant-stencil update of a whole half row, then its special points.
    ///
    /// # Safety
    /// No other thread may access row `j` or write rows `j - 1`, `j + 1`.
    #[inline]
    unsafe fn relax_row(&self, sh: SharedHalves, j: usize) {
        let start = self.row_start(j as isize);
        for a in 0..2 {
            let n = half_len(self.nx, a);
            let nb = self.around_shared(sh, a, j);
            let out = &mut sh.row_mut(a, j + 1)[1..1 + n];
            let rhs = &self.rhs[a][start + 1..start + 1 + n];
            relax_half(out, rhs, nb, &self.reg, self.reg_inv);
            for sp in self.specials_of(j, a) {
                let k = self.sp_col[sp] as usize >> 1;
                let v = (rhs[k] - nb.off_centre(&self.sp_stencil[sp], k)) * self.sp_inv[sp];
                out[k] = v;
            }
        }
    }

    /// `sweeps` four-colour Gauss-Seidel sweeps (even rows, then odd rows;
    /// within a row even then odd columns), parallel over row bands.
    ///
    /// One sweep is one pass over memory: within a band, even row `j` is
    /// updated and then odd row `j - 1`, whose even neighbours are final
    /// (the same result as all even rows before all odd rows). Odd rows at
    /// a band's edge need an even row of the neighbouring band and are
    /// updated in a second phase. Phase 1 writes the band's even rows and
    /// its odd rows strictly inside it, and reads the odd edge rows next to
    /// it, which nobody writes in phase 1; phase 2 writes only odd edge rows
    /// and reads even rows, which nobody writes in phase 2.
    pub fn smooth(&mut self, sweeps: usize) {
        let sh = SharedHalves {
            ptr: [self.u[0].as_mut_ptr(), self.u[1].as_mut_ptr()],
            hs: self.hs,
        };
        let this: &CoarseLevel = self;
        let phase1 = |&(r0, r1): &(usize, usize)| {
            for j in (r0..r1).filter(|j| j & 1 == 0) {
                // SAFETY: band schedule documented above.
                unsafe { this.relax_row(sh, j) };
                if j >= r0 + 2 {
                    unsafe { this.relax_row(sh, j - 1) };
                }
            }
        };
        let phase2 = |&(r0, r1): &(usize, usize)| {
            // SAFETY: band schedule documented above.
            if r0 & 1 == 1 {
                unsafe { this.relax_row(sh, r0) };
            }
            let last = r1 - 1;
            if last > r0 && last & 1 == 1 {
                unsafe { this.relax_row(sh, last) };
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

    /// Residual of row `j` split by column parity into `e` and `o` (padded:
    /// entry `k` at `k + 1`, leading zero; padding entries 0).
    pub fn residual_halves(&self, j: usize, e: &mut [f32], o: &mut [f32]) {
        let start = self.row_start(j as isize);
        for (a, out) in [(0, &mut *e), (1, &mut *o)] {
            let n = half_len(self.nx, a);
            out[0] = 0.0;
            out[n + 1..].fill(0.0);
            let nb = self.around(a, j);
            let centre = &self.u[a][start..start + self.hs];
            let rhs = &self.rhs[a][start + 1..start + 1 + n];
            let out = &mut out[1..1 + n];
            residual_half(out, centre, rhs, nb, &self.reg);
            for sp in self.specials_of(j, a) {
                let k = self.sp_col[sp] as usize >> 1;
                out[k] = if self.sp_inv[sp] == 0.0 {
                    0.0
                } else {
                    let s = &self.sp_stencil[sp];
                    rhs[k] - (nb.off_centre(s, k) + s[4] * centre[k + 1])
                };
            }
        }
    }

    /// Squared 2-norm of the residual (f64 sums).
    pub fn residual_norm_squared(&self) -> f64 {
        let mut e = vec![0.0f32; self.hs];
        let mut o = vec![0.0f32; self.hs];
        (0..self.ny)
            .map(|j| {
                self.residual_halves(j, &mut e, &mut o);
                sum_squares(&e) + sum_squares(&o)
            })
            .sum()
    }

    /// Solves this (small) level almost exactly: sweeps until the residual
    /// fell by 1e-6 (or a sweep limit).
    pub fn solve_coarsest(&mut self) {
        let start = self.residual_norm_squared();
        if start == 0.0 {
            return;
        }
        for _ in 0..1000 {
            self.smooth(4);
            if self.residual_norm_squared() <= 1e-12 * start {
                break;
            }
        }
    }

    /// Natural-layout row `j` of the unknown into `out[..nx]`, `out[nx] = 0`;
    /// all zeros for `j >= ny`.
    fn natural_row(&self, j: usize, out: &mut [f32]) {
        if j >= self.ny {
            out.fill(0.0);
            return;
        }
        let start = self.row_start(j as isize) + 1;
        let half = self.hs - 2;
        interleave(
            &mut out[..self.nx],
            &self.u[0][start..start + half],
            &self.u[1][start..start + half],
        );
        out[self.nx] = 0.0;
    }
}

/// `out[ci] = 1` when `irr` (one fine row) has an irregular point within
/// `NEAR` columns of `2 ci`, or that window leaves the row; `scratch` has
/// the length of `irr`.
fn dilate_columns(irr: &[u8], scratch: &mut [u8], out: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2.
        return unsafe { dilate_columns_avx2(irr, scratch, out) };
    }
    dilate_columns_kernel(irr, scratch, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn dilate_columns_avx2(irr: &[u8], scratch: &mut [u8], out: &mut [u8]) {
    dilate_columns_kernel(irr, scratch, out)
}

#[inline(always)]
fn dilate_columns_kernel(irr: &[u8], scratch: &mut [u8], out: &mut [u8]) {
    let n = irr.len();
    if n < 3 {
        out.fill(1);
        return;
    }
    // scratch[i] = irr[i - 1] | irr[i] | irr[i + 1], outside counting as 1
    // (contiguous, vectorised); the window [2 ci - 2, 2 ci + 2] is then
    // scratch[2 ci - 1] | scratch[2 ci + 1].
    scratch[0] = 1;
    scratch[n - 1] = 1;
    let (west, mid, east) = (&irr[..n - 2], &irr[1..n - 1], &irr[2..]);
    for (((s, &w), &m), &e) in scratch[1..n - 1].iter_mut().zip(west).zip(mid).zip(east) {
        *s = w | m | e;
    }
    for (ci, o) in out.iter_mut().enumerate() {
        let c = 2 * ci;
        let west = if c >= 1 { scratch[c - 1] } else { 1 };
        let east = if c + 1 < n { scratch[c + 1] } else { 1 };
        *o = west | east;
    }
}

/// Restricts the fine residual to the right-hand side of `coarse` with
/// `R = P^T` and zeroes its correction, in one pass over the coarse rows.
/// `residual(j, e, o)` writes fine row `j`'s residual split by column parity
/// (padded: entry `k` at `k + 1`, leading zero, at least `coarse.nx + 1`
/// entries, zero past the row's end) for `0 <= j < fny`.
pub(super) fn restrict<F>(coarse: &mut CoarseLevel, fny: usize, parallel: bool, residual: F)
where
    F: Fn(usize, &mut [f32], &mut [f32]) + Sync,
{
    let cny = coarse.ny;
    let target = RestrictTarget::new(coarse);
    let width = target.width();
    let fill = |j: isize, e: &mut [f32], o: &mut [f32]| {
        if j < 0 || j as usize >= fny {
            e.fill(0.0);
            o.fill(0.0);
        } else {
            residual(j as usize, e, o);
        }
    };
    let job = |t: usize, buf: &mut Vec<f32>| {
        buf.clear();
        buf.resize(7 * width, 0.0);
        let (rows, out) = buf.split_at_mut(6 * width);
        // Three fine rows (E, O) in rotation: fine row 2 cj + 1 of one
        // coarse row is row 2 cj' - 1 of the next.
        let mut slots: Vec<&mut [f32]> = rows.chunks_mut(width).collect();
        let end = ((t + 1) * ROW_CHUNK).min(cny);
        for cj in t * ROW_CHUNK..end {
            let fj = 2 * cj as isize;
            if cj == t * ROW_CHUNK {
                let (e, rest) = slots.split_at_mut(1);
                fill(fj - 1, e[0], rest[0]);
            } else {
                slots.rotate_left(4);
            }
            {
                let (head, tail) = slots.split_at_mut(3);
                fill(fj, head[2], tail[0]);
                let (e, o) = tail[1..].split_at_mut(1);
                fill(fj + 1, e[0], o[0]);
            }
            let r = |m: usize| (&*slots[2 * m], &*slots[2 * m + 1]);
            // SAFETY: each task writes only its own coarse rows.
            unsafe { target.write_row(cj, r(0), r(1), r(2), out) };
        }
    };
    let tasks = cny.div_ceil(ROW_CHUNK);
    if parallel {
        (0..tasks)
            .into_par_iter()
            .for_each_init(Vec::new, |buf, t| job(t, buf));
    } else {
        let mut buf = Vec::new();
        (0..tasks).for_each(|t| job(t, &mut buf));
    }
}

/// Write access to the right-hand side and correction of a coarse level for
/// restricting into it from several threads, each thread owning whole
/// coarse rows.
pub(super) struct RestrictTarget<'a> {
    level: &'a CoarseLevel,
    rhs: SharedHalves,
    u: SharedHalves,
}

// SAFETY: writes go to coarse rows owned by one thread (see `write_row`).
unsafe impl Sync for RestrictTarget<'_> {}

impl<'a> RestrictTarget<'a> {
    pub fn new(level: &'a mut CoarseLevel) -> RestrictTarget<'a> {
        let hs = level.hs;
        let rhs = SharedHalves {
            ptr: [level.rhs[0].as_mut_ptr(), level.rhs[1].as_mut_ptr()],
            hs,
        };
        let u = SharedHalves {
            ptr: [level.u[0].as_mut_ptr(), level.u[1].as_mut_ptr()],
            hs,
        };
        RestrictTarget { level, rhs, u }
    }

    /// Length of the fine residual rows `write_row` reads: coarse `nx + 2`.
    pub fn width(&self) -> usize {
        self.level.nx + 2
    }

    /// Coarse rows `cj` with `2 cj` in `rows`.
    pub fn rows_centred_in(&self, rows: std::ops::Range<usize>) -> std::ops::Range<usize> {
        rows.start.div_ceil(2)..rows.end.div_ceil(2).min(self.level.ny)
    }

    /// Restricts the fine residual rows `2 cj - 1` (`s`), `2 cj` (`c`) and
    /// `2 cj + 1` (`n`), each `(E, O)` as documented on [`restrict`], into
    /// coarse row `cj` of the right-hand side, and zeroes that row of the
    /// correction; `out` is scratch.
    ///
    /// # Safety
    /// No other thread may access coarse row `cj` of `rhs` or `u` meanwhile.
    pub unsafe fn write_row(
        &self,
        cj: usize,
        s: (&[f32], &[f32]),
        c: (&[f32], &[f32]),
        n: (&[f32], &[f32]),
        out: &mut [f32],
    ) {
        let level = self.level;
        let out = &mut out[..level.nx];
        let ((pe, po), (ce, co), (ne, no)) = (s, c, n);
        restrict_regular(out, s, c, n, &level.reg_block);
        for sp in level.specials(cj) {
            let ci = level.sp_col[sp] as usize;
            let r = &level.sp_restrict[sp];
            let k = ci + 1;
            out[ci] = (r[0] * ce[k] + r[1] * co[k] + r[2] * co[k - 1])
                + (r[3] * ne[k] + r[5] * no[k] + r[6] * no[k - 1])
                + (r[4] * pe[k] + r[7] * po[k] + r[8] * po[k - 1]);
        }
        let (r0, r1) = (self.rhs.row_mut(0, cj + 1), self.rhs.row_mut(1, cj + 1));
        deinterleave(out, &mut r0[1..], &mut r1[1..]);
        self.u.row_mut(0, cj + 1).fill(0.0);
        self.u.row_mut(1, cj + 1).fill(0.0);
    }
}

/// Restriction between two coarse levels: `coarse.rhs = R (fine residual)`,
/// `coarse.u = 0`.
pub(super) fn restrict_coarse(fine: &CoarseLevel, coarse: &mut CoarseLevel) {
    let parallel = fine.parallel();
    restrict(coarse, fine.ny, parallel, |j, e, o| {
        fine.residual_halves(j, e, o)
    });
}

/// Interpolates `coarse.u` to the finer level, one fine row pair at a time:
/// `add(cj, [e0, o0, e1, o1])` receives the corrections of fine rows `2 cj`
/// and `2 cj + 1` split by column parity (`coarse.nx` entries each; entries
/// past the fine row's end are 0).
pub(super) fn prolongate<F>(coarse: &CoarseLevel, parallel: bool, add: F)
where
    F: Fn(usize, [&[f32]; 4]) + Sync,
{
    let (cnx, cny) = (coarse.nx, coarse.ny);
    let width = cnx + 1;
    let job = |t: usize, buf: &mut Vec<f32>| {
        buf.clear();
        buf.resize(6 * width, 0.0);
        let (nat, corr) = buf.split_at_mut(2 * width);
        let (mut uc, mut un) = nat.split_at_mut(width);
        let end = ((t + 1) * ROW_CHUNK).min(cny);
        for cj in t * ROW_CHUNK..end {
            if cj == t * ROW_CHUNK {
                coarse.natural_row(cj, uc);
            } else {
                std::mem::swap(&mut uc, &mut un);
            }
            coarse.natural_row(cj + 1, un);
            let (e0, rest) = corr.split_at_mut(width);
            let (o0, rest) = rest.split_at_mut(width);
            let (e1, o1) = rest.split_at_mut(width);
            let (e0, o0, e1, o1) = (
                &mut e0[..cnx],
                &mut o0[..cnx],
                &mut e1[..cnx],
                &mut o1[..cnx],
            );
            prolong_regular((e0, o0), (e1, o1), uc, un, &coarse.reg_block);
            for sp in coarse.specials(cj) {
                let ci = coarse.sp_col[sp] as usize;
                let b = &coarse.sp_block[sp];
                e0[ci] = b[0] * uc[ci];
                o0[ci] = b[1] * uc[ci] + b[2] * uc[ci + 1];
                e1[ci] = b[3] * uc[ci] + b[4] * un[ci];
                o1[ci] = b[5] * uc[ci] + b[6] * uc[ci + 1] + b[7] * un[ci] + b[8] * un[ci + 1];
            }
            add(cj, [&*e0, &*o0, &*e1, &*o1]);
        }
    };
    let tasks = cny.div_ceil(ROW_CHUNK);
    if parallel {
        (0..tasks)
            .into_par_iter()
            .for_each_init(Vec::new, |buf, t| job(t, buf));
    } else {
        let mut buf = Vec::new();
        (0..tasks).for_each(|t| job(t, &mut buf));
    }
}

/// `fine.u += P coarse.u` between two coarse levels.
///
/// `before_sweep`: a four-colour sweep follows, whose first colour (even
/// rows, even columns) does not read the values it replaces, so those
/// points are not corrected (the result after the sweep is the same).
pub(super) fn prolongate_coarse(coarse: &CoarseLevel, fine: &mut CoarseLevel, before_sweep: bool) {
    let parallel = fine.parallel();
    let (fny, hs) = (fine.ny, fine.hs);
    let sh = SharedHalves {
        ptr: [fine.u[0].as_mut_ptr(), fine.u[1].as_mut_ptr()],
        hs,
    };
    let counts = [half_len(fine.nx, 0), half_len(fine.nx, 1)];
    prolongate(coarse, parallel, |cj, [e0, o0, e1, o1]| {
        for (fj, (e, o)) in [(2 * cj, (e0, o0)), (2 * cj + 1, (e1, o1))] {
            if fj >= fny {
                continue;
            }
            for (a, c) in [(0, e), (1, o)] {
                if before_sweep && a == 0 && fj & 1 == 0 {
                    continue;
                }
                // SAFETY: each call owns fine rows 2 cj and 2 cj + 1.
                let row = unsafe { &mut sh.row_mut(a, fj + 1)[1..1 + counts[a]] };
                for (u, &v) in row.iter_mut().zip(c) {
                    *u += v;
                }
            }
        }
    });
}
