//! True heights: how a DEM's stored values become metres. A band may store
//! its heights scaled and offset (GDAL's band scale/offset, e.g. an Int32
//! DEM in decimetres with scale 0.1) and in another unit than the metre (the
//! band unit, `ft` or `US survey foot`, or the unit of the vertical axis of
//! a compound or vertical CRS such as NAVD88 height (ftUS)). Everything
//! inside demsketch works in metres: the tile layer converts on read with
//! [`Vertical::to_metres`] and the write-back converts back with
//! [`Vertical::to_raw`], so that written files keep their scale, offset and
//! unit.

use serde::Serialize;

/// Where the vertical unit of a band was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum UnitSource {
    /// The band's unit (GDAL's `UNITTYPE`, `gdalinfo` "Unit Type").
    Band,
    /// The vertical axis of the file's compound or vertical CRS.
    Crs,
    /// Neither says: metres assumed.
    Default,
}

/// The vertical description of a band: stored value -> metres.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Vertical {
    /// GDAL band scale (1 when absent).
    pub scale: f64,
    /// GDAL band offset (0 when absent).
    pub offset: f64,
    /// The unit's name as the file gives it (`metre` when none is given).
    pub unit: String,
    /// Metres per unit.
    pub unit_to_metre: f64,
    /// Where the unit came from.
    pub unit_source: UnitSource,
    /// The vertical CRS's name (e.g. "NAVD88 height (ftUS)"), if any.
    pub datum: Option<String>,
}

impl Default for Vertical {
    fn default() -> Self {
        Vertical::metres()
    }
}

impl Vertical {
    /// Plain metres: scale 1, offset 0.
    pub fn metres() -> Vertical {
        Vertical {
            scale: 1.0,
            offset: 0.0,
            unit: "metre".into(),
            unit_to_metre: 1.0,
            unit_source: UnitSource::Default,
            datum: None,
        }
    }

    /// True when stored values already are metres (no conversion needed).
    pub fn is_identity(&self) -> bool {
        self.scale == 1.0 && self.offset == 0.0 && self.unit_to_metre == 1.0
    }

    /// A stored value in metres: `(raw * scale + offset) * unit_to_metre`.
    #[inline]
    pub fn to_metres(&self, raw: f64) -> f64 {
        (raw * self.scale + self.offset) * self.unit_to_metre
    }

    /// The stored value of a height in metres (inverse of
    /// [`Vertical::to_metres`]; before rounding to the sample type).
    #[inline]
    pub fn to_raw(&self, metres: f64) -> f64 {
        if self.is_identity() {
            return metres;
        }
        (metres / self.unit_to_metre - self.offset) / self.scale
    }

    /// [`Vertical::from_parts`] for the file at `path`, with its vertical
    /// CRS as read (name, and unit name with metres per unit); the error
    /// names the file.
    pub fn of_file(
        path: &std::path::Path,
        scale: Option<f64>,
        offset: Option<f64>,
        band_unit: &str,
        vertical_crs: Option<(String, Option<(String, f64)>)>,
    ) -> Result<Vertical, super::RasterError> {
        let (datum, crs_unit) = match vertical_crs {
            Some((name, unit)) => (Some(name), unit),
            None => (None, None),
        };
        Vertical::from_parts(scale, offset, band_unit, crs_unit, datum).map_err(|message| {
            super::RasterError::Crs {
                path: path.to_path_buf(),
                message,
            }
        })
    }

