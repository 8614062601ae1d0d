//! What a photo's EXIF says about where and how it was taken, for photo
//! tracing: the GPS position (and altitude, and the direction the camera
//! faced when the GPS recorded it), and the horizontal field of view from
//! the focal length, by its 35 mm equivalent (`FocalLengthIn35mmFilm`,
//! defined on the 35 mm frame's diagonal of 43.27 mm) or else by the
//! sensor's width (`FocalPlaneXResolution` and its unit with
//! `PixelXDimension`). Parsed with the `kamadak-exif` crate from the
//! first bytes of the file the page sends (the EXIF segment of a JPEG lies
//! in its first 64 KiB); a photo without EXIF, or without a usable tag,
//! gives `None` for what it lacks.

use exif::{In, Reader, Tag, Value};
use serde::Serialize;

use super::ServeError;

/// Most bytes of a photo the server reads for its EXIF.
pub const MAX_EXIF_BYTES: usize = 1024 * 1024;

/// Diagonal of the 35 mm film frame (36 x 24 mm), millimetres.
const FRAME_35MM_DIAGONAL_MM: f64 = 43.266_615;

/// What the EXIF of a photo gives.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct PhotoExif {
    /// GPS position, degrees (WGS84).
    pub lon: Option<f64>,
    pub lat: Option<f64>,
    /// GPS altitude above sea level, metres.
    pub alt_m: Option<f64>,
    /// Direction the camera faced (true north), degrees.
    pub heading_deg: Option<f64>,
    /// Focal length, millimetres, and its 35 mm equivalent.
    pub focal_mm: Option<f64>,
    pub focal_35mm: Option<f64>,
    /// Horizontal field of view for a picture `width` x `height`, degrees.
    pub hfov_deg: Option<f64>,
    /// Which tags gave the field of view: "35mm" or "sensor".
    pub hfov_from: Option<&'static str>,
}

/// The EXIF of `bytes` (the start of a JPEG, PNG, TIFF, ... file) for a
/// picture shown `width` x `height` pixels. Bytes without EXIF give an
/// empty answer; more than [`MAX_EXIF_BYTES`] are refused.
pub fn read(bytes: &[u8], width: u32, height: u32) -> Result<PhotoExif, ServeError> {
    if bytes.len() > MAX_EXIF_BYTES {
        return Err(ServeError::BadRequest(format!(
            "photo: send at most the first {MAX_EXIF_BYTES} bytes for its EXIF"
        )));
    }
    if width == 0 || height == 0 {
        return Err(ServeError::BadRequest(
            "photo: width and height must be positive".into(),
        ));
    }
    let Ok(exif) = Reader::new().read_from_container(&mut std::io::Cursor::new(bytes)) else {
        return Ok(PhotoExif::default());
    };
    let get = |tag: Tag| exif.get_field(tag, In::PRIMARY).map(|f| &f.value);
    let text = |tag: Tag| match get(tag) {
        Some(Value::Ascii(v)) => v
            .first()
            .map(|s| String::from_utf8_lossy(s).trim().to_uppercase()),
        _ => None,
    };
    let number = |tag: Tag| get(tag).and_then(first_number);
    let mut out = PhotoExif::default();
    let lat = get(Tag::GPSLatitude).and_then(degrees);
    let lon = get(Tag::GPSLongitude).and_then(degrees);
    if let (Some(lat), Some(lon)) = (lat, lon) {
        let lat = if text(Tag::GPSLatitudeRef).as_deref() == Some("S") {
            -lat
        } else {
            lat
        };
        let lon = if text(Tag::GPSLongitudeRef).as_deref() == Some("W") {
            -lon
        } else {
            lon
        };
        if (-90.0..=90.0).contains(&lat) && (-180.0..=180.0).contains(&lon) {
            out.lat = Some(lat);
            out.lon = Some(lon);
        }
    }
    out.alt_m = number(Tag::GPSAltitude).map(|a| {
        // GPSAltitudeRef 1: below sea level.
        if get(Tag::GPSAltitudeRef).and_then(|v| v.get_uint(0)) == Some(1) {
            -a
        } else {
            a
        }
    });
    // Only a true bearing (ref "T"): a magnetic one needs the declination.
    if text(Tag::GPSImgDirectionRef).as_deref() == Some("T") {
        out.heading_deg = number(Tag::GPSImgDirection).filter(|d| (0.0..=360.0).contains(d));
    }
    out.focal_mm = number(Tag::FocalLength).filter(|f| *f > 0.0);
    out.focal_35mm = number(Tag::FocalLengthIn35mmFilm).filter(|f| *f > 0.0);
    let (w, h) = (width as f64, height as f64);
    if let Some(f35) = out.focal_35mm {
        // The picture's width on the 35 mm frame's diagonal.
        let frame_w = FRAME_35MM_DIAGONAL_MM * w / w.hypot(h);
        out.hfov_deg = Some(hfov(frame_w, f35));
        out.hfov_from = Some("35mm");
    } else if let (Some(f), Some(sensor_w)) = (out.focal_mm, sensor_width_mm(&get)) {
        out.hfov_deg = Some(hfov(sensor_w, f));
        out.hfov_from = Some("sensor");
    }
    Ok(out)
}

