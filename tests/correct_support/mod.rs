//! Helpers of the `correct_*` tests: rasters read by GDAL, bilinear
//! sampling, point in polygon and coordinate transforms done independently
//! of the library.
#![allow(dead_code)]

use std::path::Path;

use gdal::spatial_ref::{AxisMappingStrategy, CoordTransform, SpatialRef};

/// A raster read by GDAL: size, geotransform, band 1 as f64 (NaN = nodata).
pub struct Raster {
    pub w: usize,
    pub h: usize,
    pub gt: [f64; 6],
    pub v: Vec<f64>,
}

impl Raster {
    pub fn read(path: &Path) -> Raster {
        let ds = gdal::Dataset::open(path).expect("GDAL opens the file");
        let gt = ds.geo_transform().expect("geotransform");
        let band = ds.rasterband(1).expect("band 1");
        let (w, h) = band.size();
        let nd = band.no_data_value();
        let buf = band
            .read_as::<f64>((0, 0), (w, h), (w, h), None)
            .expect("GDAL reads the band");
        let v = buf
            .data()
            .iter()
            .map(|&x| {
                if Some(x) == nd || x < -1e30 {
                    f64::NAN
                } else {
                    x
                }
            })
            .collect();
        Raster { w, h, gt, v }
    }

    pub fn at(&self, c: usize, r: usize) -> f64 {
        self.v[r * self.w + c]
    }

    /// CRS to pixel space (north-up).
    pub fn pixel(&self, x: f64, y: f64) -> [f64; 2] {
        [(x - self.gt[0]) / self.gt[1], (y - self.gt[3]) / self.gt[5]]
    }

    /// Pixel space to CRS.
    pub fn crs(&self, p: [f64; 2]) -> [f64; 2] {
        [
            self.gt[0] + p[0] * self.gt[1],
            self.gt[3] + p[1] * self.gt[5],
        ]
    }

    /// Bilinear between cell centres at pixel-space `p`.
    pub fn bilinear(&self, p: [f64; 2]) -> Option<f64> {
        let (x, y) = (p[0] - 0.5, p[1] - 0.5);
        if x < 0.0 || y < 0.0 {
            return None;
        }
        let (c0, r0) = (x.floor() as usize, y.floor() as usize);
        let (fx, fy) = (x - c0 as f64, y - r0 as f64);
        let (c1, r1) = ((c0 + 1).min(self.w - 1), (r0 + 1).min(self.h - 1));
        if c0 >= self.w || r0 >= self.h {
            return None;
        }
        let v = self.at(c0, r0) * (1.0 - fx) * (1.0 - fy)
            + self.at(c1, r0) * fx * (1.0 - fy)
            + self.at(c0, r1) * (1.0 - fx) * fy
            + self.at(c1, r1) * fx * fy;
        (!v.is_nan()).then_some(v)
    }

    /// The 99th percentile of `|h(c) - h(n)|` over 4-neighbour pairs of
    /// valid cells: the DEM's own typical neighbour difference.
    pub fn neighbour_diff_p99(&self) -> f64 {
        let mut d = Vec::new();
        for r in 0..self.h {
            for c in 0..self.w {
                let a = self.at(c, r);
                for (cc, rr) in [(c + 1, r), (c, r + 1)] {
                    if cc < self.w && rr < self.h {
                        let b = self.at(cc, rr);
                        if !a.is_nan() && !b.is_nan() {
                            d.push((a - b).abs());
                        }
                    }
                }
            }
        }
        d.sort_by(|a, b| a.partial_cmp(b).unwrap());
        d[(d.len() as f64 * 0.99) as usize]
    }
}

/// WGS84 lon/lat to `epsg`, by GDAL/OSR.
pub fn lonlat_to(epsg: u32, lonlat: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut src = SpatialRef::from_epsg(4326).unwrap();
    src.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let mut dst = SpatialRef::from_epsg(epsg).unwrap();
    dst.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let t = CoordTransform::new(&src, &dst).unwrap();
    let mut xs: Vec<f64> = lonlat.iter().map(|p| p[0]).collect();
    let mut ys: Vec<f64> = lonlat.iter().map(|p| p[1]).collect();
    let mut zs = vec![0.0; xs.len()];
    t.transform_coords(&mut xs, &mut ys, &mut zs).unwrap();
    xs.into_iter().zip(ys).map(|(x, y)| [x, y]).collect()
}

