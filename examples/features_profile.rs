//! Stage-by-stage timing of feature extraction on the synthetic fractal DEM
//! of `benches/features.rs` (same DEM, eye and camera), for profiling:
//! terrain set-up, depth buffer, silhouettes and ridges, best of N runs.
//!
//!     cargo run --release --example features_profile -- 4096 [800x450] [runs]
//!     perf record -g target/release/examples/features_profile 4096

#[path = "../benches/support/cpu_time.rs"]
mod cpu_time;
#[path = "../benches/support/fractal.rs"]
mod fractal;

use demsketch::features::{detect_ridges, extract_silhouettes, RidgeParams, SilhouetteParams};
use demsketch::render::{DepthBuffer, LocalTerrain};
use std::time::Instant;

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Best wall time (ms) and mean CPU time per run (ms) over `runs` runs.
fn best<T>(runs: usize, mut f: impl FnMut() -> T) -> ((f64, f64), T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    let c0 = cpu_time::cpu_s();
    for _ in 0..runs {
        let t = Instant::now();
        let v = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(v);
    }
    let cpu = (cpu_time::cpu_s() - c0) / runs as f64;
    ((best * 1e3, cpu * 1e3), out.expect("at least one run"))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(512);
    let (vw, vh) = args
        .get(2)
        .and_then(|s| {
            let (a, b) = s.split_once('x')?;
            Some((a.parse().ok()?, b.parse().ok()?))
        })
        .unwrap_or((800usize, 450usize));
    let runs: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(10);
    let map = fractal::fractal(n);
    let (frame, camera) = fractal::bench_view(&map, n, vw, vh);
    // STAGE=terrain|depth|silhouettes|ridges: run only that stage `runs`
    // times after one set-up run (for `perf stat`, whose counts do not
    // depend on the machine's load).
    if let Ok(stage) = std::env::var("STAGE") {
        let terrain = LocalTerrain::new(&map, &frame, None);
        let db = DepthBuffer::render(&terrain, &camera);
        let sp = SilhouetteParams::default();
        let mut times = Vec::with_capacity(runs);
        for _ in 0..runs {
            let t0 = Instant::now();
            match stage.as_str() {
                "terrain" => drop(LocalTerrain::new(&map, &frame, None)),
                "render" => {
                    let t = LocalTerrain::new(&map, &frame, None);
                    drop(DepthBuffer::render(&t, &camera));
                }
                "depth" => drop(DepthBuffer::render(&terrain, &camera)),
                "silhouettes" => drop(extract_silhouettes(&terrain, &db, &sp)),
                "ridges" => drop(detect_ridges(&map, &RidgeParams::default())),
                _ => {}
            }
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        times.sort_by(f64::total_cmp);
        if let (Some(first), Some(last)) = (times.first(), times.last()) {
            let mean = times.iter().sum::<f64>() / times.len() as f64;
            eprintln!(
                "{stage}: mean {mean:.2} ms, min {first:.2}, median {:.2}, max {last:.2}",
                times[times.len() / 2]
            );
        }
        return;
    }
    let (t_terrain, terrain) = best(runs, || LocalTerrain::new(&map, &frame, None));
    let (t_depth, db) = best(runs, || DepthBuffer::render(&terrain, &camera));
    let sp = SilhouetteParams::default();
    let (t_sil, sil) = best(runs, || {
        extract_silhouettes(&terrain, &db, &sp).expect("silhouettes")
    });
    let rp = RidgeParams::default();
    let (t_ridges, ridges) = best(runs, || detect_ridges(&map, &rp).expect("ridges"));
    let ms = |t: (f64, f64)| format!("{:.1} ms (cpu {:.1})", t.0, t.1);
    println!(
        "{n}x{n}, view {vw}x{vh}, best of {runs}: terrain {}, depth buffer {}, silhouettes {} ({} curves, {} samples), ridges {} ({} lines); sum {:.1} ms (cpu {:.1})",
        ms(t_terrain),
        ms(t_depth),
        ms(t_sil),
        sil.curves.len(),
        sil.sample_count(),
        ms(t_ridges),
        ridges.lines.len(),
        t_terrain.0 + t_depth.0 + t_sil.0 + t_ridges.0,
        t_terrain.1 + t_depth.1 + t_sil.1 + t_ridges.1
    );
}
