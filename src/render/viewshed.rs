//! Visibility from the eye: which DEM cells can be seen, the library side of
//! `demsketch view --viewshed vis.tif`. A cell is visible when the straight
//! line of sight (in the local frame, so curvature and refraction with k =
//! 1/7 are included, as gdal_viewshed's coefficient 0.85714) from the eye to
//! the terrain point at the cell centre plus a target height is not blocked
//! by the triangulated terrain. The result is on the DEM's own grid, 255
//! visible / 0 not (nodata cells and cells beyond the maximum distance are
//! 0), like gdal_viewshed's output.
//!
//! Three ways to compute it:
//! - [`viewshed`] (and [`viewshed_from_dem`], the same answer without
//!   building a [`LocalTerrain`], and [`viewshed_from_file`], the same
//!   again with the DEM read from its file in bands of rows as the sweep
//!   reaches them, never whole), the default: horizon propagation. The
//!   grid is cut into four quadrants around the eye, swept in parallel,
//!   each row by row outward from the eye and each row outward from the
//!   eye's column (as gdal_viewshed sweeps). Every vertex keeps its horizon,
//!   the largest tan elevation of the terrain from the eye to it. The line
//!   of sight to a vertex crosses the grid line one step nearer the eye
//!   between two vertices already done; its horizon there is interpolated
//!   between theirs, and from there to the vertex the line stays in one
//!   cell, crossing at most its diagonal, so the triangulated surface on
//!   that last step is taken exactly. O(n) in the cells with a small
//!   constant; cells within [`EXACT_NEAR_CELLS`] of the eye are decided by
//!   an exact walk over the triangulated surface. It agrees with exact
//!   lines of sight on all but cells next to a horizon (99.3 to 99.99 % on
//!   the fixtures' viewpoints, see `tests/view_viewshed.rs`). Rows away
//!   from the eye run in vector passes ([`RowScratch`]), which give the
//!   same bits as the cell-by-cell rule.
//! - [`viewshed_rays`], the previous default: a radial sweep in the manner
//!   of Franklin and Ray's R2 (one exact ray per border vertex, each owning
//!   the vertices nearest it; about as accurate, several times slower).
//! - [`viewshed_exact`]: one exact cast ([`LocalTerrain::cast`]) per cell,
//!   rows in parallel: the reference the sweeps are tested against.

use super::atomic::write_atomically;
use super::terrain::LocalTerrain;
use super::RenderError;
use crate::raster::{Crs, Dem, GeoTransform, HeightMap, Window};
use crate::view::{Georef, LocalFrame, Viewpoint};
use rayon::prelude::*;
use std::path::Path;
use std::sync::atomic::{AtomicU8, Ordering};

/// A viewshed on the grid of the DEM the terrain was built from.
#[derive(Debug, Clone)]
pub struct Viewshed {
    pub width: usize,
    pub height: usize,
    /// 255 visible, 0 not visible; row-major.
    pub data: Vec<u8>,
    pub geotransform: GeoTransform,
    pub crs: Crs,
}

impl Viewshed {
    /// The part of this viewshed over `window` of its grid (clipped to
    /// the grid), with its geotransform: for instance the window a view
    /// reads ([`crate::render::Scene::window_of`]) out of a viewshed of the
    /// whole DEM.
    pub fn crop(&self, window: crate::raster::Window) -> Viewshed {
        let c0 = window.col.clamp(0, self.width as i64) as usize;
        let r0 = window.row.clamp(0, self.height as i64) as usize;
        let c1 = (window.col + window.width as i64).clamp(c0 as i64, self.width as i64) as usize;
        let r1 = (window.row + window.height as i64).clamp(r0 as i64, self.height as i64) as usize;
        let mut data = Vec::with_capacity((c1 - c0) * (r1 - r0));
        for r in r0..r1 {
            data.extend_from_slice(&self.data[r * self.width + c0..r * self.width + c1]);
        }
        Viewshed {
            width: c1 - c0,
            height: r1 - r0,
            data,
            geotransform: self.geotransform.offset(c0 as f64, r0 as f64),
            crs: self.crs.clone(),
        }
    }

    /// Share of valid cells (`mask` true) that are visible.
    pub fn visible_count(&self) -> usize {
        self.data.iter().filter(|&&v| v == 255).count()
    }
}

/// Cells within this many cells of the eye are cast exactly by
/// [`viewshed`]: the rays of the sweep fan out from the eye and pass far
/// from most cell centres there.
pub const EXACT_NEAR_CELLS: f64 = 3.0;

/// Viewshed of `terrain` on the grid of `dem` (the height map the terrain
/// was built from: the whole DEM or the window within the maximum view
/// distance, like gdal_viewshed's `-md` output extent) for a target
/// `target_height` metres above the surface, by the radial sweep of the
/// module documentation (the previous default of [`viewshed`]).
///
/// ```no_run
/// # use demsketch::render::{viewshed, LocalTerrain};
/// # fn f(terrain: &LocalTerrain, dem: &demsketch::raster::HeightMap) {
/// let vs = viewshed(terrain, dem, 0.0);
/// println!("{} cells visible", vs.visible_count());
/// # }
/// ```
pub fn viewshed_rays(terrain: &LocalTerrain, dem: &HeightMap, target_height: f64) -> Viewshed {
    let (nx, ny) = (terrain.nx, terrain.ny);
    let sweep = Sweep::new(terrain, target_height);
    if nx < 2 || ny < 2 {
        return on_grid(terrain, dem, |c, r| sweep.exact(c, r));
    }
    let (width, height) = (dem.width, dem.height);
    let mut data = vec![0u8; width * height];
    {
        // SAFETY: AtomicU8 has the size, alignment and bit validity of u8,
        // and `data` is not otherwise accessed while `out` lives.
        let out: &[AtomicU8] = unsafe { &*(data.as_mut_slice() as *mut [u8] as *const [AtomicU8]) };
        let grid = OutGrid {
            out,
            width,
            height,
            col0: terrain.col0,
            row0: terrain.row0,
        };
        let halves = Half::all(&sweep);
        let bundles: Vec<(&Half, Vec<RayWalk>)> = halves
            .iter()
            .flat_map(|h| {
                let rays = h.rays(&sweep);
                rays.chunks(RAY_BUNDLE)
                    .map(|c| (h, c.to_vec()))
                    .collect::<Vec<_>>()
            })
            .collect();
        let heights = terrain.z.slice();
        bundles.into_par_iter().for_each(|(h, mut rays)| {
            // the rays of a bundle advance together, a few lines at a
            // time, so that the heights they read stay in cache
            loop {
                let mut live = false;
                for ray in rays.iter_mut() {
                    live |= sweep.advance(h, ray, &heights, &grid, BUNDLE_STEPS);
                }
                if !live {
                    break;
                }
            }
        });
        // the square around the eye, cast exactly
        let (eu, ev) = sweep.eye;
        let near = EXACT_NEAR_CELLS + 1.0;
        let (c_lo, c_hi) = ((eu - near).ceil().max(0.0), (eu + near).floor());
        let (r_lo, r_hi) = ((ev - near).ceil().max(0.0), (ev + near).floor());
        if c_hi >= 0.0 && r_hi >= 0.0 {
            for r in r_lo as usize..=(r_hi as usize).min(ny - 1) {
                for c in c_lo as usize..=(c_hi as usize).min(nx - 1) {
                    if sweep.near_or_invalid(c, r) == Some(true) {
                        grid.set(c, r);
                    }
                }
            }
        }
    }
    Viewshed {
        width,
        height,
        data,
        geotransform: dem.geotransform,
        crs: dem.crs.clone(),
    }
}

/// Viewshed of `terrain` on the grid of `dem` (the height map the terrain
/// was built from: the whole DEM or the window within the maximum view
/// distance, like gdal_viewshed's `-md` output extent) for a target
/// `target_height` metres above the surface, by horizon propagation (see
/// the module documentation).
///
/// ```no_run
/// # use demsketch::render::{viewshed, LocalTerrain};
/// # fn f(terrain: &LocalTerrain, dem: &demsketch::raster::HeightMap) {
/// let vs = viewshed(terrain, dem, 0.0);
/// println!("{} cells visible", vs.visible_count());
/// # }
/// ```
pub fn viewshed(terrain: &LocalTerrain, dem: &HeightMap, target_height: f64) -> Viewshed {
    if terrain.nx < 2 || terrain.ny < 2 {
        let sweep = Sweep::new(terrain, target_height);
        return on_grid(terrain, dem, |c, r| sweep.exact(c, r));
    }
    let prop = Prop::new(
        terrain,
        &terrain.frame,
        (terrain.col0, terrain.row0, terrain.nx, terrain.ny),
        terrain.max_distance,
        target_height,
    );
    infallible(prop.run(dem.width, dem.height, &dem.geotransform, &dem.crs))
}

/// A target height (`--target-height`) that is not a finite number of
/// metres (one line).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("--target-height {} must be a finite number of metres", crate::num::Num(*.0))]
pub struct TargetHeightError(pub f64);

/// The height above the surface at which a cell is looked for is a finite
/// number of metres (negative: below the surface; a NaN or infinite one
/// would leave every line of sight undecided). [`viewshed_from_file`]
/// checks it; the viewsheds that cannot fail ([`viewshed`],
/// [`viewshed_from_dem`], [`viewshed_rays`], [`viewshed_exact`]) take it
/// checked: a caller with a flag checks it before any work.
pub fn check_target_height(target_height: f64) -> Result<(), TargetHeightError> {
    if target_height.is_finite() {
        Ok(())
    } else {
        Err(TargetHeightError(target_height))
    }
}

/// [`viewshed`] straight from the DEM: the same answer as
/// `viewshed(&LocalTerrain::new(dem, frame, max_distance), dem,
/// target_height)`, bit for bit, without building the terrain (its
/// apparent heights are computed row by row as the sweep reaches them).
/// For a viewshed alone (no picture), a DEM read and one pass.
///
/// ```no_run
/// # use demsketch::render::viewshed_from_dem;
/// # fn f(dem: &demsketch::raster::HeightMap, frame: &demsketch::view::LocalFrame) {
/// let vs = viewshed_from_dem(dem, frame, Some(20_000.0), 0.0);
/// # }
/// ```
pub fn viewshed_from_dem(
    dem: &HeightMap,
    frame: &LocalFrame,
    max_distance: Option<f64>,
    target_height: f64,
) -> Viewshed {
    let max_d = crate::view::distance_limit(max_distance).unwrap_or(f64::INFINITY);
    let (c0, r0, c1, r1) =
        LocalTerrain::extent_in((dem.width, dem.height), frame, max_distance, None);
    let nx = c1.saturating_sub(c0).max(1);
    let ny = r1.saturating_sub(r0).max(1);
    if nx < 2 || ny < 2 {
        return viewshed(
            &LocalTerrain::new(dem, frame, max_distance),
            dem,
            target_height,
        );
    }
    let heights = DemHeights {
        dem,
        ap: Apparent::new(frame, (c0, r0, nx), max_d),
    };
    let prop = Prop::new(&heights, frame, (c0, r0, nx, ny), max_d, target_height);
    infallible(prop.run(dem.width, dem.height, &dem.geotransform, &dem.crs))
}

