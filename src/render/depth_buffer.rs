//! The depth buffer of a first-person view: for every pixel, the distance
//! from the eye to the first terrain hit along the ray through the pixel
//! centre (`f32::INFINITY` for sky) and the id of the cell half hit, on the
//! bilinear height field, by z-buffer rasterisation of triangles that follow
//! each cell's patch to [`super::triangle_raster::PATCH_TOLERANCE_PX`]
//! ([`super::triangle_raster`]); [`DepthBuffer::render_by_ray_casting`]
//! gives the same by one exact [`LocalTerrain::cast`] per pixel.
//!
//! This is what the silhouette extractor and the sketch matcher consume:
//! [`DepthBuffer::hit`] gives the terrain point a pixel shows in the local
//! frame and in the DEM's CRS, with its cell and triangle.

use super::terrain::LocalTerrain;
use super::triangle_raster::{
    box_columns, rasterise, rasterise_below, rasterise_into, rasterise_keeping,
};
use crate::view::{Camera, CameraModel};
use rayon::prelude::*;

/// Sentinel triangle id of sky pixels.
pub const SKY: u32 = u32::MAX;

/// Per-pixel depth and triangle id of a rendered view.
#[derive(Debug, Clone)]
pub struct DepthBuffer {
    pub camera: Camera,
    pub width: usize,
    pub height: usize,
    /// Distance in metres from the eye to the hit along the pixel-centre ray,
    /// `f32::INFINITY` for sky. Row-major, row 0 at the top.
    pub depth: Vec<f32>,
    /// Triangle id hit (see [`LocalTerrain`]), [`SKY`] for sky.
    pub triangle: Vec<u32>,
}

impl Drop for DepthBuffer {
    /// The buffers go back to [`crate::buffer_pool`], for the next render
    /// (the rounds of an edit render the same view again and again).
    fn drop(&mut self) {
        crate::buffer_pool::recycle_f32(std::mem::take(&mut self.depth));
        crate::buffer_pool::recycle_u32(std::mem::take(&mut self.triangle));
    }
}

/// What a pixel shows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TerrainHit {
    /// Distance from the eye, metres.
    pub distance: f64,
    /// Hit point in the local frame (ENU metres at the eye, apparent z).
    pub local: [f64; 3],
    /// Hit point in the DEM's CRS and its true height.
    pub x: f64,
    pub y: f64,
    pub z: f64,
    /// DEM cell (column, row) of the hit triangle and which half (0, 1).
    pub cell: (usize, usize),
    pub half: u8,
    /// Triangle id in the [`LocalTerrain`].
    pub triangle: u32,
}

impl DepthBuffer {
    /// Render the depth buffer of `camera` over `terrain` (exact z-buffer
    /// rasterisation of the terrain's triangles at the pixel centres, see
    /// [`super::triangle_raster`]).
    pub fn render(terrain: &LocalTerrain, camera: &Camera) -> Self {
        Self::of(camera, rasterise(terrain, camera, None))
    }

    /// [`DepthBuffer::render`] into the buffers of `old` (an earlier view,
    /// of any size): the same depths and triangles, without allocating
    /// (or touching fresh pages) when the size is the same. For a caller
    /// rendering view after view (the browser app).
    pub fn render_reusing(terrain: &LocalTerrain, camera: &Camera, mut old: DepthBuffer) -> Self {
        let (mut depth, mut triangle) = (
            std::mem::take(&mut old.depth),
            std::mem::take(&mut old.triangle),
        );
        rasterise_into(terrain, camera, None, &mut depth, &mut triangle, true);
        Self::of(camera, (depth, triangle))
    }

