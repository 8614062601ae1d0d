//! The level of detail of a long view (issue 15): the terrain is read at
//! the DEM's resolution out to [`LodPlan::near_m`], and beyond in rings,
//! each on a grid `k` times coarser (`k` = 2, 4, 8 ...), where a coarse
//! cell spans at most one pixel of the camera. The rings become the far
//! layers of the exact terrain ([`super::far_layers`]).
//!
//! Where the rings start: ring `k` may begin at the distance where `k`
//! cells of the DEM span one pixel at the image centre (where pixels are
//! widest): `k * cell * focal_px`. The exact terrain reaches at least to
//! the start of ring 2, and at least [`LOD_MIN_NEAR_M`], so that an edit's
//! strokes, deformation, observer and ridges lie on exact terrain with a
//! wide margin. A view whose maximum distance is within that reads no
//! ring: it is exactly what it was without a level of detail.
//!
//! What a ring holds: each coarse vertex is the highest of the DEM cells
//! its coarse cell covers ([`crate::raster::Dem::read_block_max`]). The
//! maximum, not the mean, because what a far ring decides is the sky line
//! and what lies behind the near silhouettes: a mean lowers every ridge
//! by up to its relief within a coarse cell, which can open sky behind a
//! near crest that the DEM closes; the maximum never lowers a vertex below
//! a cell it stands for, and departs from the DEM's surface by at most the
//! relief within one coarse cell, which spans at most a pixel.
//!
//! What is read: for each ring, the box of the camera's wedge on the
//! coarse grid, in chunks of [`crate::raster::BLOCK_MAX_CHUNK`] cells; a
//! chunk wholly inside the ring's inner radius, beyond its outer one, or
//! outside the wedge is not read. Where every tile has an overview exactly
//! `k` times coarser ([`crate::raster::Dem::overview_layer`]), the ring is
//! read from the overviews: its cells are then what they hold (GDAL's
//! `AVERAGE` overviews lower a far ridge by up to its relief within a
//! coarse cell, under a pixel there; `MAX`-like overviews would not).
//! Without overviews every chunk the wedge crosses is decoded at full
//! resolution: the reading, not the terrain, is then the cost of a long
//! view.
//!
//! An edit may cut the exact terrain nearer ([`LodPlan::new_within`]): a
//! ring of the DEM's own cells (`k` = 1) then lies between the cut and the
//! exact reach. The picture is the same surface; what the cut saves is the
//! work an edit does on its exact terrain only (ridges, rounds,
//! re-renders), and the edit checks that it kept within the cut.

use rayon::prelude::*;

use super::far_layers::FarRing;
use super::terrain::wedge_azimuths;
use super::{LocalTerrain, RenderError};
use crate::raster::{block_max_extent, Dem, Window};
use crate::view::{Camera, LocalFrame};

/// The least distance, metres, the exact terrain of a level-of-detail view
/// reaches (where the first ring may start earlier by the pixel rule).
pub const LOD_MIN_NEAR_M: f64 = 20_000.0;

/// [`LodPlan::new_within`] cuts the exact terrain only where it reaches
/// farther than this many times the cut.
const MIN_CUT: f64 = 1.25;

/// Coarsest ring: cells of the DEM per ring cell (a chunk is one cell).
const MAX_K: usize = 256;

/// The rings of a view: the exact terrain's reach and the rings beyond.
#[derive(Debug, Clone, PartialEq)]
pub struct LodPlan {
    /// The exact terrain reaches this far (metres).
    pub near_m: f64,
    /// `(k, inner, outer)`: ring of coarseness `k` from `inner` to `outer`
    /// metres, innermost first; the last ends at the maximum distance.
    pub rings: Vec<(usize, f64, f64)>,
}