    /// Build from what a file says: band scale, offset and unit (empty =
    /// none), and the vertical CRS's name and (unit name, metres per unit).
    /// The band unit wins over the CRS's; a unit that is not a length, or a
    /// zero or non-finite scale, is an error (a message without the path).
    pub fn from_parts(
        scale: Option<f64>,
        offset: Option<f64>,
        band_unit: &str,
        crs_unit: Option<(String, f64)>,
        datum: Option<String>,
    ) -> Result<Vertical, String> {
        let scale = scale.unwrap_or(1.0);
        let offset = offset.unwrap_or(0.0);
        if !scale.is_finite() || scale == 0.0 {
            return Err(format!("band scale {scale} is not a usable factor"));
        }
        if !offset.is_finite() {
            return Err(format!("band offset {offset} is not a finite number"));
        }
        let band_unit = band_unit.trim();
        let (unit, unit_to_metre, unit_source) = if !band_unit.is_empty() {
            match unit_to_metre(band_unit) {
                Some(f) => (band_unit.to_string(), f, UnitSource::Band),
                // A band unit GDAL could not parse but the CRS gives the
                // unit: the CRS is authoritative then.
                None => match &crs_unit {
                    Some((n, f)) if *f > 0.0 && f.is_finite() => (n.clone(), *f, UnitSource::Crs),
                    _ => {
                        return Err(format!(
                            "band unit '{band_unit}' is not a length unit demsketch knows \
                             (metre, foot, US survey foot, centimetre, ...)"
                        ))
                    }
                },
            }
        } else {
            match crs_unit {
                Some((n, f)) if f > 0.0 && f.is_finite() => (n, f, UnitSource::Crs),
                _ => ("metre".to_string(), 1.0, UnitSource::Default),
            }
        };
        Ok(Vertical {
            scale,
            offset,
            unit,
            unit_to_metre,
            unit_source,
            datum,
        })
    }
}

/// Metres per unit for the names DEMs use for their band unit (GDAL's
/// `UNITTYPE`, PROJ and EPSG unit names and abbreviations).
pub fn unit_to_metre(name: &str) -> Option<f64> {
    const US_FOOT: f64 = 1200.0 / 3937.0;
    let n = name.trim().to_ascii_lowercase().replace(['_', '-'], " ");
    Some(match n.as_str() {
        "m" | "metre" | "metres" | "meter" | "meters" | "metre (m)" => 1.0,
        "ft" | "foot" | "feet" | "international foot" | "international feet" | "intl foot" => {
            0.3048
        }
        "us ft" | "usft" | "ftus" | "us survey foot" | "us survey feet" | "us foot" | "us feet"
        | "foot us" | "foot (us)" | "us survey ft" | "survey foot" => US_FOOT,
        "cm" | "centimetre" | "centimetres" | "centimeter" | "centimeters" => 0.01,
        "dm" | "decimetre" | "decimetres" | "decimeter" | "decimeters" => 0.1,
        "mm" | "millimetre" | "millimetres" | "millimeter" | "millimeters" => 0.001,
        "km" | "kilometre" | "kilometres" | "kilometer" | "kilometers" => 1000.0,
        _ => return None,
    })
}

/// The vertical CRS of a spatial reference (a vertical CRS itself or the
/// vertical part of a compound one): its name and (unit name, metres per
/// unit). `None` for a purely horizontal CRS.
pub fn vertical_of_srs(
    srs: &gdal::spatial_ref::SpatialRef,
) -> Option<(String, Option<(String, f64)>)> {
    if !(srs.is_compound() || srs.is_vertical()) {
        return None;
    }
    let name = srs.get_attr_value("VERT_CS", 0).ok().flatten()?;
    let unit = match (
        srs.get_attr_value("VERT_CS|UNIT", 0).ok().flatten(),
        srs.get_attr_value("VERT_CS|UNIT", 1)
            .ok()
            .flatten()
            .and_then(|f| f.trim().parse::<f64>().ok()),
    ) {
        (Some(n), Some(f)) => Some((n, f)),
        (Some(n), None) => unit_to_metre(&n).map(|f| (n, f)),
        _ => None,
    };
    Some((name, unit))
}

/// The vertical CRS named by an EPSG code (GeoTIFF's
/// `VerticalCSTypeGeoKey`): its name and unit. Looked up in PROJ's
/// database once per code and process (every tile of a directory names
/// the same one).
pub fn vertical_of_epsg(code: u32) -> Option<(String, Option<(String, f64)>)> {
    use std::collections::HashMap;
    use std::sync::{Mutex, OnceLock};
    type Found = Option<(String, Option<(String, f64)>)>;
    static CACHE: OnceLock<Mutex<HashMap<u32, Found>>> = OnceLock::new();
    let cache = CACHE.get_or_init(Default::default);
    if let Some(hit) = cache.lock().ok().and_then(|c| c.get(&code).cloned()) {
        return hit;
    }
    let found = crate::raster::crs::srs_from_epsg(code)
        .ok()
        .and_then(|srs| vertical_of_srs(&srs));
    if let Ok(mut c) = cache.lock() {
        c.entry(code).or_insert_with(|| found.clone());
    }
    found
}

