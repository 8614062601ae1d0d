//! Bounds of a raster in WGS84 longitude/latitude, through PROJ, with the
//! edges densified so that curved projected edges are covered.

use super::{Crs, GeoTransform};

/// `[west, south, east, north]` in degrees WGS84 of a `width` x `height`
/// raster, or `None` when the CRS is unknown to PROJ.
pub fn lonlat_bounds(
    crs: &Crs,
    gt: &GeoTransform,
    width: usize,
    height: usize,
) -> Option<[f64; 4]> {
    let def = crs.proj_definition();
    if def.is_empty() {
        return None;
    }
    let to_ll = proj::Proj::new_known_crs(&def, "EPSG:4326", None).ok()?;
    let n = 20;
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let (w, h) = (width as f64, height as f64);
        for (px, py) in [(t * w, 0.0), (t * w, h), (0.0, t * h), (w, t * h)] {
            let (x, y) = gt.pixel_to_crs(px, py);
            if let Ok((lon, lat)) = to_ll.convert((x, y)) {
                b = [b[0].min(lon), b[1].min(lat), b[2].max(lon), b[3].max(lat)];
            }
        }
    }
    b.iter().all(|v| v.is_finite()).then_some(b)
}
