//! Viewpoint mapping: a lon/lat (WGS84) position and an eye height resolved
//! against a DEM with PROJ, giving the eye's position in the DEM's CRS and
//! the *local frame* everything 3D is computed in.
//!
//! The local frame is east-north-up metres centred at the eye, with `z`
//! the apparent height relative to the eye: `z = h - eye_alt - drop(d)`
//! where `drop` is the curvature-and-refraction drop of [`Curvature`] at the
//! horizontal distance `d` from the eye. In this frame lines of sight are
//! straight, so ray casting, projection and visibility are plain geometry.
//! The horizontal part is the tangent plane of the WGS84 ellipsoid at the
//! eye: the DEM CRS is mapped to it by the Jacobian of CRS -> (east, north)
//! at the eye, taken through PROJ. That one affine map applies meridian
//! convergence (heading from true north) and the projection's scale factor
//! for projected CRSs, and the metric size of a degree (`N cos(lat)`, `M`)
//! for geographic CRSs, so both kinds of DEM get correct metric geometry.

use super::{Curvature, ViewError};
use crate::raster::{Crs, HeightMap};
use proj::Proj;
use std::rc::Rc;

/// How high the eye is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EyeHeight {
    /// Metres above the DEM surface (bilinear) at the viewpoint.
    AboveSurface(f64),
    /// Absolute altitude in the DEM's vertical datum.
    Absolute(f64),
}

impl Default for EyeHeight {
    fn default() -> Self {
        EyeHeight::AboveSurface(1.7)
    }
}

/// A viewpoint as `DESIGN.md` defines it: lon/lat in degrees WGS84 and a height.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Viewpoint {
    pub lon: f64,
    pub lat: f64,
    pub height: EyeHeight,
}

impl Viewpoint {
    /// A viewpoint `eye_height_m` above the surface.
    pub fn above_surface(lon: f64, lat: f64, eye_height_m: f64) -> Self {
        Viewpoint {
            lon,
            lat,
            height: EyeHeight::AboveSurface(eye_height_m),
        }
    }
}

/// PROJ transformations between WGS84 lon/lat and a DEM's CRS. Not `Send`
/// (PROJ contexts are per thread); resolve a [`LocalFrame`] from it and share
/// that instead.
pub struct Georef {
    /// WGS84 lon/lat to the DEM's CRS (forward), and back (inverse): one
    /// PROJ object, because creating one (its own context, proj.db lookups)
    /// costs milliseconds; shared by every `Georef` of the same CRS on this
    /// thread (see [`transformation`]).
    transform: Rc<Proj>,
    geographic: bool,
    dem: String,
}

impl std::fmt::Debug for Georef {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Georef").field("dem", &self.dem).finish()
    }
}