impl LodPlan {
    /// The rings of `camera` from `frame`'s eye out to `max_d` metres on a
    /// DEM whose cells `frame` resolves; `None` when the view needs none
    /// (its maximum distance within the exact reach, or not finite).
    pub fn new(frame: &LocalFrame, camera: &Camera, max_d: Option<f64>) -> Option<LodPlan> {
        let max_d = crate::view::distance_limit(max_d)?;
        let p = frame.p;
        // the longer side of a cell: a coarse cell spans at most a pixel
        // along both
        let cell = p[0][0].hypot(p[1][0]).max(p[0][1].hypot(p[1][1]));
        let unit = cell * camera.focal_px;
        if !(unit.is_finite() && unit > 0.0) {
            return None;
        }
        let near_m = (2.0 * unit).max(LOD_MIN_NEAR_M);
        if max_d <= near_m {
            return None;
        }
        let mut rings = Vec::new();
        let mut inner = near_m;
        while inner < max_d {
            // the coarsest power of two whose cells span a pixel at `inner`
            let mut k = 2usize;
            while 2 * k <= MAX_K && (2 * k) as f64 * unit <= inner {
                k *= 2;
            }
            let outer = if k >= MAX_K {
                max_d
            } else {
                ((2 * k) as f64 * unit).min(max_d)
            };
            rings.push((k, inner, outer));
            inner = outer;
        }
        Some(LodPlan { near_m, rings })
    }

    /// [`LodPlan::new`] with the exact terrain cut at `exact_cells` cells
    /// of the DEM from the eye where that is nearer than the plan's exact
    /// reach: between the two a ring of the DEM's own cells (`k` = 1, the
    /// same surface as the exact terrain's), which is drawn and cast into
    /// as a far layer but is not part of the terrain an edit changes,
    /// re-renders or detects ridges on. For an edit whose strokes and
    /// deformation lie well within the cut (the caller checks it,
    /// [`crate::edit`]'s pipeline). A view whose exact reach (or maximum
    /// distance) is within [`MIN_CUT`] times the cut is not cut.
    pub fn new_within(
        frame: &LocalFrame,
        camera: &Camera,
        max_d: Option<f64>,
        exact_cells: Option<f64>,
    ) -> Option<LodPlan> {
        let plan = LodPlan::new(frame, camera, max_d);
        let Some(r) = exact_cells
            .map(|n| n * frame_cell_m(frame))
            .filter(|r| r.is_finite() && *r > 0.0)
        else {
            return plan;
        };
        let max_d = crate::view::distance_limit(max_d)?;
        // (no cut where it would leave the exact terrain most of its reach)
        let reach = plan.as_ref().map_or(max_d, |p| p.near_m.min(max_d));
        if reach <= MIN_CUT * r || !(frame_cell_m(frame) * camera.focal_px).is_finite() {
            return plan;
        }
        match plan {
            Some(mut p) if r < p.near_m => {
                p.rings.insert(0, (1, r, p.near_m));
                p.near_m = r;
                Some(p)
            }
            Some(p) => Some(p),
            None => Some(LodPlan {
                near_m: r,
                rings: vec![(1, r, max_d)],
            }),
        }
    }

    /// The rings' cells (coarse), each the box of the camera's wedge on its
    /// grid: for checking sizes before reading.
    pub fn ring_cells(&self, dem: &Dem, frame_abs: &LocalFrame, camera: &Camera) -> u64 {
        self.rings
            .iter()
            .map(|&(k, _, outer)| ring_box(dem, frame_abs, camera, k, outer).len() as u64)
            .sum()
    }

    /// Read and build the rings of this plan as far layers: `frame_abs` is
    /// the view's frame on the whole DEM's grid, `origin` the cell of the
    /// DEM where the exact terrain's window starts.
    pub fn build_rings(
        &self,
        dem: &Dem,
        frame_abs: &LocalFrame,
        camera: &Camera,
        origin: (i64, i64),
    ) -> Result<Vec<FarRing>, RenderError> {
        // The rings are read and built at once (each reads its chunks in
        // parallel too): one ring has too few bands of chunks to keep
        // every core busy, and the first cores done would wait.
        self.rings
            .par_iter()
            .map(|&ring| build_ring(ring, dem, frame_abs, camera, origin))
            .collect()
    }
}