/// Give band 1 of `dst` the scale, offset and unit of band 1 of `src`
/// (GDAL's generic copy to a MEM dataset drops the unit), so that a
/// re-encoded file keeps the meaning of its values.
pub fn keep_band_vertical(src: &gdal::Dataset, dst: &gdal::Dataset) -> gdal::errors::Result<()> {
    let s = src.rasterband(1)?;
    let mut d = dst.rasterband(1)?;
    if let Some(v) = s.scale() {
        d.set_scale(v)?;
    }
    if let Some(v) = s.offset() {
        d.set_offset(v)?;
    }
    let unit = s.unit();
    if !unit.is_empty() {
        let c = std::ffi::CString::new(unit).map_err(gdal::errors::GdalError::FfiNulError)?;
        // SAFETY: `d` is a live band of `dst`; GDAL copies the string.
        let rc = unsafe { gdal_sys::GDALSetRasterUnitType(d.c_rasterband(), c.as_ptr()) };
        if rc != gdal_sys::CPLErr::CE_None {
            return Err(gdal::errors::GdalError::CplError {
                class: rc,
                number: 0,
                msg: "GDALSetRasterUnitType failed".into(),
            });
        }
    }
    Ok(())
}

/// The band scale, offset and unit stored in a `GDAL_METADATA` TIFF tag
/// (items of band 0 with role `scale`, `offset`, `unittype`).
pub fn from_gdal_metadata(xml: &str) -> (Option<f64>, Option<f64>, String) {
    let (mut scale, mut offset, mut unit) = (None, None, String::new());
    for item in xml.split("<Item").skip(1) {
        let Some((attrs, rest)) = item.split_once('>') else {
            continue;
        };
        if attrs.ends_with('/') {
            continue;
        }
        let text = rest.split("</Item>").next().unwrap_or("");
        let attr = |key: &str| -> Option<String> {
            let pat = format!("{key}=\"");
            let start = attrs.find(&pat)? + pat.len();
            let end = attrs[start..].find('"')? + start;
            Some(unescape(&attrs[start..end]))
        };
        if attr("sample").as_deref() != Some("0") {
            continue;
        }
        let role = attr("role").unwrap_or_default().to_ascii_lowercase();
        let value = unescape(text.trim());
        match role.as_str() {
            "scale" => scale = value.parse::<f64>().ok(),
            "offset" => offset = value.parse::<f64>().ok(),
            "unittype" => unit = value,
            _ => {}
        }
    }
    (scale, offset, unit)
}

fn unescape(s: &str) -> String {
    s.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&amp;", "&")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_are_recognised() {
        assert_eq!(unit_to_metre("m"), Some(1.0));
        assert_eq!(unit_to_metre("Metre"), Some(1.0));
        assert_eq!(unit_to_metre("ft"), Some(0.3048));
        assert_eq!(unit_to_metre("US survey foot"), Some(1200.0 / 3937.0));
        assert_eq!(unit_to_metre("us-ft"), Some(1200.0 / 3937.0));
        assert_eq!(unit_to_metre("degree Celsius"), None);
    }

    #[test]
    fn conversion_round_trips() {
        let v = Vertical::from_parts(Some(0.1), Some(-5.0), "ft", None, None).expect("valid");
        assert_eq!(v.unit_source, UnitSource::Band);
        let m = v.to_metres(12345.0);
        assert!((m - (1234.5 - 5.0) * 0.3048).abs() < 1e-9);
        assert!((v.to_raw(m) - 12345.0).abs() < 1e-6);
        assert!(Vertical::metres().is_identity());
        assert!(Vertical::from_parts(Some(0.0), None, "", None, None).is_err());
        assert!(Vertical::from_parts(None, None, "kelvin", None, None).is_err());
    }

    #[test]
    fn gdal_metadata_items_are_parsed() {
        let xml = r#"<GDALMetadata>
  <Item name="OFFSET" sample="0" role="offset">2.5</Item>
  <Item name="SCALE" sample="0" role="scale">0.100000000000000006</Item>
  <Item name="UNITTYPE" sample="0" role="unittype">US survey foot</Item>
  <Item name="DEMSKETCH_PROVENANCE">a &amp; b</Item>
</GDALMetadata>"#;
        let (s, o, u) = from_gdal_metadata(xml);
        assert_eq!(s, Some(0.1));
        assert_eq!(o, Some(2.5));
        assert_eq!(u, "US survey foot");
    }
}
