//! Sample types of DEM rasters and the conversion of decoded blocks into the
//! floating-point arrays the pipeline works on. Integer write-back rounds to
//! nearest and clamps, as GDAL does.

use serde::Serialize;
use tiff::decoder::DecodingResult;

/// The on-disk sample type of a DEM band (GDAL's names in `Display`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SampleType {
    Int8,
    UInt8,
    Int16,
    UInt16,
    Int32,
    UInt32,
    Float32,
    Float64,
}

impl SampleType {
    pub fn bytes(self) -> usize {
        match self {
            SampleType::Int8 | SampleType::UInt8 => 1,
            SampleType::Int16 | SampleType::UInt16 => 2,
            SampleType::Int32 | SampleType::UInt32 | SampleType::Float32 => 4,
            SampleType::Float64 => 8,
        }
    }

    /// GDAL's name (`gdalinfo` "type").
    pub fn gdal_name(self) -> &'static str {
        match self {
            SampleType::Int8 => "Int8",
            SampleType::UInt8 => "Byte",
            SampleType::Int16 => "Int16",
            SampleType::UInt16 => "UInt16",
            SampleType::Int32 => "Int32",
            SampleType::UInt32 => "UInt32",
            SampleType::Float32 => "Float32",
            SampleType::Float64 => "Float64",
        }
    }

    pub fn is_integer(self) -> bool {
        !matches!(self, SampleType::Float32 | SampleType::Float64)
    }

    /// Value range of integer types (`None` for floats).
    pub fn integer_range(self) -> Option<(f64, f64)> {
        Some(match self {
            SampleType::Int8 => (i8::MIN as f64, i8::MAX as f64),
            SampleType::UInt8 => (0.0, u8::MAX as f64),
            SampleType::Int16 => (i16::MIN as f64, i16::MAX as f64),
            SampleType::UInt16 => (0.0, u16::MAX as f64),
            SampleType::Int32 => (i32::MIN as f64, i32::MAX as f64),
            SampleType::UInt32 => (0.0, u32::MAX as f64),
            _ => return None,
        })
    }

    /// The value `v` as stored in this type: rounded to nearest (half away
    /// from zero) and clamped for integers, rounded to f32 for Float32.
    pub fn quantize(self, v: f64) -> f64 {
        match self.integer_range() {
            Some((lo, hi)) => v.round().clamp(lo, hi),
            None if self == SampleType::Float32 => v as f32 as f64,
            None => v,
        }
    }

    pub fn from_gdal(t: gdal::raster::GdalDataType) -> Option<SampleType> {
        use gdal::raster::GdalDataType as G;
        Some(match t {
            G::UInt8 => SampleType::UInt8,
            G::Int16 => SampleType::Int16,
            G::UInt16 => SampleType::UInt16,
            G::Int32 => SampleType::Int32,
            G::UInt32 => SampleType::UInt32,
            G::Float32 => SampleType::Float32,
            G::Float64 => SampleType::Float64,
            _ => return None,
        })
    }
}

impl std::fmt::Display for SampleType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.gdal_name())
    }
}

/// A floating-point type that windows are read into (`f32` for the
/// pipeline's height maps, `f64` for exact comparisons and integer types).
pub trait Sample: Copy + Send + Sync + Default + 'static {
    fn from_f64(v: f64) -> Self;
    fn to_f64(self) -> f64;
    fn nan() -> Self;
    /// Copy `n` samples of a decoded block, starting at `start`, into `out`.
    fn copy_from_block(block: &DecodingResult, start: usize, out: &mut [Self]);
}

macro_rules! copy_block {
    ($block:expr, $start:expr, $out:expr, $t:ty) => {{
        let n = $out.len();
        match $block {
            DecodingResult::U8(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::I8(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::U16(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::I16(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::U32(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::I32(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::U64(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::I64(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::F32(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::F64(v) => conv(&v[$start..$start + n], $out, |x| x as $t),
            DecodingResult::F16(v) => conv(&v[$start..$start + n], $out, |x| f32::from(x) as $t),
        }
    }};
}

#[inline]
fn conv<S: Copy, T>(src: &[S], out: &mut [T], f: impl Fn(S) -> T) {
    for (o, s) in out.iter_mut().zip(src) {
        *o = f(*s);
    }
}

impl Sample for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
    fn nan() -> Self {
        f32::NAN
    }
    fn copy_from_block(block: &DecodingResult, start: usize, out: &mut [Self]) {
        copy_block!(block, start, out, f32)
    }
}

impl Sample for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
    fn nan() -> Self {
        f64::NAN
    }
    fn copy_from_block(block: &DecodingResult, start: usize, out: &mut [Self]) {
        copy_block!(block, start, out, f64)
    }
}

/// Size in bytes of a decoded block.
pub fn decoded_bytes(block: &DecodingResult) -> usize {
    match block {
        DecodingResult::U8(v) => v.len(),
        DecodingResult::I8(v) => v.len(),
        DecodingResult::U16(v) => v.len() * 2,
        DecodingResult::I16(v) => v.len() * 2,
        DecodingResult::F16(v) => v.len() * 2,
        DecodingResult::U32(v) => v.len() * 4,
        DecodingResult::I32(v) => v.len() * 4,
        DecodingResult::F32(v) => v.len() * 4,
        DecodingResult::U64(v) => v.len() * 8,
        DecodingResult::I64(v) => v.len() * 8,
        DecodingResult::F64(v) => v.len() * 8,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_and_clamps_like_gdal() {
        assert_eq!(SampleType::Int16.quantize(12.5), 13.0);
        assert_eq!(SampleType::Int16.quantize(-12.5), -13.0);
        assert_eq!(SampleType::Int16.quantize(40000.0), 32767.0);
        assert_eq!(SampleType::UInt16.quantize(-3.0), 0.0);
        assert_eq!(SampleType::Float32.quantize(0.1), 0.1f32 as f64);
    }
}
