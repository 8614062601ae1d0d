//! Multigrid solver for the diffusion of displacements (section 6.1 of
//! Tassé et al. 2014; Hnaidi et al. 2010).
//!
//! The deformation step rasterises the placed 3D curves as displacement
//! constraints `delta = z - H(x, y)` on the DEM grid and diffuses them into a
//! displacement map `M`, so that `H' = H + M` matches the curves and keeps the
//! terrain's own detail. This module solves that diffusion: on an
//! `nx x ny` grid of cells of size `hx x hy` metres (they may differ, as on
//! geographic DEMs), the 5-point discretisation of
//!
//! ```text
//!     Laplace(M) - c M = 0        (c >= 0: c = 0 is Laplace, c > 0 screened Poisson)
//! ```
//!
//! on the free cells, with Dirichlet values on an arbitrary set of fixed cells
//! (rasterised curves, scattered points, nodata holes fixed to 0) and `M = 0`
//! outside the grid. The screening term makes the displacement fall off
//! within about `1 / sqrt(c)` metres of the constraints, which is how the
//! caller keeps an edit local.
//!
//! # Method
//!
//! Black-box (Galerkin) multigrid after Dendy (1982), V-cycles (optionally
//! preceded by a full multigrid pass):
//!
//! - the finest level keeps the 5-point operator in red-black split storage
//!   (`level.rs`): red-black Gauss-Seidel, parallel over row bands with rayon,
//!   contiguous AVX2 kernels, f32 storage with f64 norms; the last
//!   pre-smoothing sweep restricts the residual and the last post-smoothing
//!   sweep sums the residual norm as the rows become final, so neither needs
//!   a pass of its own;
//! - coarsening is vertex-centred (coarse point `(I, J)` on fine point
//!   `(2I, 2J)`), with operator-dependent interpolation read off the fine
//!   operator's rows, in which the couplings to fixed cells are eliminated:
//!   the interpolated correction falls to zero towards every constraint as
//!   the solution does, whatever the constraint's shape (`galerkin.rs`);
//! - coarse operators are `A_c = P^T A P`, computed once per solve in f64,
//!   9-point; restriction is `P^T`. Away from constraints and from the grid's
//!   edge every stencil is the same, so only coarse points within 2 fine
//!   points of an irregular one store a stencil and weights (a few % of
//!   them); the others share the level's constant stencil and weights and
//!   are handled by vectorised constant-coefficient kernels (`coarse.rs`);
//! - coarse levels are smoothed by four-colour Gauss-Seidel (even rows, then
//!   odd rows; even, then odd columns) in storage split by column parity,
//!   one pass over memory per sweep, parallel over row bands.
//!
//! A V-cycle is V(2,2) by default (`pre_smooth`, `post_smooth`); the
//! coarsest level (at most 4 x 4) is solved by sweeps to a 1e-6 residual
//! drop. One cycle is one V-cycle: there is no Krylov acceleration. Measured
//! per-cycle residual reductions on scattered one-cell-wide curve
//! constraints are 0.02 to 0.08 on 513 to 4097 grids (see
//! `docs/benchmarks.md`), where a geometric hierarchy with rediscretised
//! coarse operators reached only 0.2 to 0.3.
//!
//! # Relative residual
//!
//! With `A` the operator restricted to the free cells and `b` the coupling of
//! the free cells to the fixed values (so the system is `A m = b`), the
//! relative residual of an approximation `m` is `||b - A m||_2 / ||b||_2`:
//! the residual is measured against the residual of the **zero** initial
//! guess, which does not depend on the caller's initial guess (it is also
//! pyamg's convention, `||r|| / ||b||`, used in `tools/compare_pyamg.py`).
//! The rows of `A` are the 5-point stencil
//! `(2/hx^2 + 2/hy^2 + c) m_ij - (m_i-1,j + m_i+1,j)/hx^2 - (m_i,j-1 + m_i,j+1)/hy^2`.
//! [`relative_residual`] computes it independently in f64.
//!
//! # Example
//!
//! ```
//! use demsketch::deform::multigrid::{solve, MultigridOptions};
//!
//! let (nx, ny) = (65, 65);
//! let mut fixed = vec![false; nx * ny];
//! let mut values = vec![0.0f32; nx * ny];
//! // A 10 m displacement along a horizontal curve across the middle row.
//! for i in 10..55 {
//!     fixed[32 * nx + i] = true;
//!     values[32 * nx + i] = 10.0;
//! }
//! let stats = solve(nx, ny, 30.0, 30.0, &fixed, &mut values, &MultigridOptions::default())?;
//! assert!(stats.relative_residual <= 1e-4);
//! // The displacement diffuses away from the curve.
//! assert!(values[31 * nx + 32] > 5.0 && values[31 * nx + 32] < 10.0);
//! assert!(values[0] < 1.0);
//! # Ok::<(), demsketch::deform::multigrid::MultigridError>(())
//! ```

