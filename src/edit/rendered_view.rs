//! One rendering of a sketch view, as the edit pipeline uses it before and
//! after deformation: the local terrain it was cast against, the depth
//! buffer, the silhouettes, and per image column the occlusion boundaries
//! (silhouette samples and the skyline). Also the placed stroke curves the
//! fit measures and the lowering loop compare against.

use crate::features::{
    extract_silhouettes, extract_silhouettes_where, FeatureError, SilhouetteParams,
    SilhouetteSample, Silhouettes,
};
use crate::raster::HeightMap;
use crate::render::{DepthBuffer, LocalTerrain, SKY};
use crate::sketch::{PointSource, Stroke, StrokeMatch};
use crate::view::{Camera, CameraModel, LocalFrame};

/// The part of a view that the edit's re-renders compute: the strokes'
/// columns widened by this many pixels on each side ...
pub const REGION_PAD_PX: f64 = 16.0;
/// ... from the top of the image down to this many pixels under the
/// strokes ...
pub const REGION_BELOW_PX: f64 = 16.0;
/// ... and there, the silhouettes nearer than the strokes' placed curves
/// (by this fraction of their depth, as a margin) or within
/// [`REGION_NEAR_ROWS`] rows of a stroke.
pub const REGION_DEPTH_MARGIN: f64 = 0.05;
/// See [`REGION_DEPTH_MARGIN`].
pub const REGION_NEAR_ROWS: f32 = 3.0;

/// What the edit's re-renders of a view compute ([`RenderedView::render_region`]).
///
/// Everything the lowering ([`super::lowering`]), the contour fitting
/// ([`super::contour`]) and the fit measure ([`super::fit`]) look at lies in
/// the columns of a stroke (or [`super::lowering::LOWERING_PAD_PX`] beside
/// it) at or above it: an occlusion boundary within
/// [`super::fit::FIT_TOLERANCE_PX`] of the stroke, at any depth; a
/// protruding silhouette, above the stroke and nearer than its placed
/// curve; the nearer terrain over a hidden stroke. So the depth buffer is
/// rendered only down to a little under the strokes, and silhouettes are
/// refined only where they can be one of these.
#[derive(Debug, Clone)]
pub struct StrokeRegion {
    /// Per image column, the last row rendered (-1: none).
    pub last_row: Vec<i32>,
    /// Per image column, silhouettes whose near side is nearer than this
    /// (metres) are extracted; 0 where no stroke is near.
    pub depth_limit: Vec<f32>,
    /// Per image column, the rows of the strokes crossing it: silhouettes
    /// within [`REGION_NEAR_ROWS`] of them are extracted at any depth.
    pub stroke_rows: Vec<Vec<f32>>,
}

impl StrokeRegion {
    /// The region of `strokes` in a `width` x `height` view.
    pub fn new(strokes: &[StrokeCurve], width: usize, height: usize) -> StrokeRegion {
        // Per column, the lowest stroke row (its points and its centre),
        // the farthest placed depth, and the strokes' rows ...
        let mut lowest = vec![f64::NEG_INFINITY; width];
        let mut farthest = vec![0.0f64; width];
        let mut stroke_rows = vec![Vec::new(); width];
        for s in strokes {
            let (x0, x1) = s.stroke.x_range();
            if !(x0.is_finite() && x1.is_finite()) {
                continue;
            }
            let mut put = |x: f64, y: f64| {
                if x >= 0.0 && x < width as f64 && y.is_finite() {
                    let i = x as usize;
                    lowest[i] = lowest[i].max(y);
                    farthest[i] = farthest[i].max(s.depth_at(x).unwrap_or(0.0));
                }
            };
            for p in &s.stroke.points {
                put(p[0], p[1]);
            }
            let first = x0.floor().max(0.0) as usize;
            let end = (x1.ceil().max(0.0) as usize).min(width);
            for i in first..end {
                let x = (i as f64 + 0.5).clamp(x0, x1);
                if let Some(y) = s.stroke.y_at(x) {
                    put(x, y);
                    stroke_rows[i].push(y as f32);
                }
            }
        }
        // ... then the deepest and farthest of them within the padding on
        // either side.
        let pad = REGION_PAD_PX.ceil() as usize;
        let near = |i: usize| i.saturating_sub(pad)..(i + pad + 1).min(width);
        let last_row = (0..width)
            .map(|i| {
                let y = lowest[near(i)]
                    .iter()
                    .fold(f64::NEG_INFINITY, |a, &b| a.max(b));
                if y.is_finite() {
                    (y + REGION_BELOW_PX)
                        .ceil()
                        .clamp(-1.0, height as f64 - 1.0) as i32
                } else {
                    -1
                }
            })
            .collect();
        let depth_limit = (0..width)
            .map(|i| {
                let d = farthest[near(i)].iter().fold(0.0f64, |a, &b| a.max(b));
                (d * (1.0 + REGION_DEPTH_MARGIN)) as f32
            })
            .collect();
        StrokeRegion {
            last_row,
            depth_limit,
            stroke_rows,
        }
    }

