//! The pictures of a dry run, made when the page asks for them: for every
//! view of the sketch the shaded view before and after the edit with its
//! strokes drawn in red, and the map of the height change with its colour
//! scale ([`crate::edit::renders::height_change_map`]). They are what
//! `edit --dry-run --renders` writes, but a dry run of the server does not
//! render and encode them inside the edit (that was most of its time):
//! the edit writes its height change (`--dz`, a small GeoTIFF of the
//! deformation's window) and the pictures are drawn from it and from the
//! terrain the server already holds for the viewpoint
//! ([`super::state::CachedScene`]), once each, when first fetched.

use std::path::Path;

use super::overview::encode_rgb;
use super::state::AppState;
use super::ServeError;
use crate::edit::picture_stem;
use crate::edit::renders::height_change_map;
use crate::raster::{Dem, HeightMap, Window};
use crate::render::{draw_polyline, shade, DepthBuffer, LocalTerrain, ShadeOptions};
use crate::sketch::{SketchFile, ViewSpec};

/// The deformation of a dry run: its window in the DEM's grid and the
/// height change there (NaN: no change known).
pub struct HeightChange {
    pub window: Window,
    pub dz: HeightMap,
}

impl HeightChange {
    /// Read the edit's `--dz` file; `window` is the report's
    /// `deformation.window` (`[col, row, width, height]`).
    pub fn read(path: &Path, window: [i64; 4]) -> Result<HeightChange, ServeError> {
        let internal = |e: crate::raster::RasterError| ServeError::Internal(e.to_string());
        let dem = Dem::open(path).map_err(internal)?;
        let dz = dem.read_height_map(dem.full_window()).map_err(internal)?;
        let window = Window::new(
            window[0],
            window[1],
            window[2].max(0) as usize,
            window[3].max(0) as usize,
        );
        if (dz.width, dz.height) != (window.width, window.height) {
            return Err(ServeError::Internal(format!(
                "{}: {} x {} cells, the report's window is {} x {}",
                path.display(),
                dz.width,
                dz.height,
                window.width,
                window.height
            )));
        }
        Ok(HeightChange { window, dz })
    }

    /// `map` (a DEM window at `offset`) with the change added where it is
    /// known and not zero (what the edit renders as the edited terrain).
    fn applied_to(&self, map: &HeightMap, offset: (i64, i64)) -> HeightMap {
        let mut out = map.clone();
        let mw = Window::new(offset.0, offset.1, map.width, map.height);
        let Some(ov) = mw.intersect(&self.window) else {
            return out;
        };
        for r in ov.row..ov.row_end() {
            let src = ((r - self.window.row) as usize) * self.window.width;
            let dst = ((r - offset.1) as usize) * map.width;
            for c in ov.col..ov.col_end() {
                let m = self.dz.data[src + (c - self.window.col) as usize];
                let t = dst + (c - offset.0) as usize;
                if !out.data[t].is_nan() && m.is_finite() && m != 0.0 {
                    out.data[t] += m;
                }
            }
        }
        out
    }
}

/// The names of a dry run's pictures: per view `NAME_before.png` and
/// `NAME_after.png`, then `height_change.png`.
pub fn picture_names(sketch: &SketchFile) -> Vec<String> {
    let mut names = Vec::new();
    for v in &sketch.views {
        let stem = picture_stem(&v.name);
        names.push(format!("{stem}_before.png"));
        names.push(format!("{stem}_after.png"));
    }
    names.push("height_change.png".into());
    names
}

/// Draw picture `name` of a dry run of `sketch` whose change is `change`, as PNG.
pub fn draw(
    state: &AppState,
    sketch: &SketchFile,
    change: &HeightChange,
    name: &str,
) -> Result<Vec<u8>, ServeError> {
    if name == "height_change.png" {
        return height_change_picture(state, change);
    }
    for v in &sketch.views {
        let stem = picture_stem(&v.name);
        if name == format!("{stem}_before.png") {
            return view_picture(state, v, None);
        }
        if name == format!("{stem}_after.png") {
            return view_picture(state, v, Some(change));
        }
    }
    Err(ServeError::NotFound(format!("no picture '{name}'")))
}

/// The view `v` on the DEM (with `change` applied: after the edit), its
/// strokes in red, as the edit's pictures draw it.
fn view_picture(
    state: &AppState,
    v: &ViewSpec,
    change: Option<&HeightChange>,
) -> Result<Vec<u8>, ServeError> {
    let camera = super::first_person::camera_of(&v.camera)?;
    let scene = state.scene_for(&v.viewpoint)?;
    let max_d = Some(state.config.max_distance_m);
    // Built for the camera, as the edit's views are (the colour ramp
    // spans the heights the camera can see).
    let terrain = match change {
        None => LocalTerrain::in_view(&scene.window, &scene.frame, max_d, &camera),
        Some(ch) => {
            let map = ch.applied_to(&scene.window, scene.window_offset);
            LocalTerrain::in_view(&map, &scene.frame, max_d, &camera)
        }
    };
    let depth = DepthBuffer::render(&terrain, &camera);
    let mut rgb = shade(&depth, &terrain, &ShadeOptions::default());
    let (w, h) = (camera.width, camera.height);
    let thick = (w as f64 / 600.0).clamp(2.0, 4.0);
    for s in &v.strokes {
        draw_polyline(&mut rgb, w, h, &s.points, [230, 30, 30], thick);
    }
    encode_rgb(w, h, &rgb)
}

/// The height change over the deformation's window on a faint hillshade
/// of the heights after the edit, with its colour bar.
fn height_change_picture(state: &AppState, change: &HeightChange) -> Result<Vec<u8>, ServeError> {
    let base = state
        .dem
        .read_height_map(change.window)
        .map_err(|e| ServeError::Internal(e.to_string()))?;
    let (gx, gy) = base.geotransform.pixel_size();
    let cell_m = if base.crs.geographic {
        let lat = base.geotransform.0[3].to_radians();
        (
            gx.abs() * 111_320.0 * lat.cos().max(0.01),
            gy.abs() * 110_540.0,
        )
    } else {
        (gx.abs(), gy.abs())
    };
    let (w, h, rgb) = height_change_map(
        change.window.width,
        change.window.height,
        cell_m,
        &base.data,
        &change.dz.data,
    );
    encode_rgb(w, h, &rgb)
}