/// Defines `$name` as `$kernel` compiled for AVX2 + FMA where the CPU has
/// them (checked per call; the standard library caches the answer), and for
/// the baseline target otherwise. The kernels are plain loops written so
/// that they vectorise.
macro_rules! dispatch {
    ($vis:vis $name:ident, $avx:ident, $kernel:ident, ($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?) => {
        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma")]
        #[allow(clippy::too_many_arguments)]
        unsafe fn $avx($($arg: $ty),*) $(-> $ret)? {
            $kernel($($arg),*)
        }

        #[allow(clippy::too_many_arguments)]
        #[inline]
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[cfg(target_arch = "x86_64")]
            if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                // SAFETY: the CPU supports AVX2 and FMA.
                return unsafe { $avx($($arg),*) };
            }
            $kernel($($arg),*)
        }
    };
}

mod coarse;
mod galerkin;
mod level;
pub mod synthetic;

use coarse::{prolongate_coarse, restrict_coarse, CoarseLevel, RestrictTarget};
use galerkin::StencilSource;
use level::{Level, RowVisitor};
use rayon::prelude::*;

/// Options of [`solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct MultigridOptions {
    /// Stop when the relative residual (see the module documentation) is at
    /// most this. Default `1e-4`.
    pub tolerance: f64,
    /// Give up (with [`MultigridError::NotConverged`]) after this many
    /// V-cycles. Default 50.
    pub max_cycles: usize,
    /// Red-black Gauss-Seidel sweeps before the coarse-grid correction. Default 2.
    pub pre_smooth: usize,
    /// Sweeps after the coarse-grid correction. Default 2.
    pub post_smooth: usize,
    /// Screening coefficient `c >= 0` in `Laplace(M) - c M = 0`, in 1/m^2.
    /// Default 0 (Laplace).
    pub screening: f64,
    /// Start with a full multigrid pass (solve coarse versions of the problem
    /// first, interpolate, one V-cycle per level) instead of from the initial
    /// guess in `values`. Default false.
    pub full_multigrid: bool,
}

impl Default for MultigridOptions {
    fn default() -> Self {
        MultigridOptions {
            tolerance: 1e-4,
            max_cycles: 50,
            pre_smooth: 2,
            post_smooth: 2,
            screening: 0.0,
            full_multigrid: false,
        }
    }
}

/// What a solve did.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveStats {
    /// V-cycles run (not counting the full multigrid pass).
    pub cycles: usize,
    /// Relative residual before the first V-cycle (after the full multigrid
    /// pass when there is one) and after each V-cycle.
    pub residual_history: Vec<f64>,
    /// Relative residual of the returned field.
    pub relative_residual: f64,
    /// Grid levels in the hierarchy (1 = no coarsening was possible).
    pub levels: usize,
    /// Wall-clock seconds spent building the hierarchy (Galerkin coarse
    /// operators and interpolation weights), included in the solve.
    pub setup_seconds: f64,
}