    /// Is a silhouette between rows `y - 1` and `y` of column `x`, whose
    /// near side (row `y`) lies at distance `near` metres, in the region?
    pub fn wants(&self, x: usize, y: usize, near: f32) -> bool {
        let y = y as f32;
        x < self.last_row.len()
            && y <= self.last_row[x] as f32
            && (near < self.depth_limit[x]
                || self.stroke_rows[x]
                    .iter()
                    .any(|&r| (y - r).abs() <= REGION_NEAR_ROWS))
    }
}

/// A rendered view and its occlusion boundaries.
pub struct RenderedView {
    pub terrain: LocalTerrain,
    pub camera: Camera,
    pub depth: DepthBuffer,
    pub silhouettes: Silhouettes,
    /// For each image column, the `(curve, sample)` indices of the
    /// silhouette samples in it.
    pub by_column: Vec<Vec<(u32, u32)>>,
    /// For each image column, the row of the topmost terrain pixel (the
    /// skyline lies on its upper edge), `None` when the column is all sky.
    pub skyline_row: Vec<Option<usize>>,
}

impl RenderedView {
    /// Render `map` (a window of the DEM in the pixel space `frame` was
    /// resolved on) from `frame` with `camera`, keeping cells within
    /// `max_distance` metres.
    pub fn render(
        map: &HeightMap,
        frame: &LocalFrame,
        camera: &Camera,
        max_distance: Option<f64>,
    ) -> Result<RenderedView, FeatureError> {
        let terrain = LocalTerrain::in_view(map, frame, max_distance, camera);
        Self::from_terrain(terrain, camera)
    }

    /// Render only `region` of the view (see [`StrokeRegion`] and
    /// [`DepthBuffer::render_rows`]): the depths there, and the silhouette
    /// samples it wants, are those of the whole view; a silhouette is cut
    /// where it leaves the region.
    pub fn render_region(
        map: &HeightMap,
        frame: &LocalFrame,
        camera: &Camera,
        max_distance: Option<f64>,
        region: &StrokeRegion,
    ) -> Result<RenderedView, FeatureError> {
        let terrain = LocalTerrain::in_view(map, frame, max_distance, camera);
        // The edit casts many rays on this terrain (silhouettes, hidden
        // strokes): the full cast index is built beside the render.
        let (depth, ()) = rayon::join(
            || DepthBuffer::render_rows(&terrain, camera, &region.last_row),
            || terrain.build_cast_index(),
        );
        Self::from_depth(terrain, depth, Some(region))
    }

    /// Render an already built terrain.
    pub fn from_terrain(
        terrain: LocalTerrain,
        camera: &Camera,
    ) -> Result<RenderedView, FeatureError> {
        let (depth, ()) = rayon::join(
            || DepthBuffer::render(&terrain, camera),
            || terrain.build_cast_index(),
        );
        Self::from_depth(terrain, depth, None)
    }

    /// Silhouettes (those `region` wants, or all) and boundaries of a
    /// rendered depth buffer.
    fn from_depth(
        terrain: LocalTerrain,
        depth: DepthBuffer,
        region: Option<&StrokeRegion>,
    ) -> Result<RenderedView, FeatureError> {
        let camera = depth.camera;
        let params = SilhouetteParams::default();
        let silhouettes = match region {
            Some(r) => extract_silhouettes_where(&terrain, &depth, &params, &|x, y, near| {
                r.wants(x, y, near)
            })?,
            None => extract_silhouettes(&terrain, &depth, &params)?,
        };
        let w = camera.width;
        let mut by_column = vec![Vec::new(); w];
        for (ci, c) in silhouettes.curves.iter().enumerate() {
            for (si, s) in c.samples.iter().enumerate() {
                let x = s.pixel[0].floor();
                if x >= 0.0 && (x as usize) < w {
                    by_column[x as usize].push((ci as u32, si as u32));
                }
            }
        }
        // Row by row (the buffer is row-major) until every column has met
        // the terrain.
        let mut skyline_row = vec![None; w];
        let mut open = w;
        for (j, row) in depth.triangle.chunks_exact(w.max(1)).enumerate() {
            if open == 0 {
                break;
            }
            for (s, &t) in skyline_row.iter_mut().zip(row) {
                if s.is_none() && t != SKY {
                    *s = Some(j);
                    open -= 1;
                }
            }
        }
        Ok(RenderedView {
            terrain,
            camera,
            depth,
            silhouettes,
            by_column,
            skyline_row,
        })
    }

