//! Setting up a view on a DEM of any size: resolve the viewpoint through
//! PROJ, read only the window of the tile layer within the maximum view
//! distance, and build the [`LocalTerrain`] that rendering, locating and
//! visibility use. This is the one entry point the command line (and the
//! edit pipeline) needs to go from "DEM + lon/lat" to something to render.

use super::far_layers::{FarLayers, FarRing};
use super::level_of_detail::LodPlan;
use super::{LocalTerrain, RenderError};
use crate::raster::{Dem, HeightMap, Window};
use crate::view::{Georef, LocalFrame, ViewError, Viewpoint};

/// What [`Scene::open_wedge`] reads, found before reading.
struct WedgePlan {
    georef: Georef,
    /// The grid of the square around the eye, and its size.
    gt: crate::raster::GeoTransform,
    size: (usize, usize),
    /// The wedge's box: its origin in the square, and in the DEM.
    c0: usize,
    r0: usize,
    win: Window,
    /// The frame on the square's grid, resolved with any ground (for
    /// planning: its cells and eye, not its heights).
    probe: LocalFrame,
}

/// The far rings of a level-of-detail scene, planned and not yet read
/// ([`Scene::open_wedge_lod_deferred`]): what [`LodPlan::build_rings`]
/// takes besides the DEM.
#[derive(Clone)]
pub struct FarRingsToRead {
    lod: LodPlan,
    /// The view's frame on the whole DEM's grid.
    frame_abs: LocalFrame,
    camera: crate::view::Camera,
    /// The cell of the DEM where the exact terrain's window starts.
    origin: (i64, i64),
}

impl FarRingsToRead {
    /// `terrain` (the scene's exact terrain) with the rings read from
    /// `dem` (the DEM the scene was opened on) as its far layers.
    pub fn add_to(&self, terrain: LocalTerrain, dem: &Dem) -> Result<LocalTerrain, RenderError> {
        Ok(terrain.with_far_layers(self.read(dem)?))
    }

    /// The rings read from `dem`, to join the scene's exact terrain
    /// ([`LocalTerrain::with_far_layers`]).
    pub fn read(&self, dem: &Dem) -> Result<Vec<FarRing>, RenderError> {
        self.lod
            .build_rings(dem, &self.frame_abs, &self.camera, self.origin)
    }
}

/// A viewpoint resolved on a DEM, with the terrain around it.
pub struct Scene {
    /// The DEM window that was read (whole DEM without a maximum distance).
    pub window: HeightMap,
    /// Where the window lies in the DEM's grid.
    pub window_offset: (i64, i64),
    pub georef: Georef,
    pub frame: LocalFrame,
    pub terrain: LocalTerrain,
}

impl Scene {
    /// Resolve `vp` on `dem`, reading only the cells within `max_distance`
    /// metres (`None`: the whole DEM), with refraction coefficient `k`.
    pub fn open(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
    ) -> Result<Scene, RenderError> {
        Self::open_for(dem, vp, max_distance, k, None)
    }

