//! The far layers of a level-of-detail terrain: coarser [`LocalTerrain`]s
//! (rings around the eye, each on a grid `k` times coarser than the DEM's)
//! that a terrain carries beyond its own reach. A long view's terrain is
//! then exact near the eye, where the strokes, the deformation and the
//! observer are, and coarse only where a coarse cell still spans at most a
//! pixel ([`super::level_of_detail`] plans the rings and reads them).
//!
//! The layers are one surface with the terrain for everything that looks
//! at it: the rasteriser draws them into the same depth buffer (the nearer
//! hit wins, as between the triangles of one terrain; a layer is drawn
//! only in the rows the image does not already show nearer than any of its
//! points, which changes no pixel: [`FarLayer::rows_shown`]), the casts return
//! the nearest hit over the terrain and its layers, and the triangle ids of
//! a layer follow the terrain's (`id0` on), so that a pixel's id says which
//! layer it shows and every per-triangle question (vertices, normals, the
//! patch distance) is answered by that layer. A layer's segment casts
//! start at its reach and are remembered ([`super::cast_memo`]): it never
//! changes, so the same question gets the same answer. The cell of a layer's
//! triangle is given in the DEM grid the terrain was built from (the
//! coarse cell's centre). Layers are never patched by an edit's
//! re-renders: they lie beyond the deformations (which the planner keeps
//! well inside the exact terrain).

use std::sync::Arc;

use super::cast_memo::{CastKey, CastMemo};
use super::terrain::{LocalTerrain, RayHit};
use super::SKY;

/// One far layer of a terrain.
#[derive(Debug, Clone)]
pub(crate) struct FarLayer {
    pub(crate) terrain: Arc<LocalTerrain>,
    /// Triangle ids of this layer are `id0 + ` its own ids.
    pub(crate) id0: u32,
    /// No point of the layer lies nearer than this (metres, horizontal):
    /// its inner radius less its overlap with the layer inside it.
    pub(crate) reach_m: f64,
    /// Cells of the DEM per cell of the layer (along each axis).
    pub(crate) k: usize,
    /// Where the layer's grid starts, in cells of the grid the terrain was
    /// built from (may be negative: a layer reaches beyond the terrain).
    pub(crate) origin: (i64, i64),
    /// The layer's last render (of the rows nearer terrain leaves it, see
    /// [`FarLayer::render_with`]), kept for the next render with the same
    /// camera (an edit re-renders one view round after round; the layer
    /// never changes): shared by the clones of the layer.
    pub(crate) drawn: Arc<std::sync::Mutex<Option<Arc<LayerRender>>>>,
    /// The answers of the segment casts made into the layer (it never
    /// changes: the same question gets the same answer), shared by the
    /// clones of the layer.
    pub(crate) casts: Arc<CastMemo>,
    /// The answers of the walks of the layer's cells
    /// ([`LocalTerrain::far_walk`]), shared likewise.
    pub(crate) walks: Arc<CastMemo>,
}

/// A kept render of a far layer, and which of its strips of pixel columns
/// (`x0..=x1`) a new render of the same camera takes from it
/// ([`FarLayer::render_with`]).
pub(crate) type KeptRender<'a> = (&'a LayerRender, &'a (dyn Fn(usize, usize) -> bool + Sync));

/// A far layer's render: the camera and, per pixel, depth and the
/// layer's own triangle id (sky: infinite depth and [`SKY`]); with
/// `last_row`, only the rows `0..=last_row[x]` of each column `x` (the
/// others NaN and [`SKY`]: nearer terrain hides them).
#[derive(Debug)]
pub(crate) struct LayerRender {
    pub(crate) camera: crate::view::Camera,
    pub(crate) last_row: Option<Vec<i32>>,
    pub(crate) depth: Vec<f32>,
    pub(crate) triangle: Vec<u32>,
    /// The first row with a finite depth (the image's height where none
    /// has): the rows above are sky or not drawn, which no composite
    /// takes.
    pub(crate) first_row: usize,
}

impl LayerRender {
    /// Does this render hold every row of `needed` (rows `0..=needed[x]`
    /// of each column `x`)?
    fn holds(&self, needed: &[i32]) -> bool {
        match &self.last_row {
            None => true,
            Some(rows) => {
                rows.len() == needed.len() && needed.iter().zip(rows).all(|(n, r)| n <= r)
            }
        }
    }
}

