//! Coarse levels of the hierarchy: Galerkin 9-point operators (see
//! `galerkin.rs`), four-colour Gauss-Seidel smoothing, and the transfers
//! (`P` and `R = P^T`) between a level and the next coarser one.
//!
//! A coarse level is stored in natural layout with a one-point ghost border
//! (`pitch = nx + 2`). Each point has an index: 0 for dead points (no free
//! fine point under them) and ghosts, 1 for regular points, which share the
//! level's constant stencil, `k >= 2` for irregular points, whose stencil is
//! `irr[k - 2]`.

use rayon::prelude::*;

use super::galerkin::{
    block_weights, galerkin, interp, weights_from_block, BlockWeights, ConstantSource,
    StencilSource, Weights,
};

/// Below this many points a level is processed on one thread.
const PARALLEL_MIN_POINTS: usize = 1 << 14;

/// Index of dead points and ghosts.
const DEAD: u32 = 0;
/// Index of regular points.
const REGULAR: u32 = 1;

/// One coarse level.
pub(super) struct CoarseLevel {
    pub nx: usize,
    pub ny: usize,
    pub pitch: usize,
    /// Correction (unknown), padded layout.
    pub u: Vec<f32>,
    /// Right-hand side, padded layout.
    pub rhs: Vec<f32>,
    /// Residual scratch, padded layout (ghosts stay 0).
    pub res: Vec<f32>,
    /// Stencil index per point, padded layout.
    pub idx: Vec<u32>,
    /// Irregular stencils and their inverse diagonals.
    pub irr: Vec<[f32; 9]>,
    pub irr_inv: Vec<f32>,
    /// The constant stencil of regular points (f32 and f64) and its inverse diagonal.
    pub reg: [f32; 9],
    pub reg64: [f64; 9],
    pub reg_inv: f32,
    /// Interpolation from this level into the finer one, per block (the
    /// fine points `(2i + a, 2j + b)` of coarse point `(i, j)`): 0 for the
    /// constant `reg_block`, `k > 0` for `bw[k - 1]`. Padded layout.
    pub bw_idx: Vec<u32>,
    pub bw: Vec<BlockWeights>,
    pub reg_block: BlockWeights,
    /// Number of live points.
    pub live: usize,
}

impl StencilSource for CoarseLevel {
    #[inline]
    fn stencil(&self, i: isize, j: isize) -> [f64; 9] {
        if i < 0 || j < 0 || i as usize >= self.nx || j as usize >= self.ny {
            return [0.0; 9];
        }
        match self.idx[self.at(i as usize, j as usize)] {
            DEAD => [0.0; 9],
            REGULAR => self.reg64,
            k => self.irr[(k - 2) as usize].map(f64::from),
        }
    }
}

/// Raw pointer to a level's unknown, shared by the smoother's threads.
/// Soundness: in each phase a thread writes only rows of one parity that no
/// other thread touches and reads rows of the other parity, which nobody
/// writes in that phase.
#[derive(Clone, Copy)]
struct SharedRows(*mut f32);
// SAFETY: see the type's documentation; access is row-disjoint by schedule.
unsafe impl Send for SharedRows {}
unsafe impl Sync for SharedRows {}

impl CoarseLevel {
    #[inline]
    pub fn at(&self, i: usize, j: usize) -> usize {
        (j + 1) * self.pitch + i + 1
    }

    /// Whether this level is large enough to use several threads.
    #[inline]
    fn parallel(&self) -> bool {
        self.nx * self.ny >= PARALLEL_MIN_POINTS
    }

    /// Whether coarse point `(i, j)` is regular (then every fine point within
    /// 3 of `(2i, 2j)` has the finer level's constant stencil).
    #[inline]
    pub fn is_regular(&self, i: usize, j: usize) -> bool {
        self.idx[self.at(i, j)] == REGULAR
    }

