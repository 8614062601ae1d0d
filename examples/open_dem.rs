//! Open a DEM (file or tile directory) `N` times and print the time of
//! each `Dem::open` (and of dropping what it opened): what
//! `benches/tile_open.rs` measures, on any directory, for profiling.
//!
//!     cargo run --release --example open_dem -- DIR [N]

use demsketch::raster::Dem;
use std::time::Instant;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .ok_or_else(|| anyhow::anyhow!("usage: open_dem DIR [N]"))?;
    let n: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(5);
    for _ in 0..n {
        let t = Instant::now();
        let dem = Dem::open(std::path::Path::new(&path))?;
        let open = t.elapsed().as_secs_f64();
        let tiles = dem.tiles.len();
        let rss = rss_mb();
        let t = Instant::now();
        drop(dem);
        println!(
            "open {:.1} ms ({tiles} tiles, {:.2} us/tile, resident {rss:.0} MB), drop {:.1} ms (resident {:.0} MB)",
            open * 1e3,
            open * 1e6 / tiles as f64,
            t.elapsed().as_secs_f64() * 1e3,
            rss_mb()
        );
    }
    Ok(())
}

/// This process's resident memory, MB (`VmRSS`).
fn rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            let line = s.lines().find(|l| l.starts_with("VmRSS:"))?.to_string();
            line.split_whitespace().nth(1)?.parse::<f64>().ok()
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}