/// [`viewshed_from_dem`] over a DEM read from its file as the sweep goes:
/// each quadrant reads bands of whole blocks of rows outward from the eye
/// into a buffer of its own that it reuses (as gdal_viewshed reads lines),
/// so that the DEM is never in memory as a whole (on 8192^2 cells, a few
/// MB instead of a 256 MB copy and its page faults). The same answer as [`viewshed_from_dem`] on
/// the DEM read whole, bit for bit; `frame` is on `dem`'s grid (see
/// [`eye_frame`]). Open `dem` with [`Dem::without_block_cache`]: the bands
/// are read once, and a cache would keep their blocks. Fails when a band
/// cannot be read, or on a target height that is not finite
/// ([`check_target_height`]).
///
/// ```no_run
/// # use demsketch::render::{eye_frame, viewshed_from_file};
/// # fn f(dem: &demsketch::raster::Dem, georef: &demsketch::view::Georef,
/// #      vp: &demsketch::view::Viewpoint) -> Result<(), demsketch::render::RenderError> {
/// let frame = eye_frame(dem, georef, vp, 1.0 / 7.0)?;
/// let vs = viewshed_from_file(dem, &frame, None, 0.0)?;
/// # Ok(())
/// # }
/// ```
pub fn viewshed_from_file(
    dem: &Dem,
    frame: &LocalFrame,
    max_distance: Option<f64>,
    target_height: f64,
) -> Result<Viewshed, RenderError> {
    check_target_height(target_height)?;
    let max_d = crate::view::distance_limit(max_distance).unwrap_or(f64::INFINITY);
    let (c0, r0, c1, r1) =
        LocalTerrain::extent_in((dem.width, dem.height), frame, max_distance, None);
    let nx = c1.saturating_sub(c0).max(1);
    let ny = r1.saturating_sub(r0).max(1);
    if nx < 2 || ny < 2 {
        // (only a DEM under 2 cells wide or high: the window is grown by
        // 2 cells around the eye)
        let map = dem.read_height_map(dem.full_window())?;
        return Ok(viewshed_from_dem(&map, frame, max_distance, target_height));
    }
    let band_rows = FileHeights::band_rows(dem);
    if band_rows > MAX_BAND_ROWS {
        // blocks of more rows than that (a file in one strip): each band
        // would hold much of the DEM, once per quadrant; read it once
        let map = dem.read_height_map(dem.full_window())?;
        return Ok(viewshed_from_dem(&map, frame, max_distance, target_height));
    }
    let ap = Apparent::new(frame, (c0, r0, nx), max_d);
    let (ex, ey) = frame.eye_pixel;
    let eye = (ex - 0.5 - c0 as f64, ey - 0.5 - r0 as f64);
    let heights = FileHeights::new(dem, ap, band_rows, ny, eye)?;
    let prop = Prop::new(&heights, frame, (c0, r0, nx, ny), max_d, target_height);
    prop.run(dem.width, dem.height, &dem.geotransform, &dem.crs)
}

/// The local frame of viewpoint `vp` on `dem`'s whole grid, reading only
/// the cells around it (for [`viewshed_from_file`]): the frame
/// [`Georef::local_frame`] gives on the DEM read whole.
pub fn eye_frame(
    dem: &Dem,
    georef: &Georef,
    vp: &Viewpoint,
    refraction_k: f64,
) -> Result<LocalFrame, RenderError> {
    let size = (dem.width, dem.height);
    let gt = dem.geotransform;
    // where the eye is needs no heights: found first with any ground
    let probe = georef.local_frame_on(vp, &gt, size, &|_, _| Some(0.0), refraction_k)?;
    let (px, py) = probe.eye_pixel;
    let c = (floor(px) as i64 - 2).max(0);
    let r = (floor(py) as i64 - 2).max(0);
    let win = Window::new(c, r, 5, 5)
        .intersect(&dem.full_window())
        .unwrap_or_else(|| Window::new(0, 0, 0, 0));
    let near = dem.read_height_map(win)?;
    let ground = |x: f64, y: f64| near.bilinear(x - win.col as f64, y - win.row as f64);
    Ok(georef.local_frame_on(vp, &gt, size, &ground, refraction_k)?)
}

/// The value of a result that cannot fail.
fn infallible<T>(r: Result<T, std::convert::Infallible>) -> T {
    match r {
        Ok(v) => v,
        Err(e) => match e {},
    }
}

/// Where [`Prop`] takes the apparent heights (relative to the eye,
/// curvature and refraction subtracted) of the terrain's vertices from.
trait Heights: Sync {
    /// What reading a row may fail with ([`std::convert::Infallible`] for
    /// heights in memory).
    type Error: Send;
    /// Vertices `c_lo..=c_hi` of row `r` into `buf[c + 1]` (NaN: nodata).
    /// `band` is the calling sweep's own buffer of rows read ahead (used by
    /// heights read from a file).
    fn row(
        &self,
        r: usize,
        c_lo: usize,
        c_hi: usize,
        buf: &mut [f64],
        band: &mut Band,
    ) -> Result<(), Self::Error>;
    /// Vertex `(c, r)`, NaN for nodata (only asked for vertices within a
    /// few cells of the eye).
    fn at(&self, c: usize, r: usize) -> f64;
}

/// Rows of DEM heights read ahead by one quadrant's sweep: DEM rows
/// `rows.0..rows.1`, columns `cols.0..cols.1`, row-major, NaN for nodata.
#[derive(Default)]
struct Band {
    rows: (usize, usize),
    cols: (usize, usize),
    data: Vec<f32>,
}

impl Heights for LocalTerrain {
    type Error = std::convert::Infallible;
    fn row(
        &self,
        r: usize,
        c_lo: usize,
        c_hi: usize,
        buf: &mut [f64],
        _: &mut Band,
    ) -> Result<(), Self::Error> {
        let row = self.z.row(r);
        let src = &row[c_lo..=c_hi];
        for (o, &v) in buf[c_lo + 1..=c_hi + 1].iter_mut().zip(src) {
            *o = v as f64;
        }
        Ok(())
    }
    fn at(&self, c: usize, r: usize) -> f64 {
        self.z.at_cr(c, r) as f64
    }
}

/// How the apparent height of a DEM cell is computed from its height, as
/// [`LocalTerrain`] computes it (the same expression, so the same bits).
struct Apparent {
    /// The window's first column and row in the DEM, and its width.
    c0: usize,
    r0: usize,
    nx: usize,
    p: [[f64; 2]; 2],
    eye_pixel: (f64, f64),
    coef: f64,
    eye_alt: f64,
    /// Squared distance beyond which vertices are nodata.
    max_d2: f64,
    /// Per window column, the first terms of east and north (`p[0][0] *
    /// dx` and `p[1][0] * dx`).
    pe: Vec<f64>,
    pn: Vec<f64>,
}

impl Apparent {
    fn new(frame: &LocalFrame, (c0, r0, nx): (usize, usize, usize), max_d: f64) -> Self {
        let (p, (ex, _)) = (frame.p, frame.eye_pixel);
        let dx0 = c0 as f64 + 0.5 - ex;
        let dx = |c: usize| dx0 + c as f64;
        Apparent {
            pe: (0..nx).map(|c| p[0][0] * dx(c)).collect(),
            pn: (0..nx).map(|c| p[1][0] * dx(c)).collect(),
            c0,
            r0,
            nx,
            p: frame.p,
            eye_pixel: frame.eye_pixel,
            coef: frame.curvature.coefficient(),
            eye_alt: frame.eye_alt,
            max_d2: max_d * max_d * 1.0001 + 1.0,
        }
    }

    /// The columns of the window's row that lie on a DEM `dem_width`
    /// cells wide, of those asked for (`c_lo..=c_hi`): `c_lo..end`.
    fn end(&self, dem_width: usize, c_lo: usize, c_hi: usize) -> usize {
        let inside = dem_width.saturating_sub(self.c0).min(self.nx);
        (c_hi + 1).min(inside).max(c_lo)
    }

    /// Apparent heights of window vertices `c_lo..` of DEM row `src_r`
    /// from their DEM heights `src` into `out` (as long as `src`).
    fn convert(&self, src_r: usize, c_lo: usize, src: &[f32], out: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (detected at run time).
            unsafe { self.convert_avx2(src_r, c_lo, src, out) };
            return;
        }
        self.convert_any(src_r, c_lo, src, out);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn convert_avx2(&self, src_r: usize, c_lo: usize, src: &[f32], out: &mut [f64]) {
        self.convert_any(src_r, c_lo, src, out);
    }

    #[inline(always)]
    fn convert_any(&self, src_r: usize, c_lo: usize, src: &[f32], out: &mut [f64]) {
        // the expression of LocalTerrain's build, term for term
        // (the terms in dx from the tables, the same products)
        let (p, (_, ey)) = (self.p, self.eye_pixel);
        let dy = src_r as f64 + 0.5 - ey;
        let (e0, n0) = (p[0][1] * dy, p[1][1] * dy);
        let (eye_alt, coef, max_d2) = (self.eye_alt, self.coef, self.max_d2);
        let n = src.len().min(out.len());
        let (pe, pn) = (&self.pe[c_lo..c_lo + n], &self.pn[c_lo..c_lo + n]);
        let (src, out) = (&src[..n], &mut out[..n]);
        for k in 0..n {
            let h = src[k];
            let o = &mut out[k];
            let e = pe[k] + e0;
            let nn = pn[k] + n0;
            let d2 = e * e + nn * nn;
            let v = (h as f64 - eye_alt - coef * d2) as f32;
            *o = if d2 > max_d2 { f64::NAN } else { v as f64 };
        }
    }
}

/// The apparent heights of a window of a DEM in memory.
struct DemHeights<'a> {
    dem: &'a HeightMap,
    ap: Apparent,
}

impl DemHeights<'_> {
    /// Vertices `c_lo..=c_hi` of row `r` into `out` (as long).
    fn fill(&self, r: usize, c_lo: usize, c_hi: usize, out: &mut [f64]) {
        let src_r = self.ap.r0 + r;
        let dem = self.dem;
        out.fill(f64::NAN);
        if src_r >= dem.height {
            return;
        }
        let end = self.ap.end(dem.width, c_lo, c_hi);
        let base = src_r * dem.width + self.ap.c0;
        let src = &dem.data[base + c_lo..base + end];
        self.ap.convert(src_r, c_lo, src, out);
    }
}

impl Heights for DemHeights<'_> {
    type Error = std::convert::Infallible;
    fn row(
        &self,
        r: usize,
        c_lo: usize,
        c_hi: usize,
        buf: &mut [f64],
        _: &mut Band,
    ) -> Result<(), Self::Error> {
        self.fill(r, c_lo, c_hi, &mut buf[c_lo + 1..=c_hi + 1]);
        Ok(())
    }
    fn at(&self, c: usize, r: usize) -> f64 {
        let mut one = [f64::NAN];
        self.fill(r, c, c, &mut one);
        one[0]
    }
}

/// The apparent heights of a window of a DEM read from its file in bands
/// of rows as each quadrant's sweep reaches them (whole blocks of the file,
/// so that no block is decoded twice by one quadrant), into a buffer the
/// quadrant reuses: the DEM is never in memory as a whole.
struct FileHeights<'a> {
    dem: &'a Dem,
    ap: Apparent,
    /// Rows per band (a multiple of the file's block height).
    band_rows: usize,
    /// The vertices around the eye ([`Heights::at`]): window vertex
    /// `(near.0, near.1)` is the map's first cell.
    near: (usize, usize, HeightMap),
}