/// Horizontal field of view of a frame `width_mm` wide behind a lens of
/// focal length `focal_mm`, degrees.
fn hfov(width_mm: f64, focal_mm: f64) -> f64 {
    2.0 * (width_mm / (2.0 * focal_mm)).atan().to_degrees()
}

/// The sensor's width from the focal plane's resolution and the image's
/// width in pixels, millimetres.
fn sensor_width_mm<'a>(get: &dyn Fn(Tag) -> Option<&'a Value>) -> Option<f64> {
    let res = get(Tag::FocalPlaneXResolution).and_then(first_number)?;
    let px = get(Tag::PixelXDimension).and_then(first_number)?;
    // FocalPlaneResolutionUnit: 2 inch (the default), 3 cm, 4 mm, 5 um.
    let unit_mm = match get(Tag::FocalPlaneResolutionUnit).and_then(|v| v.get_uint(0)) {
        None | Some(2) => 25.4,
        Some(3) => 10.0,
        Some(4) => 1.0,
        Some(5) => 0.001,
        Some(_) => return None,
    };
    let w = px / res * unit_mm;
    (res > 0.0 && w.is_finite() && w > 0.0 && w < 1000.0).then_some(w)
}

/// The first value of a numeric field.
fn first_number(v: &Value) -> Option<f64> {
    let x = match v {
        Value::Rational(r) => r.first().filter(|r| r.denom != 0).map(|r| r.to_f64()),
        Value::SRational(r) => r.first().filter(|r| r.denom != 0).map(|r| r.to_f64()),
        Value::Short(_) | Value::Long(_) | Value::Byte(_) => v.get_uint(0).map(f64::from),
        Value::Float(f) => f.first().map(|&x| x as f64),
        Value::Double(f) => f.first().copied(),
        _ => None,
    }?;
    x.is_finite().then_some(x)
}

/// Degrees from the three rationals (degrees, minutes, seconds) of a GPS
/// coordinate.
fn degrees(v: &Value) -> Option<f64> {
    let Value::Rational(r) = v else {
        return None;
    };
    if r.len() < 3 || r[..3].iter().any(|x| x.denom == 0) {
        return None;
    }
    let d = r[0].to_f64() + r[1].to_f64() / 60.0 + r[2].to_f64() / 3600.0;
    d.is_finite().then_some(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_exif_gives_nothing() {
        assert_eq!(read(b"not a photo", 100, 50).unwrap(), PhotoExif::default());
    }

    #[test]
    fn too_many_bytes_are_refused() {
        let big = vec![0u8; MAX_EXIF_BYTES + 1];
        assert!(matches!(read(&big, 10, 10), Err(ServeError::BadRequest(_))));
    }

    #[test]
    fn gps_and_35mm_focal_length_of_a_jpeg() {
        // 64 x 32 px, made by gdal_translate, tags written by exiftool
        // (fixtures/README.md).
        let jpeg = include_bytes!("../../fixtures/photos/exif_gps_35mm.jpg");
        let e = read(jpeg, 64, 32).unwrap();
        assert!((e.lon.unwrap() + 112.9).abs() < 1e-9, "{e:?}");
        assert!((e.lat.unwrap() - 37.4).abs() < 1e-9, "{e:?}");
        assert_eq!(e.alt_m, Some(1700.0));
        assert_eq!(e.heading_deg, Some(123.5));
        assert_eq!((e.focal_mm, e.focal_35mm), (Some(6.1), Some(28.0)));
        // 2:1 on the 43.27 mm diagonal: 38.70 mm across, 28 mm: 69.3 degrees.
        assert!((e.hfov_deg.unwrap() - 69.30).abs() < 0.01, "{e:?}");
        assert_eq!(e.hfov_from, Some("35mm"));
        // Only the first bytes are needed.
        assert_eq!(read(&jpeg[..jpeg.len().min(4096)], 64, 32).unwrap(), e);
    }

    #[test]
    fn field_of_view_of_the_35mm_frame() {
        // 36 mm across a 3:2 frame: 50 mm gives 39.6 degrees.
        let w = FRAME_35MM_DIAGONAL_MM * 3.0 / 13f64.sqrt();
        assert!((w - 36.0).abs() < 1e-3);
        assert!((hfov(36.0, 50.0) - 39.598).abs() < 1e-2);
    }
}
