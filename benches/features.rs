//! Feature extraction benchmark (issue 3, item 6/7 acceptance): on a
//! synthetic fractal DEM of 512 x 512 and 4096 x 4096 cells (30 m), time
//! - `render`: the local terrain around the eye and its depth buffer,
//! - `silhouettes`: silhouette extraction from that depth buffer,
//! - `ridges`: the PPA ridge network of the whole DEM,
//! - `total`: all three, as one feature-extraction pass of an edit,
//! - `render_1600x900` (4096 only): terrain + depth buffer of a full-size
//!   1600 x 900 view, the picture `demsketch view` draws by default.
//!
//! Run: `cargo bench --bench features` (`-- 512` to select a size). The
//! feature-extraction view is `DEMSKETCH_BENCH_VIEW` (default 800x450)
//! pixels, hfov 60, eye 1.7 m above the ground, pitch 1 degree.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use demsketch::features::{detect_ridges, extract_silhouettes, RidgeParams, SilhouetteParams};
use demsketch::render::{DepthBuffer, LocalTerrain};
use demsketch::view::Camera;
use std::time::Duration;

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[path = "support/fractal.rs"]
mod fractal;
use fractal::fractal;

fn view_size() -> (usize, usize) {
    std::env::var("DEMSKETCH_BENCH_VIEW")
        .ok()
        .and_then(|s| {
            let (a, b) = s.split_once('x')?;
            Some((a.parse().ok()?, b.parse().ok()?))
        })
        .unwrap_or((800, 450))
}

fn bench(c: &mut Criterion) {
    let (vw, vh) = view_size();
    let mut g = c.benchmark_group("features");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5));
    for n in [512usize, 4096] {
        let map = fractal(n);
        let (frame, camera) = fractal::bench_view(&map, n, vw, vh);
        let render = || {
            let t = LocalTerrain::new(&map, &frame, None);
            let db = DepthBuffer::render(&t, &camera);
            (t, db)
        };
        let (terrain, db) = render();
        let sp = SilhouetteParams::default();
        let rp = RidgeParams::default();
        g.bench_with_input(BenchmarkId::new("render", n), &n, |b, _| b.iter(render));
        g.bench_with_input(BenchmarkId::new("silhouettes", n), &n, |b, _| {
            b.iter(|| extract_silhouettes(&terrain, &db, &sp).expect("silhouettes"))
        });
        g.bench_with_input(BenchmarkId::new("ridges", n), &n, |b, _| {
            b.iter(|| detect_ridges(&map, &rp).expect("ridges"))
        });
        g.bench_with_input(BenchmarkId::new("total", n), &n, |b, _| {
            b.iter(|| {
                let (t, db) = render();
                let s = extract_silhouettes(&t, &db, &sp).expect("silhouettes");
                let r = detect_ridges(&map, &rp).expect("ridges");
                (s.curves.len(), r.lines.len())
            })
        });
        if n == 4096 {
            let big = Camera::new(1600, 900, 10.0, 1.0, 0.0, 60.0).expect("camera");
            g.bench_with_input(BenchmarkId::new("render_1600x900", n), &n, |b, _| {
                b.iter(|| {
                    let t = LocalTerrain::new(&map, &frame, None);
                    DepthBuffer::render(&t, &big)
                })
            });
        }
        let s = extract_silhouettes(&terrain, &db, &sp).expect("silhouettes");
        let r = detect_ridges(&map, &rp).expect("ridges");
        eprintln!(
            "{n}x{n}: view {vw}x{vh}, {:.0}% terrain, {} silhouettes / {} samples / {} T-junctions; {} ridge candidates, {} lines, {} nodes",
            100.0 * db.terrain_fraction(),
            s.curves.len(),
            s.sample_count(),
            s.junctions.len(),
            r.candidate_cells,
            r.lines.len(),
            r.nodes.len()
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