    /// Like [`Scene::open`], with the terrain built only where `camera` can
    /// see ([`LocalTerrain::in_view`]): for work that only renders and casts
    /// along that camera's rays (not a viewshed).
    pub fn open_in_view(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<Scene, RenderError> {
        Self::open_for(dem, vp, max_distance, k, Some(camera))
    }

    /// Like [`Scene::open_in_view`], reading only the cells the terrain
    /// keeps: the camera's horizontal wedge within the maximum distance
    /// (its bounding box, [`LocalTerrain::extent_in`]), not the whole
    /// square around the eye. The scene's window is that box. The terrain
    /// is the one [`Scene::open_in_view`] builds (the same vertices, with
    /// the same bits: the frame is resolved on the square's grid and moved
    /// by whole cells), for a fraction of the reading where the view looks
    /// across a large DEM. For work that renders and casts along the
    /// camera's rays only (`view` without a viewshed).
    pub fn open_wedge(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<Scene, RenderError> {
        let max_d = crate::view::distance_limit(max_distance);
        let plan = Self::wedge_plan(dem, vp, max_d, k, camera)?;
        let (window, frame, georef, win) = Self::read_wedge(dem, vp, k, plan)?;
        let terrain = LocalTerrain::over(&window, &frame, max_d);
        Ok(Scene {
            window,
            window_offset: (win.col, win.row),
            georef,
            frame,
            terrain,
        })
    }

    /// The window [`Scene::open_wedge`] reads, found without reading any
    /// height: for checking sizes before the work.
    pub fn wedge_window(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<Window, RenderError> {
        let max_d = crate::view::distance_limit(max_distance);
        Ok(Self::wedge_plan(dem, vp, max_d, k, camera)?.win)
    }

    /// Like [`Scene::open_wedge`], with a level of detail where the view
    /// reaches far ([`super::level_of_detail`]): the window, and the
    /// terrain's own grid, stop at the plan's exact reach, and the rings
    /// beyond, read coarser, are the terrain's far layers. A view within
    /// the exact reach is [`Scene::open_wedge`]'s, bit for bit.
    ///
    /// `reuse`: the far layers of an earlier scene of this view (an edit's
    /// second pass reads the DEM through the first's result), taken instead
    /// of reading the rings again where they serve
    /// ([`FarLayers::serve`]: the same eye, and no changed cell of the
    /// DEM's overlay within their reach).
    pub fn open_wedge_lod(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
        reuse: Option<&FarLayers>,
    ) -> Result<Scene, RenderError> {
        Self::open_wedge_lod_within(dem, vp, max_distance, k, camera, reuse, None)
    }

    /// [`Scene::open_wedge_lod`] with the exact terrain cut at
    /// `exact_cells` cells from the eye ([`LodPlan::new_within`]: a ring
    /// of the DEM's own cells between it and the plan's exact reach);
    /// `None`: the same.
    pub fn open_wedge_lod_within(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
        reuse: Option<&FarLayers>,
        exact_cells: Option<f64>,
    ) -> Result<Scene, RenderError> {
        let (scene, rings) =
            Self::open_wedge_lod_deferred(dem, vp, max_distance, k, camera, reuse, exact_cells)?;
        scene.with_rings(dem, rings)
    }

    /// [`Scene::open_wedge_lod_within`] with the far rings not yet read:
    /// the scene's terrain without the far layers it is to have, and what
    /// reads them ([`FarRingsToRead`]; `None` where it has none to read,
    /// or took `reuse`'s). [`Scene::with_rings`] then makes
    /// [`Scene::open_wedge_lod_within`]'s scene, bit for bit: the caller
    /// may read the rings beside other work (an edit reads them while it
    /// detects the ridges of the exact terrain).
    #[allow(clippy::too_many_arguments)]
    pub fn open_wedge_lod_deferred(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
        reuse: Option<&FarLayers>,
        exact_cells: Option<f64>,
    ) -> Result<(Scene, Option<FarRingsToRead>), RenderError> {
        Self::open_lod(dem, vp, max_distance, k, camera, reuse, exact_cells, |_| {
            None
        })
    }

    /// This scene with `rings` read from `dem` as its terrain's far layers
    /// (none: as it is).
    pub fn with_rings(
        mut self,
        dem: &Dem,
        rings: Option<FarRingsToRead>,
    ) -> Result<Scene, RenderError> {
        if let Some(r) = rings {
            self.terrain = r.add_to(self.terrain, dem)?;
        }
        Ok(self)
    }

    /// Like [`Scene::open_wedge_lod`] for a picture (`demsketch view`):
    /// without a maximum distance the whole DEM is in view, and the rings
    /// reach the farthest cell of the camera's wedge (its box's farthest
    /// corner). A view whose wedge lies within the exact reach is
    /// [`Scene::open_wedge`]'s, bit for bit, as is every view with
    /// `max_distance` within it.
    pub fn open_view_lod(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<Scene, RenderError> {
        let (scene, rings) =
            Self::open_lod(dem, vp, max_distance, k, camera, None, None, |plan| {
                Some(farthest_corner_m(plan))
            })?;
        scene.with_rings(dem, rings)
    }

    /// [`Scene::open_wedge_lod`] and [`Scene::open_view_lod`]: the rings
    /// reach `max_distance`, or without one `unbounded_reach` of the
    /// wedge's plan (`None`: no rings).
    #[allow(clippy::too_many_arguments)]
    fn open_lod(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
        reuse: Option<&FarLayers>,
        exact_cells: Option<f64>,
        unbounded_reach: impl Fn(&WedgePlan) -> Option<f64>,
    ) -> Result<(Scene, Option<FarRingsToRead>), RenderError> {
        let max_d = crate::view::distance_limit(max_distance);
        let plan = Self::wedge_plan(dem, vp, max_d, k, camera)?;
        let reach = max_d.or_else(|| unbounded_reach(&plan));
        match LodPlan::new_within(&plan.probe, camera, reach, exact_cells) {
            Some(lod) => Self::open_planned_lod(dem, vp, max_d, k, camera, lod, reuse),
            None => Ok((Self::open_wedge(dem, vp, max_distance, k, camera)?, None)),
        }
    }

    /// The scene of a level-of-detail plan: the wedge's box read at the
    /// DEM's resolution out to the plan's exact reach (on the square of
    /// `max_d` around the eye, the whole DEM for `None`), the rings beyond
    /// as the terrain's far layers (`reuse`'s where they serve; else
    /// returned to be read, [`FarRingsToRead`]).
    fn open_planned_lod(
        dem: &Dem,
        vp: &Viewpoint,
        max_d: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
        lod: LodPlan,
        reuse: Option<&FarLayers>,
    ) -> Result<(Scene, Option<FarRingsToRead>), RenderError> {
        let plan = Self::wedge_plan_within(dem, vp, max_d, Some(lod.near_m), k, camera)?;
        let (window, frame, georef, win) = Self::read_wedge(dem, vp, k, plan)?;
        let mut frame_abs = frame;
        frame_abs.eye_pixel = (
            frame.eye_pixel.0 + win.col as f64,
            frame.eye_pixel.1 + win.row as f64,
        );
        let near = LocalTerrain::over(&window, &frame, Some(lod.near_m));
        let ks: Vec<usize> = lod.rings.iter().map(|r| r.0).collect();
        let (terrain, rings) =
            match reuse.filter(|r| r.serve(&frame, &frame_abs, &ks, dem.overlay_window())) {
                Some(layers) => (near.with_shared_far_layers(layers), None),
                None => (
                    near,
                    Some(FarRingsToRead {
                        lod,
                        frame_abs,
                        camera: *camera,
                        origin: (win.col, win.row),
                    }),
                ),
            };
        let scene = Scene {
            window,
            window_offset: (win.col, win.row),
            georef,
            frame,
            terrain,
        };
        Ok((scene, rings))
    }

    /// Read a wedge's box and resolve the eye on it: the heights, the
    /// frame (on the box's grid), the georeference and the box in the DEM.
    fn read_wedge(
        dem: &Dem,
        vp: &Viewpoint,
        k: f64,
        plan: WedgePlan,
    ) -> Result<(HeightMap, LocalFrame, Georef, Window), RenderError> {
        let WedgePlan {
            georef,
            gt,
            size,
            c0,
            r0,
            win,
            ..
        } = plan;
        let window = dem.read_height_map(win)?;
        // The ground under the eye from the wedge's cells (it holds the eye
        // and the cells around it), at the square's pixel moved by whole
        // cells: the same bilinear weights.
        let ground = |px: f64, py: f64| window.bilinear(px - c0 as f64, py - r0 as f64);
        let frame = georef
            .local_frame_on(vp, &gt, size, &ground, k)?
            .shifted(c0, r0);
        Ok((window, frame, georef, win))
    }

    /// What [`Scene::open_wedge_lod`] reads, found without reading any
    /// height: the window at the DEM's resolution, and the cells of the
    /// coarser rings (0 without a level of detail).
    pub fn wedge_cells(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<(Window, u64), RenderError> {
        let max_d = crate::view::distance_limit(max_distance);
        let plan = Self::wedge_plan(dem, vp, max_d, k, camera)?;
        let Some(lod) = LodPlan::new(&plan.probe, camera, max_d) else {
            return Ok((plan.win, 0));
        };
        let near = Self::wedge_plan_within(dem, vp, max_d, Some(lod.near_m), k, camera)?;
        let square = Self::window_of(dem, &near.georef, vp.lon, vp.lat, max_d)?;
        let mut frame_abs = near.probe;
        frame_abs.eye_pixel = (
            frame_abs.eye_pixel.0 + square.col as f64,
            frame_abs.eye_pixel.1 + square.row as f64,
        );
        Ok((near.win, lod.ring_cells(dem, &frame_abs, camera)))
    }

    /// Where the wedge of `camera` lies: the square around the eye, its
    /// grid, and the wedge's box in it and in the DEM.
    fn wedge_plan(
        dem: &Dem,
        vp: &Viewpoint,
        max_d: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<WedgePlan, RenderError> {
        Self::wedge_plan_within(dem, vp, max_d, max_d, k, camera)
    }

    /// [`Scene::wedge_plan`] with the wedge's box cut at `reach` metres
    /// (the frame still resolved on the square of `max_d`).
    fn wedge_plan_within(
        dem: &Dem,
        vp: &Viewpoint,
        max_d: Option<f64>,
        reach: Option<f64>,
        k: f64,
        camera: &crate::view::Camera,
    ) -> Result<WedgePlan, RenderError> {
        let name = dem.path.display().to_string();
        let georef = Georef::for_crs(&dem.crs, &name)?;
        let square = Self::window_of(dem, &georef, vp.lon, vp.lat, max_d)?;
        // The grid of the square, as `read_height_map` would georeference it.
        let gt = dem
            .geotransform
            .offset(square.col as f64, square.row as f64);
        let size = (square.width, square.height);
        // Where the eye is and what it sees need no heights: the wedge is
        // found first (with any ground), then only it is read.
        let probe = georef.local_frame_on(vp, &gt, size, &|_, _| Some(0.0), k)?;
        let (c0, r0, c1, r1) = LocalTerrain::extent_in(size, &probe, reach, Some(camera));
        let win = Window::new(
            square.col + c0 as i64,
            square.row + r0 as i64,
            c1 - c0,
            r1 - r0,
        );
        Ok(WedgePlan {
            georef,
            gt,
            size,
            c0,
            r0,
            win,
            probe,
        })
    }

    /// The window of `dem` a view from `(lon, lat)` reads: the cells
    /// within `max_distance` metres of it (a square in metres on the
    /// ground, grown by two cells; the whole DEM without a limit). Fails
    /// when the viewpoint is off the DEM or cannot be converted to its
    /// CRS. The batch planner ([`crate::batch`]) uses the same window.
    pub fn window_of(
        dem: &Dem,
        georef: &Georef,
        lon: f64,
        lat: f64,
        max_distance: Option<f64>,
    ) -> Result<Window, RenderError> {
        let (x, y) = georef.lonlat_to_crs(lon, lat)?;
        let outside = || ViewError::OutsideDem {
            dem: dem.path.display().to_string(),
            lon,
            lat,
        };
        let (px, py) = dem.geotransform.crs_to_pixel(x, y).ok_or_else(outside)?;
        if !(px >= 0.0 && py >= 0.0 && px < dem.width as f64 && py < dem.height as f64) {
            return Err(outside().into());
        }
        Ok(match crate::view::distance_limit(max_distance) {
            None => dem.full_window(),
            Some(r) => {
                let m = georef.metric_matrix(lon, lat)?;
                let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
                let mi = [
                    [m[1][1] / det, -m[0][1] / det],
                    [-m[1][0] / det, m[0][0] / det],
                ];
                let (gx, gy) = dem.geotransform.pixel_size();
                let dx = r * mi[0][0].hypot(mi[0][1]) + 2.0 * gx;
                let dy = r * mi[1][0].hypot(mi[1][1]) + 2.0 * gy;
                dem.window_for_bounds([x - dx, y - dy, x + dx, y + dy])
                    .unwrap_or_else(|| Window::new(px as i64, py as i64, 1, 1))
            }
        })
    }

    fn open_for(
        dem: &Dem,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
        camera: Option<&crate::view::Camera>,
    ) -> Result<Scene, RenderError> {
        let name = dem.path.display().to_string();
        let georef = Georef::for_crs(&dem.crs, &name)?;
        let max_d = crate::view::distance_limit(max_distance);
        let win = Self::window_of(dem, &georef, vp.lon, vp.lat, max_d)?;
        let window = dem.read_height_map(win)?;
        let frame = georef.local_frame(vp, &window, k)?;
        let terrain = match camera {
            Some(c) => LocalTerrain::in_view(&window, &frame, max_d, c),
            None => LocalTerrain::new(&window, &frame, max_d),
        };
        Ok(Scene {
            window,
            window_offset: (win.col, win.row),
            georef,
            frame,
            terrain,
        })
    }

    /// Resolve `vp` on a height map already in memory.
    pub fn from_height_map(
        dem: HeightMap,
        name: &str,
        vp: &Viewpoint,
        max_distance: Option<f64>,
        k: f64,
    ) -> Result<Scene, RenderError> {
        let georef = Georef::new(&dem, name)?;
        let frame = georef.local_frame(vp, &dem, k)?;
        let terrain = LocalTerrain::new(&dem, &frame, max_distance);
        Ok(Scene {
            window: dem,
            window_offset: (0, 0),
            georef,
            frame,
            terrain,
        })
    }
}

/// The distance, metres, from the eye to the farthest corner of a wedge's
/// box (on the square's grid, where the probe frame is resolved).
fn farthest_corner_m(plan: &WedgePlan) -> f64 {
    let (c0, r0) = (plan.c0 as f64, plan.r0 as f64);
    let (c1, r1) = (c0 + plan.win.width as f64, r0 + plan.win.height as f64);
    [(c0, r0), (c1, r0), (c0, r1), (c1, r1)]
        .iter()
        .map(|&(x, y)| {
            let (e, n) = plan.probe.pixel_to_en(x, y);
            e.hypot(n)
        })
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::DepthBuffer;
    use crate::view::Camera;

    /// A scene opened with its far rings deferred, then read
    /// ([`Scene::with_rings`]), is the scene opened at once: the same far
    /// layers and the same render, to the bit; a view within the exact
    /// reach has no ring to read.
    #[test]
    fn rings_read_later_give_the_scene_opened_at_once() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures")
            .join("zion_srtm_utm12n.tif");
        let dem = Dem::open(&path).unwrap();
        let (x, y) = dem.geotransform.pixel_to_crs(210.5, 440.5);
        let georef = Georef::for_crs(&dem.crs, "zion").unwrap();
        let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
        let vp = Viewpoint::above_surface(lon, lat, 1500.0);
        let cam = Camera::new(160, 90, 0.0, -2.0, 0.0, 90.0).unwrap();
        let k = 1.0 / 7.0;
        let at_once =
            Scene::open_wedge_lod_within(&dem, &vp, Some(40_000.0), k, &cam, None, None).unwrap();
        let (deferred, rings) =
            Scene::open_wedge_lod_deferred(&dem, &vp, Some(40_000.0), k, &cam, None, None).unwrap();
        assert!(rings.is_some());
        assert!(deferred.terrain.far_layer_sizes().is_empty());
        let later = deferred.with_rings(&dem, rings).unwrap();
        assert!(!at_once.terrain.far_layer_sizes().is_empty());
        assert_eq!(
            at_once.terrain.far_layer_sizes(),
            later.terrain.far_layer_sizes()
        );
        let (a, b) = (
            DepthBuffer::render(&at_once.terrain, &cam),
            DepthBuffer::render(&later.terrain, &cam),
        );
        assert_eq!(a.triangle, b.triangle);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.depth), bits(&b.depth));
        // Within the exact reach: nothing deferred.
        let (_, none) =
            Scene::open_wedge_lod_deferred(&dem, &vp, Some(5_000.0), k, &cam, None, None).unwrap();
        assert!(none.is_none());
    }
}