/// Why [`solve`] failed.
#[derive(Debug, thiserror::Error)]
pub enum MultigridError {
    /// A slice's length is not `nx * ny`.
    #[error("{what} has {len} entries, expected nx * ny = {expected}")]
    SizeMismatch {
        what: &'static str,
        len: usize,
        expected: usize,
    },
    /// `nx` or `ny` is zero or `nx * ny` overflows.
    #[error("grid size {nx} x {ny} is empty or too large")]
    BadGridSize { nx: usize, ny: usize },
    /// A cell size is not a positive finite number.
    #[error("cell size {hx} x {hy} must be positive and finite")]
    BadCellSize { hx: f64, hy: f64 },
    /// An option is out of range.
    #[error("invalid option: {0}")]
    BadOption(String),
    /// A value (Dirichlet value or initial guess) is NaN or infinite.
    #[error("value at cell ({i}, {j}) is not finite")]
    NonFiniteValue { i: usize, j: usize },
    /// The tolerance was not reached; `values` holds the last iterate.
    #[error(
        "multigrid did not reach the tolerance: relative residual {:.3e} after {} cycles",
        .stats.relative_residual,
        .stats.cycles
    )]
    NotConverged { stats: SolveStats },
}

/// Solves for `M` (see the module documentation) in place.
///
/// `fixed[i]` true: `values[i]` is a Dirichlet value and is kept (fix
/// nodata cells with value 0). Other entries of `values` are the initial
/// guess (ignored with `full_multigrid`) and receive the solution. Both
/// slices are row-major, `i + nx * j`, row `j = 0` first.
///
/// On [`MultigridError::NotConverged`] `values` holds the last iterate; on
/// any other error it is unchanged.
pub fn solve(
    nx: usize,
    ny: usize,
    hx: f64,
    hy: f64,
    fixed: &[bool],
    values: &mut [f32],
    opts: &MultigridOptions,
) -> Result<SolveStats, MultigridError> {
    // Finiteness is checked while the values are copied in, below.
    validate_shape(nx, ny, hx, hy, fixed, values)?;
    if !(opts.tolerance.is_finite() && opts.tolerance > 0.0) {
        return Err(MultigridError::BadOption(format!(
            "tolerance {} must be positive and finite",
            opts.tolerance
        )));
    }
    if !(opts.screening.is_finite() && opts.screening >= 0.0) {
        return Err(MultigridError::BadOption(format!(
            "screening {} must be >= 0 and finite",
            opts.screening
        )));
    }
    if opts.pre_smooth + opts.post_smooth == 0 {
        return Err(MultigridError::BadOption(
            "pre_smooth + post_smooth must be at least 1".into(),
        ));
    }

    let setup_start = std::time::Instant::now();
    let mut fine = Level::new(nx, ny, hx, hy, opts.screening);
    let intake = fine
        .load(fixed, values)
        .map_err(|(i, j)| MultigridError::NonFiniteValue { i, j })?;
    let b_norm = intake.b_norm;
    if fine.free_cells == 0 || b_norm == 0.0 {
        // Nothing to solve, or the exact solution is M = 0 on free cells.
        for (v, &f) in values.iter_mut().zip(fixed) {
            if !f {
                *v = 0.0;
            }
        }
        return Ok(SolveStats {
            cycles: 0,
            residual_history: vec![0.0],
            relative_residual: 0.0,
            levels: 0,
            setup_seconds: 0.0,
        });
    }
    let mut h = build_hierarchy(fine, hx, hy, opts.screening, fixed);
    let setup_seconds = setup_start.elapsed().as_secs_f64();
    let mut stats = SolveStats {
        cycles: 0,
        residual_history: Vec::new(),
        relative_residual: f64::INFINITY,
        levels: h.levels(),
        setup_seconds,
    };
    if opts.full_multigrid {
        full_multigrid(&mut h, opts);
    }
    // From a zero guess the residual is `b` itself.
    let mut rel = if intake.zero_guess && !opts.full_multigrid {
        1.0
    } else {
        h.fine.residual_norm_squared().sqrt() / b_norm
    };
    stats.residual_history.push(rel);
    let mut slow_cycles = 0;
    while rel > opts.tolerance && stats.cycles < opts.max_cycles {
        let fused = v_cycle(&mut h, opts.pre_smooth, opts.post_smooth);
        stats.cycles += 1;
        let squared = fused.unwrap_or_else(|| h.fine.residual_norm_squared());
        let next = squared.sqrt() / b_norm;
        stats.residual_history.push(next);
        // Stop when rounding (f32 storage) stalls the iteration.
        slow_cycles = if next > 0.9 * rel { slow_cycles + 1 } else { 0 };
        rel = next;
        if slow_cycles >= 3 || !rel.is_finite() {
            break;
        }
    }
    stats.relative_residual = rel;
    h.fine.store(values);
    if rel <= opts.tolerance {
        Ok(stats)
    } else {
        Err(MultigridError::NotConverged { stats })
    }
}

