//! Visibility from the eye: which DEM cells can be seen, the library side of
//! `demsketch view --viewshed vis.tif`. A cell is visible when the straight
//! line of sight (in the local frame, so curvature and refraction with k =
//! 1/7 are included, as gdal_viewshed's coefficient 0.85714) from the eye to
//! the terrain point at the cell centre plus a target height is not blocked
//! by the triangulated terrain. The result is on the DEM's own grid, 255
//! visible / 0 not (nodata cells and cells beyond the maximum distance are
//! 0), like gdal_viewshed's output.
//!
//! Two ways to compute it:
//! - [`viewshed`], the default: a radial sweep in the manner of Franklin and
//!   Ray's R2 algorithm. One ray from the eye to every vertex on the border
//!   of the terrain window; along each ray the triangulated surface is a
//!   polyline whose vertices are the ray's crossings of grid lines and cell
//!   diagonals, and the largest elevation angle of the terrain so far is
//!   the running maximum over those crossings, exactly (between two
//!   crossings the height is linear in distance, so `z / s` is monotonic).
//!   Each cell centre takes the answer of the ray that passes nearest to it
//!   (within half a cell); cells within [`EXACT_NEAR_CELLS`] of the eye,
//!   where rays fan out, are cast exactly. The work is one pass over each
//!   ray instead of one cast per cell: far less than GDAL's sweep, and it
//!   agrees with exact lines of sight on all but the cells next to a
//!   horizon (see `tests/view_viewshed.rs`).
//! - [`viewshed_exact`]: one exact cast ([`LocalTerrain::cast`]) per cell,
//!   rows in parallel: the reference the sweep is tested against.

use super::atomic::write_atomically;
use super::terrain::LocalTerrain;
use super::RenderError;
use crate::raster::{Crs, GeoTransform, HeightMap};
use rayon::prelude::*;
use std::path::Path;
use std::sync::atomic::{AtomicU32, Ordering};

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
/// module documentation.
///
/// ```no_run
/// # use demsketch::render::{viewshed, LocalTerrain};
/// # fn f(terrain: &LocalTerrain, dem: &demsketch::raster::HeightMap) {
/// let vs = viewshed(terrain, dem, 0.0);
/// println!("{} cells visible", vs.visible_count());
/// # }
/// ```
pub fn viewshed(terrain: &LocalTerrain, dem: &HeightMap, target_height: f64) -> Viewshed {
    let (nx, ny) = (terrain.nx, terrain.ny);
    let sweep = Sweep::new(terrain, target_height);
    if nx < 2 || ny < 2 {
        return on_grid(terrain, dem, |c, r| sweep.exact(c, r));
    }
    // Per vertex, the nearest ray's answer: (offset << 1) | visible,
    // row-major for rays along columns, column-major for the others.
    let keys: Vec<AtomicU32> = (0..nx * ny).map(|_| AtomicU32::new(u32::MAX)).collect();
    let keys_t: Vec<AtomicU32> = (0..nx * ny).map(|_| AtomicU32::new(u32::MAX)).collect();
    let (eu, ev) = sweep.eye;
    let (umaj, vmaj): (Vec<_>, Vec<_>) = border_vertices(nx, ny)
        .into_iter()
        .partition(|&(c, r)| (c as f64 - eu).abs() >= (r as f64 - ev).abs());
    umaj.par_iter()
        .for_each(|&(c, r)| sweep.ray(c as f64, r as f64, &terrain.z, &keys));
    // Rays that advance along rows read the heights column by column:
    // from a transposed copy, so that each step reads nearby memory.
    let zt = transpose(&terrain.z, nx, ny);
    vmaj.par_iter()
        .for_each(|&(c, r)| sweep.ray(c as f64, r as f64, &zt, &keys_t));
    drop(zt);
    on_grid(terrain, dem, |c, r| {
        sweep.near_or_invalid(c, r).unwrap_or_else(|| {
            let k = keys[r * nx + c]
                .load(Ordering::Relaxed)
                .min(keys_t[c * ny + r].load(Ordering::Relaxed));
            // a vertex no ray passed (none should, beyond the near
            // square): cast it
            if k == u32::MAX {
                sweep.exact(c, r)
            } else {
                k & 1 == 1
            }
        })
    })
}

