//! Pixel to terrain point and back: `demsketch locate` answers which terrain
//! point (lon, lat, height, distance) a pixel of a view shows, and
//! [`project_point`] maps a terrain point to the pixel it appears at. The two
//! are inverse for every pixel that shows terrain.

use super::depth_buffer::{pick, TerrainHit};
use super::terrain::LocalTerrain;
use crate::view::{Camera, CameraModel, Georef, LocalFrame, ViewError};
use serde::Serialize;

/// A located terrain point, as `demsketch locate` prints it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Located {
    pub lon: f64,
    pub lat: f64,
    /// Height of the terrain point (DEM vertical datum), metres.
    pub height: f64,
    /// Distance from the eye, metres.
    pub distance: f64,
    /// Position in the DEM's CRS.
    pub x: f64,
    pub y: f64,
    /// DEM cell (column, row) of the hit.
    pub col: usize,
    pub row: usize,
}

/// The terrain point shown at pixel coordinates `(x, y)` of `camera`; `None`
/// when the pixel shows sky. A pixel outside the image is an error
/// ([`Camera::check_pixel`]; callers check it before any work too).
pub fn locate(
    terrain: &LocalTerrain,
    camera: &Camera,
    georef: &Georef,
    x: f64,
    y: f64,
) -> Result<Option<Located>, ViewError> {
    camera.check_pixel(x, y)?;
    let Some(h): Option<TerrainHit> = pick(terrain, camera, x, y) else {
        return Ok(None);
    };
    let (lon, lat) = georef.crs_to_lonlat(h.x, h.y)?;
    Ok(Some(Located {
        lon,
        lat,
        height: h.z,
        distance: h.distance,
        x: h.x,
        y: h.y,
        col: h.cell.0,
        row: h.cell.1,
    }))
}

/// Pixel coordinates at which the DEM point `(x, y)` (CRS) with true height
/// `h` appears in `camera` at the viewpoint of `frame`; `None` when behind.
/// (Occlusion is not checked: compare the depth buffer for that.)
pub fn project_point(
    frame: &LocalFrame,
    camera: &Camera,
    x: f64,
    y: f64,
    h: f64,
) -> Option<[f64; 2]> {
    camera.project(frame.crs_to_local(x, y, h))
}
