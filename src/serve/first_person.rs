//! First-person views for the browser, by the library's renderer: the
//! shaded view of a camera at a viewpoint with the view's silhouettes (red)
//! and visible ridge lines (yellow) drawn over it on request, the same
//! features as pixel polylines (JSON), the terrain point under a pixel, and
//! the viewshed from the viewpoint on the map overview's grid. The terrain
//! around the last viewpoint is kept ([`super::state::CachedScene`]), so
//! turning the camera only renders.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use super::overview::{encode_rgb, encode_rgba};
use super::state::{AppState, CachedScene, SceneKey};
use super::ServeError;
use crate::features::{
    detect_ridges, extract_silhouettes, RidgeNetwork, RidgeParams, SilhouetteParams,
};
use crate::render::{
    draw_polyline, locate, shade_into, viewshed, visible_polylines, DepthBuffer, Scene,
    ShadeOptions,
};
use crate::sketch::{CameraSpec, ViewpointSpec};
use crate::view::Camera;

/// Largest image side and pixel count a view may ask for.
pub const MAX_SIDE_PX: u32 = 4096;
pub const MAX_PIXELS: u64 = 4096 * 2304;

/// A pixel polyline of a view and whether it is part of the skyline.
type PixelCurve = (Vec<[f64; 2]>, bool);

/// A view as the page asks for it: the sketch file's viewpoint and camera.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewRequest {
    pub viewpoint: ViewpointSpec,
    pub camera: CameraSpec,
    /// What to draw over the picture: "silhouettes", "ridges".
    #[serde(default)]
    pub overlays: Vec<String>,
    /// For a locate request: the pixel.
    #[serde(default)]
    pub pixel: Option<[f64; 2]>,
}

/// The camera of `spec`, held to the sketch format's ranges
/// ([`CameraSpec::check_ranges`]: finite angles, sides of at least 1 px)
/// and refused when its image is larger than the app draws.
pub fn camera_of(spec: &CameraSpec) -> Result<Camera, ServeError> {
    spec.check_ranges("camera")
        .map_err(ServeError::BadRequest)?;
    if spec.width == 0
        || spec.height == 0
        || spec.width > MAX_SIDE_PX
        || spec.height > MAX_SIDE_PX
        || spec.width as u64 * spec.height as u64 > MAX_PIXELS
    {
        return Err(ServeError::BadRequest(format!(
            "camera: image {} x {} is outside 1..{MAX_SIDE_PX} px a side or over {MAX_PIXELS} pixels",
            spec.width, spec.height
        )));
    }
    Camera::new(
        spec.width as usize,
        spec.height as usize,
        spec.heading_deg,
        spec.pitch_deg,
        spec.roll_deg,
        spec.hfov_deg,
    )
    .map_err(|e| ServeError::BadRequest(e.to_string()))
}

fn key_of(vp: &ViewpointSpec) -> SceneKey {
    SceneKey {
        lon: vp.lon,
        lat: vp.lat,
        eye_height_m: vp.eye_height_m,
        alt_m: vp.alt_m,
    }
}

impl AppState {
    /// The terrain around `vp`: the cached one when the viewpoint is the
    /// same, else read from the DEM (within the maximum view distance).
    pub fn scene_for(&self, vp: &ViewpointSpec) -> Result<Arc<CachedScene>, ServeError> {
        let key = key_of(vp);
        if let Ok(guard) = self.scene.lock() {
            if let Some(s) = guard.as_ref().filter(|s| s.key == key) {
                return Ok(s.clone());
            }
        }
        vp.check_ranges("viewpoint")
            .map_err(ServeError::BadRequest)?;
        let viewpoint = vp.resolved();
        let height = viewpoint.height;
        let scene = Scene::open(
            &self.dem,
            &viewpoint,
            Some(self.config.max_distance_m),
            self.config.refraction,
        )
        .map_err(|e| ServeError::Unprocessable(e.to_string()))?;
        if let Some(problem) =
            crate::view::below_ground_problem("viewpoint alt_m", height, scene.frame.ground)
        {
            return Err(ServeError::Unprocessable(problem));
        }
        let Scene {
            window,
            window_offset,
            frame,
            terrain,
            ..
        } = scene;
        let cached = Arc::new(CachedScene {
            key,
            window,
            window_offset,
            frame,
            terrain,
            ridges: std::sync::OnceLock::new(),
        });
        if let Ok(mut guard) = self.scene.lock() {
            *guard = Some(cached.clone());
        }
        Ok(cached)
    }
}