    /// [`DepthBuffer::render`], with rows `0..first_row[x]` of each column
    /// `x` taken from `earlier`, a render of the same camera and terrain
    /// holding the whole render's pixels there (as
    /// [`DepthBuffer::render_rows`] gives them, with `last_row[x] =
    /// first_row[x] - 1`): the same depths and triangles, for the cost of
    /// the rows below (the culling skips terrain seen only in the rows
    /// taken). Terrains with far layers render whole.
    pub fn render_below(
        terrain: &LocalTerrain,
        camera: &Camera,
        first_row: &[i32],
        earlier: &DepthBuffer,
    ) -> Self {
        let earlier = (&earlier.depth[..], &earlier.triangle[..]);
        Self::of(camera, rasterise_below(terrain, camera, first_row, earlier))
    }

    /// The buffer of `camera` from the rasteriser's depths and triangles.
    fn of(camera: &Camera, (depth, triangle): (Vec<f32>, Vec<u32>)) -> Self {
        DepthBuffer {
            camera: *camera,
            width: camera.width,
            height: camera.height,
            depth,
            triangle,
        }
    }

    /// Render only the rows `0..=last_row[x]` of each image column `x` (none
    /// where it is negative; `last_row` has one entry per column): those
    /// pixels are exactly what [`DepthBuffer::render`] gives, the others
    /// have a NaN depth and [`SKY`]. For work that only looks at part of the
    /// view (the edit's re-renders look at and above its strokes), at a
    /// fraction of the cost: terrain seen only outside the part is culled.
    ///
    /// # Panics
    /// When `last_row.len() != camera.width`.
    pub fn render_rows(terrain: &LocalTerrain, camera: &Camera, last_row: &[i32]) -> Self {
        assert_eq!(last_row.len(), camera.width, "one last row per column");
        Self::of(camera, rasterise(terrain, camera, Some(last_row)))
    }

    /// What [`DepthBuffer::render_rows`] gives for `last_row`, taken from
    /// `whole`, a whole render ([`DepthBuffer::render`]) of the same
    /// camera and terrain, which has no far layers: a region's rows hold
    /// the whole render's pixels (the premise of
    /// [`DepthBuffer::render_below`]), the rows below a NaN depth and
    /// [`SKY`], as the rasteriser leaves them.
    ///
    /// # Panics
    /// When `last_row.len() != whole.width`.
    pub fn rows_of(whole: &DepthBuffer, last_row: &[i32]) -> Self {
        let (w, h) = (whole.width, whole.height);
        assert_eq!(last_row.len(), w, "one last row per column");
        // Rows `first_below[x]..` of column `x` are not rendered.
        let first_below: Vec<i32> = last_row
            .iter()
            .map(|&r| (r + 1).clamp(0, h as i32))
            .collect();
        let n = w * h;
        let mut depth = crate::buffer_pool::overwritten_f32(n);
        let mut triangle = crate::buffer_pool::overwritten_u32(n);
        depth
            .par_chunks_mut(w)
            .zip(triangle.par_chunks_mut(w))
            .enumerate()
            .for_each(|(j, (t, id))| {
                let k = j * w;
                let (wt, wid) = (&whole.depth[k..k + w], &whole.triangle[k..k + w]);
                for x in 0..w {
                    let inside = (j as i32) < first_below[x];
                    t[x] = if inside { wt[x] } else { f32::NAN };
                    id[x] = if inside { wid[x] } else { SKY };
                }
            });
        Self::of(&whole.camera, (depth, triangle))
    }

    /// [`DepthBuffer::render_rows`], taking the strips of pixel columns
    /// `x0..=x1` for which `keep(x0, x1)` holds from `earlier` (a render of
    /// the same camera and rows, on a terrain whose changed triangles none
    /// of those columns can show: [`DepthBuffer::box_columns`]).
    pub fn render_rows_keeping(
        terrain: &LocalTerrain,
        camera: &Camera,
        last_row: &[i32],
        earlier: &DepthBuffer,
        keep: &(dyn Fn(usize, usize) -> bool + Sync),
    ) -> Self {
        assert_eq!(last_row.len(), camera.width, "one last row per column");
        let earlier = (&earlier.depth[..], &earlier.triangle[..]);
        Self::of(
            camera,
            rasterise_keeping(terrain, camera, Some(last_row), earlier, keep),
        )
    }