/// The most rows a band of [`FileHeights`] may have: a DEM whose blocks
/// have more (one strip for the whole file, say) is read whole instead.
const MAX_BAND_ROWS: usize = 1024;

/// Window vertices on each side of the eye that [`FileHeights`] keeps for
/// the exact walk near the eye (which reaches [`EXACT_NEAR_CELLS`] + 2).
const NEAR_MARGIN: usize = 8;

impl<'a> FileHeights<'a> {
    /// Rows per band on `dem`: at least 64, a multiple of the height of
    /// its GeoTIFF blocks (the tallest, when its tiles differ: a block of a
    /// tile whose rows do not start on a band's then spans two bands, and
    /// is decoded twice, not once per band it would otherwise cross).
    fn band_rows(dem: &Dem) -> usize {
        let block = dem
            .tiles
            .iter()
            .filter_map(|t| match &t.source {
                crate::raster::TileSource::Tiff(tiff) => Some(tiff.layout.block_height as usize),
                crate::raster::TileSource::Gdal(_) => None,
            })
            .max()
            .unwrap_or(64)
            .max(1);
        block * 64usize.div_ceil(block)
    }

    fn new(
        dem: &'a Dem,
        ap: Apparent,
        band_rows: usize,
        ny: usize,
        eye: (f64, f64),
    ) -> Result<Self, RenderError> {
        let span = |e: f64, n: usize| {
            let e = floor(e).max(0.0) as usize;
            let lo = e.saturating_sub(NEAR_MARGIN).min(n.saturating_sub(1));
            let hi = (e + NEAR_MARGIN + 1).min(n);
            (lo, hi.max(lo))
        };
        let (cl, ch) = span(eye.0, ap.end(dem.width, 0, ap.nx.saturating_sub(1)));
        let (rl, rh) = span(eye.1, dem.height.saturating_sub(ap.r0).min(ny));
        let win = Window::new((ap.c0 + cl) as i64, (ap.r0 + rl) as i64, ch - cl, rh - rl);
        let map = if win.width > 0 && win.height > 0 {
            dem.read_height_map(win)?
        } else {
            HeightMap {
                width: 0,
                height: 0,
                data: Vec::new(),
                geotransform: dem.geotransform,
                crs: dem.crs.clone(),
            }
        };
        Ok(FileHeights {
            dem,
            ap,
            band_rows,
            near: (cl, rl, map),
        })
    }
}

impl Heights for FileHeights<'_> {
    type Error = RenderError;
    fn row(
        &self,
        r: usize,
        c_lo: usize,
        c_hi: usize,
        buf: &mut [f64],
        band: &mut Band,
    ) -> Result<(), RenderError> {
        let out = &mut buf[c_lo + 1..=c_hi + 1];
        out.fill(f64::NAN);
        let src_r = self.ap.r0 + r;
        let dem = self.dem;
        if src_r >= dem.height {
            return Ok(());
        }
        let end = self.ap.end(dem.width, c_lo, c_hi);
        if end == c_lo {
            return Ok(());
        }
        let cols = (self.ap.c0 + c_lo, self.ap.c0 + end);
        if !(band.rows.0 <= src_r
            && src_r < band.rows.1
            && band.cols.0 <= cols.0
            && cols.1 <= band.cols.1)
        {
            let lo = src_r / self.band_rows * self.band_rows;
            let hi = (lo + self.band_rows).min(dem.height);
            let win = Window::new(cols.0 as i64, lo as i64, cols.1 - cols.0, hi - lo);
            // (the previous band's buffer goes first, so that the
            // allocator hands its pages to the next)
            band.data = Vec::new();
            band.data = dem.read_height_map(win)?.data;
            band.rows = (lo, hi);
            band.cols = cols;
        }
        let w = band.cols.1 - band.cols.0;
        let at = (src_r - band.rows.0) * w + (cols.0 - band.cols.0);
        let src = &band.data[at..at + (cols.1 - cols.0)];
        self.ap.convert(src_r, c_lo, src, out);
        Ok(())
    }
    fn at(&self, c: usize, r: usize) -> f64 {
        let (cl, rl, map) = &self.near;
        let (Some(dc), Some(dr)) = (c.checked_sub(*cl), r.checked_sub(*rl)) else {
            debug_assert!(false, "vertex ({c}, {r}) is not near the eye");
            return f64::NAN;
        };
        if dc >= map.width || dr >= map.height {
            debug_assert!(
                c >= self.ap.nx || self.ap.r0 + r >= self.dem.height,
                "vertex ({c}, {r}) is not near the eye"
            );
            return f64::NAN;
        }
        let mut one = [f64::NAN];
        self.ap.convert(
            self.ap.r0 + r,
            c,
            &map.data[dr * map.width + dc..][..1],
            &mut one,
        );
        one[0]
    }
}

/// The horizon propagation of [`viewshed`] over one set of heights.
struct Prop<'a, H: Heights> {
    heights: &'a H,
    /// The window's first column and row in the DEM and its size.
    col0: usize,
    row0: usize,
    nx: usize,
    ny: usize,
    /// Eye in vertex coordinates.
    eye: (f64, f64),
    /// Vertex offsets -> local (east, north) metres.
    a: [[f64; 2]; 2],
    max_d2: f64,
    target_height: f64,
    /// Rows away from the eye in vector passes ([`RowScratch`]; else
    /// cell by cell, as the tests compare), with AVX2 where detected.
    vector_rows: bool,
    avx2: bool,
}

impl<'a, H: Heights> Prop<'a, H> {
    fn new(
        heights: &'a H,
        frame: &LocalFrame,
        (col0, row0, nx, ny): (usize, usize, usize, usize),
        max_distance: f64,
        target_height: f64,
    ) -> Self {
        // as LocalTerrain::v_to_en and eye_vertex
        let en =
            |vx: f64, vy: f64| frame.pixel_to_en(vx + 0.5 + col0 as f64, vy + 0.5 + row0 as f64);
        let (e0, n0) = en(0.0, 0.0);
        let (e1, n1) = en(1.0, 0.0);
        let (e2, n2) = en(0.0, 1.0);
        let (ex, ey) = frame.eye_pixel;
        Prop {
            heights,
            col0,
            row0,
            nx,
            ny,
            eye: (ex - 0.5 - col0 as f64, ey - 0.5 - row0 as f64),
            a: [[e1 - e0, e2 - e0], [n1 - n0, n2 - n0]],
            max_d2: max_distance * max_distance,
            target_height,
            vector_rows: true,
            #[cfg(target_arch = "x86_64")]
            avx2: std::arch::is_x86_feature_detected!("avx2"),
            #[cfg(not(target_arch = "x86_64"))]
            avx2: false,
        }
    }

    /// The viewshed on the DEM's grid (`width` x `height` cells, with
    /// that georeferencing), the four quadrants in parallel.
    fn run(
        &self,
        width: usize,
        height: usize,
        geotransform: &GeoTransform,
        crs: &Crs,
    ) -> Result<Viewshed, H::Error> {
        let mut data = vec![0u8; width * height];
        {
            // SAFETY: AtomicU8 has the size, alignment and bit validity of
            // u8, and `data` is not otherwise accessed while `out` lives.
            let out: &[AtomicU8] =
                unsafe { &*(data.as_mut_slice() as *mut [u8] as *const [AtomicU8]) };
            let grid = OutGrid {
                out,
                width,
                height,
                col0: self.col0,
                row0: self.row0,
            };
            [(1i8, 1i8), (1, -1), (-1, 1), (-1, -1)]
                .into_par_iter()
                .try_for_each(|(sx, sy)| {
                    Quadrant::new(self.eye, (self.nx, self.ny), sx, sy).propagate(self, &grid)
                })?;
        }
        Ok(Viewshed {
            width,
            height,
            data,
            geotransform: *geotransform,
            crs: crs.clone(),
        })
    }
}

/// No horizon yet (finite, so that interpolating it stays a number).
const NO_HORIZON: f64 = -1.0e300;

/// One quadrant of [`viewshed`]'s propagation: columns from the eye's
/// outward in direction `sx` and rows outward in direction `sy`, the one or
/// two columns (rows) within a cell of the eye included on both sides (the
/// quadrants compute them alike; each cell is written by the one quadrant
/// that owns it: `du >= 0` for `sx = +1`, `du < 0` for `sx = -1`, and the
/// same for rows).
struct Quadrant {
    sx: i8,
    sy: i8,
    /// Columns and rows in the order of the sweep (outward).
    cols: Vec<usize>,
    rows: Vec<usize>,
}

impl Quadrant {
    fn new((eu, ev): (f64, f64), (nx, ny): (usize, usize), sx: i8, sy: i8) -> Self {
        // integers within a cell of the eye, then outward
        let order = |e: f64, s: i8, n: usize| -> Vec<usize> {
            let last = n as i64 - 1;
            if s > 0 {
                let start = (floor(e) as i64).max(0);
                (start..=last).map(|i| i as usize).collect()
            } else {
                let start = (-floor(-e) as i64).min(last);
                (0..=start).rev().map(|i| i as usize).collect()
            }
        };
        Quadrant {
            sx,
            sy,
            cols: order(eu, sx, nx),
            rows: order(ev, sy, ny),
        }
    }

