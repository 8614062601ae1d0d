//! The one error type of the raster layer. Every variant names the file it is
//! about, and its message is a single line a GIS user can act on.

use std::path::PathBuf;

/// Errors of reading, georeferencing, tiling and writing DEMs.
#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a TIFF file ({detail})")]
    NotTiff { path: PathBuf, detail: String },
    /// A tile parsed at open and mapped only when first read was replaced
    /// or rewritten in between.
    #[error("{path}: the file changed since it was opened (replaced or rewritten by another program): run again once it is written")]
    ChangedSinceOpened { path: PathBuf },
    #[error("{path}: corrupt or truncated TIFF: {detail}")]
    Corrupt { path: PathBuf, detail: String },
    #[error("{path}: unsupported {what}")]
    Unsupported { path: PathBuf, what: String },
    /// Something the native GeoTIFF decoder does not do but GDAL may
    /// (a compression, a CRS it cannot build from GeoKeys): the tile layer
    /// reads such files through GDAL instead.
    #[error("{path}: unsupported {what}")]
    NotNative { path: PathBuf, what: String },
    #[error(
        "{path}: no georeference (no ModelTiepoint/ModelPixelScale or ModelTransformation tag)"
    )]
    NoGeoreference { path: PathBuf },
    #[error("{path}: {width} x {height} {sample} pixels need {bytes} bytes, more than the memory budget of {budget} bytes")]
    TooLarge {
        path: PathBuf,
        width: u64,
        height: u64,
        sample: String,
        bytes: u64,
        budget: u64,
    },
    #[error("{path}: does not fit the tile grid of {reference}: {what}")]
    TileMismatch {
        path: PathBuf,
        reference: PathBuf,
        what: String,
    },
    #[error("{path}: no GeoTIFF tiles in this directory")]
    EmptyDirectory { path: PathBuf },
    #[error("{path}: window {what} lies outside the {width} x {height} raster")]
    OutOfBounds {
        path: PathBuf,
        what: String,
        width: usize,
        height: usize,
    },
    #[error("{path}: GDAL: {message}")]
    Gdal { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Crs { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Write { path: PathBuf, message: String },
}

impl RasterError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        RasterError::Io {
            path: path.into(),
            source,
        }
    }
    pub(crate) fn gdal(path: impl Into<PathBuf>, e: impl std::fmt::Display) -> Self {
        RasterError::Gdal {
            path: path.into(),
            message: e.to_string().lines().next().unwrap_or("").to_string(),
        }
    }
    /// True for errors caused by the input (exit code 1), false for internal
    /// failures.
    pub fn is_user_error(&self) -> bool {
        true
    }
}
