//! The map view's underlay (`serve --underlay FILE`): any georeferenced
//! raster GDAL opens (an orthophoto in RGB, a single-band scan or
//! classification, ...), reprojected and resampled by GDAL
//! (`GDALReprojectImage`, bilinear) onto the grid of the map's overview
//! ([`super::overview`]) in the DEM's CRS, and encoded once at start as an
//! RGBA PNG: three or more bands are drawn as red, green and blue (an
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
    gdal::raster::reproject(src, &dst)?;
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