    /// Sweep the quadrant, marking the visible cells it owns.
    fn propagate<H: Heights>(&self, sweep: &Prop<H>, grid: &OutGrid) -> Result<(), H::Error> {
        let nx = sweep.nx;
        let (eu, ev) = sweep.eye;
        let mut band = Band::default();
        let mut fill =
            |r, c_lo, c_hi, buf: &mut [f64]| sweep.heights.row(r, c_lo, c_hi, buf, &mut band);
        let pad = nx + 2;
        let (Some(&c_first), Some(&c_last)) = (self.cols.first(), self.cols.last()) else {
            return Ok(());
        };
        if self.rows.is_empty() {
            return Ok(());
        }
        let (c_lo, c_hi) = (c_first.min(c_last), c_first.max(c_last));
        let blank_z = vec![f64::NAN; pad];
        let blank_g = vec![NO_HORIZON; pad];
        // horizons (largest tan elevation from the eye to the vertex, the
        // vertex included) and heights of the current and previous rows
        let (mut g_cur, mut g_prev) = (blank_g.clone(), blank_g.clone());
        let (mut z_cur, mut z_prev) = (blank_z.clone(), blank_z.clone());
        // the rows within a cell of the eye first, column by column
        let axis: Vec<usize> = self
            .rows
            .iter()
            .copied()
            .take_while(|&r| (r as f64 - ev).abs() < 1.0)
            .collect();
        let owns_row = |r: usize| (r as f64 >= ev) == (self.sy > 0);
        let owns_col = |c: usize| (c as f64 >= eu) == (self.sx > 0);
        if !axis.is_empty() {
            // row a (and b, the other axis row, when there are two)
            let (mut g_a, mut g_b) = (blank_g.clone(), blank_g.clone());
            let (mut z_a, mut z_b) = (blank_z.clone(), blank_z.clone());
            fill(axis[0], c_lo, c_hi, &mut z_a)?;
            if axis.len() > 1 {
                fill(axis[1], c_lo, c_hi, &mut z_b)?;
            }
            for &c in &self.cols {
                let vis = sweep.cell(c, axis[0], &z_a, &z_b, &mut g_a, &g_b);
                if vis && owns_row(axis[0]) && owns_col(c) {
                    grid.set(c, axis[0]);
                }
                if axis.len() > 1 {
                    let vis = sweep.cell(c, axis[1], &z_b, &z_a, &mut g_b, &g_a);
                    if vis && owns_row(axis[1]) && owns_col(c) {
                        grid.set(c, axis[1]);
                    }
                }
            }
            // the last axis row is the one before the first other row
            if axis.len() > 1 {
                (g_prev, z_prev) = (g_b, z_b);
            } else {
                (g_prev, z_prev) = (g_a, z_a);
            }
        }
        let mut rows = RowScratch::new(sweep, pad);
        let near = EXACT_NEAR_CELLS + 1.0;
        // rows away from the eye in vector passes, two at a time
        let far = |r: usize| sweep.vector_rows && (r as f64 - ev).abs() > near;
        let (mut g_next, mut z_next) = (blank_g.clone(), blank_z.clone());
        let rest = &self.rows[axis.len()..];
        let mut j = 0;
        while j < rest.len() {
            let r = rest[j];
            fill(r, c_lo, c_hi, &mut z_cur)?;
            let own_r = owns_row(r);
            let cells = |r, z_r, z_o| RowCells {
                r,
                sx: self.sx,
                c_lo,
                c_hi,
                z_r,
                z_o,
            };
            if far(r) && j + 1 < rest.len() {
                let r2 = rest[j + 1];
                fill(r2, c_lo, c_hi, &mut z_next)?;
                let one = cells(r, &z_cur, &z_prev);
                let two = cells(r2, &z_next, &z_cur);
                rows.rows2(sweep, (&one, &two), &g_prev, &mut g_cur, &mut g_next);
                if own_r {
                    rows.mark(0, &one, grid);
                }
                if owns_row(r2) {
                    rows.mark(1, &two, grid);
                }
                std::mem::swap(&mut g_next, &mut g_prev);
                std::mem::swap(&mut z_next, &mut z_prev);
                j += 2;
                continue;
            }
            if far(r) {
                let one = cells(r, &z_cur, &z_prev);
                rows.row(sweep, &one, &g_prev, &mut g_cur);
                if own_r {
                    rows.mark(0, &one, grid);
                }
            } else {
                for &c in &self.cols {
                    let vis = sweep.cell(c, r, &z_cur, &z_prev, &mut g_cur, &g_prev);
                    if vis && own_r && owns_col(c) {
                        grid.set(c, r);
                    }
                }
            }
            std::mem::swap(&mut g_cur, &mut g_prev);
            std::mem::swap(&mut z_cur, &mut z_prev);
            j += 1;
        }
        Ok(())
    }
}

impl<H: Heights> Prop<'_, H> {
    /// Decide vertex `(c, r)` and set its horizon `g_r[c + 1]`, from the
    /// heights `z_r` of its row and `z_o` of the row next to it towards
    /// the eye, and that row's horizons `g_o` (all indexed `c + 1`; the
    /// vertices towards the eye in its own row already decided).
    ///
    /// The line of sight from the eye to the vertex crosses the grid line
    /// one step nearer the eye (the previous column where `|du| >= |dv|`,
    /// else the previous row) at a point `C` between two vertices `Q0`,
    /// `Q1`; the horizon there is interpolated between theirs. From `C` to
    /// the vertex the line of sight stays in one cell, where it crosses at
    /// most the cell's diagonal: the triangulated surface along it is
    /// linear between `C`, that crossing and the vertex, so the largest
    /// elevation angle on that stretch is exact. Cells within
    /// [`EXACT_NEAR_CELLS`] of the eye are decided by an exact walk.
    #[inline(always)]
    fn cell(
        &self,
        c: usize,
        r: usize,
        z_r: &[f64],
        z_o: &[f64],
        g_r: &mut [f64],
        g_o: &[f64],
    ) -> bool {
        let (du, dv) = (c as f64 - self.eye.0, r as f64 - self.eye.1);
        let (adu, adv) = (du.abs(), dv.abs());
        let i = c + 1;
        let z = z_r[i];
        let e = self.a[0][0] * du + self.a[0][1] * dv;
        let n = self.a[1][0] * du + self.a[1][1] * dv;
        let s2 = e * e + n * n;
        let near = EXACT_NEAR_CELLS + 1.0;
        if adu <= near && adv <= near {
            let (g, vis) = self.walk(c, r, s2.sqrt());
            g_r[i] = g;
            return vis && s2 <= self.max_d2;
        }
        let d = s2.sqrt();
        let inv_d = 1.0 / d;
        // the neighbour towards the eye along columns
        let ic = if du > 0.0 { i - 1 } else { i + 1 };
        let anti = du * dv < 0.0;
        let mut h;
        if adu >= adv {
            // C on the previous column, between Q0 = (c', r) and Q1 = (c', r')
            let w = adv / adu;
            let (zq0, zq1) = (z_r[ic], z_o[ic]);
            h = g_r[ic] * (1.0 - w) + g_o[ic] * w;
            let k = adu * inv_d;
            // (Q1 unused on the eye's row, where it may be off the grid)
            let zc = zq0 * (1.0 - w) + if w > 0.0 { zq1 * w } else { 0.0 };
            let t = zc * k / (adu - 1.0);
            if t > h {
                h = t;
            }
            if anti && w > 0.0 {
                // the diagonal from (c', r) to (c, r'), at s of the step
                let s = w / (1.0 + w);
                let zx = zq0 * (1.0 - s) + z_o[i] * s;
                let t = zx * k / (adu - 1.0 + s);
                if t > h {
                    h = t;
                }
            }
        } else {
            // C on the previous row, between Q0 = (c, r') and Q1 = (c', r')
            let w = adu / adv;
            let (zq0, zq1) = (z_o[i], z_o[ic]);
            h = g_o[i] * (1.0 - w) + if w > 0.0 { g_o[ic] * w } else { 0.0 };
            let k = adv * inv_d;
            let zc = zq0 * (1.0 - w) + if w > 0.0 { zq1 * w } else { 0.0 };
            let t = zc * k / (adv - 1.0);
            if t > h {
                h = t;
            }
            if anti && w > 0.0 {
                // the diagonal from (c, r') to (c', r)
                let s = w / (1.0 + w);
                let zx = zq0 * (1.0 - s) + z_r[ic] * s;
                let t = zx * k / (adv - 1.0 + s);
                if t > h {
                    h = t;
                }
            }
        }
        let own = z * inv_d;
        g_r[i] = if own > h { own } else { h };
        z + self.target_height + 1e-3 >= h * d && s2 <= self.max_d2
    }

    /// The exact line of sight to vertex `(c, r)` (horizontal distance
    /// `d` metres) over the triangulated surface: its horizon (the largest
    /// tan elevation up to and including the vertex) and whether the vertex
    /// plus the target height is visible. Every crossing of the segment
    /// with a grid line or cell diagonal counts (in any order: only the
    /// largest matters).
    #[cold]
    #[inline(never)]
    fn walk(&self, c: usize, r: usize, d: f64) -> (f64, bool) {
        let z = self.heights.at(c, r);
        if z.is_nan() {
            return (self.walk_best(c, r, d), false);
        }
        if d < 1e-9 {
            return (NO_HORIZON, true);
        }
        let best = self.walk_best(c, r, d);
        let vis = z + self.target_height + 1e-3 >= best * d;
        let own = z / d;
        (if own > best { own } else { best }, vis)
    }

    /// The largest tan elevation of the triangulated surface strictly
    /// between the eye and vertex `(c, r)`, `d` metres away.
    fn walk_best(&self, c: usize, r: usize, d: f64) -> f64 {
        let (eu, ev) = self.eye;
        let (du, dv) = (c as f64 - eu, r as f64 - ev);
        let mut best = NO_HORIZON;
        if d < 1e-9 {
            return best;
        }
        let mut at = |tt: f64| {
            if tt > 1e-12 && tt < 1.0 - 1e-12 {
                let h = self.surface_z(eu + tt * du, ev + tt * dv);
                let s = tt * d;
                if h > best * s {
                    best = h / s;
                }
            }
        };
        // lines u = k, v = k and v - u = k strictly between the ends
        for (a0, da) in [(eu, du), (ev, dv), (ev - eu, dv - du)] {
            if da != 0.0 {
                let (lo, hi) = (a0.min(a0 + da), a0.max(a0 + da));
                let mut k = floor(lo) + 1.0;
                while k < hi {
                    at((k - a0) / da);
                    k += 1.0;
                }
            }
        }
        best
    }

    /// Height of the triangulated surface at vertex coordinates `(u, v)`
    /// (NaN in holes and off the grid).
    fn surface_z(&self, u: f64, v: f64) -> f64 {
        let (nx, ny) = (self.nx, self.ny);
        if u < 0.0 || v < 0.0 || u > (nx - 1) as f64 || v > (ny - 1) as f64 {
            return f64::NAN;
        }
        let cu = (floor(u) as usize).min(nx - 2);
        let cv = (floor(v) as usize).min(ny - 2);
        let (fx, fy) = (u - cu as f64, v - cv as f64);
        let zv = |c: usize, r: usize| self.heights.at(c, r);
        let (z00, z10, z01, z11) = (
            zv(cu, cv),
            zv(cu + 1, cv),
            zv(cu, cv + 1),
            zv(cu + 1, cv + 1),
        );
        if fx >= fy {
            z00 + fx * (z10 - z00) + fy * (z11 - z10)
        } else {
            z00 + fy * (z01 - z00) + fx * (z11 - z01)
        }
    }
}

/// The constants of one row's vector passes ([`RowScratch`]).
struct RowPass {
    /// `dv` times the second column of the metric matrix.
    a01: f64,
    a11: f64,
    /// `|dv|`, the target height and the squared maximum distance.
    adv: f64,
    th: f64,
    max_d2: f64,
}

/// Per column of a stretch: `du`, its east and north images, then
/// heights of the row (`z_r`) and of the row before (`z_o`) and horizons
/// of the row before (`g_o`), each at the column and at its neighbour
/// towards the eye.
type RowArgs<'a> = (
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
);
type ColArgs<'a> = (
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
    &'a [f64],
);

