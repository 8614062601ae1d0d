//! The map view's picture: the DEM decimated to at most a given number of
//! pixels on its longest side, read through GDAL's decimating reads of each
//! tile file (which use the file's overviews when it has them, so a DEM of
//! any size opens quickly), shaded (height tint times a hillshade lit from
//! the north-west) and encoded once as an RGBA PNG (nodata transparent).
//! Overview pixel `(i, j)` covers the DEM pixels `[i * sx, (i + 1) * sx) x
//! [j * sy, (j + 1) * sy)`.

use gdal::raster::ResampleAlg;

use super::ServeError;
use crate::raster::{Dem, TileSource};
use crate::view::Georef;

/// The decimated DEM and its picture.
pub struct Overview {
    pub width: usize,
    pub height: usize,
    /// DEM pixels per overview pixel, across and down.
    pub sx: f64,
    pub sy: f64,
    /// Heights in metres, NaN for nodata, row-major.
    pub heights: Vec<f32>,
    /// Smallest and largest valid height.
    pub min_max: Option<(f32, f32)>,
    /// The shaded picture (PNG, RGBA).
    pub png: Vec<u8>,
    /// Some tile file has no overviews, so its every cell was read (a
    /// large DEM then opens slowly: `gdaladdo` is the remedy).
    pub read_in_full: bool,
}

impl Overview {
    /// Decimate `dem` to at most `max_px` pixels on its longest side.
    pub fn build(dem: &Dem, max_px: usize) -> Result<Overview, ServeError> {
        let s = (dem.width.max(dem.height) as f64 / max_px.max(16) as f64).max(1.0);
        let width = ((dem.width as f64 / s).round() as usize).max(1);
        let height = ((dem.height as f64 / s).round() as usize).max(1);
        let (sx, sy) = (
            dem.width as f64 / width as f64,
            dem.height as f64 / height as f64,
        );
        let mut heights = vec![f32::NAN; width * height];
        let mut read_in_full = false;
        for tile in &dem.tiles {
            let had_overviews = read_tile(tile, sx, sy, width, height, &mut heights)?;
            read_in_full |= !had_overviews && (sx > 1.5 || sy > 1.5);
        }
        let min_max = heights.iter().filter(|v| v.is_finite()).fold(
            None,
            |a: Option<(f32, f32)>, &v| match a {
                None => Some((v, v)),
                Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
            },
        );
        let cell_m = cell_metres(dem).map(|(x, y)| (x * sx, y * sy));
        let rgba = shade_map(
            width,
            height,
            &heights,
            min_max,
            cell_m.unwrap_or((1.0, 1.0)),
        );
        let png = encode_rgba(width, height, &rgba)?;
        Ok(Overview {
            width,
            height,
            sx,
            sy,
            heights,
            min_max,
            png,
            read_in_full,
        })
    }

    /// The DEM pixel (fractional) at overview pixel coordinates `(x, y)`.
    pub fn to_dem_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        (x * self.sx, y * self.sy)
    }

    /// Overview pixel coordinates of DEM pixel `(px, py)`.
    pub fn from_dem_pixel(&self, px: f64, py: f64) -> (f64, f64) {
        (px / self.sx, py / self.sy)
    }
}