thread_local! {
    /// The transformations made on this thread, by CRS definition.
    static TRANSFORMATIONS: std::cell::RefCell<Vec<(String, Rc<Proj>)>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// Where PROJ's own messages go ([`route_proj_messages`]).
static PROJ_ECHO: std::sync::OnceLock<fn(&str)> = std::sync::OnceLock::new();

extern "C" fn proj_message(
    _app_data: *mut std::os::raw::c_void,
    _level: std::os::raw::c_int,
    message: *const std::os::raw::c_char,
) {
    if message.is_null() {
        return;
    }
    // SAFETY: PROJ passes a NUL-terminated string that lives for the call.
    let text = unsafe { std::ffi::CStr::from_ptr(message) }.to_string_lossy();
    if let Some(echo) = PROJ_ECHO.get() {
        // Never unwind into PROJ's C code.
        let _ = std::panic::catch_unwind(|| echo(&text));
    }
}

/// Send PROJ's own messages (`utm: Invalid longitude`, printed on stderr
/// by default beside the one-line error the failing call comes back with)
/// to `echo` instead; the first call decides `echo`. PROJ gives every
/// context it creates afterwards a copy of its default context's logger
/// (`proj_context_create`), so this is called once, before any
/// transformation is made (the command line does it at start, as it does
/// for GDAL's messages).
pub fn route_proj_messages(echo: fn(&str)) {
    let _ = PROJ_ECHO.set(echo);
    // SAFETY: a null context is PROJ's default context; the function
    // pointer is 'static and takes what PROJ_LOG_FUNCTION says.
    unsafe {
        proj_sys::proj_log_func(
            std::ptr::null_mut(),
            std::ptr::null_mut(),
            Some(proj_message),
        );
    }
}

/// The transformation from WGS84 lon/lat to the CRS `def`, made once per
/// thread and CRS: opening PROJ's database and searching it for the
/// operation costs a few milliseconds, which a batch of edits (or of views)
/// on the same tile pyramid would otherwise pay every time. PROJ objects
/// hold their own context and are used on the thread that made them only,
/// so the cache is per thread.
fn transformation(def: &str) -> Result<Rc<Proj>, proj::ProjCreateError> {
    if let Some(p) = TRANSFORMATIONS.with(|t| {
        t.borrow()
            .iter()
            .find(|(d, _)| d == def)
            .map(|(_, p)| Rc::clone(p))
    }) {
        return Ok(p);
    }
    let p = Rc::new(Proj::new_known_crs("EPSG:4326", def, None)?);
    TRANSFORMATIONS.with(|t| {
        let mut t = t.borrow_mut();
        // A handful of CRSs at most in practice; bounded all the same.
        if t.len() >= 16 {
            t.remove(0);
        }
        t.push((def.to_string(), Rc::clone(&p)));
    });
    Ok(p)
}

impl Georef {
    /// Transformations for the CRS of `dem`; `dem_name` names the DEM in errors.
    pub fn new(dem: &HeightMap, dem_name: &str) -> Result<Self, ViewError> {
        Self::for_crs(&dem.crs, dem_name)
    }

    /// Transformations for `crs`; `dem_name` names the DEM in errors.
    pub fn for_crs(crs: &Crs, dem_name: &str) -> Result<Self, ViewError> {
        let def = crs.proj_definition();
        let perr = |e: &dyn std::fmt::Display| ViewError::Proj {
            dem: dem_name.to_string(),
            message: e.to_string().lines().next().unwrap_or("").to_string(),
        };
        if def.trim().is_empty() {
            return Err(perr(&"the DEM has no CRS"));
        }
        let transform = transformation(&def).map_err(|e| perr(&e))?;
        Ok(Georef {
            transform,
            geographic: crs.geographic,
            dem: dem_name.to_string(),
        })
    }

    fn err(&self, e: impl std::fmt::Display) -> ViewError {
        ViewError::Proj {
            dem: self.dem.clone(),
            message: e.to_string().lines().next().unwrap_or("").to_string(),
        }
    }

    /// DEM CRS coordinates of WGS84 `(lon, lat)` in degrees.
    pub fn lonlat_to_crs(&self, lon: f64, lat: f64) -> Result<(f64, f64), ViewError> {
        if !(lon.is_finite() && lat.is_finite() && lat.abs() <= 90.0) {
            return Err(ViewError::BadViewpoint { lon, lat });
        }
        let p = self
            .transform
            .convert((lon, lat))
            .map_err(|e| self.err(e))?;
        if !(p.0.is_finite() && p.1.is_finite()) {
            return Err(self.err(format!("no finite position for lon {lon}, lat {lat}")));
        }
        Ok(p)
    }

    /// WGS84 `(lon, lat)` in degrees of DEM CRS coordinates `(x, y)`.
    pub fn crs_to_lonlat(&self, x: f64, y: f64) -> Result<(f64, f64), ViewError> {
        // `project` with `inverse` runs the same transformation backwards
        // (`proj_trans` with `PJ_INV`), coordinates passed through as given.
        self.transform
            .project((x, y), true)
            .map_err(|e| self.err(e))
    }

    /// Jacobian `d(x, y) / d(lon, lat)` (CRS units per degree) at a point,
    /// columns lon and lat: `[[dx/dlon, dx/dlat], [dy/dlon, dy/dlat]]`.
    pub fn jacobian(&self, lon: f64, lat: f64) -> Result<[[f64; 2]; 2], ViewError> {
        if self.geographic {
            // Check the axis order PROJ gives back (normalised: lon, lat).
            return Ok([[1.0, 0.0], [0.0, 1.0]]);
        }
        let h = 1e-5;
        let (xe, ye) = self.lonlat_to_crs(lon + h, lat)?;
        let (xw, yw) = self.lonlat_to_crs(lon - h, lat)?;
        let (xn, yn) = self.lonlat_to_crs(lon, lat + h)?;
        let (xs, ys) = self.lonlat_to_crs(lon, lat - h)?;
        Ok([
            [(xe - xw) / (2.0 * h), (xn - xs) / (2.0 * h)],
            [(ye - yw) / (2.0 * h), (yn - ys) / (2.0 * h)],
        ])
    }

    /// Meridian convergence in degrees at `(lon, lat)` with PROJ's sign (the
    /// value `proj -V` prints): grid north lies at bearing `convergence`
    /// (clockwise from true north), so true north is at grid bearing
    /// `-convergence`. Zero for geographic CRSs.
    pub fn meridian_convergence_deg(&self, lon: f64, lat: f64) -> Result<f64, ViewError> {
        let j = self.jacobian(lon, lat)?;
        // Direction of true north in grid coordinates: (dx/dlat, dy/dlat).
        Ok(-j[0][1].atan2(j[1][1]).to_degrees())
    }

    /// The matrix `m` with `(east, north) = m * (dx, dy)` for CRS offsets
    /// `(dx, dy)` around `(lon, lat)`: the inverse Jacobian of the CRS in
    /// metres of the WGS84 tangent plane (`N cos(lat)`, `M` per radian).
    pub fn metric_matrix(&self, lon: f64, lat: f64) -> Result<[[f64; 2]; 2], ViewError> {
        let j = self.jacobian(lon, lat)?;
        let (m_rad, n_rad) = super::curvature::radii_of_curvature(lat);
        let deg = std::f64::consts::PI / 180.0;
        let d = [n_rad * lat.to_radians().cos() * deg, m_rad * deg];
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.is_finite() && det != 0.0) {
            return Err(self.err("singular projection at the viewpoint"));
        }
        let ji = [
            [j[1][1] / det, -j[0][1] / det],
            [-j[1][0] / det, j[0][0] / det],
        ];
        Ok([
            [d[0] * ji[0][0], d[0] * ji[0][1]],
            [d[1] * ji[1][0], d[1] * ji[1][1]],
        ])
    }

    /// Resolve `vp` against `dem` (whose CRS this `Georef` was built for).
    /// Errors when the viewpoint lies outside the DEM or on nodata.
    pub fn local_frame(
        &self,
        vp: &Viewpoint,
        dem: &HeightMap,
        refraction_k: f64,
    ) -> Result<LocalFrame, ViewError> {
        self.local_frame_on(
            vp,
            &dem.geotransform,
            (dem.width, dem.height),
            &|px, py| dem.bilinear(px, py),
            refraction_k,
        )
    }

    /// [`Georef::local_frame`] on a grid of `size` cells with geotransform
    /// `gt` whose heights are not all in memory: `ground(px, py)` is the
    /// bilinear surface at pixel `(px, py)` of that grid (read from a
    /// smaller window around the eye, see [`crate::render::Scene`]).
    pub fn local_frame_on(
        &self,
        vp: &Viewpoint,
        gt: &crate::raster::GeoTransform,
        size: (usize, usize),
        ground: &dyn Fn(f64, f64) -> Option<f64>,
        refraction_k: f64,
    ) -> Result<LocalFrame, ViewError> {
        let (width, height) = size;
        let (x, y) = self.lonlat_to_crs(vp.lon, vp.lat)?;
        let outside = || ViewError::OutsideDem {
            dem: self.dem.clone(),
            lon: vp.lon,
            lat: vp.lat,
        };
        let (px, py) = gt.crs_to_pixel(x, y).ok_or_else(outside)?;
        if !(px >= 0.0 && py >= 0.0 && px < width as f64 && py < height as f64) {
            return Err(outside());
        }
        // Bilinear surface; in the outer half cell clamp to the cell centres.
        let cx = px.clamp(0.5, width as f64 - 0.5);
        let cy = py.clamp(0.5, height as f64 - 0.5);
        let ground = ground(cx, cy).ok_or_else(|| ViewError::OnNodata {
            dem: self.dem.clone(),
            lon: vp.lon,
            lat: vp.lat,
        })?;
        // The renderer draws the bilinear surface (to a fraction of a
        // pixel), so the eye stands above `ground`. It is resolved here,
        // once, and every render of an edit uses it (the report gives it as
        // `eye_alt_m`). An absolute eye just over the ground is lifted to
        // stand clear of it.
        let eye_alt = match vp.height {
            EyeHeight::AboveSurface(h) => ground + h,
            EyeHeight::Absolute(a) if a >= ground => a.max(ground + MIN_EYE_CLEARANCE_M),
            EyeHeight::Absolute(a) => a,
        };
        if !eye_alt.is_finite() {
            return Err(ViewError::BadViewpoint {
                lon: vp.lon,
                lat: vp.lat,
            });
        }
        let m = self.metric_matrix(vp.lon, vp.lat)?;
        Ok(LocalFrame::new(
            vp.lon,
            vp.lat,
            (x, y),
            (px, py),
            ground,
            eye_alt,
            m,
            Curvature::at_latitude(vp.lat, refraction_k),
            gt,
        ))
    }
}