impl RowPass {
    /// [`Prop::cell`] over a stretch where the line of sight crosses the
    /// previous row (`ANTI`: the vertices lie across a cell diagonal).
    #[inline(always)]
    fn rows<const ANTI: bool>(&self, args: RowArgs, g_r: &mut [f64], vis: &mut [u8]) {
        let (du, ae, an, z_r, z_r_c, z_o, z_o_c, g_o, g_o_c) = args;
        let n = g_r.len();
        let (du, ae, an, z_r, z_r_c) = (&du[..n], &ae[..n], &an[..n], &z_r[..n], &z_r_c[..n]);
        let (z_o, z_o_c, g_o, g_o_c, vis) = (
            &z_o[..n],
            &z_o_c[..n],
            &g_o[..n],
            &g_o_c[..n],
            &mut vis[..n],
        );
        let (adv, am1) = (self.adv, self.adv - 1.0);
        for k in 0..n {
            let adu = du[k].abs();
            let e = ae[k] + self.a01;
            let nn = an[k] + self.a11;
            let s2 = e * e + nn * nn;
            let d = s2.sqrt();
            let inv_d = 1.0 / d;
            let w = adu / adv;
            let (zq0, zq1) = (z_o[k], z_o_c[k]);
            let mut h = g_o[k] * (1.0 - w) + g_o_c[k] * w;
            let kk = adv * inv_d;
            let zc = zq0 * (1.0 - w) + zq1 * w;
            let t = zc * kk / am1;
            h = if t > h { t } else { h };
            if ANTI {
                let s = w / (1.0 + w);
                let zx = zq0 * (1.0 - s) + z_r_c[k] * s;
                let t = zx * kk / (am1 + s);
                h = if t > h { t } else { h };
            }
            let z = z_r[k];
            let own = z * inv_d;
            g_r[k] = if own > h { own } else { h };
            vis[k] = (z + self.th + 1e-3 >= h * d && s2 <= self.max_d2) as u8;
        }
    }

    /// What [`Prop::cell`] computes without the neighbour's horizon over a
    /// stretch where the line of sight crosses the previous column: the
    /// weight `w`, the largest tan elevation of the last step `tm`, the
    /// vertex's own and its distance (NaN beyond the maximum distance).
    #[inline(always)]
    fn cols<const ANTI: bool>(
        &self,
        args: ColArgs,
        (w_out, tm_out, own_out, dist_out): (&mut [f64], &mut [f64], &mut [f64], &mut [f64]),
    ) {
        let (du, ae, an, z_r, z_r_c, z_o, z_o_c) = args;
        let n = w_out.len();
        let (du, ae, an, z_r, z_r_c) = (&du[..n], &ae[..n], &an[..n], &z_r[..n], &z_r_c[..n]);
        let (z_o, z_o_c) = (&z_o[..n], &z_o_c[..n]);
        let (tm_out, own_out, dist_out) = (&mut tm_out[..n], &mut own_out[..n], &mut dist_out[..n]);
        let adv = self.adv;
        for k in 0..n {
            let adu = du[k].abs();
            let e = ae[k] + self.a01;
            let nn = an[k] + self.a11;
            let s2 = e * e + nn * nn;
            let d = s2.sqrt();
            let inv_d = 1.0 / d;
            let w = adv / adu;
            let (zq0, zq1) = (z_r_c[k], z_o_c[k]);
            let kk = adu * inv_d;
            let zc = zq0 * (1.0 - w) + zq1 * w;
            let bm1 = adu - 1.0;
            let mut tm = zc * kk / bm1;
            if ANTI {
                let s = w / (1.0 + w);
                let zx = zq0 * (1.0 - s) + z_o[k] * s;
                let t = zx * kk / (bm1 + s);
                // the larger, a NaN (a hole) counting for nothing
                tm = if t > tm || tm.is_nan() { t } else { tm };
            }
            w_out[k] = w;
            tm_out[k] = tm;
            own_out[k] = z_r[k] * inv_d;
            dist_out[k] = if s2 <= self.max_d2 { d } else { f64::NAN };
        }
    }
}

/// One row of a quadrant for [`RowScratch`]: row `r`, swept in direction
/// `sx` over columns `c_lo..=c_hi`, its heights `z_r` and those of the row
/// before it `z_o` (towards the eye), indexed `c + 1`.
struct RowCells<'a> {
    r: usize,
    sx: i8,
    c_lo: usize,
    c_hi: usize,
    z_r: &'a [f64],
    z_o: &'a [f64],
}

/// What [`RowScratch`] keeps of one row between its passes, per column
/// (`c + 1`) where the line of sight crosses the previous column: the
/// weight `w` of the neighbour row's horizon, the largest tan elevation of
/// the last step `tm`, the vertex's own, and its distance (NaN beyond the
/// maximum distance); and, for every column, whether it is visible (1).
struct Lane {
    w: Vec<f64>,
    tm: Vec<f64>,
    own: Vec<f64>,
    dist: Vec<f64>,
    vis: Vec<u8>,
}

impl Lane {
    fn new(pad: usize) -> Self {
        Lane {
            w: vec![0.0; pad],
            tm: vec![0.0; pad],
            own: vec![0.0; pad],
            dist: vec![0.0; pad],
            vis: vec![0; pad],
        }
    }

    /// The horizon carried outward over column `i` (its neighbour towards
    /// the eye has horizon `prev` in this row and `g_o_c` in the row
    /// before): the vertex's horizon, and its visibility in `vis`.
    #[inline(always)]
    fn carry(&mut self, i: usize, prev: f64, g_o_c: f64, z: f64, th: f64) -> f64 {
        let w = self.w[i];
        let mut h = prev * (1.0 - w) + g_o_c * w;
        let tm = self.tm[i];
        h = if tm > h { tm } else { h };
        let own = self.own[i];
        self.vis[i] = (z + th + 1e-3 >= h * self.dist[i]) as u8;
        if own > h {
            own
        } else {
            h
        }
    }
}

/// What [`Prop::cell`] computes for a row, rearranged so that it runs on
/// vectors: a row more than [`EXACT_NEAR_CELLS`] + 1 from the eye is, on
/// the quadrant's side of the eye's column, one stretch where the line of
/// sight crosses the previous row (`|du| < |dv|`: each vertex depends on
/// the row before only, computed over all of them at once) and one where
/// it crosses the previous column (`|du| >= |dv|`: each vertex takes its
/// neighbour's horizon; all that does not depend on it, the divisions and
/// square roots, is computed first over the stretch at once, then a short
/// serial pass carries the horizon outward, two rows at a time, the outer
/// one a column behind, so that the two carries overlap). The same
/// operations in the same order as [`Prop::cell`], so the same bits; the
/// one or two columns within a cell of the eye's go through [`Prop::cell`]
/// itself. On x86-64 with AVX2 (detected at run time) the passes run on 4
/// lanes.
struct RowScratch {
    /// Per column (`c + 1`): `c - eye`, and its images in east and north
    /// metres (the first terms of [`Prop::cell`]'s `e` and `n`).
    du: Vec<f64>,
    ae: Vec<f64>,
    an: Vec<f64>,
    /// The row being done, and the one after it.
    lanes: [Lane; 2],
    avx2: bool,
}

impl RowScratch {
    fn new<H: Heights>(prop: &Prop<H>, pad: usize) -> Self {
        let eu = prop.eye.0;
        let du: Vec<f64> = (0..pad).map(|i| i as f64 - 1.0 - eu).collect();
        let ae = du.iter().map(|&d| prop.a[0][0] * d).collect();
        let an = du.iter().map(|&d| prop.a[1][0] * d).collect();
        RowScratch {
            du,
            ae,
            an,
            lanes: [Lane::new(pad), Lane::new(pad)],
            avx2: prop.avx2,
        }
    }

