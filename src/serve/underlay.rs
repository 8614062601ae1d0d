//! The map view's underlay (`serve --underlay FILE`): any georeferenced
//! raster GDAL opens (an orthophoto in RGB, a single-band scan or
//! classification, ...), reprojected and resampled by GDAL
//! (`GDALReprojectImage`, bilinear) onto the grid of the map's overview
//! ([`super::overview`]) in the DEM's CRS, and encoded once at start as an
//! RGBA PNG. A file much finer than the map (an orthophoto of any size) is
//! first read through GDAL's decimating reads of the part under the map
//! (averaged, from the file's overviews when it has them, as the DEM's
//! map overview is), so that only about one source pixel per map pixel is
//! warped and a large file opens in a fraction of a second: three or more bands are drawn as red, green and blue (an
//! alpha band as transparency), one or two as grey; 8-bit bands as they
//! are, others stretched between their 2nd and 98th percentile; nodata and
//! cells outside the file transparent. The page draws it with the
//! hillshade, blended by an opacity control.

use std::path::Path;

use gdal::raster::{ColorInterpretation, GdalDataType};
use gdal::{Dataset, DriverManager};

use super::overview::{encode_rgba, Overview};
use super::ServeError;
use crate::raster::Dem;

/// Most bands an underlay may have (each is warped onto the map's grid).
pub const MAX_BANDS: usize = 64;

/// The underlay on the map's grid.
pub struct Underlay {
    /// The file's name (for the page).
    pub name: String,
    pub width: usize,
    pub height: usize,
    /// RGBA PNG of `width` x `height`, the overview's size.
    pub png: Vec<u8>,
}

/// How the bands of the file become the picture's channels.
struct BandUse {
    /// Bands (0-based) shown as red, green, blue (one band: grey).
    colour: Vec<usize>,
    /// An alpha band, if the file has one.
    alpha: Option<usize>,
}

impl Underlay {
    /// Warp `path` onto the grid of `overview` (of `dem`). A file GDAL
    /// cannot open, without a georeference or without bands is refused
    /// with a one-line message naming it.
    pub fn build(path: &Path, dem: &Dem, overview: &Overview) -> Result<Underlay, ServeError> {
        let name = path.display().to_string();
        let bad = |m: String| ServeError::BadRequest(format!("{name}: underlay: {m}"));
        let first_line = |e: gdal::errors::GdalError| {
            e.to_string()
                .lines()
                .next()
                .unwrap_or("GDAL error")
                .to_string()
        };
        if !path.is_file() {
            return Err(bad("no such file".into()));
        }
        let src = Dataset::open(path)
            .map_err(|_| bad("not a raster GDAL can open (a GeoTIFF is expected)".into()))?;
        let n = src.raster_count();
        if n == 0 {
            return Err(bad("the file has no raster bands".into()));
        }
        if n > MAX_BANDS {
            return Err(bad(format!("{n} bands, at most {MAX_BANDS}")));
        }
        let has_crs = src
            .spatial_ref()
            .ok()
            .and_then(|s| s.to_wkt().ok())
            .is_some_and(|w| !w.is_empty());
        if src.geo_transform().is_err() || !has_crs {
            return Err(bad(
                "no georeference (a GeoTIFF or other raster with a CRS and a geotransform is needed)"
                    .into(),
            ));
        }
        let uses = band_use(&src).map_err(|e| bad(first_line(e)))?;
        let (w, h) = (overview.width, overview.height);
        let warped = warp_to_grid(&src, dem, overview).map_err(|e| bad(first_line(e)))?;
        let mut rgba = vec![0u8; w * h * 4];
        let scaled: Vec<Vec<u8>> = uses
            .colour
            .iter()
            .map(|&b| to_bytes(&warped[b], is_byte(&src, b)))
            .collect();
        for k in 0..w * h {
            let valid = uses.colour.iter().all(|&b| warped[b][k].is_finite());
            if !valid {
                continue;
            }
            let px = &mut rgba[k * 4..k * 4 + 4];
            for (c, out) in px.iter_mut().take(3).enumerate() {
                *out = scaled[c.min(scaled.len() - 1)][k];
            }
            px[3] = match uses.alpha {
                Some(a) => warped[a][k].clamp(0.0, 255.0) as u8,
                None => 255,
            };
        }
        let png = encode_rgba(w, h, &rgba)?;
        Ok(Underlay {
            name: path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or(name),
            width: w,
            height: h,
            png,
        })
    }
}

/// Which bands are colour and which alpha: by colour interpretation where
/// the file says, else the first three (or the first one) as colour.
fn band_use(src: &Dataset) -> gdal::errors::Result<BandUse> {
    let n = src.raster_count();
    let mut alpha = None;
    let mut colour = Vec::new();
    for b in 0..n {
        let band = src.rasterband(b + 1)?;
        if band.color_interpretation() == ColorInterpretation::AlphaBand && alpha.is_none() {
            alpha = Some(b);
        } else if colour.len() < 3 {
            colour.push(b);
        }
    }
    if colour.len() == 2 {
        colour.truncate(1);
    }
    if colour.is_empty() {
        // Only an alpha band: drawn as grey.
        colour.push(alpha.take().unwrap_or(0));
    }
    Ok(BandUse { colour, alpha })
}

