//! Times demsketch's tile layer on one DEM: full read (open + decode into
//! f32) and a write-back of the whole raster to a new file with the same
//! layout and encoding. Prints one JSON object. Used by `tools/bench_io.sh`,
//! which times GDAL on the same file in the same run.
//!
//!     cargo run --release --example raster_io -- DEM OUT.tif [--read-only]

use std::path::PathBuf;
use std::time::Instant;

use demsketch::raster::{Dem, Destination, Provenance};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let input = PathBuf::from(
        args.next()
            .ok_or_else(|| anyhow::anyhow!("usage: raster_io DEM OUT.tif"))?,
    );
    let out = PathBuf::from(
        args.next()
            .ok_or_else(|| anyhow::anyhow!("usage: raster_io DEM OUT.tif"))?,
    );
    let read_only = args.next().as_deref() == Some("--read-only");
    let repeats = 3;
    let mut read_s = Vec::new();
    let mut cells = 0usize;
    let mut sum = 0f64;
    for _ in 0..repeats {
        let t = Instant::now();
        let dem = Dem::open(&input)?;
        let hm = dem.read_height_map(dem.full_window())?;
        read_s.push(t.elapsed().as_secs_f64());
        cells = hm.data.len();
        sum = hm
            .data
            .iter()
            .filter(|v| !v.is_nan())
            .map(|v| *v as f64)
            .sum();
    }
    if read_only {
        println!(
            "{}",
            serde_json::json!({"cells": cells, "checksum": sum, "read_s": read_s})
        );
        return Ok(());
    }
    let dem = Dem::open(&input)?;
    let win = dem.full_window();
    let hm = dem.read_height_map(win)?;
    let new: Vec<f64> = hm.data.iter().map(|v| *v as f64 + 1.0).collect();
    let t = Instant::now();
    dem.write_back(
        win,
        &new,
        &Destination::Path(out.clone()),
        &Provenance {
            edit_id: "bench".into(),
        },
    )?;
    let write_s = t.elapsed().as_secs_f64();
    let best = read_s.iter().cloned().fold(f64::INFINITY, f64::min);
    println!(
        "{}",
        serde_json::json!({
            "cells": cells, "checksum": sum, "read_s": read_s, "read_best_s": best,
            "read_mcells_per_s": cells as f64 / best / 1e6, "write_s": write_s,
            "threads": rayon::current_num_threads(),
        })
    );
    Ok(())
}
