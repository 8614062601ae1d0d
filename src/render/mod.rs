//! First-person rendering of a DEM: depth buffer, shaded image and viewshed.
//!
//! A [`LocalTerrain`] holds the part of the DEM within the maximum view
//! distance in a viewpoint's local frame; [`DepthBuffer::render`] rasterises its
//! triangles exactly at the pixel centres; [`shade`] turns a depth buffer
//! into a picture (lighting + distance haze) and [`write_png`] saves it;
//! [`viewshed`] computes which DEM cells the eye sees and
//! [`write_viewshed_tiff`] writes it on the DEM's grid like `gdal_viewshed`;
//! [`locate`] answers "which terrain point is at this pixel" and
//! [`project_point`] the reverse; [`visible_polylines`] projects 3D curves
//! (ridges) into a view, keeping what the eye sees. [`Scene`] sets all of this up on a tiled
//! DEM of any size, reading only the window within the maximum view distance.

mod atomic;
mod cast_memo;
mod depth_buffer;
mod far_layers;
mod horizon;
mod level_of_detail;
mod locate;
mod overlay;
mod scene;
mod shaded_image;
mod strip_columns;
mod terrain;
mod triangle_raster;
mod vertex_heights;
mod viewshed;

pub use depth_buffer::{pick, DepthBuffer, TerrainHit, SKY};
pub use far_layers::{FarLayers, FarRing};
pub use level_of_detail::{LodPlan, LOD_MIN_NEAR_M};
pub use locate::{locate, project_point, Located};
pub use overlay::visible_polylines;
pub use scene::{FarRingsToRead, Scene};
pub use shaded_image::{
    depth_for_file, draw_polyline, shade, shade_into, write_depth_tiff, write_png, ShadeOptions,
    DEPTH_NODATA,
};
#[doc(hidden)]
pub use terrain::acceleration_bits;
pub use terrain::{LocalTerrain, RayHit};
pub use triangle_raster::PATCH_TOLERANCE_PX;
pub use vertex_heights::VertexHeights;
pub use viewshed::{
    check_target_height, eye_frame, viewshed, viewshed_exact, viewshed_from_dem,
    viewshed_from_file, viewshed_rays, write_viewshed_tiff, write_viewshed_tiff_with,
    TargetHeightError, Viewshed, VIEWSHED_TIFF_OPTIONS,
};

/// Errors of rendering and writing views. One line naming the file and the problem.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    View(#[from] crate::view::ViewError),
    #[error(transparent)]
    Raster(#[from] crate::raster::RasterError),
    #[error("{path}: cannot write: {message}")]
    Write { path: String, message: String },
    #[error(transparent)]
    TargetHeight(#[from] TargetHeightError),
}