/// Read the overview pixels whose centres fall in `tile` by one decimating
/// read of the tile's file through GDAL; whether the file has overviews.
fn read_tile(
    tile: &crate::raster::Tile,
    sx: f64,
    sy: f64,
    width: usize,
    height: usize,
    out: &mut [f32],
) -> Result<bool, ServeError> {
    let e = tile.extent;
    let first = |start: i64, s: f64| ((start as f64 / s - 0.5).ceil().max(0.0)) as usize;
    let (i0, i1) = (first(e.col, sx), first(e.col_end(), sx).min(width));
    let (j0, j1) = (first(e.row, sy), first(e.row_end(), sy).min(height));
    if i0 >= i1 || j0 >= j1 {
        return Ok(true);
    }
    // The tile's pixels under those overview pixels.
    let clamp = |v: f64, n: usize| (v.round().max(0.0) as usize).min(n);
    let x0 = clamp(i0 as f64 * sx - e.col as f64, e.width);
    let x1 = clamp(i1 as f64 * sx - e.col as f64, e.width)
        .max(x0 + 1)
        .min(e.width);
    let y0 = clamp(j0 as f64 * sy - e.row as f64, e.height);
    let y1 = clamp(j1 as f64 * sy - e.row as f64, e.height)
        .max(y0 + 1)
        .min(e.height);
    let (ow, oh) = (i1 - i0, j1 - j0);
    let name = tile.path.display().to_string();
    let err = |m: String| ServeError::Internal(format!("{name}: overview: {m}"));
    let read = |ds: &gdal::Dataset| -> Result<(Vec<f64>, bool), ServeError> {
        let band = ds.rasterband(1).map_err(|e| err(e.to_string()))?;
        let has_overviews = band.overview_count().is_ok_and(|n| n > 0);
        let alg = if sx > 1.5 || sy > 1.5 {
            ResampleAlg::Average
        } else {
            ResampleAlg::NearestNeighbour
        };
        let buf = band
            .read_as::<f64>(
                (x0 as isize, y0 as isize),
                (x1 - x0, y1 - y0),
                (ow, oh),
                Some(alg),
            )
            .map_err(|e| err(e.to_string()))?;
        Ok((buf.into_shape_and_vec().1, has_overviews))
    };
    let (raw, has_overviews) = match &tile.source {
        TileSource::Gdal(ds) => {
            let ds = ds
                .lock()
                .map_err(|_| err("the dataset's lock is poisoned".into()))?;
            read(&ds)?
        }
        TileSource::Tiff(_) => {
            let ds = gdal::Dataset::open(&tile.path).map_err(|e| err(e.to_string()))?;
            read(&ds)?
        }
    };
    let nodata = tile.nodata.map(|v| tile.sample_type.quantize(v));
    for j in 0..oh {
        for i in 0..ow {
            let v = raw[j * ow + i];
            let is_nodata =
                v.is_nan() || nodata.is_some_and(|n| v == n || (n.is_nan() && v.is_nan()));
            if !is_nodata {
                out[(j0 + j) * width + i0 + i] = tile.vertical.to_metres(v) as f32;
            }
        }
    }
    Ok(has_overviews)
}

/// Size of a DEM cell in metres (across, down) at the DEM's centre.
fn cell_metres(dem: &Dem) -> Option<(f64, f64)> {
    let geo = Georef::for_crs(&dem.crs, &dem.path.display().to_string()).ok()?;
    let (cx, cy) = (dem.width as f64 / 2.0, dem.height as f64 / 2.0);
    let ll = |px: f64, py: f64| {
        let (x, y) = dem.geotransform.pixel_to_crs(px, py);
        geo.crs_to_lonlat(x, y).ok()
    };
    let c = ll(cx, cy)?;
    let e = ll(cx + 1.0, cy)?;
    let s = ll(cx, cy + 1.0)?;
    let d = |a: (f64, f64), b: (f64, f64)| great_circle_m(a.0, a.1, b.0, b.1);
    Some((d(c, e).max(1e-3), d(c, s).max(1e-3)))
}

/// Distance between two lon/lat points on a sphere of the earth's mean
/// radius, metres (good to a fraction of a percent for map shading).
pub fn great_circle_m(lon1: f64, lat1: f64, lon2: f64, lat2: f64) -> f64 {
    let (p1, p2) = (lat1.to_radians(), lat2.to_radians());
    let dp = p2 - p1;
    let dl = (lon2 - lon1).to_radians();
    let a = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * 6_371_008.8 * a.sqrt().asin()
}