/// `epsg` to WGS84 lon/lat, by GDAL/OSR.
pub fn to_lonlat(epsg: u32, xy: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut src = SpatialRef::from_epsg(epsg).unwrap();
    src.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let mut dst = SpatialRef::from_epsg(4326).unwrap();
    dst.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let t = CoordTransform::new(&src, &dst).unwrap();
    let mut xs: Vec<f64> = xy.iter().map(|p| p[0]).collect();
    let mut ys: Vec<f64> = xy.iter().map(|p| p[1]).collect();
    let mut zs = vec![0.0; xs.len()];
    t.transform_coords(&mut xs, &mut ys, &mut zs).unwrap();
    xs.into_iter().zip(ys).map(|(x, y)| [x, y]).collect()
}

/// Even-odd point in polygon.
pub fn inside(ring: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut inside = false;
    let n = ring.len();
    let mut j = n - 1;
    for i in 0..n {
        let (a, b) = (ring[i], ring[j]);
        if (a[1] > p[1]) != (b[1] > p[1])
            && p[0] < (b[0] - a[0]) * (p[1] - a[1]) / (b[1] - a[1]) + a[0]
        {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// The report written by `--report`, parsed.
pub fn report(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).expect("report written")).expect("report is JSON")
}

/// A GeoJSON FeatureCollection of `features`, with a legacy `crs` member
/// naming `epsg` when given.
pub fn collection(features: Vec<serde_json::Value>, epsg: Option<u32>) -> String {
    let mut fc = serde_json::json!({"type": "FeatureCollection", "features": features});
    if let Some(code) = epsg {
        fc["crs"] = serde_json::json!({"type": "name",
            "properties": {"name": format!("urn:ogc:def:crs:EPSG::{code}")}});
    }
    serde_json::to_string_pretty(&fc).unwrap()
}

/// Writes a single-band Float32 GeoTIFF (`epsg`, geotransform) through GDAL.
pub fn write_f32_geotiff(path: &Path, w: usize, h: usize, gt: [f64; 6], epsg: u32, data: &[f32]) {
    let driver = gdal::DriverManager::get_driver_by_name("GTiff").expect("GTiff driver");
    let mut ds = driver
        .create_with_band_type::<f32, _>(path, w, h, 1)
        .expect("create GeoTIFF");
    ds.set_geo_transform(&gt).expect("set geotransform");
    let srs = SpatialRef::from_epsg(epsg).expect("EPSG");
    ds.set_spatial_ref(&srs).expect("set srs");
    let mut band = ds.rasterband(1).expect("band");
    let mut buf = gdal::raster::Buffer::new((w, h), data.to_vec());
    band.write((0, 0), (w, h), &mut buf).expect("write");
}

/// How flat a river is across: bilinear along cross-sections of a
/// centreline (pixel space), each sampled at 21 points within `reach`
/// pixels of the centreline. `normal` holds the normals of every segment at
/// every twentieth of its length (ends included); `bend` the sections at
/// every interior vertex (both segments' normals and their bisector).
/// Sections whose centre lies within `exclude_m` of a knot (arc length,
/// metres) are counted apart.
#[derive(Debug, Default)]
pub struct Flatness {
    pub normal_worst: f64,
    pub normal_count: usize,
    pub bend_worst: f64,
    pub bend_count: usize,
    pub near_knots_worst: f64,
}

pub fn flatness(
    out: &Raster,
    line: &[[f64; 2]],
    knots: &[f64],
    reach: f64,
    exclude_m: f64,
) -> Flatness {
    let cell = out.gt[1];
    let spread = |c: [f64; 2], n: [f64; 2]| {
        let vals: Vec<f64> = (-10..=10)
            .filter_map(|j| {
                let d = j as f64 / 10.0 * reach;
                out.bilinear([c[0] + n[0] * d, c[1] + n[1] * d])
            })
            .collect();
        let (lo, hi) = vals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        hi - lo
    };
    let normal_of = |a: [f64; 2], b: [f64; 2]| {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len = dx.hypot(dy);
        [-dy / len, dx / len]
    };
    let near = |s: f64| knots.iter().any(|k| (k - s).abs() <= exclude_m);
    let mut f = Flatness::default();
    let mut s0 = 0.0;
    for (i, seg) in line.windows(2).enumerate() {
        let (a, b) = (seg[0], seg[1]);
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let n = normal_of(a, b);
        for k in 0..=20 {
            let t = k as f64 / 20.0;
            let c = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
            let sp = spread(c, n);
            if near(s0 + t * len * cell) {
                f.near_knots_worst = f.near_knots_worst.max(sp);
            } else {
                f.normal_worst = f.normal_worst.max(sp);
                f.normal_count += 1;
            }
        }
        s0 += len * cell;
        if i + 2 < line.len() {
            let n2 = normal_of(b, line[i + 2]);
            let bis = [n[0] + n2[0], n[1] + n2[1]];
            let l = bis[0].hypot(bis[1]);
            for d in [n, n2, [bis[0] / l, bis[1] / l]] {
                let sp = spread(b, d);
                if near(s0) {
                    f.near_knots_worst = f.near_knots_worst.max(sp);
                } else {
                    f.bend_worst = f.bend_worst.max(sp);
                    f.bend_count += 1;
                }
            }
        }
    }
    f
}

/// Runs `demsketch correct DEM --features F --out OUT --report REPORT`,
/// asserts that it succeeded, and returns the report.
pub fn correct_ok(
    dem: &Path,
    features: &Path,
    out: &Path,
    report_path: &Path,
) -> serde_json::Value {
    correct_succeeds(
        dem,
        features,
        out,
        &["--report", &report_path.to_string_lossy()],
    );
    report(report_path)
}

/// Runs `demsketch correct DEM --features F --out OUT` with `extra`
/// arguments and asserts that it succeeded.
pub fn correct_succeeds(dem: &Path, features: &Path, out: &Path, extra: &[&str]) {
    let (dem, features, out) = (
        dem.to_string_lossy(),
        features.to_string_lossy(),
        out.to_string_lossy(),
    );
    let mut args = vec!["correct", &dem, "--features", &features, "--out", &out];
    args.extend_from_slice(extra);
    let o = super::common::demsketch(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Splits `src` into an `n` x `n` tile set in `dir` (`tile_{row}_{col}.tif`,
/// `gdal_translate -srcwin`), for the seam tests.
pub fn split(src: &Path, dir: &Path, n: usize) {
    let r = Raster::read(src);
    for ty in 0..n {
        for tx in 0..n {
            let (x0, x1) = (r.w * tx / n, r.w * (tx + 1) / n);
            let (y0, y1) = (r.h * ty / n, r.h * (ty + 1) / n);
            let win = [x0, y0, x1 - x0, y1 - y0].map(|v| v.to_string());
            let dst = dir.join(format!("tile_{ty}_{tx}.tif"));
            super::common::gdal_translate(
                src,
                &dst,
                &["-srcwin", &win[0], &win[1], &win[2], &win[3]],
            );
        }
    }
}

/// A VRT (`gdalbuildvrt`) over the GeoTIFF tiles of `dir`, written to
/// `vrt`; returns how many tiles it holds.
pub fn vrt_of_tiles(dir: &Path, vrt: &Path) -> usize {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path().to_string_lossy().into_owned())
        .filter(|p| p.ends_with(".tif"))
        .collect();
    names.sort();
    let n = names.len();
    let mut args = vec!["-q".to_string(), vrt.to_string_lossy().into_owned()];
    args.extend(names);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    super::common::run("gdalbuildvrt", &args);
    n
}