/// Relative residual `||b - A m||_2 / ||b||_2` of `values` (see the module
/// documentation), computed in f64 directly on the natural layout. Returns 0
/// when `b = 0` and the free cells are 0.
pub fn relative_residual(
    nx: usize,
    ny: usize,
    hx: f64,
    hy: f64,
    screening: f64,
    fixed: &[bool],
    values: &[f32],
) -> Result<f64, MultigridError> {
    validate(nx, ny, hx, hy, fixed, values)?;
    let ax = 1.0 / (hx * hx);
    let ay = 1.0 / (hy * hy);
    let diag = 2.0 * ax + 2.0 * ay + screening;
    let residual_sq: f64 = (0..ny)
        .into_par_iter()
        .map(|j| {
            let mut sum = 0.0;
            for i in 0..nx {
                let idx = j * nx + i;
                if fixed[idx] {
                    continue;
                }
                let at = |ii: usize, jj: usize| values[jj * nx + ii] as f64;
                let s = weighted_neighbour_sum(i, j, nx, ny, ax, ay, at);
                let r = s - diag * values[idx] as f64;
                sum += r * r;
            }
            sum
        })
        .sum();
    let b = dirichlet_coupling_norm(nx, ny, hx, hy, fixed, values);
    if b == 0.0 {
        return Ok(residual_sq.sqrt());
    }
    Ok(residual_sq.sqrt() / b)
}

/// Checks sizes, cell sizes and finiteness of the inputs.
fn validate(
    nx: usize,
    ny: usize,
    hx: f64,
    hy: f64,
    fixed: &[bool],
    values: &[f32],
) -> Result<(), MultigridError> {
    validate_shape(nx, ny, hx, hy, fixed, values)?;
    // Row by row, with a branch-free (vectorised) test per row.
    let bad_row = values
        .par_chunks(nx)
        .position_first(|row| row.iter().fold(false, |bad, v| bad | !v.is_finite()));
    if let Some(j) = bad_row {
        let i = values[j * nx..(j + 1) * nx]
            .iter()
            .position(|v| !v.is_finite())
            .unwrap_or(0);
        return Err(MultigridError::NonFiniteValue { i, j });
    }
    Ok(())
}

/// Checks sizes and cell sizes of the inputs.
fn validate_shape(
    nx: usize,
    ny: usize,
    hx: f64,
    hy: f64,
    fixed: &[bool],
    values: &[f32],
) -> Result<(), MultigridError> {
    let expected = match nx.checked_mul(ny) {
        Some(n) if nx > 0 && ny > 0 && n < (isize::MAX as usize) / 8 => n,
        _ => return Err(MultigridError::BadGridSize { nx, ny }),
    };
    if fixed.len() != expected {
        return Err(MultigridError::SizeMismatch {
            what: "fixed",
            len: fixed.len(),
            expected,
        });
    }
    if values.len() != expected {
        return Err(MultigridError::SizeMismatch {
            what: "values",
            len: values.len(),
            expected,
        });
    }
    if !(hx.is_finite() && hy.is_finite() && hx > 0.0 && hy > 0.0) {
        return Err(MultigridError::BadCellSize { hx, hy });
    }
    Ok(())
}

