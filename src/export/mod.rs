//! Exports of a DEM (typically one `demsketch edit` corrected) to the
//! formats web maps, GIS catalogues and 3D viewers read (`demsketch
//! export`):
//!
//! - [`xyz_tiles`]: Terrain-RGB ([`terrain_rgb`]) or Terrarium
//!   ([`terrarium`]) PNG tiles in Web Mercator ([`web_mercator`]), each
//!   tile warped by GDAL ([`tile_warp`]) and encoded ([`tile_encoding`]),
//!   for the whole DEM or only the tiles over an edit's change
//!   ([`change_mask`]).
//! - [`cog`]: a Cloud Optimized GeoTIFF through GDAL's COG driver.
//! - [`curves_geojson`]: the placed 3D curves of an edit report and the
//!   outline of the change ([`change_footprint`]) as GeoJSON.
//! - [`stac_item`]: a STAC item of the corrected product (raster,
//!   projection and processing extensions) with the edit's provenance.
//! - [`gltf_mesh`]: a triangle mesh of an area as binary glTF, in a local
//!   east-north-up frame.
//!
//! Every file goes through the project's atomic writers
//! ([`crate::raster::atomic_file`]); a tile tree is staged and renamed.
//! The DEM is read through GDAL ([`gdal_source`]) where GDAL does the
//! work, else through the tile layer.

pub mod change_footprint;
pub mod change_mask;
pub mod cog;
pub mod curves_geojson;
pub mod edit_report;
pub mod gdal_source;
pub mod gltf_mesh;
pub mod stac_item;
pub mod terrain_rgb;
pub mod terrarium;
pub mod tile_encoding;
pub mod tile_warp;
pub mod web_mercator;
pub mod xyz_tiles;

pub use tile_encoding::Encoding;

/// Errors of an export: one line naming the file and the problem.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Raster(#[from] crate::raster::RasterError),
    /// `--min-dz` out of its range ([`change_mask::check_min_dz`]).
    #[error(transparent)]
    MinDz(#[from] change_mask::MinDzError),
    /// `--bounds` unusable ([`gltf_mesh::parse_bounds`]).
    #[error(transparent)]
    Bounds(#[from] gltf_mesh::BoundsError),
    /// An input (DEM, report, dz raster, flag value) is unusable.
    #[error("{path}: {message}")]
    Input { path: String, message: String },
    /// An output cannot be written; nothing was.
    #[error("{path}: cannot write: {message}")]
    Write { path: String, message: String },
    /// A failure of the program rather than of the input.
    #[error("internal error: {0}")]
    Internal(String),
}

impl ExportError {
    /// True when the input is at fault (exit code 1).
    pub fn is_user_error(&self) -> bool {
        !matches!(self, ExportError::Internal(_))
    }
}
