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