/// The problem with an absolute eye (`height`: `alt_m`, `--alt`) at or
/// below `ground`, the surface the renderer draws at the viewpoint
/// ([`LocalFrame::ground`]), as `edit`, `view`, `locate` and `serve`
/// refuse it: `"{what} {alt} is not above the ground ({ground} m) at the
/// viewpoint"`. `None` for an eye above the ground or given as a height
/// above it.
pub fn below_ground_problem(what: &str, height: EyeHeight, ground: f64) -> Option<String> {
    match height {
        EyeHeight::Absolute(a) if a <= ground => Some(format!(
            "{what} {} is not above the ground ({ground:.2} m) at the viewpoint",
            crate::num::Num(a)
        )),
        _ => None,
    }
}

/// An absolute eye (`alt_m`) is at least this far above the surface the
/// renderer draws, metres.
pub const MIN_EYE_CLEARANCE_M: f64 = 0.5;

/// The local frame of a resolved viewpoint: east-north-up metres centred at
/// the eye, `z` apparent (curvature and refraction subtracted). Plain data,
/// `Copy + Send + Sync`, shared by the renderer, features and sketch code.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalFrame {
    /// Viewpoint longitude and latitude (degrees WGS84).
    pub lon: f64,
    pub lat: f64,
    /// Eye position in the DEM's CRS.
    pub eye_crs: (f64, f64),
    /// Eye position in pixel space of the DEM the frame was resolved on.
    pub eye_pixel: (f64, f64),
    /// DEM surface height (bilinear) below the eye.
    pub ground: f64,
    /// Absolute eye altitude in the DEM's vertical datum.
    pub eye_alt: f64,
    /// `(east, north) = m * (x - x_eye, y - y_eye)`.
    pub m: [[f64; 2]; 2],
    /// Inverse of `m`.
    pub m_inv: [[f64; 2]; 2],
    /// `(east, north) = p * (px - px_eye, py - py_eye)` for pixel space of
    /// the DEM the frame was resolved on (geotransform composed with `m`).
    pub p: [[f64; 2]; 2],
    pub curvature: Curvature,
}

