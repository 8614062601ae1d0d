//! Rasters: GeoTIFF decoding, georeferencing, the tile layer and write-back.

mod crs;
mod error;
mod geotransform;
mod height_map;

pub use crs::Crs;
pub use error::RasterError;
pub use geotransform::GeoTransform;
pub use height_map::HeightMap;