/// `||b||_2`: the 2-norm over free cells of the coupling to fixed neighbours,
/// `sum over fixed 4-neighbours of value / h^2` (the residual of a zero guess).
fn dirichlet_coupling_norm(
    nx: usize,
    ny: usize,
    hx: f64,
    hy: f64,
    fixed: &[bool],
    values: &[f32],
) -> f64 {
    let ax = 1.0 / (hx * hx);
    let ay = 1.0 / (hy * hy);
    let sq: f64 = (0..ny)
        .into_par_iter()
        .map(|j| {
            let mut sum = 0.0;
            let at = |ii: usize, jj: usize| {
                let k = jj * nx + ii;
                if fixed[k] {
                    values[k] as f64
                } else {
                    0.0
                }
            };
            for i in 0..nx {
                if fixed[j * nx + i] {
                    continue;
                }
                let b = weighted_neighbour_sum(i, j, nx, ny, ax, ay, at);
                sum += b * b;
            }
            sum
        })
        .sum();
    sq.sqrt()
}

/// Coarsening stops once both dimensions of a level are at most this.
const COARSEST_MAX_DIM: usize = 4;

/// The finest level's stencils, from the caller's fixed mask: the 5-point
/// operator on free cells, couplings to fixed cells and to the outside
/// eliminated.
struct FineSource<'a> {
    nx: usize,
    ny: usize,
    ax: f64,
    ay: f64,
    diag: f64,
    fixed: &'a [bool],
}

impl FineSource<'_> {
    #[inline]
    fn free(&self, i: isize, j: isize) -> bool {
        i >= 0
            && j >= 0
            && (i as usize) < self.nx
            && (j as usize) < self.ny
            && !self.fixed[j as usize * self.nx + i as usize]
    }

    /// The stencil away from constraints.
    fn regular(&self) -> [f64; 9] {
        let (ax, ay) = (self.ax, self.ay);
        [0.0, -ay, 0.0, -ax, self.diag, -ax, 0.0, -ay, 0.0]
    }
}

impl StencilSource for FineSource<'_> {
    #[inline]
    fn stencil(&self, i: isize, j: isize) -> [f64; 9] {
        if !self.free(i, j) {
            return [0.0; 9];
        }
        let f = |a: isize, b: isize| if self.free(a, b) { 1.0 } else { 0.0 };
        let (ax, ay) = (self.ax, self.ay);
        [
            0.0,
            -ay * f(i, j - 1),
            0.0,
            -ax * f(i - 1, j),
            self.diag,
            -ax * f(i + 1, j),
            0.0,
            -ay * f(i, j + 1),
            0.0,
        ]
    }

    /// Fixed cells, cells with a fixed 4-neighbour, and the grid's edge.
    fn irregular_row(&self, j: usize, out: &mut [u8]) {
        let (nx, ny) = (self.nx, self.ny);
        if j == 0 || j + 1 >= ny || nx < 3 {
            out.fill(1);
            return;
        }
        let fixed = self.fixed;
        let up = &fixed[(j - 1) * nx..j * nx];
        let mid = &fixed[j * nx..(j + 1) * nx];
        let dn = &fixed[(j + 1) * nx..(j + 2) * nx];
        out[0] = 1;
        out[nx - 1] = 1;
        for i in 1..nx - 1 {
            out[i] = u8::from(mid[i] | mid[i - 1] | mid[i + 1] | up[i] | dn[i]);
        }
    }
}

/// The finest level (red-black split storage, 5-point operator) and the
/// Galerkin coarse levels under it.
struct Hierarchy {
    fine: Level,
    coarse: Vec<CoarseLevel>,
}

impl Hierarchy {
    fn levels(&self) -> usize {
        1 + self.coarse.len()
    }
}

fn fine_source<'a>(fine: &Level, fixed: &'a [bool], ax: f64, ay: f64, diag: f64) -> FineSource<'a> {
    FineSource {
        nx: fine.nx,
        ny: fine.ny,
        ax,
        ay,
        diag,
        fixed,
    }
}

