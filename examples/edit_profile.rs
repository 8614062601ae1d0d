//! Stage-by-stage timing of a whole `edit` on the case of `benches/edit.rs`
//! (512 x 512 Zion, 10 strokes): the report's stage timings, median and
//! minimum over N runs after one warm-up run, for profiling.
//!
//!     cargo run --release --example edit_profile -- [runs]
//!     perf record -g target/release/examples/edit_profile 50

#[path = "../benches/support/cpu_time.rs"]
mod cpu_time;
#[path = "../benches/support/edit_case.rs"]
mod edit_case;

use demsketch::edit::{run, EditOptions};
use demsketch::raster::Destination;

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() {
    let runs: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let tmp = tempfile::tempdir().expect("temporary directory");
    let (dem, sketch) = edit_case::setup(tmp.path());
    // EDIT_CASE_KEEP=DIR: keep a copy of the DEM and the sketch there.
    if let Some(dir) = std::env::var_os("EDIT_CASE_KEEP") {
        let dir = std::path::PathBuf::from(dir);
        std::fs::create_dir_all(&dir).expect("EDIT_CASE_KEEP directory");
        std::fs::copy(&dem, dir.join("zion512.tif")).expect("copy DEM");
        std::fs::copy(&sketch, dir.join("sketch.json")).expect("copy sketch");
    }
    let mut opts = EditOptions::new(Destination::Path(tmp.path().join("out.tif")));
    // The figures are those of a whole edit, written whatever its fit.
    opts.allow_partial = true;
    let first = run(&dem, &sketch, &opts).expect("edit");
    eprintln!(
        "first run: {:?}, lowering iterations {}, contour iterations {}",
        first.timings_s, first.views[0].lowering_iterations, first.views[0].contour_iterations
    );
    let names = [
        "load",
        "features",
        "matching",
        "deformation",
        "lowering",
        "write",
        "total",
    ];
    let mut rows: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let mut solver: Vec<[f64; 3]> = Vec::new();
    let c0 = cpu_time::cpu_s();
    for _ in 0..runs {
        let r = run(&dem, &sketch, &opts).expect("edit");
        let t = &r.timings_s;
        let sv = &r.deformation.solver;
        let get = |k: &str| sv.get(k).and_then(|v| v.as_f64()).unwrap_or(f64::NAN) * 1e3;
        solver.push([get("read_s"), get("constraints_s"), get("solve_s")]);
        for (row, v) in rows.iter_mut().zip([
            t.load,
            t.features,
            t.matching,
            t.deformation,
            t.lowering,
            t.write,
            t.total,
        ]) {
            row.push(v * 1e3);
        }
    }
    let cpu = (cpu_time::cpu_s() - c0) / runs.max(1) as f64;
    println!("{runs} runs, CPU time per run {:.1} ms", cpu * 1e3);
    for (k, name) in ["read", "constraints", "solve"].iter().enumerate() {
        let mut v: Vec<f64> = solver.iter().map(|s| s[k]).collect();
        v.sort_by(f64::total_cmp);
        println!("last deformation's {name}: median {:.2} ms", v[v.len() / 2]);
    }
    println!("{runs} runs, ms: stage median min");
    for (name, mut row) in names.iter().zip(rows) {
        row.sort_by(f64::total_cmp);
        println!("{name:>12} {:8.2} {:8.2}", row[row.len() / 2], row[0]);
    }
}