    /// The image row, in column `i`, of the silhouette of `sample` on
    /// DESIGN.md's surface: the bilinear height field of the DEM's cells,
    /// which the renderer's two triangles per cell approximate (they differ
    /// by up to a quarter of a cell's twist, a few pixels where cells look
    /// large). Rays of the column near the sample's row are tested against
    /// the bilinear surface within [`BILINEAR_REACH_CELLS`] cells of the
    /// sample's terrain point, and the row where they stop clearing it is
    /// found by bisection. `None` when the rows around the sample do not
    /// bracket such a change (the triangle row stands).
    pub fn bilinear_row(&self, i: usize, sample: &SilhouetteSample) -> Option<f64> {
        let x = i as f64 + 0.5;
        let y0 = sample.pixel[1];
        let t_p = sample.depth;
        let t = &self.terrain;
        // The two surfaces cannot put this boundary farther apart than
        // this: nothing to refine where it is a fraction of a pixel.
        let open = self.interpolation_bound_px(sample.cell, sample.depth);
        if open < 0.05 {
            return Some(y0);
        }
        // The ray span around the sample's point: a few cells either way.
        let (e, n) = (sample.local[0], sample.local[1]);
        let (ve, vn) = t.en_to_v(e, n);
        let (ve1, vn1) = t.en_to_v(e + 1.0, n);
        let (ve2, vn2) = t.en_to_v(e, n + 1.0);
        let cells_per_m = (ve1 - ve).hypot(vn1 - vn).max((ve2 - ve).hypot(vn2 - vn));
        if !(cells_per_m > 0.0 && ve.is_finite() && vn.is_finite()) {
            return None;
        }
        let reach = BILINEAR_REACH_CELLS / cells_per_m;
        let (ta, tb) = ((t_p - reach).max(0.5 * t_p), t_p + reach);
        // Quarter-cell steps over the span, then sixteenth-cell steps around
        // the least of them (quarter-cell steps alone miss a crest between
        // them by up to a pixel where cells look large).
        let steps = (4.0 * 2.0 * BILINEAR_REACH_CELLS) as usize;
        let dt = (tb - ta) / steps as f64;
        // Least clearance of the ray through row y above the bilinear
        // surface over the span (negative: it hits the occluder).
        let clearance = |y: f64| -> Option<f64> {
            let d = self.camera.unproject([x, y]);
            let at = |tt: f64| {
                let p = [d[0] * tt, d[1] * tt, d[2] * tt];
                let (vx, vy) = t.en_to_v(p[0], p[1]);
                bilinear_vertex_z(t, vx, vy).map(|h| p[2] - h)
            };
            let (mut least, mut k_least) = (f64::INFINITY, 0);
            for k in 0..=steps {
                if let Some(c) = at(ta + dt * k as f64) {
                    if c < least {
                        (least, k_least) = (c, k);
                    }
                }
            }
            let t0 = ta + dt * k_least as f64;
            for j in (-3..=3).filter(|&j| j != 0) {
                let tt = t0 + dt * j as f64 / 4.0;
                if (ta..=tb).contains(&tt) {
                    if let Some(c) = at(tt) {
                        least = least.min(c);
                    }
                }
            }
            least.is_finite().then_some(least)
        };
        let reach_px = open + 1.0;
        let (mut above, mut below) = (y0 - reach_px, y0 + reach_px);
        if !(clearance(above)? > 0.0 && clearance(below)? <= 0.0) {
            return None;
        }
        for _ in 0..10 {
            let mid = 0.5 * (above + below);
            if clearance(mid)? > 0.0 {
                above = mid;
            } else {
                below = mid;
            }
        }
        Some(0.5 * (above + below))
    }