    /// The coarse level under a finer level given by `src` (`fnx x fny`
    /// points, constant stencil `fine_reg`), with `fine_irregular[i + fnx j]`
    /// true where the finer stencil is not `fine_reg`.
    pub fn build<S: StencilSource + ?Sized>(
        src: &S,
        fnx: usize,
        fny: usize,
        fine_reg: [f64; 9],
        fine_irregular: &[bool],
    ) -> CoarseLevel {
        let nx = fnx.div_ceil(2);
        let ny = fny.div_ceil(2);
        let pitch = nx + 2;
        let len = (ny + 2) * pitch;
        // Horizontal dilation by 3 at even columns.
        let near: Vec<bool> = fine_irregular
            .par_chunks(fnx)
            .flat_map_iter(|row| {
                let mut prefix = Vec::with_capacity(fnx + 1);
                prefix.push(0u32);
                for &b in row {
                    prefix.push(prefix[prefix.len() - 1] + u32::from(b));
                }
                (0..nx).map(move |ci| {
                    let c = 2 * ci;
                    if c < 3 || c + 3 >= fnx {
                        return true;
                    }
                    prefix[c + 4] - prefix[c - 3] > 0
                })
            })
            .collect();
        let const_src = ConstantSource(fine_reg);
        let reg64 = galerkin(&const_src, |i, j| interp(&const_src, i, j), 0, 0);
        let reg_block = block_weights(&const_src, 0, 0);
        let reg_diag = reg64[4];
        let regular = |ci: usize, cj: usize| {
            let fj = 2 * cj;
            fj >= 3 && fj + 3 < fny && (fj - 3..=fj + 3).all(|r| !near[r * nx + ci])
        };
        // Interpolation weights of the blocks of non-regular points.
        let blocks: Vec<Vec<(usize, BlockWeights)>> = (0..ny)
            .into_par_iter()
            .map(|cj| {
                (0..nx)
                    .filter(|&ci| !regular(ci, cj))
                    .map(|ci| (ci, block_weights(src, ci as isize, cj as isize)))
                    .collect()
            })
            .collect();
        let mut bw_idx = vec![0u32; len];
        let mut bw = Vec::new();
        for (cj, row) in blocks.into_iter().enumerate() {
            for (ci, b) in row {
                bw.push(b);
                bw_idx[(cj + 1) * pitch + ci + 1] = bw.len() as u32;
            }
        }
        let weights_at = |fi: isize, fj: isize| -> Weights {
            if fi < 0 || fj < 0 || fi as usize >= fnx || fj as usize >= fny {
                return Weights::default();
            }
            let k = (fj as usize / 2 + 1) * pitch + fi as usize / 2 + 1;
            let b = match bw_idx[k] {
                0 => &reg_block,
                n => &bw[(n - 1) as usize],
            };
            weights_from_block(b, fi, fj)
        };
        // Per coarse row: indices (local) and irregular stencils.
        let rows: Vec<(Vec<u32>, Vec<[f32; 9]>)> = (0..ny)
            .into_par_iter()
            .map(|cj| {
                let mut ids = vec![DEAD; nx];
                let mut sts = Vec::new();
                for (ci, id) in ids.iter_mut().enumerate() {
                    if regular(ci, cj) {
                        *id = REGULAR;
                        continue;
                    }
                    let st = galerkin(src, weights_at, ci as isize, cj as isize);
                    if st[4] <= 1e-9 * reg_diag {
                        continue;
                    }
                    sts.push(st.map(|v| v as f32));
                    *id = 1 + sts.len() as u32; // local index + 2 - 1
                }
                (ids, sts)
            })
            .collect();
        let mut idx = vec![DEAD; len];
        let mut irr = Vec::new();
        let mut live = 0;
        for (cj, (ids, sts)) in rows.into_iter().enumerate() {
            let base = irr.len() as u32;
            for (ci, &id) in ids.iter().enumerate() {
                let k = (cj + 1) * pitch + ci + 1;
                idx[k] = match id {
                    DEAD => DEAD,
                    REGULAR => REGULAR,
                    local => local + base,
                };
                live += usize::from(id != DEAD);
            }
            irr.extend(sts);
        }
        let irr_inv = irr.iter().map(|s| 1.0 / s[4]).collect();
        let reg = reg64.map(|v| v as f32);
        CoarseLevel {
            nx,
            ny,
            pitch,
            u: vec![0.0; len],
            rhs: vec![0.0; len],
            res: vec![0.0; len],
            idx,
            irr,
            irr_inv,
            reg,
            reg64,
            reg_inv: (1.0 / reg64[4]) as f32,
            bw_idx,
            bw,
            reg_block,
            live,
        }
    }

    /// `irregular[i + nx j]`: true where the stencil is not the constant one.
    pub fn irregular(&self) -> Vec<bool> {
        (0..self.ny)
            .into_par_iter()
            .flat_map_iter(|j| (0..self.nx).map(move |i| self.idx[self.at(i, j)] != REGULAR))
            .collect()
    }