/// Ring `(k, inner, outer)` of [`LodPlan::build_rings`], read and built.
fn build_ring(
    (k, inner, outer): (usize, f64, f64),
    dem: &Dem,
    frame_abs: &LocalFrame,
    camera: &Camera,
    origin: (i64, i64),
) -> Result<FarRing, RenderError> {
    let cell = frame_cell_m(frame_abs);
    let wedge = wedge_azimuths(camera);
    let cwin = ring_box(dem, frame_abs, camera, k, outer);
    // A ring's vertices start a little inside its inner radius (it
    // overlaps the terrain inside it by two coarse cells: no gap
    // between them), and its chunks are read with a coarse cell's
    // margin more.
    let coarse_m = k as f64 * cell;
    let inner_v = (inner - 2.0 * coarse_m).max(0.0);
    let area = ReadArea {
        frame: frame_abs,
        inner: inner_v - 2.0 * coarse_m,
        outer: outer + 2.0 * coarse_m,
        wedge,
        margin: 2.0 * coarse_m,
    };
    // From the tiles' overviews where they have them (the coarse
    // cells then are what the overviews hold), else block maxima;
    // over the part of the box the reading reaches.
    let started = std::time::Instant::now();
    let overviews = dem.overview_layer(k, finer(cwin, k));
    let from_overview = |w: Window| area.wants(finer(w, k));
    let from_dem = |w: Window| area.wants(w);
    // (the box of what reading from overviews reads, which holds
    // what reading block maxima reads: the same cut either way)
    let grid = Window::new(0, 0, dem.width.div_ceil(k), dem.height.div_ceil(k));
    let read = block_max_extent(cwin, grid, &from_overview);
    let eye = frame_abs.eye_pixel;
    let cwin = trimmed(cwin, read, (eye.0 / k as f64, eye.1 / k as f64));
    let map = match &overviews {
        Some(ov) => ov.read_block_max(cwin, 1, &from_overview)?,
        None => dem.read_block_max(cwin, k, &from_dem)?,
    };
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        eprintln!(
            "level of detail: ring k {k} from {inner:.0} to {outer:.0} m, {} x {} cells, {}",
            cwin.width,
            cwin.height,
            if overviews.is_some() {
                "from overviews"
            } else {
                "block maxima"
            }
        );
    }
    let frame_c = coarse_frame(frame_abs, k, (cwin.col, cwin.row));
    let read_s = started.elapsed().as_secs_f64();
    let terrain = LocalTerrain::ring_from(map, &frame_c, inner_v, outer);
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        eprintln!(
            "level of detail: ring k {k} read in {read_s:.3} s, built in {:.3} s",
            started.elapsed().as_secs_f64() - read_s
        );
    }
    Ok(FarRing {
        terrain,
        inner_m: inner_v,
        k,
        origin: (
            cwin.col * k as i64 - origin.0,
            cwin.row * k as i64 - origin.1,
        ),
    })
}

/// The frame of a grid `k` times coarser than `frame_abs`'s (the whole
/// DEM's), for the coarse window starting at coarse cell `(c0, r0)`:
/// coarse pixel `x` is DEM pixel `k (x + c0)`.
fn coarse_frame(frame_abs: &LocalFrame, k: usize, (c0, r0): (i64, i64)) -> LocalFrame {
    let kf = k as f64;
    let mut f = *frame_abs;
    f.eye_pixel = (
        frame_abs.eye_pixel.0 / kf - c0 as f64,
        frame_abs.eye_pixel.1 / kf - r0 as f64,
    );
    f.p = [
        [frame_abs.p[0][0] * kf, frame_abs.p[0][1] * kf],
        [frame_abs.p[1][0] * kf, frame_abs.p[1][1] * kf],
    ];
    f
}

/// Window `w` of the grid `k` times coarser, in cells of the DEM.
fn finer(w: Window, k: usize) -> Window {
    let ki = k as i64;
    Window::new(w.col * ki, w.row * ki, w.width * k, w.height * k)
}

/// A ring's window is cut at its start by whole multiples of this many
/// coarse cells (see [`trimmed`]).
const TRIM_ALIGN: i64 = 64;