impl Drop for LayerRender {
    /// The buffers go back to [`crate::buffer_pool`] when a later render
    /// replaces this one (a layer is drawn again as an edit's rounds open
    /// more sky), for that render or the view's next.
    fn drop(&mut self) {
        crate::buffer_pool::recycle_f32(std::mem::take(&mut self.depth));
        crate::buffer_pool::recycle_u32(std::mem::take(&mut self.triangle));
    }
}

impl FarLayer {
    /// The layer's render with `camera`, holding at least the rows
    /// `0..=needed[x]` of each column `x` (the others may be left out: see
    /// [`LayerRender`]): the kept one when it was made with the same camera
    /// and holds them, else made by `render` (given the rows to draw,
    /// `None` for all, and the kept render of the same camera with which
    /// of its strips of columns `x0..=x1` to take: those whose rows are the
    /// new render's, which a render of the strip gives again, each strip
    /// being drawn on its own) and kept. A new render draws the rows of
    /// the kept one too (same camera), so that the renders of an edit's
    /// rounds, whose nearer terrain opens a little more sky here and
    /// there, settle after a few. The lock is not held while rendering (a
    /// render is parallel: a worker waiting in it may take up another
    /// render of this layer).
    pub(crate) fn render_with(
        &self,
        camera: &crate::view::Camera,
        needed: &[i32],
        render: impl FnOnce(&LocalTerrain, Option<&[i32]>, Option<KeptRender>) -> (Vec<f32>, Vec<u32>),
    ) -> Arc<LayerRender> {
        let lock = || {
            self.drawn
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        let same = lock().as_ref().filter(|r| r.camera == *camera).cloned();
        if let Some(r) = same.as_ref().filter(|r| r.holds(needed)) {
            return Arc::clone(r);
        }
        let mut rows = needed.to_vec();
        if let Some(Some(old)) = same.as_ref().map(|r| r.last_row.as_ref()) {
            for (n, &o) in rows.iter_mut().zip(old) {
                *n = (*n).max(o);
            }
        }
        let h = camera.height as i32;
        let last_row = if rows.len() == camera.width && rows.iter().any(|&r| r < h - 1) {
            Some(rows)
        } else {
            None
        };
        // The rows drawn of column `x` (`0..` this) under `rows`.
        let drawn = |rows: Option<&[i32]>, x: usize| match rows {
            None => Some(h),
            Some(l) => l.get(x).map(|&r| (r + 1).clamp(0, h)),
        };
        let keep = |x0: usize, x1: usize| {
            same.as_ref().is_some_and(|old| {
                (x0..=x1).all(|x| {
                    let d = drawn(last_row.as_deref(), x);
                    d.is_some() && d == drawn(old.last_row.as_deref(), x)
                })
            })
        };
        let kept = same
            .as_deref()
            .map(|old| (old, &keep as &(dyn Fn(usize, usize) -> bool + Sync)));
        let (depth, triangle) = render(&self.terrain, last_row.as_deref(), kept);
        // (a whole row at a time, branch-free: it vectorises)
        let first_row = depth
            .chunks(camera.width.max(1))
            .position(|row| {
                row.iter()
                    .fold(false, |a, &d| a | (d.abs() < f32::INFINITY))
            })
            .unwrap_or(camera.height);
        let r = Arc::new(LayerRender {
            camera: *camera,
            last_row,
            depth,
            triangle,
            first_row,
        });
        *lock() = Some(Arc::clone(&r));
        r
    }

    /// The rows of each column of an image that this layer can show, given
    /// `depth` (the image's depths so far, `width` pixels a row): per
    /// column `x`, the last row above the pixels, from the bottom up, that
    /// are already nearer than any point of the layer or NaN (not drawn:
    /// a NaN pixel keeps its NaN whatever the layer holds). There the
    /// nearer hit wins whatever the layer holds, so a render of the layer
    /// without those rows gives the same image. `-1`: no row.
    pub(crate) fn rows_shown(&self, depth: &[f32], width: usize) -> Vec<i32> {
        let w = width.max(1);
        let h = depth.len() / w;
        // (a margin of 0.1 % for the rounding of the depths in f32)
        let bound = (self.reach_m * 0.999) as f32;
        let mut last = vec![h as i32 - 1; w];
        // (branch-free over whole rows, which vectorises; rows are taken
        // from the bottom up while some column is still covered)
        let mut open = vec![1i32; w];
        for j in (0..h).rev() {
            let row = &depth[j * w..(j + 1) * w];
            if covered_row(&mut last, &mut open, row, bound) == 0 {
                break;
            }
        }
        last
    }
}

/// One row of [`FarLayer::rows_shown`], from the bottom up: each column
/// still `open` (covered in every row below) stays open where this row's
/// depth is NaN or nearer than `bound`, and its `last` row shown moves
/// above this one. Returns non-zero while some column is open. Compiled
/// for AVX2 where the CPU has it (integer selects: the same result).
fn covered_row(last: &mut [i32], open: &mut [i32], row: &[f32], bound: f32) -> i32 {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { covered_row_avx2(last, open, row, bound) };
    }
    covered_row_body(last, open, row, bound)
}