fn is_byte(src: &Dataset, b: usize) -> bool {
    src.rasterband(b + 1)
        .map(|band| band.band_type() == GdalDataType::UInt8)
        .unwrap_or(false)
}

/// Every band of `src` on the overview's grid (f32, NaN where nothing
/// was warped or the source is nodata).
fn warp_to_grid(src: &Dataset, dem: &Dem, ov: &Overview) -> gdal::errors::Result<Vec<Vec<f32>>> {
    let n = src.raster_count();
    let (w, h) = (ov.width, ov.height);
    let mem = DriverManager::get_driver_by_name("MEM")?;
    let mut dst = mem.create_with_band_type::<f32, _>("", w, h, n)?;
    let g = dem.geotransform.0;
    dst.set_geo_transform(&[
        g[0],
        g[1] * ov.sx,
        g[2] * ov.sy,
        g[3],
        g[4] * ov.sx,
        g[5] * ov.sy,
    ])?;
    let mut srs = gdal::spatial_ref::SpatialRef::from_definition(&dem.crs.gdal_definition())?;
    // x = easting/longitude, as in the geotransform, whatever the CRS's axis order.
    srs.set_axis_mapping_strategy(gdal::spatial_ref::AxisMappingStrategy::TraditionalGisOrder);
    dst.set_spatial_ref(&srs)?;
    for b in 0..n {
        let mut band = dst.rasterband(b + 1)?;
        band.set_no_data_value(Some(f64::NAN))?;
        band.fill(f64::NAN, None)?;
    }
    match decimated_source(src, &srs, &dst, w, h)? {
        Some(small) => gdal::raster::reproject(&small, &dst)?,
        None => gdal::raster::reproject(src, &dst)?,
    }
    let mut out = Vec::with_capacity(n);
    for b in 0..n {
        let nodata = src.rasterband(b + 1)?.no_data_value();
        let buf = dst
            .rasterband(b + 1)?
            .read_as::<f32>((0, 0), (w, h), (w, h), None)?;
        let mut v = buf.into_shape_and_vec().1;
        if let Some(nd) = nodata.filter(|nd| !nd.is_nan()) {
            for x in v.iter_mut().filter(|x| (**x as f64 - nd).abs() < 1e-6) {
                *x = f32::NAN;
            }
        }
        out.push(v);
    }
    Ok(out)
}

/// Source pixels per map pixel under which the file is warped as it is.
const DECIMATE_ABOVE: f64 = 2.0;

/// The part of `src` under the map grid `dst` (`w` x `h`, CRS `dst_srs`),
/// read decimated to about one pixel per map pixel into a MEM dataset of
/// the same bands (nodata and colour interpretation kept, f32), when the
/// file has more than [`DECIMATE_ABOVE`] pixels per map pixel; `None`
/// when it has not, or when the map's points do not transform into the
/// file's CRS (the file is then warped as it is).
fn decimated_source(
    src: &Dataset,
    dst_srs: &gdal::spatial_ref::SpatialRef,
    dst: &Dataset,
    w: usize,
    h: usize,
) -> gdal::errors::Result<Option<Dataset>> {
    let Some((win, scale)) = source_window(src, dst_srs, dst, w, h) else {
        return Ok(None);
    };
    if scale <= DECIMATE_ABOVE {
        return Ok(None);
    }
    let [x0, y0, x1, y1] = win;
    let (ww, wh) = (x1 - x0, y1 - y0);
    let f = scale.floor();
    let (ow, oh) = (
        ((ww as f64 / f).ceil() as usize).max(1),
        ((wh as f64 / f).ceil() as usize).max(1),
    );
    let n = src.raster_count();
    let mem = DriverManager::get_driver_by_name("MEM")?;
    let mut out = mem.create_with_band_type::<f32, _>("", ow, oh, n)?;
    let g = src.geo_transform()?;
    let (sx, sy) = (ww as f64 / ow as f64, wh as f64 / oh as f64);
    out.set_geo_transform(&[
        g[0] + x0 as f64 * g[1] + y0 as f64 * g[2],
        g[1] * sx,
        g[2] * sy,
        g[3] + x0 as f64 * g[4] + y0 as f64 * g[5],
        g[4] * sx,
        g[5] * sy,
    ])?;
    out.set_spatial_ref(&src.spatial_ref()?)?;
    for b in 1..=n {
        let band = src.rasterband(b)?;
        let mut buf = band.read_as::<f32>(
            (x0 as isize, y0 as isize),
            (ww, wh),
            (ow, oh),
            Some(gdal::raster::ResampleAlg::Average),
        )?;
        let mut ob = out.rasterband(b)?;
        if let Some(nd) = band.no_data_value() {
            ob.set_no_data_value(Some(nd))?;
        }
        ob.set_color_interpretation(band.color_interpretation())?;
        ob.write((0, 0), (ow, oh), &mut buf)?;
    }
    Ok(Some(out))
}

