//! The observer's fixed ground: the cells around each viewpoint held at
//! their input heights, the eye's ground resolved once, and the view's
//! cells for held stroke points.

use super::*;

impl ViewState<'_> {
    /// The DEM cell under the eye, as a one-cell window.
    pub(super) fn eye_cell(&self) -> Window {
        let (ex, ey) = self.frame.eye_pixel;
        Window::new(
            self.window_offset.0 + ex.floor() as i64,
            self.window_offset.1 + ey.floor() as i64,
            1,
            1,
        )
    }

    /// The cells of the bilinear stencil of DEM CRS point `(x, y)`, held
    /// at their input heights (`window`: the view's window's heights).
    pub(super) fn stencil_cells(&self, window: &HeightMap, x: f64, y: f64) -> Vec<CellConstraint> {
        let Some((c0, r0)) = self.cell_of(x, y) else {
            return Vec::new();
        };
        [(c0, r0), (c0 + 1, r0), (c0, r0 + 1), (c0 + 1, r0 + 1)]
            .into_iter()
            .filter_map(|(c, r)| self.held_cell(window, c, r))
            .collect()
    }

    /// The DEM cell (whole-DEM grid) whose centre is the upper left one of
    /// the bilinear stencil of CRS point `(x, y)`, found on the grid of the
    /// square around the eye ([`EyeGround::grid`]).
    pub(super) fn cell_of(&self, x: f64, y: f64) -> Option<(i64, i64)> {
        let (px, py) = self.eye_ground.grid.crs_to_pixel(x, y)?;
        let off = self.eye_ground.grid_offset;
        Some((
            (px - 0.5).floor() as i64 + off.0,
            (py - 0.5).floor() as i64 + off.1,
        ))
    }

    /// DEM cell `(col, row)` (whole-DEM grid) held at its input height;
    /// `None` outside the window and the eye's ground ([`EyeGround`]), or
    /// on nodata.
    pub(super) fn held_cell(
        &self,
        window: &HeightMap,
        col: i64,
        row: i64,
    ) -> Option<CellConstraint> {
        let at = |map: &HeightMap, off: (i64, i64)| {
            let (x, y) = (col - off.0, row - off.1);
            (x >= 0 && y >= 0 && (x as usize) < map.width && (y as usize) < map.height)
                .then(|| map.get(x as usize, y as usize))
        };
        let h = at(window, self.window_offset)
            .or_else(|| at(&self.eye_ground.map, self.eye_ground.offset))??;
        Some(CellConstraint {
            col,
            row,
            height: h as f64,
        })
    }

    /// The radius of the observer's fixed ground: `radius_m` (the sketch's
    /// `observer_radius_m`), else [`OBSERVER_RADIUS_M`] and at least two
    /// cells.
    pub(super) fn observer_radius(&self, radius_m: Option<f64>) -> f64 {
        observer_radius(&self.frame, radius_m)
    }

    /// The ground the observer stands on: every cell whose surface reaches
    /// within `radius_m` of the viewpoint (default 100 m, at least two
    /// cells), held at its input height.
    pub(super) fn observer_cells(
        &self,
        window: &HeightMap,
        radius_m: Option<f64>,
    ) -> Vec<CellConstraint> {
        let Some((reach, nc, nr)) = observer_reach(&self.frame, radius_m) else {
            return Vec::new();
        };
        let (ex, ey) = self.frame.eye_pixel;
        let (c_eye, r_eye) = (ex.floor() as i64, ey.floor() as i64);
        let mut out = Vec::new();
        for r in r_eye - nr..=r_eye + nr {
            for c in c_eye - nc..=c_eye + nc {
                let (e, n) = self.frame.pixel_to_en(c as f64 + 0.5, r as f64 + 0.5);
                if e.hypot(n) > reach {
                    continue;
                }
                out.extend(self.held_cell(
                    window,
                    c + self.window_offset.0,
                    r + self.window_offset.1,
                ));
            }
        }
        out
    }
}

/// Metres per cell along the columns and rows of the grid `frame` is on.
pub(super) fn cell_m(frame: &LocalFrame) -> (f64, f64) {
    let p = frame.p;
    (p[0][0].hypot(p[1][0]), p[0][1].hypot(p[1][1]))
}

/// See [`ViewState::observer_radius`].
pub(super) fn observer_radius(frame: &LocalFrame, radius_m: Option<f64>) -> f64 {
    let (hx, hy) = cell_m(frame);
    radius_m.unwrap_or(OBSERVER_RADIUS_M.max(2.0 * hx.max(hy)))
}

/// How far the observer's fixed ground reaches ([`ViewState::observer_cells`]):
/// metres from the viewpoint, and cells across and down either side of the
/// eye's cell; `None` when nothing is held.
pub(super) fn observer_reach(frame: &LocalFrame, radius_m: Option<f64>) -> Option<(f64, i64, i64)> {
    let (hx, hy) = cell_m(frame);
    let radius = observer_radius(frame, radius_m);
    if !(hx > 0.0 && hy > 0.0 && radius.is_finite()) {
        return None;
    }
    let reach = radius + hx.hypot(hy);
    Some((
        reach,
        (reach / hx).ceil() as i64 + 1,
        (reach / hy).ceil() as i64 + 1,
    ))
}

/// The cells around `scene`'s eye that its observer's fixed ground can take
/// ([`observer_reach`]), within the square of the view distance around the
/// viewpoint (the cells a view could hold before it read only its wedge):
/// read from `dem` (a few hundred cells by default).
pub(super) fn eye_ground(
    dem: &Dem,
    scene: &Scene,
    vp: &crate::view::Viewpoint,
    max_d: Option<f64>,
    radius_m: Option<f64>,
) -> Result<EyeGround, crate::render::RenderError> {
    let square = Scene::window_of(dem, &scene.georef, vp.lon, vp.lat, max_d)?;
    let grid = dem
        .geotransform
        .offset(square.col as f64, square.row as f64);
    let empty = || EyeGround {
        map: scene.window.crop(0, 0, 0, 0),
        offset: (0, 0),
        grid,
        grid_offset: (square.col, square.row),
    };
    let Some((_, nc, nr)) = observer_reach(&scene.frame, radius_m) else {
        return Ok(empty());
    };
    let (ex, ey) = scene.frame.eye_pixel;
    let (c, r) = (
        scene.window_offset.0 + ex.floor() as i64,
        scene.window_offset.1 + ey.floor() as i64,
    );
    let around = Window::new(c - nc, r - nr, (2 * nc + 1) as usize, (2 * nr + 1) as usize);
    let Some(w) = around.intersect(&square) else {
        return Ok(empty());
    };
    Ok(EyeGround {
        map: dem.read_height_map(w)?,
        offset: (w.col, w.row),
        grid,
        grid_offset: (square.col, square.row),
    })
}