/// Builds the finest level from the caller's arrays and the Galerkin coarse
/// levels below it; stops when both dimensions are small or a coarse level
/// would have no live point.
fn build_hierarchy(fine: Level, hx: f64, hy: f64, screening: f64, fixed: &[bool]) -> Hierarchy {
    let (nx, ny) = (fine.nx, fine.ny);
    let ax = 1.0 / (hx * hx);
    let ay = 1.0 / (hy * hy);
    let diag = 2.0 * ax + 2.0 * ay + screening;
    let src = fine_source(&fine, fixed, ax, ay, diag);
    let mut coarse: Vec<CoarseLevel> = Vec::new();
    if nx > COARSEST_MAX_DIM || ny > COARSEST_MAX_DIM {
        let first = CoarseLevel::build(&src, nx, ny, src.regular());
        if first.live > 0 {
            coarse.push(first);
        }
    }
    while let Some(last) = coarse.last() {
        if last.nx <= COARSEST_MAX_DIM && last.ny <= COARSEST_MAX_DIM {
            break;
        }
        let next = CoarseLevel::build(last, last.nx, last.ny, last.reg64);
        if next.live == 0 {
            break;
        }
        coarse.push(next);
    }
    Hierarchy { fine, coarse }
}

/// Smooths a level that has no coarse level under it until its residual
/// fell by 1e-3 (or a sweep limit): an almost exact solve of a tiny grid.
fn solve_fine_alone(level: &mut Level) {
    let start = level.residual_norm_squared();
    if start == 0.0 {
        return;
    }
    for _ in 0..500 {
        level.smooth(4);
        if level.residual_norm_squared() <= 1e-6 * start {
            break;
        }
    }
}

/// Computes the finest level's residual and restricts it to the first
/// coarse level's right-hand side in one pass (the fine residual is only
/// held three rows at a time), and zeroes the coarse correction.
/// `after_sweep`: the fine level was just smoothed, so its black residual
/// is 0 up to rounding (see [`Level::residual_halves`]).
fn restrict_fine(h: &mut Hierarchy, after_sweep: bool) {
    let fine = &h.fine;
    coarse::restrict(&mut h.coarse[0], fine.ny, fine.parallel(), |j, e, o| {
        fine.residual_halves(j, e, o, after_sweep)
    });
}

/// Adds the interpolated correction of the first coarse level to the finest.
/// `before_sweep`: a smoothing sweep follows (see [`Level::prolongate_from`]).
fn prolongate_fine(h: &mut Hierarchy, before_sweep: bool) {
    h.fine.prolongate_from(&h.coarse[0], before_sweep);
}

/// One V-cycle on the coarse levels `levels[0]` (right-hand side given).
fn coarse_cycle(levels: &mut [CoarseLevel], pre: usize, post: usize) {
    let Some((first, rest)) = levels.split_first_mut() else {
        return;
    };
    if rest.is_empty() {
        first.solve_coarsest();
        return;
    }
    first.smooth(pre);
    restrict_coarse(first, &mut rest[0]);
    coarse_cycle(rest, pre, post);
    prolongate_coarse(&rest[0], first, post > 0);
    first.smooth(post);
}

/// One V-cycle on the finest level. Returns the squared residual norm of
/// the result when it was computed on the way (during the last
/// post-smoothing sweep).
fn v_cycle(h: &mut Hierarchy, pre: usize, post: usize) -> Option<f64> {
    if h.coarse.is_empty() {
        solve_fine_alone(&mut h.fine);
        return None;
    }
    if pre > 0 {
        // The last pre-smoothing sweep restricts the residual as it goes.
        let fny = h.fine.ny;
        let visitor = RestrictVisitor {
            target: RestrictTarget::new(&mut h.coarse[0]),
            fny,
        };
        h.fine.smooth_visiting(pre, &visitor);
    } else {
        restrict_fine(h, false);
    }
    coarse_cycle(&mut h.coarse, pre, post);
    prolongate_fine(h, post > 0);
    if post == 0 {
        return None;
    }
    let visitor = NormVisitor {
        width: h.fine.w + 2,
    };
    let norm = h.fine.smooth_visiting(post, &visitor);
    Some(norm.iter().map(|s| s.0).sum())
}

/// Restricts the finest level's residual to the first coarse level as the
/// rows become final in the last pre-smoothing sweep: coarse row `cj` as
/// soon as fine rows `2 cj - 1 ..= 2 cj + 1` are, by the band holding fine
/// row `2 cj`, and the coarse rows at band edges after the sweep.
struct RestrictVisitor<'a> {
    target: RestrictTarget<'a>,
    fny: usize,
}