/// [`covered_row`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn covered_row_avx2(last: &mut [i32], open: &mut [i32], row: &[f32], bound: f32) -> i32 {
    covered_row_body(last, open, row, bound)
}

/// The loop of [`covered_row`] (branch-free over the row: it vectorises).
#[inline(always)]
fn covered_row_body(last: &mut [i32], open: &mut [i32], row: &[f32], bound: f32) -> i32 {
    let mut any = 0i32;
    for ((l, o), &d) in last.iter_mut().zip(open.iter_mut()).zip(row) {
        // NaN or nearer than the bound: covered
        let covered = i32::from(!(d >= bound));
        *o &= covered;
        // while open, the last row shown is above this one
        *l -= *o;
        any |= *o;
    }
    any
}

/// The far layers of a terrain, as they are (shared): for a later view of
/// the same eye on the same DEM to take them instead of reading them again
/// ([`crate::render::Scene::open_wedge_lod`]).
#[derive(Debug, Clone, Default)]
pub struct FarLayers(pub(crate) Vec<FarLayer>);

impl FarLayers {
    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Do these layers serve a view from `frame` (the same eye, the same
    /// refraction) with rings of coarseness `ks`, on a DEM whose heights
    /// differ from those they were read from only within `changed` (a
    /// window of the DEM, `frame_abs` on the DEM's grid)? Only when no
    /// layer reaches a changed cell: they are then what reading them again
    /// would give, bit for bit.
    pub(crate) fn serve(
        &self,
        frame: &crate::view::LocalFrame,
        frame_abs: &crate::view::LocalFrame,
        ks: &[usize],
        changed: Option<crate::raster::Window>,
    ) -> bool {
        let same_eye = |f: &crate::view::LocalFrame| {
            f.eye_alt.to_bits() == frame.eye_alt.to_bits()
                && f.eye_crs.0.to_bits() == frame.eye_crs.0.to_bits()
                && f.eye_crs.1.to_bits() == frame.eye_crs.1.to_bits()
                && f.curvature == frame.curvature
        };
        if self.0.len() != ks.len()
            || self
                .0
                .iter()
                .zip(ks)
                .any(|(l, &k)| l.k != k || !same_eye(&l.terrain.frame))
        {
            return false;
        }
        let Some(w) = changed else {
            return true;
        };
        // The changed window's farthest corner, against the nearest any
        // layer reads (a coarse cell nearer than its vertex's reach).
        let (x0, y0, x1, y1) = (
            w.col as f64,
            w.row as f64,
            w.col_end() as f64,
            w.row_end() as f64,
        );
        let farthest = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
            .iter()
            .map(|&(x, y)| {
                let (e, n) = frame_abs.pixel_to_en(x, y);
                e.hypot(n)
            })
            .fold(0.0, f64::max);
        self.0.iter().all(|l| {
            let coarse_m = cell_size_m(&l.terrain);
            farthest < l.reach_m - 2.0 * coarse_m
        })
    }
}

/// A far layer before it joins a terrain ([`LocalTerrain::with_far_layers`]).
pub struct FarRing {
    /// The layer, built by [`LocalTerrain::ring_from`] on the coarse grid.
    pub terrain: LocalTerrain,
    /// Its inner radius, metres (its vertices nearer are nodata).
    pub inner_m: f64,
    /// Cells of the DEM per cell of the layer.
    pub k: usize,
    /// Its grid's origin in cells of the grid the terrain was built from.
    pub origin: (i64, i64),
}

/// Which cast a layer answers (the one asked of the terrain).
#[derive(Clone, Copy)]
pub(crate) enum CastKind {
    /// [`LocalTerrain::cast`].
    Full,
    /// [`LocalTerrain::cast_within`].
    Within,
    /// [`LocalTerrain::cast_segment`].
    Segment,
}

impl LocalTerrain {
    /// This terrain with `rings` as its far layers (innermost first), their
    /// triangle ids after this terrain's. A ring whose ids would not fit is
    /// left out, with those beyond it.
    pub fn with_far_layers(mut self, rings: Vec<FarRing>) -> Self {
        let mut next = 2 * (self.cells_x() as u64) * (self.ny.saturating_sub(1) as u64);
        for ring in rings {
            let t = ring.terrain;
            let ids = 2 * (t.cells_x() as u64) * (t.ny.saturating_sub(1) as u64);
            if next + ids >= u64::from(SKY) {
                break;
            }
            // (the layer's frame is on its coarse grid)
            let coarse_cell = cell_size_m(&t);
            // The nearest a vertex can be is the inner radius; a triangle
            // reaches a cell's diagonal nearer.
            let reach_m = (ring.inner_m - 2.0 * std::f64::consts::SQRT_2 * coarse_cell).max(0.0);
            self.far.push(FarLayer {
                terrain: Arc::new(t),
                id0: next as u32,
                reach_m,
                k: ring.k,
                origin: ring.origin,
                drawn: Arc::default(),
                casts: Arc::default(),
                walks: Arc::default(),
            });
            next += ids;
        }
        self
    }