fn mat_inv(a: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    [
        [a[1][1] / det, -a[0][1] / det],
        [-a[1][0] / det, a[0][0] / det],
    ]
}

fn mat_mul(a: [[f64; 2]; 2], b: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    [
        [
            a[0][0] * b[0][0] + a[0][1] * b[1][0],
            a[0][0] * b[0][1] + a[0][1] * b[1][1],
        ],
        [
            a[1][0] * b[0][0] + a[1][1] * b[1][0],
            a[1][0] * b[0][1] + a[1][1] * b[1][1],
        ],
    ]
}

impl LocalFrame {
    #[allow(clippy::too_many_arguments)]
    fn new(
        lon: f64,
        lat: f64,
        eye_crs: (f64, f64),
        eye_pixel: (f64, f64),
        ground: f64,
        eye_alt: f64,
        m: [[f64; 2]; 2],
        curvature: Curvature,
        geotransform: &crate::raster::GeoTransform,
    ) -> Self {
        let g = geotransform.0;
        let gt = [[g[1], g[2]], [g[4], g[5]]];
        LocalFrame {
            lon,
            lat,
            eye_crs,
            eye_pixel,
            ground,
            eye_alt,
            m,
            m_inv: mat_inv(m),
            p: mat_mul(m, gt),
            curvature,
        }
    }

