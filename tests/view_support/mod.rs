//! Shared helpers of the `view_*` tests: load a fixture through GDAL (the
//! reference reader) into a `HeightMap`, and run the reference tools.
#![allow(dead_code)]

use demsketch::raster::{Crs, GeoTransform, HeightMap};
use std::path::{Path, PathBuf};

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// Read band 1 of `path` with GDAL, nodata as NaN.
pub fn load(path: &Path) -> HeightMap {
    let ds = gdal::Dataset::open(path).expect("open fixture");
    let band = ds.rasterband(1).expect("band 1");
    let (w, h) = band.size();
    let buf = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .expect("read");
    let nodata = band.no_data_value();
    let data: Vec<f32> = buf
        .data()
        .iter()
        .map(|&v| match nodata {
            Some(nd) if v == nd || (nd.is_nan() && v.is_nan()) => f32::NAN,
            Some(nd) if nd < -1e30 && v < -1e30 => f32::NAN,
            _ => v as f32,
        })
        .collect();
    let gt = ds.geo_transform().expect("geotransform");
    let sr = ds.spatial_ref().expect("srs");
    let epsg = sr.auth_code().ok().map(|c| c as u32);
    HeightMap {
        width: w,
        height: h,
        data,
        geotransform: GeoTransform(gt),
        crs: Crs {
            epsg,
            wkt: sr.to_wkt().unwrap_or_default(),
            proj: None,
            geographic: sr.is_geographic(),
        },
    }
}

pub fn have_tool(name: &str) -> bool {
    std::process::Command::new(name)
        .arg("--version")
        .output()
        .map(|o| o.status.success() || !o.stdout.is_empty() || !o.stderr.is_empty())
        .unwrap_or(false)
}

/// A synthetic north-up metric height map (CRS units metres, EPSG:32612 so
/// PROJ can resolve viewpoints on it).
pub fn synthetic(w: usize, h: usize, cell: f64, f: impl Fn(f64, f64) -> f64) -> HeightMap {
    let x0 = 500_000.0;
    let y0 = 4_200_000.0;
    let mut data = vec![0f32; w * h];
    for r in 0..h {
        for c in 0..w {
            let x = (c as f64 + 0.5) * cell;
            let y = (r as f64 + 0.5) * cell;
            data[r * w + c] = f(x, y) as f32;
        }
    }
    HeightMap {
        width: w,
        height: h,
        data,
        geotransform: GeoTransform::north_up(x0, y0, cell, cell),
        crs: Crs {
            epsg: Some(32612),
            wkt: String::new(),
            proj: None,
            geographic: false,
        },
    }
}
