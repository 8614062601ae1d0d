//! Operator-dependent interpolation and Galerkin coarse operators (Dendy's
//! "black box" multigrid, 1982), which keep the V-cycle rate at about 0.1
//! next to irregular Dirichlet sets.
//!
//! Coarsening is vertex-centred: coarse point `(I, J)` sits on fine point
//! `(2I, 2J)`. Fixed (Dirichlet) points are eliminated from the operator:
//! their couplings are zero and their rows "dead". The interpolation of a
//! fine point is read off its own row of the operator, so it knows where the
//! constraints are:
//!
//! - a fine point on a coarse point takes its value (weight 1; 0 when dead);
//! - a fine point between two coarse points along x collapses its 9-point
//!   stencil onto its row: `w_W = -(a_sw + a_w + a_nw) / (a_c + a_s + a_n)`,
//!   the same for `w_E`, and the mirror image along y;
//! - a fine point at the centre of four coarse points solves its own row for
//!   itself, its eight neighbours being interpolated as above.
//!
//! Next to a constraint the weights drop towards zero exactly as the
//! solution does, and the coarse operator `A_c = P^T A P` (computed here, in
//! f64, once per solve) sees the constraints where they really are, including
//! one-cell-wide diagonal curves that no coarse point lies on. Away from
//! every constraint and from the grid's edge the stencils are all equal, so
//! only the "irregular" coarse points (within 3 fine points of an irregular
//! fine point) get their own stencil; the others share the level's constant
//! one.

/// Index of stencil entry `(di, dj)` (`-1 ..= 1` each): `(dj + 1) * 3 + di + 1`.
#[inline(always)]
pub(super) const fn sidx(di: isize, dj: isize) -> usize {
    ((dj + 1) * 3 + di + 1) as usize
}

/// Where the stencils of one level come from.
pub(super) trait StencilSource: Sync {
    /// Stencil of point `(i, j)` (the row of the operator, entry `sidx(di, dj)`
    /// couples to `(i + di, j + dj)`); all zeros for dead points and points
    /// outside the grid.
    fn stencil(&self, i: isize, j: isize) -> [f64; 9];
}

/// Up to four interpolation weights `(coarse i, coarse j, weight)`.
#[derive(Clone, Copy, Default)]
pub(super) struct Weights {
    pub n: usize,
    pub c: [(isize, isize, f64); 4],
}

impl Weights {
    #[inline]
    fn push(&mut self, i: isize, j: isize, w: f64) {
        self.c[self.n] = (i, j, w);
        self.n += 1;
    }

    /// Weight of coarse point `(ci, cj)` (0 when absent).
    #[inline]
    pub fn of(&self, ci: isize, cj: isize) -> f64 {
        self.c[..self.n]
            .iter()
            .filter(|c| c.0 == ci && c.1 == cj)
            .map(|c| c.2)
            .sum()
    }
}

/// Dendy weights of an edge point from its stencil: `(first, second)` for
/// the coarse neighbours west/east (`along_x`) or south/north.
#[inline]
fn edge_weights(s: &[f64; 9], along_x: bool) -> (f64, f64) {
    let (den, a, b) = if along_x {
        (
            s[4] + s[sidx(0, -1)] + s[sidx(0, 1)],
            s[sidx(-1, -1)] + s[sidx(-1, 0)] + s[sidx(-1, 1)],
            s[sidx(1, -1)] + s[sidx(1, 0)] + s[sidx(1, 1)],
        )
    } else {
        (
            s[4] + s[sidx(-1, 0)] + s[sidx(1, 0)],
            s[sidx(-1, -1)] + s[sidx(0, -1)] + s[sidx(1, -1)],
            s[sidx(-1, 1)] + s[sidx(0, 1)] + s[sidx(1, 1)],
        )
    };
    if den > 0.0 {
        (-a / den, -b / den)
    } else {
        (0.0, 0.0)
    }
}

/// Interpolation weights of non-centre fine point `(i, j)`.
#[inline]
fn interp_simple<S: StencilSource + ?Sized>(src: &S, i: isize, j: isize, out: &mut Weights) {
    let s = src.stencil(i, j);
    if s[4] <= 0.0 {
        return;
    }
    let (ci, cj) = (i.div_euclid(2), j.div_euclid(2));
    match (i & 1, j & 1) {
        (0, 0) => out.push(ci, cj, 1.0),
        (1, 0) => {
            let (w, e) = edge_weights(&s, true);
            out.push(ci, cj, w);
            out.push(ci + 1, cj, e);
        }
        _ => {
            let (so, no) = edge_weights(&s, false);
            out.push(ci, cj, so);
            out.push(ci, cj + 1, no);
        }
    }
}