    /// How far apart, in pixels, the renderer's two triangles per cell and
    /// the bilinear surface can put a boundary formed in `cell` (window
    /// coordinates) seen from `depth`: a quarter of the largest twist
    /// `|h00 + h11 - h10 - h01|` of the 3 x 3 cells around it, projected,
    /// at most [`BILINEAR_SEARCH_PX`]. Cheap: it gates
    /// [`RenderedView::bilinear_row`].
    pub fn interpolation_bound_px(&self, cell: [u32; 2], depth: f64) -> f64 {
        let t = &self.terrain;
        let (c, r) = (
            cell[0] as i64 - t.col0 as i64,
            cell[1] as i64 - t.row0 as i64,
        );
        let z = |c: i64, r: i64| {
            if c < 0 || r < 0 {
                None
            } else {
                t.vertex_z(c as usize, r as usize)
            }
        };
        let mut twist = 0.0f64;
        for dr in -1..=1 {
            for dc in -1..=1 {
                let (c, r) = (c + dc, r + dr);
                if let (Some(a), Some(b), Some(cc), Some(d)) =
                    (z(c, r), z(c + 1, r), z(c, r + 1), z(c + 1, r + 1))
                {
                    twist = twist.max((a + d - b - cc).abs());
                }
            }
        }
        if !(depth > 0.0) {
            return 0.0;
        }
        (0.25 * twist * self.camera.focal_px / depth).min(BILINEAR_SEARCH_PX)
    }

    /// Width in pixels of one DEM cell seen from `depth` metres (the larger
    /// of its two sides).
    pub fn cell_px(&self, depth: f64) -> f64 {
        let p = self.terrain.frame.p;
        let cell_m = p[0][0].hypot(p[1][0]).max(p[0][1].hypot(p[1][1]));
        if !(depth > 0.0) {
            return f64::INFINITY;
        }
        cell_m * self.camera.focal_px / depth
    }

    /// Distance from row `y` of column `i` to its nearest occlusion
    /// boundary as the renderer draws it, and whether a boundary lies
    /// within `tol` pixels of `y` as drawn or as the bilinear surface has
    /// it ([`RenderedView::bilinear_row`], computed only where it could
    /// make the difference).
    pub fn boundary_near(&self, i: usize, y: f64, tol: f64) -> (f64, bool) {
        let mut nearest = f64::INFINITY;
        let mut within = false;
        for &(c, s) in &self.by_column[i] {
            let s = &self.silhouettes.curves[c as usize].samples[s as usize];
            let d = (s.pixel[1] - y).abs();
            nearest = nearest.min(d);
            if within {
                continue;
            }
            within = d <= tol
                || (d <= tol + self.interpolation_bound_px(s.cell, s.depth)
                    && self
                        .bilinear_row(i, s)
                        .is_some_and(|b| (b - y).abs() <= tol));
        }
        if let Some(j) = self.skyline_row[i].filter(|&j| j > 0) {
            let d = (j as f64 - y).abs();
            nearest = nearest.min(d);
            within |= d <= tol;
        }
        (nearest, within)
    }

    /// Image rows of every occlusion boundary in column `i`: silhouette
    /// samples and the skyline.
    pub fn boundaries(&self, i: usize) -> impl Iterator<Item = f64> + '_ {
        let sil = self.by_column[i]
            .iter()
            .map(move |&(c, s)| self.silhouettes.curves[c as usize].samples[s as usize].pixel[1]);
        let sky = self.skyline_row[i].filter(|&j| j > 0).map(|j| j as f64);
        sil.chain(sky)
    }
}

/// [`RenderedView::bilinear_row`] looks this many cells either way of a
/// silhouette's terrain point ...
pub const BILINEAR_REACH_CELLS: f64 = 2.0;
/// ... and this many pixels either way of its row.
pub const BILINEAR_SEARCH_PX: f64 = 8.0;

