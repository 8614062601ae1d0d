//! Terrain features that strokes are matched to: the visible silhouettes of a
//! view and the ridge lines of the terrain (section 5.1 of Tassé et al.).
//!
//! - [`ridges`]: ridge network of the DEM by PPA with a maximum-height spanning
//!   forest, as 3D polylines in the DEM's CRS.
//! - [`silhouettes`]: visible occlusion boundaries of a rendered view, linked
//!   into polylines with T-junctions, each sample carrying its pixel, depth
//!   and 3D terrain point.
//! - [`geojson`]: export of features as GeoJSON LineStrings (lon, lat, z)
//!   with kind, id, length and, for silhouettes, the image polyline.

mod candidates;
pub mod geojson;
pub mod ridges;
pub mod silhouettes;
mod spanning_forest;

pub use ridges::{detect_ridges, RidgeLine, RidgeNetwork, RidgeNode, RidgeParams};
pub use silhouettes::{
    extract_silhouettes, extract_silhouettes_reusing, extract_silhouettes_where, reach_rows,
    ColumnSamples, CurveEnd, Reuse, Silhouette, SilhouetteParams, SilhouetteSample, Silhouettes,
    TJunction,
};

/// Errors of feature extraction and export.
#[derive(Debug, thiserror::Error)]
pub enum FeatureError {
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    #[error("invalid input: {0}")]
    InvalidInput(String),
    #[error("too large: {0}")]
    TooLarge(String),
    #[error("coordinate transformation: {0}")]
    Projection(String),
    #[error("{path}: {message}")]
    Write {
        path: std::path::PathBuf,
        message: String,
    },
}
