//! Times the multigrid solver on the synthetic scattered-curve layout and
//! prints one JSON object; optionally writes the layout for
//! `tools/compare_pyamg.py` so pyamg solves the identical problem.
//!
//! ```text
//! cargo run --release --example multigrid_bench -- N [SEED] [TOL] [LAYOUT_DIR] [REPEATS]
//! ```
//! `LAYOUT_DIR` receives `fixed.u8` (1 byte per cell, 1 = fixed) and
//! `values.f32` (little-endian f32), row-major `i + N * j`, cell size 30 m.
//!
//! Besides wall-clock times the JSON holds the process CPU time (user +
//! system, all threads) of each solve, `cpu_seconds_all`, read from
//! `/proc/self/stat` (Linux only, 10 ms resolution; `null` elsewhere): on a
//! shared machine it moves less with the load than the wall time.

use demsketch::deform::multigrid::{solve, synthetic::scattered_constraints, MultigridOptions};
use std::time::Instant;

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// CPU time (user + system, all threads) of this process in seconds, from
/// `/proc/self/stat`; `None` where that file is unavailable.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the command name (which is in parentheses and may hold
    // spaces): state is field 3, utime field 14, stime field 15.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    // USER_HZ is 100 on every Linux configuration in use.
    Some((utime + stime) / 100.0)
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n: usize = args.first().map(|s| s.parse()).transpose()?.unwrap_or(4096);
    let seed: u64 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(42);
    let tolerance: f64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(1e-4);
    let layout_dir = args.get(3).filter(|s| !s.is_empty() && *s != "-");
    let repeats: usize = args.get(4).map(|s| s.parse()).transpose()?.unwrap_or(3);
    let layout = scattered_constraints(n, n, 8, 20, 4, seed);
    if let Some(dir) = layout_dir {
        std::fs::create_dir_all(dir)?;
        let fixed: Vec<u8> = layout.fixed.iter().map(|&f| u8::from(f)).collect();
        std::fs::write(format!("{dir}/fixed.u8"), fixed)?;
        let bytes: Vec<u8> = layout.values.iter().flat_map(|v| v.to_le_bytes()).collect();
        std::fs::write(format!("{dir}/values.f32"), bytes)?;
    }
    let opts = MultigridOptions {
        tolerance,
        ..Default::default()
    };
    let mut times = Vec::new();
    let mut setups = Vec::new();
    let mut cpu = Vec::new();
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let mut values = layout.values.clone();
        let cpu_start = process_cpu_seconds();
        let start = Instant::now();
        let stats = solve(n, n, 30.0, 30.0, &layout.fixed, &mut values, &opts)?;
        times.push(start.elapsed().as_secs_f64());
        cpu.push(cpu_start.zip(process_cpu_seconds()).map(|(a, b)| b - a));
        setups.push(stats.setup_seconds);
        last = Some(stats);
    }
    let stats = last.ok_or_else(|| anyhow::anyhow!("no run"))?;
    let best = times.iter().cloned().fold(f64::INFINITY, f64::min);
    let json = serde_json::json!({
        "solver": "demsketch multigrid: Galerkin (Dendy) V(2,2) cycles, red-black / 4-colour GS",
        "n": n,
        "seed": seed,
        "tolerance": tolerance,
        "threads": rayon::current_num_threads(),
        "seconds_best": best,
        "seconds_all": times,
        "setup_seconds_all": setups,
        "cpu_seconds_all": cpu,
        "cycles": stats.cycles,
        "levels": stats.levels,
        "relative_residual": stats.relative_residual,
        "residual_history": stats.residual_history,
    });
    println!("{json}");
    Ok(())
}