    /// Gauss-Seidel update of row `j` (colour (0, j) then colour (1, j)).
    ///
    /// # Safety
    /// No other thread may access row `j` or write rows `j - 1`, `j + 1`.
    #[inline]
    unsafe fn relax_row(&self, u: SharedRows, j: usize) {
        let p = self.pitch as isize;
        let row = (j + 1) * self.pitch + 1;
        let u = u.0;
        let reg = &self.reg;
        for a in 0..2 {
            let mut i = a;
            while i < self.nx {
                let k = row + i;
                let id = self.idx[k];
                i += 2;
                if id == DEAD {
                    continue;
                }
                let (s, inv) = if id == REGULAR {
                    (reg, self.reg_inv)
                } else {
                    let n = (id - 2) as usize;
                    (&self.irr[n], self.irr_inv[n])
                };
                let c = u.add(k);
                let sum = s[0] * *c.offset(-p - 1)
                    + s[1] * *c.offset(-p)
                    + s[2] * *c.offset(-p + 1)
                    + s[3] * *c.offset(-1)
                    + s[5] * *c.offset(1)
                    + s[6] * *c.offset(p - 1)
                    + s[7] * *c.offset(p)
                    + s[8] * *c.offset(p + 1);
                *c = (self.rhs[k] - sum) * inv;
            }
        }
    }

    /// `sweeps` four-colour Gauss-Seidel sweeps (even rows, then odd rows;
    /// within a row even then odd columns), parallel over rows.
    pub fn smooth(&mut self, sweeps: usize) {
        let shared = SharedRows(self.u.as_mut_ptr());
        let this: &CoarseLevel = self;
        for _ in 0..sweeps {
            for parity in 0..2 {
                let rows = (this.ny + 1 - parity) / 2;
                // SAFETY: schedule documented on `SharedRows`.
                let job = |m: usize| unsafe { this.relax_row(shared, 2 * m + parity) };
                if this.parallel() {
                    (0..rows).into_par_iter().with_min_len(8).for_each(job);
                } else {
                    (0..rows).for_each(job);
                }
            }
        }
    }

    /// Residual of row `j` into `out` (padded row, entries `1 ..= nx`).
    #[inline]
    fn residual_row(&self, j: usize, out: &mut [f32]) {
        let p = self.pitch;
        let row = (j + 1) * p + 1;
        let u = &self.u;
        for i in 0..self.nx {
            let k = row + i;
            let id = self.idx[k];
            out[i + 1] = if id == DEAD {
                0.0
            } else {
                let s = if id == REGULAR {
                    &self.reg
                } else {
                    &self.irr[(id - 2) as usize]
                };
                let au = s[0] * u[k - p - 1]
                    + s[1] * u[k - p]
                    + s[2] * u[k - p + 1]
                    + s[3] * u[k - 1]
                    + s[4] * u[k]
                    + s[5] * u[k + 1]
                    + s[6] * u[k + p - 1]
                    + s[7] * u[k + p]
                    + s[8] * u[k + p + 1];
                self.rhs[k] - au
            };
        }
    }

    /// Fills `res` with the residual; returns its squared norm (f64 sums).
    pub fn compute_residual(&mut self) -> f64 {
        let mut res = std::mem::take(&mut self.res);
        let p = self.pitch;
        let this: &CoarseLevel = self;
        let rows = &mut res[p..(this.ny + 1) * p];
        let job = |(j, out): (usize, &mut [f32])| {
            this.residual_row(j, out);
            out.iter().map(|&v| (v as f64) * (v as f64)).sum::<f64>()
        };
        let sq = if this.parallel() {
            rows.par_chunks_mut(p).enumerate().map(job).sum()
        } else {
            rows.chunks_mut(p).enumerate().map(job).sum()
        };
        self.res = res;
        sq
    }

    /// Solves this (small) level almost exactly: sweeps until the residual
    /// fell by 1e-6 (or a sweep limit).
    pub fn solve_coarsest(&mut self) {
        let start = self.compute_residual();
        if start == 0.0 {
            return;
        }
        for _ in 0..1000 {
            self.smooth(4);
            if self.compute_residual() <= 1e-12 * start {
                break;
            }
        }
    }
}

impl CoarseLevel {
    /// Interpolation weights of block `k` (padded index).
    #[inline(always)]
    fn block(&self, k: usize) -> &BlockWeights {
        match self.bw_idx[k] {
            0 => &self.reg_block,
            n => &self.bw[(n - 1) as usize],
        }
    }
}