/// Three fine residual rows `(E, O)` in rotation (slot `j % 3` holds fine
/// row `j`) and the restriction's scratch row, all of one width.
struct RestrictBuffers {
    width: usize,
    r0: usize,
    buf: Vec<f32>,
}

impl RestrictBuffers {
    /// Slot `m`: `(E, O)`.
    fn slot(&mut self, m: usize) -> (&mut [f32], &mut [f32]) {
        let w = self.width;
        let (e, o) = self.buf[2 * m * w..(2 * m + 2) * w].split_at_mut(w);
        (e, o)
    }
}

impl RowVisitor for RestrictVisitor<'_> {
    type State = RestrictBuffers;
    const RED_ONLY: bool = true;

    fn start(&self, r0: usize, _r1: usize) -> RestrictBuffers {
        let width = self.target.width();
        RestrictBuffers {
            width,
            r0,
            buf: vec![0.0; 7 * width],
        }
    }

    fn row<F: FnOnce(&mut [f32], &mut [f32])>(&self, st: &mut RestrictBuffers, j: usize, fill: F) {
        let (e, o) = st.slot(j % 3);
        fill(e, o);
        // Rows j - 2 and j - 1 came through here too: coarse row (j - 1) / 2.
        if j & 1 == 1 && j >= st.r0 + 4 {
            let cj = (j - 1) / 2;
            let w = st.width;
            let (rows, out) = st.buf.split_at_mut(6 * w);
            let at = |m: usize| {
                (
                    &rows[2 * m * w..(2 * m + 1) * w],
                    &rows[(2 * m + 1) * w..(2 * m + 2) * w],
                )
            };
            // SAFETY: coarse row cj belongs to the band holding fine row 2 cj.
            unsafe {
                self.target
                    .write_row(cj, at((j - 2) % 3), at((j - 1) % 3), at(j % 3), out)
            };
        }
    }

    fn finish(
        &self,
        st: &mut RestrictBuffers,
        r0: usize,
        r1: usize,
        residual: &level::RowResidual,
    ) {
        for cj in self.target.rows_centred_in(r0..r1) {
            let fj = 2 * cj;
            if fj >= r0 + 3 && fj + 4 <= r1 {
                continue; // done during the sweep
            }
            for (m, r) in [(0, fj as isize - 1), (1, fj as isize), (2, fj as isize + 1)] {
                let (e, o) = st.slot(m);
                if r < 0 || r as usize >= self.fny {
                    e.fill(0.0);
                    o.fill(0.0);
                } else {
                    residual(r as usize, e, o);
                }
            }
            let w = st.width;
            let (rows, out) = st.buf.split_at_mut(6 * w);
            let at = |m: usize| {
                (
                    &rows[2 * m * w..(2 * m + 1) * w],
                    &rows[(2 * m + 1) * w..(2 * m + 2) * w],
                )
            };
            // SAFETY: coarse row cj belongs to this band (fine row 2 cj is in it).
            unsafe { self.target.write_row(cj, at(0), at(1), at(2), out) };
        }
    }
}

/// Sums the squared residual of the finest level during the last
/// post-smoothing sweep.
struct NormVisitor {
    /// Padded residual row length, `w + 2`.
    width: usize,
}

impl RowVisitor for NormVisitor {
    /// Sum so far and two scratch rows.
    type State = (f64, Vec<f32>, Vec<f32>);
    const RED_ONLY: bool = false;

    fn start(&self, _r0: usize, _r1: usize) -> Self::State {
        (0.0, vec![0.0; self.width], vec![0.0; self.width])
    }

    fn row<F: FnOnce(&mut [f32], &mut [f32])>(&self, st: &mut Self::State, _j: usize, fill: F) {
        let (sum, e, o) = st;
        fill(e, o);
        *sum += level::sum_squares(e) + level::sum_squares(o);
    }

    fn finish(&self, st: &mut Self::State, r0: usize, r1: usize, residual: &level::RowResidual) {
        let (sum, e, o) = st;
        for j in (r0..r1).filter(|&j| j < r0 + 2 || j + 3 > r1) {
            residual(j, e, o);
            *sum += level::sum_squares(e) + level::sum_squares(o);
        }
    }
}