    /// Horizons `g_r` and visibility (`lanes[0].vis`) of the row's
    /// vertices, from the horizons `g_o` of the row before.
    fn row<H: Heights>(&mut self, prop: &Prop<H>, cells: &RowCells, g_o: &[f64], g_r: &mut [f64]) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: AVX2 is present (detected at run time).
            unsafe { self.row_avx2(prop, cells, g_o, g_r) };
            return;
        }
        self.row_any(prop, cells, g_o, g_r);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn row_avx2<H: Heights>(
        &mut self,
        prop: &Prop<H>,
        cells: &RowCells,
        g_o: &[f64],
        g_r: &mut [f64],
    ) {
        self.row_any(prop, cells, g_o, g_r);
    }

    #[inline(always)]
    fn row_any<H: Heights>(
        &mut self,
        prop: &Prop<H>,
        cells: &RowCells,
        g_o: &[f64],
        g_r: &mut [f64],
    ) {
        let cols = self.prep(0, prop, cells, g_o, g_r);
        self.carry_one(prop, cells, g_o, g_r, cols);
    }

    /// [`RowScratch::row`] for two rows, `one` and `two` the next outward
    /// (`lanes[0].vis` and `lanes[1].vis`): `g_o` the horizons of the row
    /// before `one`, `g_1` and `g_2` theirs.
    fn rows2<H: Heights>(
        &mut self,
        prop: &Prop<H>,
        (one, two): (&RowCells, &RowCells),
        g_o: &[f64],
        g_1: &mut [f64],
        g_2: &mut [f64],
    ) {
        #[cfg(target_arch = "x86_64")]
        if self.avx2 {
            // SAFETY: AVX2 is present (detected at run time).
            unsafe { self.rows2_avx2(prop, (one, two), g_o, g_1, g_2) };
            return;
        }
        self.rows2_any(prop, (one, two), g_o, g_1, g_2);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn rows2_avx2<H: Heights>(
        &mut self,
        prop: &Prop<H>,
        rows: (&RowCells, &RowCells),
        g_o: &[f64],
        g_1: &mut [f64],
        g_2: &mut [f64],
    ) {
        self.rows2_any(prop, rows, g_o, g_1, g_2);
    }

    #[inline(always)]
    fn rows2_any<H: Heights>(
        &mut self,
        prop: &Prop<H>,
        (one, two): (&RowCells, &RowCells),
        g_o: &[f64],
        g_1: &mut [f64],
        g_2: &mut [f64],
    ) {
        let cols1 = self.prep(0, prop, one, g_o, g_1);
        let adv2 = (two.r as f64 - prop.eye.1).abs();
        let [_, _, cols2] = self.split(two, adv2);
        // the first row's carry up to where the second's starts (the
        // second's stretch across rows reads its horizons up to there)
        let (head, shared) = if one.sx > 0 {
            let at = cols2.start.max(cols1.start);
            (cols1.start..at, at..cols1.end)
        } else {
            let at = cols2.end.min(cols1.end);
            (at..cols1.end, cols1.start..at)
        };
        self.carry_one(prop, one, g_o, g_1, head);
        let cols2 = self.prep(1, prop, two, g_1, g_2);
        debug_assert!(shared.is_empty() || cols2 == shared);
        if shared.is_empty() {
            self.carry_one_lane(1, prop, two, g_1, g_2, cols2);
            return;
        }
        // both carries over the shared columns, the second row reading
        // the first's horizon at the column before (not yet overwritten)
        let th = prop.target_height;
        let (z1, z2) = (one.z_r, two.z_r);
        let [l1, l2] = &mut self.lanes;
        if one.sx > 0 {
            let (mut p1, mut p2) = (g_1[shared.start - 1], g_2[shared.start - 1]);
            for i in shared {
                let q1 = p1;
                p1 = l1.carry(i, p1, g_o[i - 1], z1[i], th);
                g_1[i] = p1;
                p2 = l2.carry(i, p2, q1, z2[i], th);
                g_2[i] = p2;
            }
        } else {
            let (mut p1, mut p2) = (g_1[shared.end], g_2[shared.end]);
            for i in shared.rev() {
                let q1 = p1;
                p1 = l1.carry(i, p1, g_o[i + 1], z1[i], th);
                g_1[i] = p1;
                p2 = l2.carry(i, p2, q1, z2[i], th);
                g_2[i] = p2;
            }
        }
    }

    /// The columns of the quadrant's row (as `c + 1`) on its side of the
    /// eye's: `(inner, rows, cols)`, the ranges within a cell of the eye's
    /// column (for [`Prop::cell`]), where the line of sight crosses the
    /// previous row, and where it crosses the previous column (in
    /// increasing order; the quadrant goes outward).
    #[inline(always)]
    fn split(&self, cells: &RowCells, adv: f64) -> [std::ops::Range<usize>; 3] {
        let (lo, hi) = (cells.c_lo + 1, cells.c_hi + 2);
        let du = &self.du;
        // the first index where `p` holds (`p` is monotone over [lo, hi))
        let first = |p: &dyn Fn(f64) -> bool| lo + du[lo..hi].partition_point(|&d| !p(d));
        if cells.sx > 0 {
            let a = first(&|d| d > 0.0);
            let b = first(&|d| d >= adv);
            [lo..a, a..b.max(a), b.max(a)..hi]
        } else {
            // du decreasing outward: here increasing with the index
            let a = first(&|d| d >= 0.0);
            let b = first(&|d| d > -adv);
            [a..hi, b.min(a)..a, lo..b.min(a)]
        }
    }

    /// The row's vertices within a cell of the eye's column and across
    /// the previous row (horizons into `g_r`, visibility into the lane),
    /// and what those across the previous column need without their
    /// neighbour's horizon; returns the columns of the latter.
    #[inline(always)]
    fn prep<H: Heights>(
        &mut self,
        lane: usize,
        prop: &Prop<H>,
        cells: &RowCells,
        g_o: &[f64],
        g_r: &mut [f64],
    ) -> std::ops::Range<usize> {
        let (z_r, z_o) = (cells.z_r, cells.z_o);
        let r = cells.r;
        let dv = r as f64 - prop.eye.1;
        let adv = dv.abs();
        let [inner, rows, cols] = self.split(cells, adv);
        let lane = &mut self.lanes[lane];
        // within a cell of the eye's column: as any other cell
        for i in inner {
            lane.vis[i] = prop.cell(i - 1, r, z_r, z_o, g_r, g_o) as u8;
        }
        let (a01, a11) = (prop.a[0][1] * dv, prop.a[1][1] * dv);
        let (th, max_d2) = (prop.target_height, prop.max_d2);
        // the neighbour towards the eye along the row, and whether the
        // stretch's vertices lie across a diagonal (du * dv < 0)
        let (off, anti) = if cells.sx > 0 {
            (-1isize, dv < 0.0)
        } else {
            (1, dv > 0.0)
        };
        let ic = |i: usize| i.wrapping_add_signed(off);
        let rp = RowPass {
            a01,
            a11,
            adv,
            th,
            max_d2,
        };
        // crossing the previous row: all at once
        if !rows.is_empty() {
            let (a, n) = (rows.start, rows.len());
            let ca = ic(a);
            let args = (
                &self.du[a..a + n],
                &self.ae[a..a + n],
                &self.an[a..a + n],
                &z_r[a..a + n],
                &z_r[ca..ca + n],
                &z_o[a..a + n],
                &z_o[ca..ca + n],
                &g_o[a..a + n],
                &g_o[ca..ca + n],
            );
            let (g, vis) = (&mut g_r[a..a + n], &mut lane.vis[a..a + n]);
            if anti {
                rp.rows::<true>(args, g, vis);
            } else {
                rp.rows::<false>(args, g, vis);
            }
        }
        // crossing the previous column: what does not depend on the
        // neighbour's horizon, all at once
        if !cols.is_empty() {
            let (a, n) = (cols.start, cols.len());
            let ca = ic(a);
            let args = (
                &self.du[a..a + n],
                &self.ae[a..a + n],
                &self.an[a..a + n],
                &z_r[a..a + n],
                &z_r[ca..ca + n],
                &z_o[a..a + n],
                &z_o[ca..ca + n],
            );
            let outs = (
                &mut lane.w[a..a + n],
                &mut lane.tm[a..a + n],
                &mut lane.own[a..a + n],
                &mut lane.dist[a..a + n],
            );
            if anti {
                rp.cols::<true>(args, outs);
            } else {
                rp.cols::<false>(args, outs);
            }
        }
        cols
    }

    /// The horizon of lane 0's row carried outward over `cols` (a part of
    /// its stretch across the previous column, from its inner end).
    #[inline(always)]
    fn carry_one<H: Heights>(
        &mut self,
        prop: &Prop<H>,
        cells: &RowCells,
        g_o: &[f64],
        g_r: &mut [f64],
        cols: std::ops::Range<usize>,
    ) {
        self.carry_one_lane(0, prop, cells, g_o, g_r, cols);
    }

    #[inline(always)]
    fn carry_one_lane<H: Heights>(
        &mut self,
        lane: usize,
        prop: &Prop<H>,
        cells: &RowCells,
        g_o: &[f64],
        g_r: &mut [f64],
        cols: std::ops::Range<usize>,
    ) {
        if cols.is_empty() {
            return;
        }
        let (th, z_r) = (prop.target_height, cells.z_r);
        let lane = &mut self.lanes[lane];
        if cells.sx > 0 {
            let mut prev = g_r[cols.start - 1];
            for i in cols {
                prev = lane.carry(i, prev, g_o[i - 1], z_r[i], th);
                g_r[i] = prev;
            }
        } else {
            let mut prev = g_r[cols.end];
            for i in cols.rev() {
                prev = lane.carry(i, prev, g_o[i + 1], z_r[i], th);
                g_r[i] = prev;
            }
        }
    }

    /// Mark the visible vertices of lane `lane`'s row that the quadrant
    /// owns on the grid (those at or right of the eye's column for `sx =
    /// +1`, those left of it for `sx = -1`).
    fn mark(&self, lane: usize, cells: &RowCells, grid: &OutGrid) {
        let (lo, hi) = (cells.c_lo + 1, cells.c_hi + 2);
        // (du is c - eye: c >= eye is du >= 0)
        let at = lo + self.du[lo..hi].partition_point(|&d| d < 0.0);
        let owned = if cells.sx > 0 { at..hi } else { lo..at };
        if !owned.is_empty() {
            grid.put_row(owned.start - 1, cells.r, &self.lanes[lane].vis[owned]);
        }
    }
}

/// Rays per bundle of [`viewshed_rays`] (neighbours in azimuth).
const RAY_BUNDLE: usize = 32;
/// Grid lines each ray of a bundle advances before the next ray's turn.
const BUNDLE_STEPS: usize = 32;

/// The output grid, written by the rays: each vertex by exactly one.
struct OutGrid<'a> {
    out: &'a [AtomicU8],
    width: usize,
    height: usize,
    col0: usize,
    row0: usize,
}

impl OutGrid<'_> {
    /// Mark terrain vertex `(c, r)` visible.
    #[inline]
    fn set(&self, c: usize, r: usize) {
        let (col, row) = (self.col0 + c, self.row0 + r);
        if col < self.width && row < self.height {
            self.out[row * self.width + col].store(255, Ordering::Relaxed);
        }
    }

    /// Mark visible the terrain vertices `c_from..` of row `r` whose
    /// `vis` is 1 (`vis` holds 0 or 1). The caller owns these vertices: no
    /// other thread writes or reads them while the grid lives.
    fn put_row(&self, c_from: usize, r: usize, vis: &[u8]) {
        let (col, row) = (self.col0 + c_from, self.row0 + r);
        if col >= self.width || row >= self.height {
            return;
        }
        let n = vis.len().min(self.width - col);
        let cells = &self.out[row * self.width + col..][..n];
        // Relaxed stores: these cells are this caller's alone (see above);
        // on the targets we build for they are plain byte stores.
        for (o, &v) in cells.iter().zip(&vis[..n]) {
            if v != 0 {
                o.store(255, Ordering::Relaxed);
            }
        }
    }
}

/// One of the four halves of the grid around the eye that [`viewshed`]
/// sweeps: east and west (vertices with `|du| >= |dv|`, rays advancing
/// along columns) and north and south (`|du| < |dv|`, along rows). Axes are
/// (major, minor): the axis the rays advance along by whole lines, and the
/// other.
struct Half {
    u_major: bool,
    /// Direction of the rays along the major axis, +1 or -1.
    sx: f64,
    /// Eye in (major, minor) vertex coordinates.
    ex: f64,
    ey: f64,
    /// Strides of (major, minor) in the row-major heights.
    sm: usize,
    sn: usize,
    nmaj: usize,
    nmin: usize,
}

impl Half {
    fn all(sweep: &Sweep) -> Vec<Half> {
        let t = sweep.terrain;
        let (eu, ev) = sweep.eye;
        let mut v = Vec::new();
        for u_major in [true, false] {
            for sx in [1.0, -1.0] {
                let (ex, ey, sm, sn, nmaj, nmin) = if u_major {
                    (eu, ev, 1, t.nx, t.nx, t.ny)
                } else {
                    (ev, eu, t.nx, 1, t.ny, t.nx)
                };
                v.push(Half {
                    u_major,
                    sx,
                    ex,
                    ey,
                    sm,
                    sn,
                    nmaj,
                    nmin,
                });
            }
        }
        v
    }

    /// Whether vertex (major offset `dx`, minor offset `dy`) from the eye
    /// belongs to this half (`dx` has the half's sign).
    #[inline]
    fn owns(&self, dx: f64, dy: f64) -> bool {
        if self.u_major {
            dy.abs() <= dx.abs()
        } else {
            dy.abs() < dx.abs()
        }
    }

    /// The rays of this half, by increasing slope: one to each border
    /// vertex of the half and the two along its edges (slopes -1 and +1),
    /// each owning the vertices nearer to it than to its neighbours.
    fn rays(&self, sweep: &Sweep) -> Vec<RayWalk> {
        let (nmaj, nmin) = (self.nmaj as f64, self.nmin as f64);
        let xb = if self.sx > 0.0 { nmaj - 1.0 } else { 0.0 };
        let mut ends: Vec<(f64, f64)> = Vec::new(); // (slope, end major)
                                                    // border vertices: the far major line, then the two minor borders
        for n in 0..self.nmin {
            let (dx, dy) = (xb - self.ex, n as f64 - self.ey);
            if dx * self.sx > 0.0 && self.owns(dx, dy) {
                ends.push((dy / dx, xb));
            }
        }
        for yb in [0.0, nmin - 1.0] {
            for m in 0..self.nmaj {
                let (dx, dy) = (m as f64 - self.ex, yb - self.ey);
                if dx * self.sx > 0.0 && m as f64 != xb && self.owns(dx, dy) {
                    ends.push((dy / dx, m as f64));
                }
            }
        }
        // the edges of the half: slopes -1 and +1 to where they leave
        for k in [-1.0, 1.0] {
            let room_maj = (xb - self.ex).abs();
            let room_min = if k * self.sx > 0.0 {
                nmin - 1.0 - self.ey
            } else {
                self.ey
            };
            let len = room_maj.min(room_min);
            if len > 0.0 {
                ends.push((k, self.ex + self.sx * len));
            }
        }
        ends.sort_by(|a, b| a.0.total_cmp(&b.0));
        ends.dedup_by(|b, a| b.0 == a.0);
        let m_per_x = |slope: f64| {
            if self.u_major {
                sweep.metres(1.0, slope)
            } else {
                sweep.metres(slope, 1.0)
            }
        };
        let first_x = if self.sx > 0.0 {
            floor(self.ex) + 1.0
        } else {
            -floor(-self.ex) - 1.0
        };
        (0..ends.len())
            .map(|i| {
                let (slope, end) = ends[i];
                let lo = if i == 0 {
                    f64::NEG_INFINITY
                } else {
                    0.5 * (ends[i - 1].0 + slope)
                };
                let hi = if i + 1 == ends.len() {
                    f64::INFINITY
                } else {
                    0.5 * (ends[i + 1].0 + slope)
                };
                RayWalk {
                    slope,
                    inv_slope: 1.0 / slope,
                    inv_slope_m1: 1.0 / (slope - 1.0),
                    m_per_x: m_per_x(slope),
                    end,
                    lo,
                    hi,
                    x: first_x,
                    prev: self.ex,
                    best: f64::NEG_INFINITY,
                }
            })
            .collect()
    }
}

