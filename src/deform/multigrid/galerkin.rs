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
//! only the "special" coarse points (within 2 fine points of an irregular
//! fine point) get their own stencil; the others share the level's constant
//! one. Two fine points is exact: the stencil of `(I, J)` reads the weights
//! of the fine points within 2 of `(2I, 2J)`, and a weight reads the fine
//! stencil of its own point, or for a cell point (odd, odd), those of its
//! 3 x 3 neighbourhood, which for the cell points of the window (at
//! distance 1) stays within 2 as well; the same holds for the weights that the
//! transfers use around a regular point.
//!
//! The weights of the four fine points `(2I + a, 2J + b)` of coarse point
//! `(I, J)` are kept together as its [`BlockWeights`]; [`block_weights`]
//! computes them from the nine fine stencils around the block, and
//! [`galerkin`] forms one coarse stencil from the nine blocks around it as a
//! small dense product (the 5 x 5 fine window's weights times the fine
//! stencils of its inner 3 x 3 points).

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

    /// `out[i] = 1` where the stencil of point `(i, j)` differs from the
    /// level's constant one (points near a constraint, a dead point or the
    /// grid's edge), 0 elsewhere; `out` has one entry per point of row `j`.
    fn irregular_row(&self, j: usize, out: &mut [u8]);
}

