//! What writing a viewshed costs with each set of GeoTIFF creation options:
//! the viewshed of Zion resampled to 8192 x 8192 cells (as in
//! `viewshed_vs_gdal`, observer 1.7 m above cell (4096, 1640)) written with
//! `write_viewshed_tiff_with` (staged beside the target, flushed to disk,
//! read back block by block and compared, renamed) with gdal_viewshed's
//! default (striped, uncompressed), `write_viewshed_tiff`'s (PackBits
//! tiles) and `demsketch view --viewshed`'s (DEFLATE tiles), the median of
//! several runs alternating between them, and the size of each file.
//!
//!     cargo run --release --example viewshed_write [-- RUNS]

use demsketch::raster::Dem;
use demsketch::render::{eye_frame, viewshed_from_file, write_viewshed_tiff_with};
use demsketch::view::{Georef, Viewpoint};
use std::path::Path;
use std::process::Command;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let runs: usize = match std::env::args().nth(1) {
        Some(a) => a.parse()?,
        None => 7,
    };
    anyhow::ensure!(runs > 0, "RUNS must be at least 1");
    let tmp = tempfile::tempdir()?;
    let dem_path = tmp.path().join("zion_8192.tif");
    let st = Command::new("gdal_translate")
        .args(["-q", "-outsize", "8192", "8192", "-r", "cubic"])
        .args(["-co", "TILED=YES"])
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/zion_srtm_utm12n.tif"))
        .arg(&dem_path)
        .status()?;
    anyhow::ensure!(st.success(), "gdal_translate failed");
    let dem = Dem::open(&dem_path)?.without_block_cache();
    let georef = Georef::for_crs(&dem.crs, "zion_8192")?;
    let (x, y) = dem.geotransform.pixel_to_crs(4096.5, 1640.5);
    let (lon, lat) = georef.crs_to_lonlat(x, y)?;
    let frame = eye_frame(
        &dem,
        &georef,
        &Viewpoint::above_surface(lon, lat, 1.7),
        1.0 / 7.0,
    )?;
    let vs = viewshed_from_file(&dem, &frame, None, 0.0)?;
    let out = tmp.path().join("vis.tif");
    let variants: [(&str, &[&str]); 4] = [
        ("none: striped, uncompressed (gdal_viewshed)", &[]),
        (
            "PackBits tiles (write_viewshed_tiff)",
            demsketch::render::VIEWSHED_TIFF_OPTIONS,
        ),
        (
            "DEFLATE tiles (view --viewshed)",
            &["TILED=YES", "COMPRESS=DEFLATE"],
        ),
        (
            "DEFLATE tiles, all cores",
            &["TILED=YES", "COMPRESS=DEFLATE", "NUM_THREADS=ALL_CPUS"],
        ),
    ];
    let mut times = vec![Vec::new(); variants.len()];
    let mut sizes = vec![0u64; variants.len()];
    for _ in 0..runs {
        for (i, (_, options)) in variants.iter().enumerate() {
            let t = Instant::now();
            write_viewshed_tiff_with(&vs, &out, options)?;
            times[i].push(t.elapsed().as_secs_f64() * 1e3);
            sizes[i] = std::fs::metadata(&out)?.len();
        }
    }
    println!("| creation options | write (ms, median of {runs}) | file (bytes) |");
    println!("|---|---|---|");
    for (i, (name, options)) in variants.iter().enumerate() {
        let t = &mut times[i];
        t.sort_by(f64::total_cmp);
        println!(
            "| {name} `{}` | {:.1} | {} |",
            options.join(" "),
            t[t.len() / 2],
            sizes[i]
        );
    }
    Ok(())
}