/// One ray of [`viewshed`] and how far it has come.
#[derive(Clone)]
struct RayWalk {
    /// Minor per major step, its inverse and that of `slope - 1` (major
    /// per unit of minor and of `minor - major` along the ray).
    slope: f64,
    inv_slope: f64,
    inv_slope_m1: f64,
    /// Horizontal metres per major step.
    m_per_x: f64,
    /// Major coordinate of its end.
    end: f64,
    /// The slopes between which it owns the vertices.
    lo: f64,
    hi: f64,
    /// Next major line, the previous one (or the eye) and the largest tan
    /// elevation of the terrain so far.
    x: f64,
    prev: f64,
    best: f64,
}

/// What the rays of one viewshed share.
struct Sweep<'a> {
    terrain: &'a LocalTerrain,
    target_height: f64,
    /// Eye in vertex coordinates.
    eye: (f64, f64),
    /// Vertex offsets -> local (east, north) metres: columns are the
    /// images of a step along u and along v.
    a: [[f64; 2]; 2],
}

impl<'a> Sweep<'a> {
    fn new(terrain: &'a LocalTerrain, target_height: f64) -> Self {
        let (e0, n0) = terrain.v_to_en(0.0, 0.0);
        let (e1, n1) = terrain.v_to_en(1.0, 0.0);
        let (e2, n2) = terrain.v_to_en(0.0, 1.0);
        Sweep {
            terrain,
            target_height,
            eye: terrain.eye_vertex(),
            a: [[e1 - e0, e2 - e0], [n1 - n0, n2 - n0]],
        }
    }

    /// Horizontal distance in metres of vertex offset `(du, dv)` from the eye.
    #[inline]
    fn metres(&self, du: f64, dv: f64) -> f64 {
        let e = self.a[0][0] * du + self.a[0][1] * dv;
        let n = self.a[1][0] * du + self.a[1][1] * dv;
        e.hypot(n)
    }

    /// `Some(answer)` for vertices the sweep does not decide: nodata (not
    /// visible), beyond the maximum distance (not visible) and those near
    /// the eye (cast exactly); `None` for the others.
    fn near_or_invalid(&self, c: usize, r: usize) -> Option<bool> {
        if self.terrain.vertex_z(c, r).is_none() {
            return Some(false);
        }
        let (du, dv) = (c as f64 - self.eye.0, r as f64 - self.eye.1);
        if self.terrain.max_distance.is_finite() && self.metres(du, dv) > self.terrain.max_distance
        {
            return Some(false);
        }
        let near = EXACT_NEAR_CELLS + 1.0;
        if du.abs() <= near && dv.abs() <= near {
            return Some(self.exact_short(c, r));
        }
        None
    }

    /// One exact line of sight to vertex `(c, r)`.
    fn exact(&self, c: usize, r: usize) -> bool {
        self.exact_by(c, r, |d, limit| self.terrain.cast(d, limit).is_none())
    }

    /// [`Sweep::exact`] for the few vertices near the eye: the same answer
    /// through the coarse cast index, building neither the full one nor the
    /// horizon index.
    fn exact_short(&self, c: usize, r: usize) -> bool {
        self.exact_by(c, r, |d, limit| {
            self.terrain.cast_segment(d, 0.0, limit).is_none()
        })
    }

    /// The line of sight to vertex `(c, r)`, `clear(direction, limit)`
    /// saying whether the terrain leaves it free up to `limit` metres.
    fn exact_by(&self, c: usize, r: usize, clear: impl Fn([f64; 3], f64) -> bool) -> bool {
        let Some(p) = self.terrain.vertex_local(c, r) else {
            return false;
        };
        let target = [p[0], p[1], p[2] + self.target_height];
        let dist = (target[0] * target[0] + target[1] * target[1] + target[2] * target[2]).sqrt();
        if dist < 1e-9 {
            return true;
        }
        let d = [target[0] / dist, target[1] / dist, target[2] / dist];
        let limit = dist - (1e-6 * dist + 1e-3);
        limit <= 0.0 || clear(d, limit)
    }

    /// Advance `ray` of half `h` over at most `steps` lines of its major
    /// axis; false once it has ended. At each line, the vertices of the
    /// line that the ray owns are visible when they rise above the largest
    /// elevation angle of the terrain nearer on the ray (with 1 mm of
    /// slack, as the exact cast's margin); then the terrain on the line
    /// counts for what lies beyond.
    ///
    /// Between two lines the ray crosses lines of the minor axis and cell
    /// diagonals, which run from (m, n) to (m + 1, n + 1) in either order of
    /// the axes, so they are the lines `minor - major = k`. Every crossing
    /// lies on a grid edge, where the surface is the linear interpolation
    /// of the edge's two vertices, and between crossings the height is
    /// linear in distance: the running maximum over the crossings is exact.
    fn advance(
        &self,
        h: &Half,
        ray: &mut RayWalk,
        z: &[f32],
        grid: &OutGrid,
        steps: usize,
    ) -> bool {
        let (ex, ey, sx) = (h.ex, h.ey, h.sx);
        let (nmaj, nmin) = (h.nmaj, h.nmin);
        // height of vertex (major, minor); NaN off the grid or nodata
        let zv = |m: i64, n: i64| -> f64 {
            if m < 0 || n < 0 || m as usize >= nmaj || n as usize >= nmin {
                return f64::NAN;
            }
            z[m as usize * h.sm + n as usize * h.sn] as f64
        };
        let slope = ray.slope;
        let m_per_x = ray.m_per_x;
        let near = EXACT_NEAR_CELLS + 1.0;
        let max_d2 = self.terrain.max_distance * self.terrain.max_distance;
        let (mut x, mut prev, mut best) = (ray.x, ray.prev, ray.best);
        let mut left = steps;
        let live = loop {
            if !((x - ray.end) * sx <= 1e-9 && x >= 0.0 && x <= (nmaj - 1) as f64) {
                break false;
            }
            if left == 0 {
                break true;
            }
            left -= 1;
            let m0 = floor(prev.min(x));
            let (y0, y1) = (ey + (prev - ex) * slope, ey + (x - ex) * slope);
            // a line of the minor axis crossed inside the strip
            let (lo, hi) = (y0.min(y1), y0.max(y1));
            let k = floor(lo) + 1.0;
            if k < hi {
                let xm = prev + (k - y0) * ray.inv_slope;
                let f = xm - m0;
                let hgt = zv(m0 as i64, k as i64) * (1.0 - f) + zv(m0 as i64 + 1, k as i64) * f;
                raise(&mut best, hgt, (xm - ex).abs() * m_per_x);
            }
            // cell diagonals crossed inside the strip: g = minor - major
            let (g0, g1) = (y0 - prev, y1 - x);
            let (lo, hi) = (g0.min(g1), g0.max(g1));
            let mut k = floor(lo) + 1.0;
            while k < hi {
                let xm = prev + (k - g0) * ray.inv_slope_m1;
                let f = xm - m0;
                let n0 = m0 + k;
                let hgt =
                    zv(m0 as i64, n0 as i64) * (1.0 - f) + zv(m0 as i64 + 1, n0 as i64 + 1) * f;
                raise(&mut best, hgt, (xm - ex).abs() * m_per_x);
                k += 1.0;
            }
            // the ray's point on this line (clamped against rounding at the
            // border the ray ends on)
            let dxl = x - ex;
            let yc = y1.clamp(0.0, (nmin - 1) as f64);
            let yf = floor(yc);
            let fy = yc - yf;
            let hgt = zv(x as i64, yf as i64) * (1.0 - fy)
                + if fy > 0.0 {
                    zv(x as i64, yf as i64 + 1) * fy
                } else {
                    0.0
                };
            let s_x = dxl.abs() * m_per_x;
            // it is visible when it rises above everything nearer on the
            // ray; the answer goes to the vertices of the line that the
            // ray passes nearest (as in Franklin and Ray's R2)
            if dxl.abs() > near {
                let horizon = best;
                let visible = |zt: f64, s2: f64| {
                    if hgt.is_nan() {
                        // the ray's point touches a hole: the vertex's own
                        // height at its own distance
                        zt + self.target_height + 1e-3 >= horizon * s2.sqrt()
                    } else {
                        hgt + self.target_height + 1e-3 >= horizon * s_x
                    }
                };
                self.claim(h, ray, x, dxl, &zv, grid, max_d2, visible);
            }
            // the terrain on this line counts for what lies beyond it
            raise(&mut best, hgt, s_x);
            prev = x;
            x += sx;
        };
        ray.x = x;
        ray.prev = prev;
        ray.best = best;
        live
    }

    /// Mark visible the vertices of major line `x` (offset `dxl` from the
    /// eye) that `ray` owns, those of the half whose slope from the eye
    /// lies in `(lo, hi]`, for which `visible(height, squared distance)`
    /// (nodata and those beyond the maximum distance skipped).
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn claim(
        &self,
        h: &Half,
        ray: &RayWalk,
        x: f64,
        dxl: f64,
        zv: &impl Fn(i64, i64) -> f64,
        grid: &OutGrid,
        max_d2: f64,
        visible: impl Fn(f64, f64) -> bool,
    ) {
        let ey = h.ey;
        let top = (h.nmin - 1) as f64;
        // the half's vertices of this line lie within |dxl| of the eye
        let lim_lo = (ey - dxl.abs() - 1.0).max(0.0);
        let lim_hi = (ey + dxl.abs() + 1.0).min(top);
        let (a, b) = (ey + dxl * ray.lo, ey + dxl * ray.hi);
        // slope in (lo, hi]: minor in (a, b] ahead of the eye, [b, a) behind
        let (n_lo, n_hi) = if dxl > 0.0 {
            (floor(a.max(lim_lo - 1.0)) + 1.0, floor(b.min(lim_hi + 1.0)))
        } else {
            (
                -floor(-b.max(lim_lo - 1.0)),
                -floor(-a.min(lim_hi + 1.0)) - 1.0,
            )
        };
        let (n_lo, n_hi) = (n_lo.max(lim_lo), n_hi.min(lim_hi));
        let mut n = n_lo;
        while n <= n_hi {
            let dy = n - ey;
            let zt = zv(x as i64, n as i64);
            if h.owns(dxl, dy) && !zt.is_nan() {
                let (du, dv) = if h.u_major { (dxl, dy) } else { (dy, dxl) };
                let e = self.a[0][0] * du + self.a[0][1] * dv;
                let nn = self.a[1][0] * du + self.a[1][1] * dv;
                let s2 = e * e + nn * nn;
                if s2 <= max_d2 && visible(zt, s2) {
                    let (c, r) = if h.u_major { (x, n) } else { (n, x) };
                    grid.set(c as usize, r as usize);
                }
            }
            n += 1.0;
        }
    }
}

