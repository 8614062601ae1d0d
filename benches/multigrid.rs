//! Criterion benchmark of the multigrid solver: the synthetic scattered-curve
//! layout (8 curves, 20 points, 4 holes) solved to a relative residual of
//! 1e-4, on 1024 x 1024 and 4096 x 4096 grids.
//!
//! `cargo bench --bench multigrid`

use criterion::{criterion_group, criterion_main, Criterion};
use demsketch::deform::multigrid::{solve, synthetic::scattered_constraints, MultigridOptions};

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn bench_multigrid(c: &mut Criterion) {
    let mut group = c.benchmark_group("multigrid");
    group.sample_size(10);
    for n in [1024usize, 4096] {
        let layout = scattered_constraints(n, n, 8, 20, 4, 42);
        let opts = MultigridOptions::default();
        let mut values = layout.values.clone();
        group.bench_function(format!("solve_{n}x{n}_tol1e-4"), |b| {
            b.iter(|| {
                values.copy_from_slice(&layout.values);
                solve(n, n, 30.0, 30.0, &layout.fixed, &mut values, &opts)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_multigrid);
criterion_main!(benches);
