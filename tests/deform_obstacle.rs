//! The deformation solver's upper bounds (an obstacle problem,
//! `multigrid::solve_below`): the bounded cells end at most at their bound,
//! a bound above the free solution changes nothing, and the result is the
//! obstacle problem's (checked against projected Gauss-Seidel run to
//! convergence in f64 on a small grid).

use demsketch::deform::multigrid::{solve, solve_below, MultigridOptions};

const SLACK: f64 = 1e-3;

fn opts() -> MultigridOptions {
    MultigridOptions {
        tolerance: 1e-6,
        ..MultigridOptions::default()
    }
}

/// A 33 x 33 grid of 30 m cells with a 40 m ridge along row 16 (cols 4-28).
fn ridge() -> (usize, usize, Vec<bool>, Vec<f32>) {
    let (nx, ny) = (33, 33);
    let mut fixed = vec![false; nx * ny];
    let mut values = vec![0f32; nx * ny];
    for i in 4..29 {
        fixed[16 * nx + i] = true;
        values[16 * nx + i] = 40.0;
    }
    (nx, ny, fixed, values)
}

/// Projected Gauss-Seidel in f64 to convergence: the reference solution.
fn projected_gs(
    nx: usize,
    ny: usize,
    h: f64,
    fixed: &[bool],
    values: &[f32],
    upper: &[f32],
) -> Vec<f64> {
    let mut u: Vec<f64> = values.iter().map(|&v| v as f64).collect();
    let w = 1.0 / (h * h);
    for _ in 0..200_000 {
        let mut change = 0f64;
        for y in 0..ny {
            for x in 0..nx {
                let i = y * nx + x;
                if fixed[i] {
                    continue;
                }
                let at = |ok: bool, k: usize, u: &[f64]| if ok { u[k] } else { 0.0 };
                let s = at(x > 0, i.wrapping_sub(1), &u)
                    + at(x + 1 < nx, i + 1, &u)
                    + at(y > 0, i.wrapping_sub(nx), &u)
                    + at(y + 1 < ny, i + nx, &u);
                let mut v = w * s / (4.0 * w);
                if upper[i].is_finite() {
                    v = v.min(upper[i] as f64);
                }
                change = change.max((v - u[i]).abs());
                u[i] = v;
            }
        }
        if change < 1e-9 {
            break;
        }
    }
    u
}

#[test]
fn bounds_hold_and_match_projected_gauss_seidel() {
    let (nx, ny, fixed, values) = ridge();
    let mut free = values.clone();
    solve(nx, ny, 30.0, 30.0, &fixed, &mut free, &opts()).unwrap();
    // Bound a block of cells in front of the ridge well under the free
    // solution, and one cell far above it.
    let mut upper = vec![f32::NAN; nx * ny];
    for y in 18..21 {
        for x in 12..17 {
            upper[y * nx + x] = 5.0;
        }
    }
    let loose = 25 * nx + 16;
    upper[loose] = free[loose] + 50.0;
    let mut v = values.clone();
    let (stats, iterations) =
        solve_below(nx, ny, 30.0, 30.0, &fixed, &mut v, &upper, SLACK, &opts()).unwrap();
    assert!(stats.relative_residual <= 1e-6);
    assert!(iterations >= 2, "the loose cell is released: {iterations}");
    let reference = projected_gs(nx, ny, 30.0, &fixed, &values, &upper);
    for i in 0..nx * ny {
        if upper[i].is_finite() {
            assert!(
                v[i] as f64 <= upper[i] as f64 + SLACK,
                "cell {i}: {} > {}",
                v[i],
                upper[i]
            );
        }
        assert!(
            (v[i] as f64 - reference[i]).abs() < 0.01,
            "cell {i}: {} against {}",
            v[i],
            reference[i]
        );
    }
    // The bounded block sits at its bound (the diffusion would take it
    // higher); the loose cell is free, and its value is the diffusion's.
    assert!((v[19 * nx + 14] - 5.0).abs() < 1e-3);
    assert!(v[loose] < upper[loose] - 1.0);
}

#[test]
fn bounds_above_the_free_solution_change_nothing() {
    let (nx, ny, fixed, values) = ridge();
    let mut free = values.clone();
    solve(nx, ny, 30.0, 30.0, &fixed, &mut free, &opts()).unwrap();
    let mut upper = vec![f32::NAN; nx * ny];
    for i in (0..nx * ny).step_by(7) {
        upper[i] = free[i] + 1.0;
    }
    let mut v = values.clone();
    solve_below(nx, ny, 30.0, 30.0, &fixed, &mut v, &upper, SLACK, &opts()).unwrap();
    for i in 0..nx * ny {
        assert!(
            (v[i] - free[i]).abs() < 1e-3,
            "cell {i}: {} against {}",
            v[i],
            free[i]
        );
    }
}

#[test]
fn no_bound_is_the_plain_solve() {
    let (nx, ny, fixed, values) = ridge();
    let mut free = values.clone();
    solve(nx, ny, 30.0, 30.0, &fixed, &mut free, &opts()).unwrap();
    let mut v = values.clone();
    let (_, iterations) = solve_below(
        nx,
        ny,
        30.0,
        30.0,
        &fixed,
        &mut v,
        &vec![f32::NAN; nx * ny],
        SLACK,
        &opts(),
    )
    .unwrap();
    assert_eq!(iterations, 0);
    assert!(v.iter().zip(&free).all(|(a, b)| a.to_bits() == b.to_bits()));
}