/// Full multigrid pass on the residual equation: the residual of the zero
/// initial guess is restricted to every level, the coarsest level is solved,
/// and on each finer level the interpolated coarse solution is the initial
/// guess of one V-cycle; the finest level then receives the interpolated
/// correction (the V-cycles that follow are counted as usual).
fn full_multigrid(h: &mut Hierarchy, opts: &MultigridOptions) {
    h.fine.zero_free();
    if h.coarse.is_empty() {
        return;
    }
    restrict_fine(h, false);
    let n = h.coarse.len();
    for l in 0..n - 1 {
        let (head, tail) = h.coarse.split_at_mut(l + 1);
        restrict_coarse(&head[l], &mut tail[0]);
    }
    h.coarse[n - 1].solve_coarsest();
    for l in (0..n - 1).rev() {
        let (head, tail) = h.coarse.split_at_mut(l + 1);
        head[l].u.iter_mut().for_each(|u| u.fill(0.0));
        prolongate_coarse(&tail[0], &mut head[l], false);
        coarse_cycle(&mut h.coarse[l..], opts.pre_smooth, opts.post_smooth);
    }
    prolongate_fine(h, false);
}

/// `ax (west + east) + ay (north + south)` of cell (i, j) for the 5-point
/// operator, with `at(i, j)` giving a neighbour's value; neighbours outside
/// the grid count as 0 (Dirichlet 0 just outside the edge).
#[inline(always)]
fn weighted_neighbour_sum(
    i: usize,
    j: usize,
    nx: usize,
    ny: usize,
    ax: f64,
    ay: f64,
    at: impl Fn(usize, usize) -> f64,
) -> f64 {
    let mut s = 0.0;
    if i > 0 {
        s += ax * at(i - 1, j);
    }
    if i + 1 < nx {
        s += ax * at(i + 1, j);
    }
    if j > 0 {
        s += ay * at(i, j - 1);
    }
    if j + 1 < ny {
        s += ay * at(i, j + 1);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::galerkin::sidx;
    use super::*;

    /// The Galerkin coarse operators are symmetric (`A_c = P^T A P` with a
    /// symmetric `A`), dead points are isolated, and the constant stencil of
    /// the Laplacian's first coarse level is the textbook one.
    #[test]
    fn galerkin_operators_are_symmetric() {
        let (nx, ny) = (77, 61);
        let layout = synthetic::scattered_constraints(nx, ny, 4, 6, 2, 5);
        let mut fine = Level::new(nx, ny, 1.0, 2.0, 0.0);
        fine.load(&layout.fixed, &layout.values)
            .expect("the layout is finite");
        let h = build_hierarchy(fine, 1.0, 2.0, 0.0, &layout.fixed);
        assert!(h.coarse.len() >= 4);
        for c in &h.coarse {
            for j in 0..c.ny as isize {
                for i in 0..c.nx as isize {
                    let s = c.stencil(i, j);
                    for dj in -1..=1isize {
                        for di in -1..=1isize {
                            let t = c.stencil(i + di, j + dj)[sidx(-di, -dj)];
                            let a = s[sidx(di, dj)];
                            assert!(
                                (a - t).abs() <= 1e-5 * s[4].abs().max(1e-30),
                                "level {}x{} ({i},{j}) ({di},{dj}): {a} vs {t}",
                                c.nx,
                                c.ny
                            );
                        }
                    }
                }
            }
        }
        let fine = Level::new(9, 9, 1.0, 1.0, 0.0);
        let fixed = vec![false; 81];
        let src = fine_source(&fine, &fixed, 1.0, 1.0, 4.0);
        let reg = CoarseLevel::build(&src, 9, 9, src.regular()).reg64;
        let expected = [-0.25, -0.5, -0.25, -0.5, 3.0, -0.5, -0.25, -0.5, -0.25];
        for (a, b) in reg.iter().zip(expected) {
            assert!((a - b).abs() < 1e-12, "{reg:?}");
        }
    }
}