    /// A frame for synthetic tests on a north-up metric grid without PROJ:
    /// CRS units are metres, grid north is true north.
    pub fn planar(
        dem: &HeightMap,
        eye_crs: (f64, f64),
        eye_alt: f64,
        curvature: Curvature,
    ) -> Self {
        let (px, py) = dem
            .geotransform
            .crs_to_pixel(eye_crs.0, eye_crs.1)
            .unwrap_or((f64::NAN, f64::NAN));
        let ground = dem.bilinear(px, py).unwrap_or(f64::NAN);
        LocalFrame::new(
            f64::NAN,
            f64::NAN,
            eye_crs,
            (px, py),
            ground,
            eye_alt,
            [[1.0, 0.0], [0.0, 1.0]],
            curvature,
            &dem.geotransform,
        )
    }

    /// Same frame, expressed for another window of the same DEM (its pixel
    /// space differs by an offset; `m` is unchanged).
    pub fn for_window(&self, window: &HeightMap) -> Self {
        let mut f = *self;
        let g = window.geotransform.0;
        f.p = mat_mul(self.m, [[g[1], g[2]], [g[4], g[5]]]);
        f.eye_pixel = window
            .geotransform
            .crs_to_pixel(self.eye_crs.0, self.eye_crs.1)
            .unwrap_or((f64::NAN, f64::NAN));
        f
    }

    /// Same frame for the window that starts `(col, row)` cells into the
    /// grid this one was resolved on: the eye's pixel is moved by whole
    /// cells (exactly, in floating point), everything else is kept, so
    /// that vertex positions relative to the eye come out with the same
    /// bits in both grids.
    pub fn shifted(&self, col: usize, row: usize) -> Self {
        let mut f = *self;
        f.eye_pixel = (self.eye_pixel.0 - col as f64, self.eye_pixel.1 - row as f64);
        f
    }

    /// Local `(east, north)` metres of CRS point `(x, y)`.
    #[inline]
    pub fn crs_to_en(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (x - self.eye_crs.0, y - self.eye_crs.1);
        (
            self.m[0][0] * dx + self.m[0][1] * dy,
            self.m[1][0] * dx + self.m[1][1] * dy,
        )
    }

    /// CRS point of local `(east, north)`.
    #[inline]
    pub fn en_to_crs(&self, e: f64, n: f64) -> (f64, f64) {
        (
            self.eye_crs.0 + self.m_inv[0][0] * e + self.m_inv[0][1] * n,
            self.eye_crs.1 + self.m_inv[1][0] * e + self.m_inv[1][1] * n,
        )
    }

    /// Local point (apparent `z`) of a CRS point with absolute height `h`.
    #[inline]
    pub fn crs_to_local(&self, x: f64, y: f64, h: f64) -> [f64; 3] {
        let (e, n) = self.crs_to_en(x, y);
        [e, n, h - self.eye_alt - self.curvature.drop(e.hypot(n))]
    }

    /// CRS point and absolute height of a local point.
    #[inline]
    pub fn local_to_crs(&self, p: [f64; 3]) -> (f64, f64, f64) {
        let (x, y) = self.en_to_crs(p[0], p[1]);
        (
            x,
            y,
            p[2] + self.eye_alt + self.curvature.drop(p[0].hypot(p[1])),
        )
    }

    /// Local `(east, north)` of pixel-space point `(px, py)` of the DEM (or
    /// window) this frame was resolved for.
    #[inline]
    pub fn pixel_to_en(&self, px: f64, py: f64) -> (f64, f64) {
        let (dx, dy) = (px - self.eye_pixel.0, py - self.eye_pixel.1);
        (
            self.p[0][0] * dx + self.p[0][1] * dy,
            self.p[1][0] * dx + self.p[1][1] * dy,
        )
    }

    /// Heading of grid north (the DEM's `-row` direction) in degrees
    /// clockwise from true north, for display.
    pub fn grid_north_bearing_deg(&self) -> f64 {
        // Grid north is CRS +y: (e, n) = m * (0, 1).
        self.m[0][1].atan2(self.m[1][1]).to_degrees()
    }
}
