//! Helpers shared by the `deform_*` tests: GeoTIFFs written through GDAL
//! from arrays, tile splits with `gdal_translate -srcwin`, mosaics of tile
//! directories read back with GDAL, exact distances to polylines.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

use gdal::raster::{Buffer, RasterCreationOptions};

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// Run `gdal_translate -q ARGS SRC DST` and fail the test if it fails.
pub fn gdal_translate(src: &Path, dst: &Path, extra: &[&str]) {
    let out = Command::new("gdal_translate")
        .arg("-q")
        .args(extra)
        .arg(src)
        .arg(dst)
        .env("GDAL_PAM_ENABLED", "NO")
        .output()
        .expect("run gdal_translate");
    assert!(
        out.status.success(),
        "gdal_translate {extra:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A raster read by GDAL: band 1 as f64, its geotransform and nodata.
#[derive(Debug, Clone)]
pub struct Grid {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f64>,
    pub gt: [f64; 6],
    pub nodata: Option<f64>,
}

impl Grid {
    pub fn at(&self, col: usize, row: usize) -> f64 {
        self.data[row * self.width + col]
    }
    pub fn is_nodata(&self, v: f64) -> bool {
        v.is_nan()
            || self
                .nodata
                .is_some_and(|n| v == n || (n < -1e30 && v < -1e30))
    }
}

/// Band 1 of a raster, read with GDAL.
pub fn gdal_read(path: &Path) -> Grid {
    let ds = gdal::Dataset::open(path).expect("GDAL opens the file");
    let band = ds.rasterband(1).expect("band 1");
    let (w, h) = band.size();
    let buf = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .expect("GDAL reads the band");
    Grid {
        width: w,
        height: h,
        data: buf.data().to_vec(),
        gt: ds.geo_transform().expect("geotransform"),
        nodata: band.no_data_value(),
    }
}

/// Every tile of a directory read with GDAL and placed on the grid of the
/// tile whose origin is the top-left one (tiles must share pixel size).
pub fn gdal_read_mosaic(dir: &Path) -> Grid {
    let mut tiles: Vec<Grid> = std::fs::read_dir(dir)
        .expect("read tile dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .map(|p| gdal_read(&p))
        .collect();
    assert!(!tiles.is_empty());
    let x0 = tiles.iter().map(|t| t.gt[0]).fold(f64::INFINITY, f64::min);
    let y0 = tiles
        .iter()
        .map(|t| t.gt[3])
        .fold(f64::NEG_INFINITY, f64::max);
    let (dx, dy) = (tiles[0].gt[1], tiles[0].gt[5]);
    let place = |t: &Grid| {
        (
            ((t.gt[0] - x0) / dx).round() as usize,
            ((t.gt[3] - y0) / dy).round() as usize,
        )
    };
    let w = tiles.iter().map(|t| place(t).0 + t.width).max().unwrap();
    let h = tiles.iter().map(|t| place(t).1 + t.height).max().unwrap();
    let mut data = vec![f64::NAN; w * h];
    tiles.sort_by(|a, b| a.gt[0].total_cmp(&b.gt[0]));
    for t in &tiles {
        let (c0, r0) = place(t);
        for r in 0..t.height {
            for c in 0..t.width {
                data[(r0 + r) * w + c0 + c] = t.at(c, r);
            }
        }
    }
    Grid {
        width: w,
        height: h,
        data,
        gt: [x0, dx, 0.0, y0, 0.0, dy],
        nodata: tiles[0].nodata,
    }
}

/// Split `src` into `n x n` tiles of `tile` pixels with `gdal_translate
/// -srcwin` (tiled DEFLATE), named `tile_RR_CC.tif`, into `dir`.
pub fn split_tiles(src: &Path, dir: &Path, n: usize, tile: usize, extra: &[&str]) {
    std::fs::create_dir_all(dir).expect("tile dir");
    for tr in 0..n {
        for tc in 0..n {
            let (c, r, t) = (
                (tc * tile).to_string(),
                (tr * tile).to_string(),
                tile.to_string(),
            );
            let mut args = vec!["-srcwin", &c, &r, &t, &t];
            args.extend_from_slice(extra);
            gdal_translate(src, &dir.join(format!("tile_{tr:02}_{tc:02}.tif")), &args);
        }
    }
}

/// Write a single-band Float32 GeoTIFF (`EPSG` code, geotransform, nodata)
/// through GDAL.
pub fn write_f32_geotiff(
    path: &Path,
    width: usize,
    height: usize,
    gt: [f64; 6],
    epsg: u32,
    data: &[f32],
    nodata: Option<f64>,
) {
    let driver = gdal::DriverManager::get_driver_by_name("GTiff").expect("GTiff driver");
    let opts = RasterCreationOptions::from_iter(["COMPRESS=DEFLATE", "PREDICTOR=3"]);
    let mut ds = driver
        .create_with_band_type_with_options::<f32, _>(path, width, height, 1, &opts)
        .expect("create GeoTIFF");
    ds.set_geo_transform(&gt).expect("set geotransform");
    let srs = gdal::spatial_ref::SpatialRef::from_epsg(epsg).expect("EPSG");
    ds.set_spatial_ref(&srs).expect("set srs");
    let mut band = ds.rasterband(1).expect("band");
    if let Some(nd) = nodata {
        band.set_no_data_value(Some(nd)).expect("nodata");
    }
    let mut buf = Buffer::new((width, height), data.to_vec());
    band.write((0, 0), (width, height), &mut buf)
        .expect("write");
}

/// Exact Euclidean distance from `p` to the polyline `pts` (2D).
pub fn distance_to_polyline(p: [f64; 2], pts: &[[f64; 2]]) -> f64 {
    let seg = |a: [f64; 2], b: [f64; 2]| {
        let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
        let l2 = ex * ex + ey * ey;
        let t = if l2 > 0.0 {
            (((p[0] - a[0]) * ex + (p[1] - a[1]) * ey) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (qx, qy) = (a[0] + t * ex, a[1] + t * ey);
        (p[0] - qx).hypot(p[1] - qy)
    };
    if pts.len() == 1 {
        return seg(pts[0], pts[0]);
    }
    pts.windows(2)
        .map(|w| seg(w[0], w[1]))
        .fold(f64::INFINITY, f64::min)
}

/// CRS coordinates of the centre of cell `(col, row)` of a north-up grid.
pub fn centre(gt: &[f64; 6], col: usize, row: usize) -> [f64; 2] {
    [
        gt[0] + (col as f64 + 0.5) * gt[1],
        gt[3] + (row as f64 + 0.5) * gt[5],
    ]
}