impl CachedScene {
    /// The ridge network of the scene's window (computed once).
    pub fn ridges(&self) -> Result<&RidgeNetwork, ServeError> {
        self.ridges
            .get_or_init(|| {
                detect_ridges(&self.window, &RidgeParams::default()).map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|e| ServeError::Internal(format!("ridges: {e}")))
    }

    /// The visible parts of the ridge lines, as pixel polylines.
    fn visible_ridges(&self, depth: &DepthBuffer) -> Result<Vec<Vec<[f64; 2]>>, ServeError> {
        let net = self.ridges()?;
        let cell = self.terrain.frame.p[0][0].hypot(self.terrain.frame.p[1][0]);
        Ok(net
            .lines
            .iter()
            .flat_map(|l| visible_polylines(&self.terrain, depth, net.line_points(l), 2.0 * cell))
            .collect())
    }

    /// The view's silhouettes as pixel polylines (and whether each is skyline).
    fn silhouettes(&self, depth: &DepthBuffer) -> Result<Vec<PixelCurve>, ServeError> {
        let sil = extract_silhouettes(&self.terrain, depth, &SilhouetteParams::default())
            .map_err(|e| ServeError::Internal(format!("silhouettes: {e}")))?;
        Ok(sil.curves.iter().map(|c| (c.pixels(), c.skyline)).collect())
    }
}

/// Seconds each step of a request took, for the `Server-Timing` header.
pub type StepTimes = Vec<(&'static str, f64)>;

/// The shaded view of `req` as PNG, with the overlays asked for, and the
/// time of each step.
pub fn render_png(state: &AppState, req: &ViewRequest) -> Result<(Vec<u8>, StepTimes), ServeError> {
    let mut times = StepTimes::new();
    let mut t = std::time::Instant::now();
    let mut lap = |name: &'static str, times: &mut StepTimes| {
        times.push((name, t.elapsed().as_secs_f64()));
        t = std::time::Instant::now();
    };
    for o in &req.overlays {
        if !matches!(o.as_str(), "silhouettes" | "ridges") {
            return Err(ServeError::BadRequest(format!(
                "overlays: unknown overlay '{o}' (silhouettes, ridges)"
            )));
        }
    }
    let camera = camera_of(&req.camera)?;
    let scene = state.scene_for(&req.viewpoint)?;
    lap("scene", &mut times);
    let depth = state.render_depth(&scene.terrain, &camera);
    lap("render", &mut times);
    // Sun behind the viewer's right shoulder, as `demsketch view`.
    let opts = ShadeOptions {
        sun_azimuth_deg: camera.heading_deg + 135.0,
        ..ShadeOptions::default()
    };
    let mut rgb = state.take_picture();
    shade_into(&depth, &scene.terrain, &opts, &mut rgb);
    lap("shade", &mut times);
    let (w, h) = (camera.width, camera.height);
    let line = (w.max(h) as f64 / 800.0).clamp(1.0, 4.0);
    let want = |o: &str| req.overlays.iter().any(|x| x == o);
    if want("ridges") {
        for part in scene.visible_ridges(&depth)? {
            draw_polyline(&mut rgb, w, h, &part, [255, 214, 0], line);
        }
    }
    if want("silhouettes") {
        for (c, _) in scene.silhouettes(&depth)? {
            draw_polyline(&mut rgb, w, h, &c, [225, 30, 30], line);
        }
    }
    lap("overlays", &mut times);
    state.give_depth(depth);
    let png = encode_rgb(w, h, &rgb);
    state.give_picture(rgb);
    let png = png?;
    lap("png", &mut times);
    Ok((png, times))
}

/// A silhouette of a view for the page.
#[derive(Debug, Serialize)]
pub struct SilhouetteOut {
    pub skyline: bool,
    pub pixels: Vec<[f64; 2]>,
}

/// The features of a view as pixel polylines.
#[derive(Debug, Serialize)]
pub struct FeaturesOut {
    pub silhouettes: Vec<SilhouetteOut>,
    pub ridges: Vec<Vec<[f64; 2]>>,
    /// Per image column, the row of the skyline (null where sky is absent).
    pub skyline: Vec<Option<f64>>,
}

/// The silhouettes (and, when asked for as an overlay, the visible ridges)
/// of the view of `req`.
pub fn features(state: &AppState, req: &ViewRequest) -> Result<FeaturesOut, ServeError> {
    let camera = camera_of(&req.camera)?;
    let scene = state.scene_for(&req.viewpoint)?;
    let depth = state.render_depth(&scene.terrain, &camera);
    let silhouettes = scene
        .silhouettes(&depth)?
        .into_iter()
        .map(|(pixels, skyline)| SilhouetteOut { skyline, pixels })
        .collect();
    let ridges = if req.overlays.iter().any(|o| o == "ridges") {
        scene.visible_ridges(&depth)?
    } else {
        Vec::new()
    };
    let skyline = (0..depth.width)
        .map(|i| {
            (0..depth.height)
                .find(|&j| depth.depth_at(i, j).is_finite())
                .filter(|&j| j > 0)
                .map(|j| j as f64)
        })
        .collect();
    state.give_depth(depth);
    Ok(FeaturesOut {
        silhouettes,
        ridges,
        skyline,
    })
}

/// The terrain point under `req.pixel` (JSON of [`crate::render::Located`], or null for sky).
pub fn locate_pixel(state: &AppState, req: &ViewRequest) -> Result<serde_json::Value, ServeError> {
    let Some([x, y]) = req.pixel else {
        return Err(ServeError::BadRequest(
            "locate: give \"pixel\": [x, y]".into(),
        ));
    };
    let camera = camera_of(&req.camera)?;
    camera
        .check_pixel(x, y)
        .map_err(|e| ServeError::BadRequest(format!("locate: {e}")))?;
    let scene = state.scene_for(&req.viewpoint)?;
    let hit = state.with_georef(|g| {
        locate(&scene.terrain, &camera, g, x, y)
            .map_err(|e| ServeError::Unprocessable(e.to_string()))
    })?;
    serde_json::to_value(hit).map_err(|e| ServeError::Internal(e.to_string()))
}

/// The viewshed from the viewpoint of `req` (target on the ground) on the
/// overview's grid: an RGBA PNG, visible cells tinted, the rest clear.
pub fn viewshed_png(state: &AppState, req: &ViewRequest) -> Result<Vec<u8>, ServeError> {
    let scene = state.scene_for(&req.viewpoint)?;
    let vs = viewshed(&scene.terrain, &scene.window, 0.0);
    let ov = &state.overview;
    let mut rgba = vec![0u8; ov.width * ov.height * 4];
    let (c0, r0) = scene.window_offset;
    for j in 0..ov.height {
        for i in 0..ov.width {
            let (px, py) = ov.to_dem_pixel(i as f64 + 0.5, j as f64 + 0.5);
            let (wc, wr) = (px.floor() as i64 - c0, py.floor() as i64 - r0);
            if wc < 0 || wr < 0 || wc as usize >= vs.width || wr as usize >= vs.height {
                continue;
            }
            if vs.data[wr as usize * vs.width + wc as usize] == 255 {
                let p = (j * ov.width + i) * 4;
                rgba[p..p + 4].copy_from_slice(&[255, 200, 0, 150]);
            }
        }
    }
    encode_rgba(ov.width, ov.height, &rgba)
}