/// Bilinear interpolation of the vertex heights of `t` at vertex
/// coordinates `(vx, vy)`; `None` outside or next to a hole.
fn bilinear_vertex_z(t: &LocalTerrain, vx: f64, vy: f64) -> Option<f64> {
    if !(vx >= 0.0 && vy >= 0.0) {
        return None;
    }
    let (c, r) = (vx.floor() as usize, vy.floor() as usize);
    let (fx, fy) = (vx - c as f64, vy - r as f64);
    let z00 = t.vertex_z(c, r)?;
    let z10 = t.vertex_z(c + 1, r)?;
    let z01 = t.vertex_z(c, r + 1)?;
    let z11 = t.vertex_z(c + 1, r + 1)?;
    Some(
        z00 * (1.0 - fx) * (1.0 - fy)
            + z10 * fx * (1.0 - fy)
            + z01 * (1.0 - fx) * fy
            + z11 * fx * fy,
    )
}

/// A stroke as drawn (x-monotone, prepared) with the depth of its placed
/// 3D curve along image x.
#[derive(Debug, Clone)]
pub struct StrokeCurve {
    pub id: String,
    pub source_id: String,
    pub stroke: Stroke,
    /// `(pixel x, depth)` of the placed points on the stroke, sorted by x.
    pub depths: Vec<(f64, f64)>,
    /// Beside each entry of `depths`: the point lies on a silhouette of
    /// the unedited view ([`super::on_silhouette`]) and is kept as it is.
    pub anchored: Vec<bool>,
}

impl StrokeCurve {
    /// The stroke and its placement.
    pub fn new(stroke: &Stroke, placed: &StrokeMatch) -> StrokeCurve {
        let mut points: Vec<(f64, f64, bool)> = placed
            .points
            .iter()
            .filter(|p| p.source != PointSource::Completion)
            .filter_map(|p| {
                p.pixel
                    .map(|px| (px[0], p.depth, p.source == PointSource::Silhouette))
            })
            .filter(|(x, d, _)| x.is_finite() && d.is_finite() && *d > 0.0)
            .collect();
        points.sort_by(|a, b| a.0.total_cmp(&b.0));
        StrokeCurve {
            id: stroke.id.clone(),
            source_id: stroke.source_id.clone(),
            stroke: stroke.clone(),
            depths: points.iter().map(|p| (p.0, p.1)).collect(),
            anchored: points.iter().map(|p| p.2).collect(),
        }
    }

    /// True when image x lies on an anchored stretch of the stroke: the
    /// placed points on both sides of it are anchored (beyond the ends:
    /// the end point is).
    pub fn is_anchored(&self, x: f64) -> bool {
        let d = &self.depths;
        if d.is_empty() {
            return false;
        }
        let k = d.partition_point(|p| p.0 < x);
        let left = k.saturating_sub(1);
        let right = k.min(d.len() - 1);
        self.anchored[left] && self.anchored[right]
    }

    /// True when every placed point of the stroke is anchored.
    pub fn fully_anchored(&self) -> bool {
        !self.anchored.is_empty() && self.anchored.iter().all(|&a| a)
    }

    /// [`StrokeCurve::columns`] without the anchored ones: the columns an
    /// edit may still have to change.
    pub fn free_columns(&self, width: usize) -> Vec<(usize, f64, f64)> {
        let mut cols = self.columns(width);
        cols.retain(|&(i, _, _)| !self.is_anchored(i as f64 + 0.5));
        cols
    }

    /// Depth of the placed curve at image x (clamped at the ends).
    pub fn depth_at(&self, x: f64) -> Option<f64> {
        let d = &self.depths;
        let first = d.first()?;
        let last = d.last()?;
        if x <= first.0 {
            return Some(first.1);
        }
        if x >= last.0 {
            return Some(last.1);
        }
        let k = d.partition_point(|p| p.0 < x).max(1);
        let (a, b) = (d[k - 1], d[k]);
        let t = if b.0 > a.0 {
            (x - a.0) / (b.0 - a.0)
        } else {
            0.0
        };
        Some(a.1 + t * (b.1 - a.1))
    }

    /// The image columns whose centre lies within the stroke's x extent,
    /// with the stroke's y and depth there.
    pub fn columns(&self, width: usize) -> Vec<(usize, f64, f64)> {
        let (x0, x1) = self.stroke.x_range();
        let first = (x0 - 0.5).ceil().max(0.0) as usize;
        let last = (x1 - 0.5).floor();
        if last < 0.0 {
            return Vec::new();
        }
        let last = (last as usize).min(width.saturating_sub(1));
        (first..=last)
            .filter_map(|i| {
                let x = i as f64 + 0.5;
                let y = self.stroke.y_at(x)?;
                let d = self.depth_at(x)?;
                Some((i, y, d))
            })
            .collect()
    }
}