/// Ring window `cwin` (coarse cells) cut to the cells a ring reads, `read`
/// (the box of the chunks read: every cell outside it is NaN), on the
/// sides the eye (`eye`, coarse pixels) lies beyond, so that the ring is
/// the same surface held in fewer cells: the box of the camera's wedge
/// starts at the eye, and a ring's inner hole is most of it. Each cut
/// leaves a column (or row) of NaN cells before the first cell read, so
/// that a cast enters the ring's first cells where the uncut grid's
/// traversal enters them; a cut at the start is a multiple of
/// [`TRIM_ALIGN`], so that the renderer's blocks and superblocks, counted
/// from the window's start, are the uncut window's, shifted. The ring's
/// vertices, and the renders and casts over it, are then the uncut
/// ring's: the vertices' offsets from the eye are computed from the same
/// numbers (the eye's coarse pixel less a whole number of cells, exact
/// where the start is at most twice the eye's pixel), and the rays from
/// the eye leave the grid by the sides it does not lie beyond, which
/// stay where they were.
fn trimmed(cwin: Window, read: Option<Window>, (ex, ey): (f64, f64)) -> Window {
    let Some(read) = read else {
        return cwin;
    };
    // (start, end) along one axis: `start..end` the window, `r0..r1` the
    // cells read, `e` the eye
    let axis = |start: i64, end: i64, r0: i64, r1: i64, e: f64| -> (i64, i64) {
        let (mut s, mut t) = (start, end);
        let cut = (r0 - 1 - start).div_euclid(TRIM_ALIGN) * TRIM_ALIGN;
        let cut_at = (start + cut) as f64;
        // (at most twice the eye's pixel: the eye's pixel less the start is
        // then exact, as it is from the uncut start)
        if cut > 0 && e + 1.0 < cut_at && cut_at <= 2.0 * e {
            s = start + cut;
        }
        if r1 + 1 < end && e > (r1 + 2) as f64 {
            t = r1 + 1;
        }
        (s, t)
    };
    let (c0, c1) = axis(cwin.col, cwin.col_end(), read.col, read.col_end(), ex);
    let (r0, r1) = axis(cwin.row, cwin.row_end(), read.row, read.row_end(), ey);
    Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize)
}

/// The box (coarse cells) of the camera's wedge out to `outer` metres on
/// the grid `k` times coarser than the DEM's.
fn ring_box(dem: &Dem, frame_abs: &LocalFrame, camera: &Camera, k: usize, outer: f64) -> Window {
    let size = (dem.width.div_ceil(k), dem.height.div_ceil(k));
    let frame_c = coarse_frame(frame_abs, k, (0, 0));
    let (c0, r0, c1, r1) = LocalTerrain::extent_in(size, &frame_c, Some(outer), Some(camera));
    Window::new(c0 as i64, r0 as i64, c1 - c0, r1 - r0)
}

/// The longer side of a frame's cell, metres.
fn frame_cell_m(frame: &LocalFrame) -> f64 {
    let p = frame.p;
    p[0][0].hypot(p[1][0]).max(p[0][1].hypot(p[1][1]))
}

/// What a ring reads of the DEM: the chunks that reach between `inner`
/// and `outer` metres of the eye within the camera's wedge (`margin`
/// metres wider on each side).
struct ReadArea<'a> {
    frame: &'a LocalFrame,
    inner: f64,
    outer: f64,
    /// Centre azimuth and the wedge's least and greatest relative to it
    /// (`None`: no wedge, every azimuth).
    wedge: Option<(f64, f64, f64)>,
    margin: f64,
}