/// Interpolation weights of fine point `(i, j)` (empty for dead points).
pub(super) fn interp<S: StencilSource + ?Sized>(src: &S, i: isize, j: isize) -> Weights {
    let mut out = Weights::default();
    if (i & 1) == 0 || (j & 1) == 0 {
        interp_simple(src, i, j, &mut out);
        return out;
    }
    let s = src.stencil(i, j);
    if s[4] <= 0.0 {
        return out;
    }
    // Centre point: u = -sum_nb a_nb u_nb / a_c over its eight neighbours.
    let (ci, cj) = ((i - 1) / 2, (j - 1) / 2);
    let mut acc = [[0.0f64; 2]; 2];
    for dj in -1..=1isize {
        for di in -1..=1isize {
            let a = s[sidx(di, dj)];
            if (di == 0 && dj == 0) || a == 0.0 {
                continue;
            }
            let mut nb = Weights::default();
            interp_simple(src, i + di, j + dj, &mut nb);
            for &(gi, gj, w) in &nb.c[..nb.n] {
                acc[(gj - cj) as usize][(gi - ci) as usize] += -a / s[4] * w;
            }
        }
    }
    for (b, row) in acc.iter().enumerate() {
        for (a, &w) in row.iter().enumerate() {
            out.push(ci + a as isize, cj + b as isize, w);
        }
    }
    out
}

/// Interpolation weights of the fine points of block `(ci, cj)` (fine points
/// `(2ci + a, 2cj + b)`, `a, b` in 0..2) in the order
/// `[centre, x-edge west, x-edge east, y-edge south, y-edge north,
///   cell sw, cell se, cell nw, cell ne]`.
pub(super) type BlockWeights = [f32; 9];

/// [`BlockWeights`] of block `(ci, cj)` from the fine stencils.
pub(super) fn block_weights<S: StencilSource + ?Sized>(
    src: &S,
    ci: isize,
    cj: isize,
) -> BlockWeights {
    let (i, j) = (2 * ci, 2 * cj);
    let c = interp(src, i, j);
    let x = interp(src, i + 1, j);
    let y = interp(src, i, j + 1);
    let z = interp(src, i + 1, j + 1);
    [
        c.of(ci, cj),
        x.of(ci, cj),
        x.of(ci + 1, cj),
        y.of(ci, cj),
        y.of(ci, cj + 1),
        z.of(ci, cj),
        z.of(ci + 1, cj),
        z.of(ci, cj + 1),
        z.of(ci + 1, cj + 1),
    ]
    .map(|v| v as f32)
}

/// Interpolation weights of fine point `(i, j)` read from its block's weights.
#[inline]
pub(super) fn weights_from_block(b: &BlockWeights, i: isize, j: isize) -> Weights {
    let (ci, cj) = (i.div_euclid(2), j.div_euclid(2));
    let mut w = Weights::default();
    match (i & 1, j & 1) {
        (0, 0) => w.push(ci, cj, b[0] as f64),
        (1, 0) => {
            w.push(ci, cj, b[1] as f64);
            w.push(ci + 1, cj, b[2] as f64);
        }
        (0, _) => {
            w.push(ci, cj, b[3] as f64);
            w.push(ci, cj + 1, b[4] as f64);
        }
        _ => {
            w.push(ci, cj, b[5] as f64);
            w.push(ci + 1, cj, b[6] as f64);
            w.push(ci, cj + 1, b[7] as f64);
            w.push(ci + 1, cj + 1, b[8] as f64);
        }
    }
    w
}

/// Galerkin stencil `(P^T A P)` of coarse point `(ci, cj)`, entry
/// `sidx(dI, dJ)` coupling to coarse point `(ci + dI, cj + dJ)`;
/// `weights(i, j)` gives the interpolation weights of fine point `(i, j)`.
pub(super) fn galerkin<S, W>(src: &S, weights: W, ci: isize, cj: isize) -> [f64; 9]
where
    S: StencilSource + ?Sized,
    W: Fn(isize, isize) -> Weights,
{
    // Interpolation weights of the fine 5 x 5 window around (2 ci, 2 cj).
    let (fi0, fj0) = (2 * ci - 2, 2 * cj - 2);
    let mut win = [[Weights::default(); 5]; 5];
    for (b, row) in win.iter_mut().enumerate() {
        for (a, w) in row.iter_mut().enumerate() {
            *w = weights(fi0 + a as isize, fj0 + b as isize);
        }
    }
    let mut acc = [0.0f64; 9];
    for fb in 1..4usize {
        for fa in 1..4usize {
            let wf = win[fb][fa].of(ci, cj);
            if wf == 0.0 {
                continue;
            }
            let s = src.stencil(fi0 + fa as isize, fj0 + fb as isize);
            for dj in -1..=1isize {
                for di in -1..=1isize {
                    let a = s[sidx(di, dj)];
                    if a == 0.0 {
                        continue;
                    }
                    let g = &win[(fb as isize + dj) as usize][(fa as isize + di) as usize];
                    for &(gi, gj, w) in &g.c[..g.n] {
                        let (d_i, d_j) = (gi - ci, gj - cj);
                        if d_i.abs() <= 1 && d_j.abs() <= 1 {
                            acc[sidx(d_i, d_j)] += wf * a * w;
                        }
                    }
                }
            }
        }
    }
    acc
}

/// The same stencil everywhere, no edge: gives a level's constant stencil
/// and weights away from constraints.
pub(super) struct ConstantSource(pub [f64; 9]);

impl StencilSource for ConstantSource {
    #[inline]
    fn stencil(&self, _i: isize, _j: isize) -> [f64; 9] {
        self.0
    }
}
