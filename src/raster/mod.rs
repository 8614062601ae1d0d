//! Rasters: GeoTIFF decoding, georeferencing, the tile layer and write-back.

pub(crate) mod crs;
mod error;
mod geotransform;
mod height_map;

pub use crs::Crs;
pub use error::RasterError;
pub use geotransform::GeoTransform;
pub use height_map::HeightMap;
pub mod geotiff;
pub(crate) mod sample_type;
pub use sample_type::{Sample, SampleType};
pub(crate) mod alloc;
mod block_cache;
mod tile_layer;
mod window;
pub use tile_layer::{read_height_map, Dem, LayerKind, Tile, TileSource};
pub use window::{Window, WindowData};
mod lonlat_bounds;
pub use lonlat_bounds::lonlat_bounds;
pub mod vertical;
pub use vertical::Vertical;
mod write_back;
pub use write_back::{rfc3339_now, Destination, Provenance, WriteReport, PROVENANCE_KEY};
pub mod atomic_file;
pub mod block_patch;
pub mod edit_lock;
pub mod gdal_errors;
pub mod journal;
pub mod output_format;
pub mod overviews;
pub mod path_check;
pub mod provenance;
pub mod pyramid;
pub mod sidecars;
pub use output_format::WriteOptions;
pub use provenance::ProvenanceRecord;