impl ReadArea<'_> {
    /// Does DEM window `w` reach the area? Conservative: `false` only when
    /// it lies wholly inside the inner radius, beyond the outer one, or
    /// beside the wedge.
    fn wants(&self, w: Window) -> bool {
        let (x0, y0) = (w.col as f64, w.row as f64);
        let (x1, y1) = (w.col_end() as f64, w.row_end() as f64);
        let corners =
            [(x0, y0), (x1, y0), (x1, y1), (x0, y1)].map(|(x, y)| self.frame.pixel_to_en(x, y));
        // (the window is convex: inside the disc when its corners are)
        if corners.iter().all(|&(e, n)| e.hypot(n) < self.inner) {
            return false;
        }
        if distance_to_quad(&corners) > self.outer {
            return false;
        }
        if let Some((centre, lo, hi)) = self.wedge {
            // The wedge is the intersection of two half-planes (it spans
            // at most a half-turn): outside one, outside it.
            let side = |a: f64, (e, n): (f64, f64)| e * a.cos() - n * a.sin();
            let (a_lo, a_hi) = (centre + lo, centre + hi);
            if corners.iter().all(|&c| side(a_lo, c) < -self.margin)
                || corners.iter().all(|&c| side(a_hi, c) > self.margin)
            {
                return false;
            }
        }
        true
    }
}

/// Distance from the origin to the convex quadrilateral `q` (0 inside).
fn distance_to_quad(q: &[(f64, f64); 4]) -> f64 {
    let cross = |a: (f64, f64), b: (f64, f64)| a.0 * b.1 - a.1 * b.0;
    let mut inside_pos = true;
    let mut inside_neg = true;
    let mut best = f64::INFINITY;
    for i in 0..4 {
        let (a, b) = (q[i], q[(i + 1) % 4]);
        let ab = (b.0 - a.0, b.1 - a.1);
        // the origin's side of edge a -> b
        let s = cross(ab, (-a.0, -a.1));
        inside_pos &= s >= 0.0;
        inside_neg &= s <= 0.0;
        let len2 = ab.0 * ab.0 + ab.1 * ab.1;
        let t = if len2 > 0.0 {
            ((-a.0 * ab.0 - a.1 * ab.1) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        best = best.min((a.0 + t * ab.0).hypot(a.1 + t * ab.1));
    }
    if inside_pos || inside_neg {
        0.0
    } else {
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ring's window is cut only on the sides the eye lies beyond, at
    /// the start by whole multiples of [`TRIM_ALIGN`] with a cell of NaN
    /// before the first cell read, at the end a cell after the last.
    #[test]
    fn a_ring_window_is_cut_beyond_the_eye_only() {
        let cwin = Window::new(100, 200, 1000, 900);
        let read = Window::new(700, 250, 380, 500);
        // eye west of the cells read, within the rows: columns cut at
        // the start (by 9 x 64 = 576: the first cell read is 700)
        let t = trimmed(cwin, Some(read), (400.0, 600.0));
        assert_eq!((t.col, t.row, t.width, t.height), (676, 200, 424, 900));
        assert!(t.col < read.col && (t.col - cwin.col) % TRIM_ALIGN == 0);
        // eye east of them: the end cut a cell after the last read
        let t = trimmed(cwin, Some(read), (1095.0, 600.0));
        assert_eq!((t.col, t.col_end()), (100, 1081));
        // eye south of them (rows grow southward): the rows' end cut
        let t = trimmed(cwin, Some(read), (800.0, 1095.0));
        assert_eq!((t.col, t.width, t.row, t.row_end()), (100, 1000, 200, 751));
        // eye among them, or nothing read: no cut
        assert_eq!(trimmed(cwin, Some(read), (800.0, 600.0)), cwin);
        assert_eq!(trimmed(cwin, None, (105.0, 600.0)), cwin);
        // a start more than twice the eye's pixel: not cut there
        let far = Window::new(0, 0, 1000, 10);
        let t = trimmed(far, Some(Window::new(600, 0, 400, 10)), (5.0, 5.0));
        assert_eq!(t.col, 0);
    }

    #[test]
    fn the_distance_to_a_square_is_to_its_nearest_edge() {
        let sq = [(1.0, -1.0), (3.0, -1.0), (3.0, 1.0), (1.0, 1.0)];
        assert!((distance_to_quad(&sq) - 1.0).abs() < 1e-12);
        let around = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
        assert_eq!(distance_to_quad(&around), 0.0);
    }
}