/// Adds `P coarse.u` to row `j` of the finer level: `out[i]`, `i < nx`.
pub(super) fn prolongate_row(coarse: &CoarseLevel, j: usize, nx: usize, out: &mut [f32]) {
    let cj = j / 2;
    let p = coarse.pitch;
    let row = coarse.at(0, cj);
    let u = &coarse.u;
    let odd_row = j & 1 == 1;
    for ci in 0..coarse.nx {
        let k = row + ci;
        let b = coarse.block(k);
        let (i0, i1) = (2 * ci, 2 * ci + 1);
        if odd_row {
            out[i0] += b[3] * u[k] + b[4] * u[k + p];
            if i1 < nx {
                out[i1] += b[5] * u[k] + b[6] * u[k + 1] + b[7] * u[k + p] + b[8] * u[k + p + 1];
            }
        } else {
            out[i0] += b[0] * u[k];
            if i1 < nx {
                out[i1] += b[1] * u[k] + b[2] * u[k + 1];
            }
        }
    }
}

/// Restricts a fine residual to the right-hand side of coarse row `cj`
/// (`out`, padded row) with `R = P^T`. `res` is the fine residual in padded
/// natural layout (zero ghost border) with row pitch `rp`.
pub(super) fn restrict_row(
    coarse: &CoarseLevel,
    cj: usize,
    res: &[f32],
    rp: usize,
    out: &mut [f32],
) {
    let p = coarse.pitch;
    let r0 = (2 * cj + 1) * rp + 1;
    for ci in 0..coarse.nx {
        let k = coarse.at(ci, cj);
        if coarse.idx[k] == DEAD {
            out[ci + 1] = 0.0;
            continue;
        }
        let (bc, bw, bs, bsw) = (
            coarse.block(k),
            coarse.block(k - 1),
            coarse.block(k - p),
            coarse.block(k - p - 1),
        );
        let c = r0 + 2 * ci;
        out[ci + 1] = bc[0] * res[c]
            + bc[1] * res[c + 1]
            + bw[2] * res[c - 1]
            + bc[3] * res[c + rp]
            + bs[4] * res[c - rp]
            + bc[5] * res[c + rp + 1]
            + bw[6] * res[c + rp - 1]
            + bs[7] * res[c - rp + 1]
            + bsw[8] * res[c - rp - 1];
    }
}

/// Restriction between two coarse levels: `coarse.rhs = R fine.res`, and
/// `coarse.u = 0`. `fine.res` must hold the fine residual.
pub(super) fn restrict_coarse(fine: &CoarseLevel, coarse: &mut CoarseLevel) {
    let fp = fine.pitch;
    let fres = &fine.res;
    let cp = coarse.pitch;
    let cny = coarse.ny;
    let mut rhs = std::mem::take(&mut coarse.rhs);
    {
        let c: &CoarseLevel = coarse;
        let rows = &mut rhs[cp..(cny + 1) * cp];
        let job = |(cj, out): (usize, &mut [f32])| restrict_row(c, cj, fres, fp, out);
        if fine.parallel() {
            rows.par_chunks_mut(cp).enumerate().for_each(job);
        } else {
            rows.chunks_mut(cp).enumerate().for_each(job);
        }
    }
    coarse.rhs = rhs;
    coarse.u.fill(0.0);
}

/// `fine.u += P coarse.u` between two coarse levels (dead fine points get 0).
pub(super) fn prolongate_coarse(coarse: &CoarseLevel, fine: &mut CoarseLevel) {
    let p = fine.pitch;
    let (nx, ny) = (fine.nx, fine.ny);
    let parallel = fine.parallel();
    let idx = &fine.idx;
    let rows = &mut fine.u[p..(ny + 1) * p];
    let job = |(j, row): (usize, &mut [f32])| {
        prolongate_row(coarse, j, nx, &mut row[1..1 + nx]);
        // Dead points keep a zero correction.
        let ids = &idx[(j + 1) * p + 1..(j + 1) * p + 1 + nx];
        for (v, &id) in row[1..1 + nx].iter_mut().zip(ids) {
            if id == DEAD {
                *v = 0.0;
            }
        }
    };
    if parallel {
        rows.par_chunks_mut(p).enumerate().for_each(job);
    } else {
        rows.chunks_mut(p).enumerate().for_each(job);
    }
}
