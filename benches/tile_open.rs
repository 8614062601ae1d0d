//! Opening a directory of many small GeoTIFF tiles (issue 15, item 1:
//! "opening 16,384 tiles under 0.2 s"). The directory is 128 x 128 tiles of
//! 16 x 16 Float32 cells (30 m, EPSG:32612, nodata -9999, as GDAL's GTiff
//! driver writes them by default: striped, uncompressed), made once in a
//! temporary directory by GDAL; `Dem::open` is timed on it: the listing,
//! each tile's header, the CRS, the grid checks and the overlap check.
//!
//!     cargo bench --bench tile_open            # 128 x 128 tiles
//!     DEMSKETCH_BENCH_TILES=64 cargo bench --bench tile_open
//!
//! `tools/bench_tile_open.sh` runs it side by side with another build's
//! `demsketch info --no-stats` on the same directory.

use criterion::{criterion_group, criterion_main, Criterion};
use demsketch::raster::Dem;
use gdal::raster::Buffer;
use gdal::spatial_ref::SpatialRef;
use gdal::DriverManager;
use std::path::Path;
use std::time::{Duration, Instant};

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

const TILE: usize = 16;

fn tiles_across() -> usize {
    std::env::var("DEMSKETCH_BENCH_TILES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(128)
}

/// `n` x `n` tiles of `TILE` x `TILE` cells in `dir`.
fn make_tiles(dir: &Path, n: usize) {
    let driver = DriverManager::get_driver_by_name("GTiff").expect("GTiff driver");
    let wkt = SpatialRef::from_epsg(32612)
        .and_then(|s| s.to_wkt())
        .expect("EPSG:32612");
    let (x0, y0, cell) = (300_000.0, 4_200_000.0, 30.0);
    for r in 0..n {
        for c in 0..n {
            let path = dir.join(format!("t_{r:03}_{c:03}.tif"));
            let mut ds = driver
                .create_with_band_type::<f32, _>(&path, TILE, TILE, 1)
                .expect("create tile");
            ds.set_geo_transform(&[
                x0 + (c * TILE) as f64 * cell,
                cell,
                0.0,
                y0 - (r * TILE) as f64 * cell,
                0.0,
                -cell,
            ])
            .expect("geotransform");
            ds.set_projection(&wkt).expect("projection");
            let mut band = ds.rasterband(1).expect("band");
            band.set_no_data_value(Some(-9999.0)).expect("nodata");
            let v: Vec<f32> = (0..TILE * TILE)
                .map(|i| 1000.0 + (10 * r + c) as f32 + i as f32 / 256.0)
                .collect();
            let mut buf = Buffer::new((TILE, TILE), v);
            band.write((0, 0), (TILE, TILE), &mut buf)
                .expect("write tile");
        }
    }
}

fn bench(c: &mut Criterion) {
    let n = tiles_across();
    // DEMSKETCH_BENCH_TILE_DIR keeps the directory (made if empty).
    let tmp = tempfile::tempdir().expect("temporary directory");
    let dir = std::env::var_os("DEMSKETCH_BENCH_TILE_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| tmp.path().to_path_buf());
    std::fs::create_dir_all(&dir).expect("tile directory");
    let t = Instant::now();
    if std::fs::read_dir(&dir).expect("list").next().is_none() {
        make_tiles(&dir, n);
    }
    eprintln!(
        "made {} tiles of {TILE} x {TILE} in {:.2} s",
        n * n,
        t.elapsed().as_secs_f64()
    );
    // One open outside the timer: check what it opened.
    let dem = Dem::open(&dir).expect("open the tile directory");
    assert_eq!(dem.tiles.len(), n * n);
    assert_eq!((dem.width, dem.height), (n * TILE, n * TILE));
    drop(dem);
    let mut g = c.benchmark_group("tile_open");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5));
    g.bench_function(format!("open_{n}x{n}_tiles_of_{TILE}x{TILE}"), |b| {
        // The DEM is dropped outside the timer: `Dem::open` alone.
        b.iter_with_large_drop(|| Dem::open(&dir).expect("open"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