/// The pixel window `[x0, y0, x1, y1)` of `src` under the map grid `dst`
/// (with a margin of a few map pixels) and the least number of source
/// pixels one map pixel spans, from a 9 x 9 lattice of the map's points
/// transformed into the file's pixels; `None` when they do not transform
/// or miss the file.
fn source_window(
    src: &Dataset,
    dst_srs: &gdal::spatial_ref::SpatialRef,
    dst: &Dataset,
    w: usize,
    h: usize,
) -> Option<([usize; 4], f64)> {
    use gdal::spatial_ref::{AxisMappingStrategy, CoordTransform};
    let mut src_srs = src.spatial_ref().ok()?;
    src_srs.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let to_src = CoordTransform::new(dst_srs, &src_srs).ok()?;
    let dg = dst.geo_transform().ok()?;
    let inv = invert_geo_transform(&src.geo_transform().ok()?)?;
    // Lattice points (k, l) and their neighbours one map pixel right and down.
    const N: usize = 9;
    let (mut xs, mut ys) = (Vec::new(), Vec::new());
    for l in 0..N {
        for k in 0..N {
            let (px, py) = (
                k as f64 / (N - 1) as f64 * (w as f64 - 1.0),
                l as f64 / (N - 1) as f64 * (h as f64 - 1.0),
            );
            for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)] {
                let (x, y) = (px + dx, py + dy);
                xs.push(dg[0] + x * dg[1] + y * dg[2]);
                ys.push(dg[3] + x * dg[4] + y * dg[5]);
            }
        }
    }
    let mut zs = vec![0.0; xs.len()];
    to_src.transform_coords(&mut xs, &mut ys, &mut zs).ok()?;
    let pix = |k: usize| {
        let (x, y) = (xs[k], ys[k]);
        (
            inv[0] + x * inv[1] + y * inv[2],
            inv[3] + x * inv[4] + y * inv[5],
        )
    };
    let mut scale = f64::INFINITY;
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for q in 0..N * N {
        let (p, r, d) = (pix(3 * q), pix(3 * q + 1), pix(3 * q + 2));
        for v in [p, r, d] {
            if !(v.0.is_finite() && v.1.is_finite()) {
                return None;
            }
        }
        let len = |a: (f64, f64)| (a.0 - p.0).hypot(a.1 - p.1);
        scale = scale.min(len(r)).min(len(d));
        lo = [lo[0].min(p.0), lo[1].min(p.1)];
        hi = [hi[0].max(p.0), hi[1].max(p.1)];
    }
    // The map's edge lies half a pixel outside its outer pixel centres; a
    // margin of a few map pixels more covers the bilinear kernel.
    let margin = 4.0 * scale;
    let (sw, sh) = src.rasterband(1).ok()?.size();
    let clip = |v: f64, n: usize| (v.max(0.0).min(n as f64)) as usize;
    let (x0, x1) = (
        clip((lo[0] - margin).floor(), sw),
        clip((hi[0] + margin).ceil(), sw),
    );
    let (y0, y1) = (
        clip((lo[1] - margin).floor(), sh),
        clip((hi[1] + margin).ceil(), sh),
    );
    (x1 > x0 && y1 > y0 && scale.is_finite()).then_some(([x0, y0, x1, y1], scale))
}

/// The inverse of an affine geotransform (`None` when singular).
fn invert_geo_transform(g: &[f64; 6]) -> Option<[f64; 6]> {
    let det = g[1] * g[5] - g[2] * g[4];
    if !(det.abs() > 0.0) || !det.is_finite() {
        return None;
    }
    let (a, b, c, d) = (g[5] / det, -g[2] / det, -g[4] / det, g[1] / det);
    Some([-(a * g[0] + b * g[3]), a, b, -(c * g[0] + d * g[3]), c, d])
}

/// One band as bytes: 8-bit values as they are, others stretched from
/// their 2nd to their 98th percentile (of the valid values).
fn to_bytes(v: &[f32], byte: bool) -> Vec<u8> {
    if byte {
        return v
            .iter()
            .map(|x| x.round().clamp(0.0, 255.0) as u8)
            .collect();
    }
    let mut valid: Vec<f32> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if valid.is_empty() {
        return vec![0; v.len()];
    }
    valid.sort_by(f32::total_cmp);
    let at = |q: f64| valid[((valid.len() - 1) as f64 * q).round() as usize] as f64;
    let (lo, hi) = (at(0.02), at(0.98));
    let span = if hi > lo { hi - lo } else { 1.0 };
    v.iter()
        .map(|&x| ((x as f64 - lo) / span * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect()
}