/// Raises the running maximum tan elevation `best` to `h / s` (`s > 0`)
/// if that is larger; NaN heights (holes) leave it. Divides only then.
#[inline]
fn raise(best: &mut f64, h: f64, s: f64) {
    if h > *best * s {
        *best = h / s;
    }
}

/// `x.floor()` without a libm call (the baseline x86-64 target has no
/// rounding instruction).
#[inline]
fn floor(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// Viewshed by one exact cast per cell (the reference of [`viewshed`]):
/// viewshed of `terrain` on the grid of `dem` (the height map the terrain
/// was built from: the whole DEM or the window within the maximum view
/// distance, like gdal_viewshed's `-md` output extent) for a target
/// `target_height` metres above the surface.
pub fn viewshed_exact(terrain: &LocalTerrain, dem: &HeightMap, target_height: f64) -> Viewshed {
    let sweep = Sweep::new(terrain, target_height);
    on_grid(terrain, dem, |c, r| sweep.exact(c, r))
}

/// The viewshed on `dem`'s grid from the answer `visible(c, r)` for each
/// terrain vertex (rows in parallel; cells outside the terrain are 0).
fn on_grid(
    terrain: &LocalTerrain,
    dem: &HeightMap,
    visible: impl Fn(usize, usize) -> bool + Sync,
) -> Viewshed {
    let (width, height) = (dem.width, dem.height);
    let mut data = vec![0u8; width * height];
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(row, out)| {
            if row < terrain.row0 || row >= terrain.row0 + terrain.ny {
                return;
            }
            let r = row - terrain.row0;
            for c in 0..terrain.nx {
                let col = terrain.col0 + c;
                if col >= width {
                    break;
                }
                if visible(c, r) {
                    out[col] = 255;
                }
            }
        });
    Viewshed {
        width,
        height,
        data,
        geotransform: dem.geotransform,
        crs: dem.crs.clone(),
    }
}

/// Creation options of [`write_viewshed_tiff`]: tiles of 256 x 256 cells
/// compressed with PackBits (baseline TIFF: every TIFF reader decodes it),
/// on all cores. A viewshed is long runs of 0 and 255: 8192^2 cells (64 MB
/// as gdal_viewshed writes them, striped and uncompressed) take about
/// 1 MB, so writing, flushing to disk and reading back cost little beside
/// the run-length coding, and PackBits codes and decodes runs several
/// times faster than DEFLATE, whose files are smaller still (see
/// docs/benchmarks.md, "Viewshed against gdal_viewshed").
pub const VIEWSHED_TIFF_OPTIONS: &[&str] = &[
    "TILED=YES",
    "BLOCKXSIZE=256",
    "BLOCKYSIZE=256",
    "COMPRESS=PACKBITS",
    "NUM_THREADS=ALL_CPUS",
];

/// Write `vs` as a single-band Byte GeoTIFF with the DEM's georeferencing
/// ([`VIEWSHED_TIFF_OPTIONS`]), atomically and verified (written in
/// memory, then to a file beside `path`, flushed, read back block by block
/// and compared, renamed over `path`).
pub fn write_viewshed_tiff(vs: &Viewshed, path: &Path) -> Result<(), RenderError> {
    write_viewshed_tiff_with(vs, path, VIEWSHED_TIFF_OPTIONS)
}

/// [`write_viewshed_tiff`] with other GeoTIFF creation options (`[]`:
/// striped and uncompressed, as gdal_viewshed writes by default).
pub fn write_viewshed_tiff_with(
    vs: &Viewshed,
    path: &Path,
    options: &[&str],
) -> Result<(), RenderError> {
    write_atomically(
        path,
        |tmp| {
            let werr = |e: gdal::errors::GdalError| RenderError::Write {
                path: path.display().to_string(),
                message: e.to_string().lines().next().unwrap_or("").to_string(),
            };
            crate::raster::atomic_file::through_memory(tmp, None, |tmp| {
                let driver = gdal::DriverManager::get_driver_by_name("GTiff").map_err(werr)?;
                let opts = gdal::raster::RasterCreationOptions::from_iter(options.iter().copied());
                let mut ds = driver
                    .create_with_band_type_with_options::<u8, _>(tmp, vs.width, vs.height, 1, &opts)
                    .map_err(werr)?;
                ds.set_geo_transform(&vs.geotransform.0).map_err(werr)?;
                let srs = vs.crs.gdal_definition();
                if !srs.is_empty() {
                    if let Ok(sr) = gdal::spatial_ref::SpatialRef::from_definition(&srs) {
                        ds.set_spatial_ref(&sr).map_err(werr)?;
                    }
                }
                write_blocks(&mut ds.rasterband(1).map_err(werr)?, vs).map_err(werr)?;
                ds.flush_cache().map_err(werr)?;
                ds.close().map_err(werr)?;
                Ok::<(), RenderError>(())
            })
            .map_err(|message| RenderError::Write {
                path: path.display().to_string(),
                message,
            })
        },
        |tmp| verify_blocks(tmp, vs),
    )
}

/// The block of `vs` at block `(bx, by)` of `size` cells into `buf`
/// (`size.0 * size.1` long, rows of the block past the raster left 0).
fn block_of(vs: &Viewshed, (bx, by): (usize, usize), size: (usize, usize), buf: &mut [u8]) {
    buf.fill(0);
    let (c0, r0) = (bx * size.0, by * size.1);
    let w = size.0.min(vs.width.saturating_sub(c0));
    for r in 0..size.1.min(vs.height.saturating_sub(r0)) {
        let src = (r0 + r) * vs.width + c0;
        buf[r * size.0..r * size.0 + w].copy_from_slice(&vs.data[src..src + w]);
    }
}

/// Write `vs` into `band` block by block (no copy of the whole raster:
/// one block at a time goes to the driver, which compresses it).
fn write_blocks(band: &mut gdal::raster::RasterBand, vs: &Viewshed) -> gdal::errors::Result<()> {
    let size = band.block_size();
    let size = (size.0.max(1), size.1.max(1));
    let mut buf = gdal::raster::Buffer::new(size, vec![0u8; size.0 * size.1]);
    for by in 0..vs.height.div_ceil(size.1) {
        for bx in 0..vs.width.div_ceil(size.0) {
            block_of(vs, (bx, by), size, buf.data_mut());
            band.write_block((bx, by), &mut buf)?;
        }
    }
    Ok(())
}

/// Does the GeoTIFF at `path` hold `vs` (its size and every cell)? Read
/// block by block, the rows of blocks split between the cores (each with
/// its own handle on the file): no second copy of the raster in memory.
fn verify_blocks(path: &Path, vs: &Viewshed) -> Result<(), String> {
    use crate::raster::atomic_file::one_line;
    let open = || {
        gdal::Dataset::open(path)
            .map_err(|e| format!("GDAL cannot open it: {}", one_line(&e.to_string())))
    };
    let ds = open()?;
    if ds.raster_size() != (vs.width, vs.height) {
        return Err(format!(
            "its size is {:?}, not {} x {}",
            ds.raster_size(),
            vs.width,
            vs.height
        ));
    }
    let size = ds.rasterband(1).map_err(|e| e.to_string())?.block_size();
    let size = (size.0.max(1), size.1.max(1));
    drop(ds);
    let rows = vs.height.div_ceil(size.1);
    let parts = rayon::current_num_threads().clamp(1, rows.max(1));
    (0..parts).into_par_iter().try_for_each(|part| {
        let ds = open()?;
        let band = ds.rasterband(1).map_err(|e| e.to_string())?;
        let mut want = vec![0u8; size.0 * size.1];
        for by in (part * rows / parts)..((part + 1) * rows / parts) {
            for bx in 0..vs.width.div_ceil(size.0) {
                let got = band
                    .read_block::<u8>((bx, by))
                    .map_err(|e| format!("GDAL cannot read it: {}", one_line(&e.to_string())))?;
                block_of(vs, (bx, by), size, &mut want);
                // (the rows and columns past the raster are not compared)
                let (c0, r0) = (bx * size.0, by * size.1);
                let w = size.0.min(vs.width - c0);
                let h = size.1.min(vs.height - r0);
                let got = got.data();
                if got.len() < size.0 * size.1
                    || (0..h).any(|r| {
                        got[r * size.0..r * size.0 + w] != want[r * size.0..r * size.0 + w]
                    })
                {
                    return Err("its values differ from those written".to_string());
                }
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::read_height_map;

    /// A fixture and the frame from 1.7 m above the centre of cell
    /// `(col, row)`, refraction k = 1/7.
    fn frame_at(name: &str, col: usize, row: usize) -> (HeightMap, LocalFrame) {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures")
            .join(name);
        let dem = read_height_map(&path).unwrap();
        let (x, y) = dem
            .geotransform
            .pixel_to_crs(col as f64 + 0.5, row as f64 + 0.5);
        let georef = Georef::new(&dem, name).unwrap();
        let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
        let vp = Viewpoint::above_surface(lon, lat, 1.7);
        let frame = georef.local_frame(&vp, &dem, 1.0 / 7.0).unwrap();
        (dem, frame)
    }

    /// The vector passes over rows (with and without AVX2) give the bytes
    /// of the cell-by-cell propagation, on real DEMs (projected and
    /// geographic, with holes, within a maximum distance or not) and
    /// targets on the ground and above it.
    #[test]
    fn vector_rows_give_the_bits_of_cell_by_cell() {
        for (name, col, row, max_d) in [
            ("zion_srtm_utm12n.tif", 210, 103, None),
            ("zion_srtm_utm12n.tif", 30, 480, Some(9_000.0)),
            ("zion_srtm90m_epsg4326.tif", 230, 230, None),
            ("arenal_aster30m_epsg4326.tif", 120, 100, None),
            ("vinschgau_250m_utm32n.tif", 101, 110, Some(20_000.0)),
            ("nz_1km_nan_nodata.tif", 600, 800, None),
            ("texas_srtm90m_tiled_int16.tif", 180, 180, None),
        ] {
            let (dem, frame) = frame_at(name, col, row);
            let md = max_d.unwrap_or(f64::INFINITY);
            let (c0, r0, c1, r1) =
                LocalTerrain::extent_in((dem.width, dem.height), &frame, max_d, None);
            let (nx, ny) = (c1 - c0, r1 - r0);
            let heights = DemHeights {
                dem: &dem,
                ap: Apparent::new(&frame, (c0, r0, nx), md),
            };
            for target in [0.0, 10.0] {
                let run = |vector: bool, avx2: bool| {
                    let mut prop = Prop::new(&heights, &frame, (c0, r0, nx, ny), md, target);
                    prop.vector_rows = vector;
                    prop.avx2 &= avx2;
                    infallible(prop.run(dem.width, dem.height, &dem.geotransform, &dem.crs))
                };
                let cells = run(false, false);
                assert!(cells.visible_count() > 0, "{name}");
                assert_eq!(run(true, true).data, cells.data, "{name}, {target} m");
                assert_eq!(run(true, false).data, cells.data, "{name}, {target} m");
            }
        }
    }
}
