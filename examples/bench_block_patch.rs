//! Write time of a small edit of a big single-file GeoTIFF: block patch
//! (the default) against a whole re-encode (forced with `-co`), for
//! `tools/bench_block_patch.sh`. Prints one JSON line.
//!
//!   cargo run --release --example bench_block_patch -- DEM OUTDIR

use std::path::PathBuf;
use std::time::Instant;

use demsketch::raster::{Dem, Destination, Provenance, Window, WriteOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let dem_path = PathBuf::from(args.get(1).ok_or("usage: DEM OUTDIR")?);
    let out_dir = PathBuf::from(args.get(2).ok_or("usage: DEM OUTDIR")?);
    let dem = Dem::open(&dem_path)?;
    // A 30 x 25 window (750 cells) in the middle, raised by 5 m.
    let win = Window::new(
        dem.width as i64 / 2 - 15,
        dem.height as i64 / 2 - 12,
        30,
        25,
    );
    let old = dem.read_window::<f64>(win)?;
    let new: Vec<f64> = old.data.iter().map(|v| v + 5.0).collect();
    let prov = Provenance {
        edit_id: "bench".into(),
    };
    let time = |name: &str,
                opts: &WriteOptions|
     -> Result<(f64, usize), Box<dyn std::error::Error>> {
        let out = out_dir.join(name);
        let mut best = f64::INFINITY;
        let mut changed = 0;
        for _ in 0..3 {
            let _ = std::fs::remove_file(&out);
            let t = Instant::now();
            let r = dem.write_back_with(win, &new, &Destination::Path(out.clone()), &prov, opts)?;
            best = best.min(t.elapsed().as_secs_f64());
            changed = r.changed_cells;
        }
        Ok((best, changed))
    };
    let (patch_s, changed) = time("patched.tif", &WriteOptions::default())?;
    let full = WriteOptions {
        creation_options: vec!["COMPRESS=DEFLATE".into()],
        ..Default::default()
    };
    let (full_s, _) = time("reencoded.tif", &full)?;
    println!(
        "{{\"cells\": {}, \"changed_cells\": {changed}, \"patch_s\": {patch_s:.4}, \"reencode_s\": {full_s:.4}, \"ratio\": {:.4}}}",
        dem.width * dem.height,
        patch_s / full_s
    );
    Ok(())
}