    /// This terrain with `layers` (another terrain's, [`LocalTerrain::far_layers`])
    /// as its far layers, their ids moved to follow this terrain's.
    pub fn with_shared_far_layers(mut self, layers: &FarLayers) -> Self {
        let mut next = 2 * (self.cells_x() as u64) * (self.ny.saturating_sub(1) as u64);
        for l in &layers.0 {
            let t = &l.terrain;
            let ids = 2 * (t.cells_x() as u64) * (t.ny.saturating_sub(1) as u64);
            if next + ids >= u64::from(SKY) {
                break;
            }
            let mut l = l.clone();
            l.id0 = next as u32;
            self.far.push(l);
            next += ids;
        }
        self
    }

    /// This terrain's far layers, shared.
    pub fn far_layers(&self) -> FarLayers {
        FarLayers(self.far.clone())
    }

    /// The far layers' coarseness (cells of the DEM per layer cell) and
    /// vertex counts, innermost first: for reports.
    pub fn far_layer_sizes(&self) -> Vec<(usize, usize)> {
        self.far
            .iter()
            .map(|l| (l.k, l.terrain.nx * l.terrain.ny))
            .collect()
    }

    /// The height range of the terrain and its far layers together (the
    /// terrain's own, [`LocalTerrain::height_range`], without any): what a
    /// picture's colour ramp spans.
    pub fn height_range_with_far(&self) -> (f64, f64) {
        self.far
            .iter()
            .map(|l| l.terrain.height_range())
            .filter(|(lo, hi)| lo <= hi)
            .fold(self.height_range(), |(a, b), (lo, hi)| {
                (a.min(lo), b.max(hi))
            })
    }

    /// Whether triangle `id` belongs to a far layer (not to this terrain's
    /// own grid: its cell is not one of [`LocalTerrain::vertex_local`]'s).
    pub fn is_far_triangle(&self, id: u32) -> bool {
        id != SKY && self.far_of(id).is_some()
    }

    /// The far layer of triangle `id` and the id within it.
    pub(crate) fn far_of(&self, id: u32) -> Option<(&FarLayer, u32)> {
        let first = self.far.first()?;
        if id < first.id0 || id == SKY {
            return None;
        }
        self.far
            .iter()
            .rev()
            .find(|l| id >= l.id0)
            .map(|l| (l, id - l.id0))
    }

    /// The nearer of `hit` (on this terrain) and the far layers' first hit
    /// of the segment `[t_start, t_limit]` of unit ray `d`, cast as `kind`.
    /// A layer is asked only when the segment reaches it.
    pub(crate) fn with_far_hit(
        &self,
        hit: Option<RayHit>,
        d: [f64; 3],
        t_start: f64,
        t_limit: f64,
        kind: CastKind,
    ) -> Option<RayHit> {
        self.with_far_hits(hit, d, t_start, t_limit, kind, None)
    }