/// Height tint: lowland green to rock brown to snow white.
fn tint(t: f64) -> [f64; 3] {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [86.0, 140.0, 80.0]),
        (0.3, [168.0, 178.0, 110.0]),
        (0.6, [176.0, 138.0, 98.0]),
        (0.85, [206.0, 196.0, 186.0]),
        (1.0, [252.0, 252.0, 252.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    for w in STOPS.windows(2) {
        let ((a, ca), (b, cb)) = (w[0], w[1]);
        if t <= b {
            let u = (t - a) / (b - a);
            return [0, 1, 2].map(|k| ca[k] + (cb[k] - ca[k]) * u);
        }
    }
    STOPS[4].1
}

/// RGBA of the tinted hillshade (nodata transparent).
fn shade_map(
    w: usize,
    h: usize,
    z: &[f32],
    min_max: Option<(f32, f32)>,
    cell_m: (f64, f64),
) -> Vec<u8> {
    let (lo, hi) = min_max
        .map(|(a, b)| (a as f64, b as f64))
        .unwrap_or((0.0, 1.0));
    let range = (hi - lo).max(1e-6);
    let at = |i: usize, j: usize| z[j * w + i] as f64;
    // Light from azimuth 315 (north-west), 45 degrees up.
    let (az, alt) = (315f64.to_radians(), 45f64.to_radians());
    let light = [alt.cos() * az.sin(), alt.cos() * az.cos(), alt.sin()];
    let mut rgba = vec![0u8; w * h * 4];
    for j in 0..h {
        for i in 0..w {
            let v = at(i, j);
            if !v.is_finite() {
                continue;
            }
            let (i0, i1) = (i.saturating_sub(1), (i + 1).min(w - 1));
            let (j0, j1) = (j.saturating_sub(1), (j + 1).min(h - 1));
            let pick = |a: f64, b: f64| if b.is_finite() { b } else { a };
            let dzdx =
                (pick(v, at(i1, j)) - pick(v, at(i0, j))) / (cell_m.0 * (i1 - i0).max(1) as f64);
            // Rows go south: north is -y.
            let dzdy =
                (pick(v, at(i, j0)) - pick(v, at(i, j1))) / (cell_m.1 * (j1 - j0).max(1) as f64);
            let n = [-dzdx, -dzdy, 1.0];
            let len = (n[0] * n[0] + n[1] * n[1] + 1.0).sqrt();
            let lambert = ((n[0] * light[0] + n[1] * light[1] + n[2] * light[2]) / len).max(0.0);
            let shade = 0.35 + 0.75 * lambert;
            let c = tint((v - lo) / range);
            let p = (j * w + i) * 4;
            for k in 0..3 {
                rgba[p + k] = (c[k] * shade).clamp(0.0, 255.0) as u8;
            }
            rgba[p + 3] = 255;
        }
    }
    rgba
}

/// Encode RGBA bytes as PNG (the fastest compression, `Up` filter and
/// fdeflate: pictures for the page, encoded per request).
pub fn encode_rgba(width: usize, height: usize, rgba: &[u8]) -> Result<Vec<u8>, ServeError> {
    encode(width, height, rgba, png::ColorType::Rgba)
}

/// Encode RGB bytes as PNG (the fastest compression, as [`encode_rgba`]).
pub fn encode_rgb(width: usize, height: usize, rgb: &[u8]) -> Result<Vec<u8>, ServeError> {
    encode(width, height, rgb, png::ColorType::Rgb)
}

fn encode(
    width: usize,
    height: usize,
    bytes: &[u8],
    color: png::ColorType,
) -> Result<Vec<u8>, ServeError> {
    // About a third of the raw size: one growth of the buffer at most.
    let mut out = Vec::with_capacity(bytes.len() / 3 + 1024);
    let err = |e: png::EncodingError| ServeError::Internal(format!("PNG: {e}"));
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fastest);
        let mut wr = enc.write_header().map_err(err)?;
        wr.write_image_data(bytes).map_err(err)?;
        wr.finish().map_err(err)?;
    }
    Ok(out)
}