/// Dendy weights of an edge point from its stencil: `(first, second)` for
/// the coarse neighbours west/east (`along_x`) or south/north.
#[inline]
fn edge_weights(s: &[f64; 9], along_x: bool) -> (f64, f64) {
    if s[4] <= 0.0 {
        return (0.0, 0.0);
    }
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

/// Interpolation weights of the fine points of block `(ci, cj)` (fine points
/// `(2ci + a, 2cj + b)`, `a, b` in 0..2) in the order
/// `[centre, x-edge west, x-edge east, y-edge south, y-edge north,
///   cell sw, cell se, cell nw, cell ne]`.
pub(super) type BlockWeights = [f32; 9];

/// [`BlockWeights`] of block `(ci, cj)` from the fine stencils (compiled for
/// AVX2 + FMA where the CPU has them).
pub(super) fn block_weights<S: StencilSource + ?Sized>(
    src: &S,
    ci: isize,
    cj: isize,
) -> BlockWeights {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA.
        return unsafe { block_weights_avx2(src, ci, cj) };
    }
    block_weights_impl(src, ci, cj)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn block_weights_avx2<S: StencilSource + ?Sized>(
    src: &S,
    ci: isize,
    cj: isize,
) -> BlockWeights {
    block_weights_impl(src, ci, cj)
}

/// [`BlockWeights`] of block `(ci, cj)` from the fine stencils.
///
/// The cell point `(2ci + 1, 2cj + 1)` solves its own row for itself, its
/// eight neighbours interpolated: a neighbour on a coarse point by its value
/// (weight 1 when alive), an edge neighbour by its own edge weights. All nine
/// fine stencils of the 3 x 3 points from `(2ci, 2cj)` are read once.
#[inline(always)]
fn block_weights_impl<S: StencilSource + ?Sized>(src: &S, ci: isize, cj: isize) -> BlockWeights {
    let (i0, j0) = (2 * ci, 2 * cj);
    // st[b][a]: stencil of fine point (i0 + a, j0 + b).
    let mut st = [[[0.0f64; 9]; 3]; 3];
    for (b, row) in st.iter_mut().enumerate() {
        for (a, s) in row.iter_mut().enumerate() {
            *s = src.stencil(i0 + a as isize, j0 + b as isize);
        }
    }
    let alive = |a: usize, b: usize| if st[b][a][4] > 0.0 { 1.0 } else { 0.0 };
    // Edge points: x-edges at (i0 + 1, j0 + 2b), y-edges at (i0 + 2a, j0 + 1).
    let x_edge = [edge_weights(&st[0][1], true), edge_weights(&st[2][1], true)];
    let y_edge = [
        edge_weights(&st[1][0], false),
        edge_weights(&st[1][2], false),
    ];
    let mut cell = [[0.0f64; 2]; 2]; // cell[J][I]: weight to (ci + I, cj + J)
    let sz = &st[1][1];
    if sz[4] > 0.0 {
        let f = |di: isize, dj: isize| -sz[sidx(di, dj)] / sz[4];
        // Corner neighbours: coarse points.
        cell[0][0] += f(-1, -1) * alive(0, 0);
        cell[0][1] += f(1, -1) * alive(2, 0);
        cell[1][0] += f(-1, 1) * alive(0, 2);
        cell[1][1] += f(1, 1) * alive(2, 2);
        // South and north neighbours: x-edges.
        let (w, e) = x_edge[0];
        cell[0][0] += f(0, -1) * w;
        cell[0][1] += f(0, -1) * e;
        let (w, e) = x_edge[1];
        cell[1][0] += f(0, 1) * w;
        cell[1][1] += f(0, 1) * e;
        // West and east neighbours: y-edges.
        let (s, n) = y_edge[0];
        cell[0][0] += f(-1, 0) * s;
        cell[1][0] += f(-1, 0) * n;
        let (s, n) = y_edge[1];
        cell[0][1] += f(1, 0) * s;
        cell[1][1] += f(1, 0) * n;
    }
    [
        alive(0, 0),
        x_edge[0].0,
        x_edge[0].1,
        y_edge[0].0,
        y_edge[0].1,
        cell[0][0],
        cell[0][1],
        cell[1][0],
        cell[1][1],
    ]
    .map(|v| v as f32)
}

/// [`galerkin_impl`] compiled for AVX2 + FMA where the CPU has them.
pub(super) fn galerkin<S, B>(src: &S, block: B, ci: isize, cj: isize) -> [f64; 9]
where
    S: StencilSource + ?Sized,
    B: Fn(isize, isize) -> BlockWeights,
{
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA.
        return unsafe { galerkin_avx2(src, block, ci, cj) };
    }
    galerkin_impl(src, block, ci, cj)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn galerkin_avx2<S, B>(src: &S, block: B, ci: isize, cj: isize) -> [f64; 9]
where
    S: StencilSource + ?Sized,
    B: Fn(isize, isize) -> BlockWeights,
{
    galerkin_impl(src, block, ci, cj)
}

/// Galerkin stencil `(P^T A P)` of coarse point `(ci, cj)`, entry
/// `sidx(dI, dJ)` coupling to coarse point `(ci + dI, cj + dJ)`;
/// `block(I, J)` gives the [`BlockWeights`] of coarse point `(I, J)` (zeros
/// outside the grid).
///
/// The fine points in the 5 x 5 window around `(2 ci, 2 cj)` interpolate
/// only from the 3 x 3 coarse points around `(ci, cj)`: their weights form a
/// dense 25 x 9 matrix `W`, and the stencil is
/// `sum over inner f, d: W[f][centre] a_f[d] W[f + d][.]`.
#[inline(always)]
fn galerkin_impl<S, B>(src: &S, block: B, ci: isize, cj: isize) -> [f64; 9]
where
    S: StencilSource + ?Sized,
    B: Fn(isize, isize) -> BlockWeights,
{
    // w[fb][fa][t]: weight of fine point (2 ci - 2 + fa, 2 cj - 2 + fb) to
    // coarse point t = sidx(dI, dJ).
    let mut w = [[[0.0f64; 9]; 5]; 5];
    for dj in -1..=1isize {
        for di in -1..=1isize {
            let b = block(ci + di, cj + dj).map(f64::from);
            let (fa, fb) = ((2 * di + 2) as usize, (2 * dj + 2) as usize);
            let t = sidx(di, dj);
            w[fb][fa][t] = b[0];
            if fa < 4 {
                w[fb][fa + 1][t] = b[1];
                w[fb][fa + 1][t + 1] = b[2];
            }
            if fb < 4 {
                w[fb + 1][fa][t] = b[3];
                w[fb + 1][fa][t + 3] = b[4];
                if fa < 4 {
                    let z = &mut w[fb + 1][fa + 1];
                    z[t] = b[5];
                    z[t + 1] = b[6];
                    z[t + 3] = b[7];
                    z[t + 4] = b[8];
                }
            }
        }
    }
    let mut acc = [0.0f64; 9];
    for fb in 1..4usize {
        for fa in 1..4usize {
            let wf = w[fb][fa][4];
            if wf == 0.0 {
                continue;
            }
            let s = src.stencil(2 * ci - 2 + fa as isize, 2 * cj - 2 + fb as isize);
            for dj in 0..3usize {
                for di in 0..3usize {
                    let a = s[dj * 3 + di];
                    if a == 0.0 {
                        continue;
                    }
                    let g = &w[fb + dj - 1][fa + di - 1];
                    let c = wf * a;
                    for (o, &x) in acc.iter_mut().zip(g) {
                        *o += c * x;
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

    fn irregular_row(&self, _j: usize, out: &mut [u8]) {
        out.fill(0);
    }
}

/// The constant coarse stencil and block weights under a constant fine
/// stencil `fine`.
pub(super) fn constant_coarse(fine: [f64; 9]) -> ([f64; 9], BlockWeights) {
    let src = ConstantSource(fine);
    let block = block_weights(&src, 0, 0);
    (galerkin(&src, |_, _| block, 0, 0), block)
}