    /// [`LocalTerrain::with_far_hit`] where the hit of layer `i` is known
    /// (`known`: `(i, hit)`, the hit in the layer's own ids): it stands
    /// for that layer's cast, in the same order (the terrain, then the
    /// layers innermost first; the nearer wins, the earlier on a tie).
    fn with_far_hits(
        &self,
        hit: Option<RayHit>,
        d: [f64; 3],
        t_start: f64,
        t_limit: f64,
        kind: CastKind,
        known: Option<(usize, RayHit)>,
    ) -> Option<RayHit> {
        if self.far.is_empty() {
            return hit;
        }
        let dh = d[0].hypot(d[1]);
        let mut best = hit;
        for (i, l) in self.far.iter().enumerate() {
            let limit = best.map_or(t_limit, |h| h.t.min(t_limit));
            let h = match known {
                Some((k, h)) if k == i => Some(h),
                _ => {
                    // (false for NaN too)
                    let reaches = dh * limit >= l.reach_m && limit > t_start;
                    if !reaches {
                        continue;
                    }
                    let t = &l.terrain;
                    match kind {
                        CastKind::Full => t.cast(d, limit),
                        CastKind::Within => t.cast_within(d, limit),
                        CastKind::Segment => {
                            let start = start_at_reach(t, d, t_start, l.reach_m / dh);
                            l.casts.answer(CastKey::new(d, start, limit), || {
                                t.cast_segment(d, start, limit)
                            })
                        }
                    }
                }
            };
            if let Some(h) = h.filter(|h| best.is_none_or(|b| h.t < b.t)) {
                best = Some(RayHit {
                    t: h.t,
                    triangle: h.triangle + l.id0,
                });
            }
        }
        best
    }

    /// [`LocalTerrain::cast_from_cell`] from far triangle `id`: the walk
    /// of its layer's own cells from the cell of `id`
    /// ([`LocalTerrain::walk_cells`], with the same checks), then the
    /// terrain's own grid and the other layers cast over the segment from
    /// `t_start` to the walk's hit for a nearer one, as
    /// [`LocalTerrain::with_far_hit`] orders them. What
    /// [`LocalTerrain::cast_segment`] from `t_start` finds where the ray
    /// meets the layer nothing before that cell (the caller's
    /// bisection knows it: the ray passes above one that first met the
    /// terrain there), for a few patches' work instead of a traversal of
    /// the layer's index. `None`: the walk refused or met nothing; the
    /// caller casts.
    pub(crate) fn far_walk(
        &self,
        d: [f64; 3],
        id: u32,
        t_start: f64,
        latest_entry: f64,
        max_cells: usize,
    ) -> Option<RayHit> {
        let first = self.far.first()?;
        if id < first.id0 || id == SKY {
            return None;
        }
        let i = self.far.iter().rposition(|l| id >= l.id0)?;
        let l = &self.far[i];
        let own_id = id - l.id0;
        let key = CastKey::walk(d, own_id, t_start, latest_entry, max_cells);
        let hit = l.walks.answer(key, || {
            l.terrain
                .walk_cells(d, own_id, t_start, latest_entry, max_cells)
                .ok()
        })?;
        let own = self.cast_segment_own(d, t_start, hit.t);
        self.with_far_hits(own, d, t_start, hit.t, CastKind::Segment, Some((i, hit)))
    }

