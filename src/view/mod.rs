//! Viewpoints and cameras: lon/lat (WGS84) to the DEM's CRS through PROJ,
//! heading from true north, and the pinhole camera of `DESIGN.md`.
//!
//! Everything the renderer, the feature extractor and the sketch matcher do
//! in 3D happens in one documented frame, the *local frame* of a viewpoint
//! ([`LocalFrame`]): east-north-up metres centred at the eye, with the
//! apparent drop of earth curvature and refraction ([`Curvature`]) already
//! subtracted from terrain heights, so that lines of sight are straight lines.
//! A [`Viewpoint`] says where the eye is (lon/lat and a height), a
//! [`Georef`] resolves it against a DEM (PROJ, meridian convergence, metric
//! scale, eye altitude) and a [`Camera`] maps rays of that frame to pixels.

mod camera;
mod curvature;
mod settings;
mod viewpoint;

pub(crate) use camera::{cross, dot};
pub use camera::{Camera, CameraModel, PixelOutside};
pub use curvature::Curvature;
pub use settings::{
    check_min_fit, check_view_settings, distance_limit, MinFitError, SettingNames, ViewSettingError,
};
pub use viewpoint::{
    below_ground_problem, route_proj_messages, EyeHeight, Georef, LocalFrame, Viewpoint,
};

/// Errors of resolving a viewpoint or camera against a DEM. Messages are one
/// line naming the DEM or viewpoint and the problem.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("{dem}: viewpoint lon {lon}, lat {lat} lies outside the DEM")]
    OutsideDem { dem: String, lon: f64, lat: f64 },
    #[error("{dem}: viewpoint lon {lon}, lat {lat} lies on nodata")]
    OnNodata { dem: String, lon: f64, lat: f64 },
    #[error("{dem}: cannot map lon/lat to the DEM's CRS with PROJ: {message}")]
    Proj { dem: String, message: String },
    #[error("viewpoint lon {lon}, lat {lat}: not a valid WGS84 position")]
    BadViewpoint { lon: f64, lat: f64 },
    #[error("camera: {0}")]
    BadCamera(String),
    #[error(transparent)]
    Pixel(#[from] PixelOutside),
}
