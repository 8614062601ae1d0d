//! Atomic, verified output for the renderer's files (PNG, depth TIFF,
//! viewshed TIFF): each is written into a staging directory beside the
//! destination ([`crate::raster::atomic_file::replace_file`]: exclusive,
//! unpredictable name, GDAL failures captured), read back and compared with
//! what was meant, and renamed over the destination only then, so a full
//! disk or a failed write never leaves a half-written or wrong file, and
//! the destination keeps its old bytes.

use super::RenderError;
use std::path::Path;

/// Run `write` on a fresh temporary path beside `path`, check the result
/// with `verify`, then rename it to `path`. On any error `path` is left as
/// it was and the temporary file is removed; the error names `path`.
pub(crate) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), RenderError>,
    verify: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), RenderError> {
    let prefix = format!("{}: cannot write: ", path.display());
    crate::raster::atomic_file::replace_file(
        path,
        |tmp| {
            write(tmp).map_err(|e| {
                let mut m = e.to_string();
                while let Some(rest) = m.strip_prefix(&prefix) {
                    m = rest.to_string();
                }
                m
            })
        },
        verify,
    )
    .map_err(|message| RenderError::Write {
        path: path.display().to_string(),
        message,
    })
}

/// Band 1 of the raster at `tmp`, read by GDAL, must be `width` x `height`
/// and equal `expected` (NaN equal to NaN).
pub(crate) fn verify_band<T>(
    tmp: &Path,
    width: usize,
    height: usize,
    expected: &[T],
) -> Result<(), String>
where
    T: gdal::raster::GdalType + PartialEq + Copy,
{
    let ds = gdal::Dataset::open(tmp).map_err(|e| format!("GDAL cannot open it: {e}"))?;
    if ds.raster_size() != (width, height) {
        return Err(format!(
            "its size is {:?}, not {width} x {height}",
            ds.raster_size()
        ));
    }
    let band = ds.rasterband(1).map_err(|e| e.to_string())?;
    let got = band
        .read_as::<T>((0, 0), (width, height), (width, height), None)
        .map_err(|e| format!("GDAL cannot read it: {e}"))?;
    #[allow(clippy::eq_op)]
    let same = |a: T, b: T| a == b || (a != a && b != b);
    if got.data().len() != expected.len()
        || got.data().iter().zip(expected).any(|(&a, &b)| !same(a, b))
    {
        return Err("its values differ from those written".into());
    }
    Ok(())
}