    /// The cell of the DEM grid the terrain was built from under far
    /// triangle `id` of layer `l` (the centre of its coarse cell, clamped
    /// to the grid's first row and column), and its half.
    pub(crate) fn far_triangle_cell(l: &FarLayer, id: u32) -> (usize, usize, u8) {
        let (c, r, half) = l.terrain.triangle_cell(id);
        let k = l.k as i64;
        let full = |o: i64, v: usize| (o + v as i64 * k + k / 2).max(0) as usize;
        (full(l.origin.0, c), full(l.origin.1, r), half)
    }
}

/// Where a segment cast of far layer `t` from `t_start` may start without
/// changing its answer: the entry of the cell the ray crosses at `t_reach`
/// (where its horizontal distance is the layer's reach), as the layer's
/// traversal computes it ([`LocalTerrain::cell_entry`]), when that lies
/// after `t_start`. No point of the layer lies nearer than its reach, so
/// the cells the ray crosses before that one hold no hit (their vertices
/// are nodata: a layer's inner hole), and the traversal from `t_start`
/// reaches that cell at that very entry: the hit is the same, bit for bit,
/// without walking the hole (most of a bisection's rays start at a near
/// crest, kilometres inside it). `t_start` where the point is off the
/// layer's grid or the reach is no later.
fn start_at_reach(t: &LocalTerrain, d: [f64; 3], t_start: f64, t_reach: f64) -> f64 {
    // (NaN: no later start)
    if t_reach.partial_cmp(&t_start) != Some(std::cmp::Ordering::Greater) {
        return t_start;
    }
    match t.cell_entry(d, t_reach) {
        Some(e) if e > t_start && e <= t_reach => e,
        _ => t_start,
    }
}

/// Mean size of a terrain's cell in metres.
fn cell_size_m(t: &LocalTerrain) -> f64 {
    let p = t.frame.p;
    (p[0][0].hypot(p[1][0]) * p[0][1].hypot(p[1][1])).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::Dem;
    use crate::render::triangle_raster::rasterise;
    use crate::render::{DepthBuffer, Scene};
    use crate::view::{Camera, Georef, Viewpoint};

    /// The render of `terrain` as if each far layer were drawn whole: the
    /// terrain's own render, then each layer's whole render where nearer.
    fn whole_layers(terrain: &LocalTerrain, cam: &Camera) -> (Vec<f32>, Vec<u32>) {
        let mut near = terrain.clone();
        near.far.clear();
        let (mut d, mut t) = rasterise(&near, cam, None);
        for l in &terrain.far {
            let (fd, ft) = rasterise(&l.terrain, cam, None);
            for i in 0..d.len() {
                if fd[i] < d[i] {
                    d[i] = fd[i];
                    t[i] = ft[i] + l.id0;
                }
            }
        }
        (d, t)
    }

    fn assert_same(db: &DepthBuffer, (d, t): &(Vec<f32>, Vec<u32>)) {
        assert_eq!(db.triangle, *t);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&db.depth), bits(d));
    }

    /// Far layers drawn only where the nearer terrain leaves them rows give
    /// the image of layers drawn whole, to the bit; a nearer terrain that
    /// opens more sky (lowered) draws a layer again, with the rows of both.
    #[test]
    fn layers_drawn_behind_the_nearer_terrain_give_the_whole_render() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("fixtures")
            .join("zion_srtm_utm12n.tif");
        let dem = Dem::open(&path).unwrap();
        let (x, y) = dem.geotransform.pixel_to_crs(210.5, 440.5);
        let georef = Georef::for_crs(&dem.crs, "zion").unwrap();
        let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
        let vp = Viewpoint::above_surface(lon, lat, 1500.0);
        let cam = Camera::new(160, 90, 0.0, -2.0, 0.0, 90.0).unwrap();
        let scene =
            Scene::open_wedge_lod(&dem, &vp, Some(40_000.0), 1.0 / 7.0, &cam, None).unwrap();
        let terrain = &scene.terrain;
        assert!(!terrain.far.is_empty());
        assert_same(
            &DepthBuffer::render(terrain, &cam),
            &whole_layers(terrain, &cam),
        );
        // The nearer terrain hid rows of a layer: it was drawn in part.
        let partial = |t: &LocalTerrain| {
            t.far.iter().any(|l| {
                l.drawn
                    .lock()
                    .unwrap()
                    .as_ref()
                    .is_some_and(|r| r.last_row.is_some())
            })
        };
        assert!(partial(terrain));
        let kept = |t: &LocalTerrain| -> Vec<Option<Arc<LayerRender>>> {
            t.far
                .iter()
                .map(|l| l.drawn.lock().unwrap().clone())
                .collect()
        };
        let before = kept(terrain);
        // The near terrain 400 m lower: more of the layers shows.
        let w = scene.window.width;
        let lowered = terrain.with_heights((0, 0, w, scene.window.height), &|c, r| {
            Some(scene.window.data[r * w + c] - 400.0)
        });
        assert_same(
            &DepthBuffer::render(&lowered, &cam),
            &whole_layers(&lowered, &cam),
        );
        // (a layer was drawn again: the kept render lacked rows)
        let after = kept(terrain);
        assert!(before.iter().zip(&after).any(|(a, b)| match (a, b) {
            (Some(a), Some(b)) => !Arc::ptr_eq(a, b),
            _ => true,
        }));
        // And the first terrain again, from the layers' kept renders.
        assert_same(
            &DepthBuffer::render(terrain, &cam),
            &whole_layers(terrain, &cam),
        );
    }
}