    /// The pixel columns (inclusive range) that may show a point of the box
    /// of vertices `c` x `r` (inclusive index ranges) of `terrain` times the
    /// apparent heights `lo..=hi`, with the renderer's margin; `None`: none.
    pub fn box_columns(
        terrain: &LocalTerrain,
        camera: &Camera,
        c: [usize; 2],
        r: [usize; 2],
        heights: (f32, f32),
    ) -> Option<(usize, usize)> {
        box_columns(terrain, camera, c, r, heights)
    }

    /// Render by casting one exact ray per pixel ([`LocalTerrain::cast`]):
    /// the reference the rasteriser is tested against.
    pub fn render_by_ray_casting(terrain: &LocalTerrain, camera: &Camera) -> Self {
        let (w, h) = (camera.width, camera.height);
        let mut depth = vec![f32::INFINITY; w * h];
        let mut triangle = vec![SKY; w * h];
        depth
            .par_chunks_mut(w)
            .zip(triangle.par_chunks_mut(w))
            .enumerate()
            .for_each(|(j, (drow, trow))| {
                for i in 0..w {
                    let d = camera.unproject([i as f64 + 0.5, j as f64 + 0.5]);
                    if let Some(hit) = terrain.cast(d, f64::INFINITY) {
                        drow[i] = hit.t as f32;
                        trow[i] = hit.triangle;
                    }
                }
            });
        DepthBuffer {
            camera: *camera,
            width: w,
            height: h,
            depth,
            triangle,
        }
    }

    /// Depth of pixel `(i, j)` (infinite for sky or outside the image).
    #[inline]
    pub fn depth_at(&self, i: usize, j: usize) -> f32 {
        if i < self.width && j < self.height {
            self.depth[j * self.width + i]
        } else {
            f32::INFINITY
        }
    }

    /// The terrain point pixel `(i, j)` shows, `None` for sky.
    pub fn hit(&self, terrain: &LocalTerrain, i: usize, j: usize) -> Option<TerrainHit> {
        if i >= self.width || j >= self.height {
            return None;
        }
        let k = j * self.width + i;
        if self.triangle[k] == SKY {
            return None;
        }
        let d = self.camera.unproject([i as f64 + 0.5, j as f64 + 0.5]);
        let drawn = self.depth[k] as f64;
        let t = terrain
            .patch_distance(d, self.triangle[k], drawn)
            .unwrap_or(drawn);
        Some(make_hit(terrain, d, t, self.triangle[k]))
    }

    /// Fraction of pixels that show terrain.
    pub fn terrain_fraction(&self) -> f64 {
        self.triangle.iter().filter(|&&t| t != SKY).count() as f64
            / self.triangle.len().max(1) as f64
    }
}

/// Build a [`TerrainHit`] from a unit ray, its hit distance and triangle.
pub(crate) fn make_hit(terrain: &LocalTerrain, d: [f64; 3], t: f64, triangle: u32) -> TerrainHit {
    let local = [d[0] * t, d[1] * t, d[2] * t];
    let (x, y, z) = terrain.frame.local_to_crs(local);
    let (c, r, half) = terrain.triangle_cell(triangle);
    TerrainHit {
        distance: t,
        local,
        x,
        y,
        z,
        cell: (c, r),
        half,
        triangle,
    }
}

/// Cast the ray through arbitrary pixel coordinates `(x, y)` of `camera`.
pub fn pick(terrain: &LocalTerrain, camera: &Camera, x: f64, y: f64) -> Option<TerrainHit> {
    let d = camera.unproject([x, y]);
    terrain
        .cast(d, f64::INFINITY)
        .map(|h| make_hit(terrain, d, h.t, h.triangle))
}