/// Column-major copy of a row-major `nx` x `ny` grid, in cache-sized
/// blocks, columns in parallel.
fn transpose(z: &[f32], nx: usize, ny: usize) -> Vec<f32> {
    const B: usize = 64;
    let mut out = vec![0f32; nx * ny];
    out.par_chunks_mut(ny * B)
        .enumerate()
        .for_each(|(bc, chunk)| {
            let c0 = bc * B;
            let cols = chunk.len() / ny;
            for r0 in (0..ny).step_by(B) {
                for c in c0..c0 + cols {
                    let dst = &mut chunk[(c - c0) * ny..(c - c0 + 1) * ny];
                    for r in r0..(r0 + B).min(ny) {
                        dst[r] = z[r * nx + c];
                    }
                }
            }
        });
    out
}

/// Every vertex on the border of an `nx` x `ny` vertex grid.
fn border_vertices(nx: usize, ny: usize) -> Vec<(usize, usize)> {
    let mut v: Vec<(usize, usize)> = (0..nx).flat_map(|c| [(c, 0), (c, ny - 1)]).collect();
    v.extend((1..ny - 1).flat_map(|r| [(0, r), (nx - 1, r)]));
    v
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
            return Some(self.exact(c, r));
        }
        None
    }

    /// One exact line of sight to vertex `(c, r)`.
    fn exact(&self, c: usize, r: usize) -> bool {
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
        limit <= 0.0 || self.terrain.cast(d, limit).is_none()
    }

    /// March the ray from the eye to border vertex `(bu, bv)`: at each grid
    /// line of its major axis, record for the vertex nearest the ray
    /// whether the ray's point there is visible, keyed by that distance so
    /// that the nearest ray wins ([`AtomicU32::fetch_min`]).
    ///
    /// Coordinates are (major, minor): the axis the ray advances along by
    /// whole lines, and the other (|slope| <= 1). Cell diagonals run from
    /// (m, n) to (m + 1, n + 1) in either order of the axes, so they are the
    /// lines `minor - major = k`. Every crossing lies on a grid edge, where
    /// the surface is the linear interpolation of the edge's two vertices.
    /// `z` is the terrain's heights and `keys` the answers, row-major for
    /// rays whose major axis is u (columns), transposed (column-major) for
    /// the others.
    fn ray(&self, bu: f64, bv: f64, z: &[f32], keys: &[AtomicU32]) {
        let t = self.terrain;
        let (eu, ev) = self.eye;
        let (du, dv) = (bu - eu, bv - ev);
        if du == 0.0 && dv == 0.0 {
            return;
        }
        let u_major = du.abs() >= dv.abs();
        // strides of (major, minor) in `z` and in `keys` (row-major)
        let (ex, ey, dx, dy, nmaj, nmin, sm, sn) = if u_major {
            (eu, ev, du, dv, t.nx, t.ny, 1, t.nx)
        } else {
            (ev, eu, dv, du, t.ny, t.nx, 1, t.ny)
        };
        // height of vertex (major, minor); NaN off the grid or nodata
        let zv = |m: i64, n: i64| -> f64 {
            if m < 0 || n < 0 || m as usize >= nmaj || n as usize >= nmin {
                return f64::NAN;
            }
            z[m as usize * sm + n as usize * sn] as f64
        };
        let slope = dy / dx;
        let sx = dx.signum();
        let m_per_x = if u_major {
            self.metres(1.0, slope)
        } else {
            self.metres(slope, 1.0)
        };
        let end = ex + dx;
        let mut best = f64::NEG_INFINITY; // largest tan elevation so far
        let near = EXACT_NEAR_CELLS + 1.0;
        let mut x = if sx > 0.0 {
            floor(ex) + 1.0
        } else {
            -floor(-ex) - 1.0
        };
        let mut prev = ex;
        while (x - end) * sx <= 1e-9 && x >= 0.0 && x <= (nmaj - 1) as f64 {
            let m0 = floor(prev.min(x));
            let (y0, y1) = (ey + (prev - ex) * slope, ey + (x - ex) * slope);
            // a line of the minor axis crossed inside the strip
            let (lo, hi) = (y0.min(y1), y0.max(y1));
            let k = floor(lo) + 1.0;
            if k < hi {
                let xm = prev + (x - prev) * (k - y0) / (y1 - y0);
                let f = xm - m0;
                let h = zv(m0 as i64, k as i64) * (1.0 - f) + zv(m0 as i64 + 1, k as i64) * f;
                raise(&mut best, h, (xm - ex).abs() * m_per_x);
            }
            // cell diagonals crossed inside the strip: g = minor - major
            let (g0, g1) = (y0 - prev, y1 - x);
            let (lo, hi) = (g0.min(g1), g0.max(g1));
            let mut k = floor(lo) + 1.0;
            while k < hi {
                let xm = prev + (x - prev) * (k - g0) / (g1 - g0);
                let f = xm - m0;
                let n0 = m0 + k;
                let h = zv(m0 as i64, n0 as i64) * (1.0 - f) + zv(m0 as i64 + 1, n0 as i64 + 1) * f;
                raise(&mut best, h, (xm - ex).abs() * m_per_x);
                k += 1.0;
            }
            // the ray's point on this major line (clamped against rounding
            // at the border the ray ends on)
            let y1 = y1.clamp(0.0, (nmin - 1) as f64);
            let yf = floor(y1);
            let fy = y1 - yf;
            let h = zv(x as i64, yf as i64) * (1.0 - fy)
                + if fy > 0.0 {
                    zv(x as i64, yf as i64 + 1) * fy
                } else {
                    0.0
                };
            let s_x = (x - ex).abs() * m_per_x;
            let yr = y1.round();
            if (x - ex).abs() > near && yr >= 0.0 && yr <= (nmin - 1) as f64 && !h.is_nan() {
                // It is visible when it rises above everything nearer on
                // the ray (with 1 mm of slack, as the exact cast's margin);
                // the answer goes to the vertex of the line nearest the ray
                // (as in Franklin and Ray's R2).
                let visible = h + self.target_height + 1e-3 >= best * s_x;
                let off = ((y1 - yr).abs().min(0.5) * 2.0 * (1u32 << 30) as f64) as u32;
                let key = (off << 1) | visible as u32;
                let slot = &keys[x as usize * sm + yr as usize * sn];
                // (read first: near the eye every ray passes the same cells)
                if key < slot.load(Ordering::Relaxed) {
                    slot.fetch_min(key, Ordering::Relaxed);
                }
            }
            // the terrain on this line counts for what lies beyond it
            raise(&mut best, h, s_x);
            prev = x;
            x += sx;
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

/// Write `vs` as a single-band Byte GeoTIFF with the DEM's georeferencing.
pub fn write_viewshed_tiff(vs: &Viewshed, path: &Path) -> Result<(), RenderError> {
    write_atomically(
        path,
        |tmp| {
            let werr = |e: gdal::errors::GdalError| RenderError::Write {
                path: path.display().to_string(),
                message: e.to_string().lines().next().unwrap_or("").to_string(),
            };
            crate::raster::atomic_file::through_memory(tmp, None, |tmp| {
                let driver = gdal::DriverManager::get_driver_by_name("GTiff").map_err(werr)?;
                let mut ds = driver
                    .create_with_band_type::<u8, _>(tmp, vs.width, vs.height, 1)
                    .map_err(werr)?;
                ds.set_geo_transform(&vs.geotransform.0).map_err(werr)?;
                let srs = vs.crs.gdal_definition();
                if !srs.is_empty() {
                    if let Ok(sr) = gdal::spatial_ref::SpatialRef::from_definition(&srs) {
                        ds.set_spatial_ref(&sr).map_err(werr)?;
                    }
                }
                let mut band = ds.rasterband(1).map_err(werr)?;
                let mut buf = gdal::raster::Buffer::new((vs.width, vs.height), vs.data.clone());
                band.write((0, 0), (vs.width, vs.height), &mut buf)
                    .map_err(werr)?;
                ds.flush_cache().map_err(werr)?;
                ds.close().map_err(werr)?;
                Ok::<(), RenderError>(())
            })
            .map_err(|message| RenderError::Write {
                path: path.display().to_string(),
                message,
            })
        },
        |tmp| crate::raster::atomic_file::verify_band(tmp, vs.width, vs.height, &vs.data),
    )
}
