//! The fuzz target of the native GeoTIFF decoder (`fuzz/`): parse bytes as
//! a GeoTIFF and decode every block, as `info`'s min/max scan does. Any
//! outcome but a panic, an abort or unbounded memory is a pass; errors are
//! the expected answer to most inputs.

use std::path::Path;

use super::GeoTiff;
use crate::raster::RasterError;

/// Parse `data` and decode each of its blocks; the number of samples
/// decoded, or the first error.
pub fn decode_all_blocks(data: &[u8]) -> Result<u64, RasterError> {
    let tiff = GeoTiff::from_bytes(Path::new("fuzz-input.tif"), data.to_vec())?;
    let mut samples = 0u64;
    for bi in 0..u32::try_from(tiff.layout.count()).unwrap_or(u32::MAX) {
        let block = tiff.decode_block(bi)?;
        samples += crate::raster::sample_type::decoded_bytes(&block) as u64
            / tiff.sample_type.bytes() as u64;
    }
    Ok(samples)
}
