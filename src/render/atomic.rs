//! Atomic output for the renderer's files (PNG, depth TIFF, viewshed TIFF):
//! each is written to a temporary file in the destination's directory and
//! renamed over the destination only once complete, so an interrupted or
//! failed write never leaves a half-written file behind.

use super::RenderError;
use std::path::{Path, PathBuf};

/// Run `write` on a fresh temporary path beside `path`, then rename it to
/// `path`. On any error the temporary file is removed.
pub(crate) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), RenderError>,
) -> Result<(), RenderError> {
    let tmp = temp_path(path);
    let res = write(&tmp).and_then(|()| {
        std::fs::rename(&tmp, path).map_err(|e| RenderError::Write {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    });
    if res.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    res
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    path.with_file_name(format!(".{name}.{}-{nanos}.tmp", std::process::id()))
}
