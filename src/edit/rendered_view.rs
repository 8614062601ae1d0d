//! One rendering of a sketch view, as the edit pipeline uses it before and
//! after deformation: the local terrain it was cast against, the depth
//! buffer, the silhouettes, and per image column the occlusion boundaries
//! (silhouette samples and the skyline). Also the placed stroke curves the
//! fit measures and the lowering loop compare against.

use crate::features::silhouettes::SilhouetteSample;
use crate::features::{
    extract_silhouettes_reusing, ColumnSamples, FeatureError, Reuse, SilhouetteParams, Silhouettes,
};
use crate::raster::HeightMap;
use crate::render::{pick, DepthBuffer, LocalTerrain, TerrainHit, SKY};
use crate::sketch::{PointSource, Stroke, StrokeMatch};
use crate::view::{Camera, LocalFrame};

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

/// An occlusion boundary counts for the fit only where what is seen beyond
/// it lies farther by at least this fraction of its depth (and one DEM
/// cell): see [`RenderedView::shows_as_boundary`].
pub const BOUNDARY_MIN_GAP: f64 = 0.05;

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
#[derive(Debug, Clone, PartialEq)]
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
            for (i, rows) in stroke_rows.iter_mut().enumerate().take(end).skip(first) {
                let x = (i as f64 + 0.5).clamp(x0, x1);
                if let Some(y) = s.stroke.y_at(x) {
                    put(x, y);
                    rows.push(y as f32);
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
    /// The silhouette samples column by column, as extracted (a later
    /// render of the view after a small change takes the columns the
    /// change cannot reach from here: [`super::rerender`]).
    pub columns: ColumnSamples,
    /// The region rendered (`None`: the whole view).
    pub region: Option<StrokeRegion>,
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

    /// Whether this is a whole render (no [`StrokeRegion`]) of `terrain`'s
    /// surface (to the bit, [`LocalTerrain::same_surface`]) with `camera`:
    /// then it is what [`RenderedView::from_terrain`] would render of it,
    /// to the bit (a later pass that reads the terrain the pass before
    /// read takes that pass's render as it is).
    pub fn is_whole_render_of(&self, terrain: &LocalTerrain, camera: &Camera) -> bool {
        self.region.is_none() && self.camera == *camera && terrain.same_surface(&self.terrain)
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
        Self::render_terrain_region(terrain, camera, region)
    }

    /// [`RenderedView::render_region`] on an already built terrain.
    pub fn render_terrain_region(
        terrain: LocalTerrain,
        camera: &Camera,
        region: &StrokeRegion,
    ) -> Result<RenderedView, FeatureError> {
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
        Self::from_terrain_after(terrain, camera, None)
    }

    /// [`RenderedView::from_terrain`], taking from `earlier` (a render of
    /// a [`StrokeRegion`] of the same view on the same surface: the edit's
    /// last render of a pass, whose result the next pass starts from)
    /// what it rendered already. A region's render holds the whole
    /// render's depths and triangles in its rows
    /// ([`DepthBuffer::render_rows`]): they are taken, and only the rows
    /// below are rendered ([`DepthBuffer::render_below`]). On the same
    /// surface (to the bit, [`LocalTerrain::same_surface`]) a silhouette
    /// candidate between rows `y - 1` and `y` with rows `y - 1 ..= y + 1`
    /// in the region, which the region wanted, is refined to the samples
    /// the region's render holds ([`Reuse::Candidates`]); the others are
    /// refined here. Anything else (another camera, another surface, a
    /// whole render) renders afresh. The result is that of
    /// [`RenderedView::from_terrain`], to the bit.
    pub fn from_terrain_after(
        terrain: LocalTerrain,
        camera: &Camera,
        earlier: Option<&RenderedView>,
    ) -> Result<RenderedView, FeatureError> {
        let usable = earlier.and_then(|e| {
            let region = e.region.as_ref()?;
            (e.camera == *camera
                && region.last_row.len() == camera.width
                && e.depth.depth.len() == camera.width * camera.height
                && terrain.same_surface(&e.terrain))
            .then_some((e, region))
        });
        let Some((earlier, region)) = usable else {
            let (depth, ()) = rayon::join(
                || DepthBuffer::render(&terrain, camera),
                || terrain.build_cast_index(),
            );
            return Self::from_depth(terrain, depth, None);
        };
        let last_row = &region.last_row;
        let first_row: Vec<i32> = last_row
            .iter()
            .map(|&r| (r + 1).clamp(0, camera.height as i32))
            .collect();
        let (depth, ()) = rayon::join(
            || DepthBuffer::render_below(&terrain, camera, &first_row, &earlier.depth),
            || terrain.build_cast_index(),
        );
        let take = |x: usize, y: usize, near: f32| {
            (y as i64) < last_row[x] as i64 && region.wants(x, y, near)
        };
        let all = |_: usize, _: usize, _: f32| true;
        let reuse = Reuse::Candidates(&earlier.columns, &take);
        Self::with_silhouettes(terrain, depth, None, &all, Some(reuse))
    }

    /// The render of `region` ([`RenderedView::render_terrain_region`])
    /// on `terrain`, taken from this whole render of the same surface (to
    /// the bit, [`LocalTerrain::same_surface`]) instead of rendered: the
    /// region's rows of the depth buffer ([`DepthBuffer::rows_of`]), and
    /// every silhouette candidate the region wants between rows `y - 1`
    /// and `y` with rows `y - 1 ..= y + 1` in the region refined to the
    /// samples this render holds ([`Reuse::Candidates`]; the others, at
    /// the region's last row, are refined). The result is that of the
    /// region's render, to the bit. `None` where this is not a whole
    /// render of that surface without far layers.
    pub fn region_of(
        &self,
        terrain: LocalTerrain,
        region: &StrokeRegion,
    ) -> Option<Result<RenderedView, FeatureError>> {
        let camera = &self.camera;
        let usable = self.region.is_none()
            && region.last_row.len() == camera.width
            && self.depth.depth.len() == camera.width * camera.height
            && self.columns.samples.len() == camera.width
            && terrain.same_surface(&self.terrain);
        if !usable {
            return None;
        }
        let last_row = &region.last_row;
        let depth = DepthBuffer::rows_of(&self.depth, last_row);
        let take = |x: usize, y: usize, near: f32| {
            (y as i64) < last_row[x] as i64 && region.wants(x, y, near)
        };
        let wants = |x: usize, y: usize, near: f32| region.wants(x, y, near);
        let reuse = Reuse::Candidates(&self.columns, &take);
        Some(Self::with_silhouettes(
            terrain,
            depth,
            Some(region),
            &wants,
            Some(reuse),
        ))
    }

    /// Silhouettes (those `region` wants, or all) and boundaries of a
    /// rendered depth buffer.
    fn from_depth(
        terrain: LocalTerrain,
        depth: DepthBuffer,
        region: Option<&StrokeRegion>,
    ) -> Result<RenderedView, FeatureError> {
        Self::from_depth_reusing(terrain, depth, region, None)
    }

    /// [`RenderedView::from_depth`], with the silhouette columns `x` for
    /// which `keep(x)` holds taken from `earlier`'s (see
    /// [`extract_silhouettes_reusing`]).
    pub(super) fn from_depth_reusing(
        terrain: LocalTerrain,
        depth: DepthBuffer,
        region: Option<&StrokeRegion>,
        reuse: Option<(&RenderedView, &(dyn Fn(usize) -> bool + Sync))>,
    ) -> Result<RenderedView, FeatureError> {
        let all = |_: usize, _: usize, _: f32| true;
        let wants = |x: usize, y: usize, near: f32| region.is_none_or(|r| r.wants(x, y, near));
        let wanted: &(dyn Fn(usize, usize, f32) -> bool + Sync) = match region {
            Some(_) => &wants,
            None => &all,
        };
        let reuse = reuse.map(|(earlier, keep)| Reuse::Columns(&earlier.columns, keep));
        Self::with_silhouettes(terrain, depth, region, wanted, reuse)
    }

    /// The view of `terrain` and its rendered `depth`, with the
    /// silhouettes `wanted` (those of `region`, or all), taking from an
    /// earlier extraction what `reuse` names.
    fn with_silhouettes(
        terrain: LocalTerrain,
        depth: DepthBuffer,
        region: Option<&StrokeRegion>,
        wanted: &(dyn Fn(usize, usize, f32) -> bool + Sync),
        reuse: Option<Reuse>,
    ) -> Result<RenderedView, FeatureError> {
        let params = SilhouetteParams::default();
        let (silhouettes, columns) =
            extract_silhouettes_reusing(&terrain, &depth, &params, wanted, reuse)?;
        let camera = depth.camera;
        let by_column = samples_by_column(&silhouettes, camera.width);
        let skyline_row = skyline_rows(&depth);
        Ok(RenderedView {
            terrain,
            camera,
            depth,
            silhouettes,
            by_column,
            skyline_row,
            columns,
            region: region.cloned(),
        })
    }

    /// Width in pixels of one DEM cell seen from `depth` metres (the larger
    /// of its two sides).
    pub fn cell_px(&self, depth: f64) -> f64 {
        if !(depth > 0.0) {
            return f64::INFINITY;
        }
        self.cell_m() * self.camera.focal_px / depth
    }

    /// Distance from row `y` of column `i` to its nearest occlusion
    /// boundary, and whether one lies within `tol` pixels of `y`.
    pub fn boundary_near(&self, i: usize, y: f64, tol: f64) -> (f64, bool) {
        let mut nearest = f64::INFINITY;
        for &(c, s) in &self.by_column[i] {
            let s = &self.silhouettes.curves[c as usize].samples[s as usize];
            if !self.shows_as_boundary(s) {
                continue;
            }
            nearest = nearest.min((s.pixel[1] - y).abs());
        }
        let mut within = nearest <= tol;
        if let Some(j) = self.skyline_row[i].filter(|&j| j > 0) {
            let d = (j as f64 - y).abs();
            nearest = nearest.min(d);
            within |= d <= tol;
        }
        (nearest, within)
    }

    /// Whether silhouette sample `s` shows as a boundary a person would
    /// draw: what lies beyond it is sky, or terrain farther than it by at
    /// least [`BOUNDARY_MIN_GAP`] of its depth and by at least one DEM cell.
    /// A crest with the terrain rising again a cell behind it (the flank of
    /// the old ridge still standing above a lowered crest in front of it)
    /// is a kink of one slope, not a silhouette: the ridge behind is what
    /// the eye sees as the outline there.
    pub fn shows_as_boundary(&self, s: &SilhouetteSample) -> bool {
        let gap = s.depth_behind - s.depth;
        !s.depth_behind.is_finite() || (gap >= BOUNDARY_MIN_GAP * s.depth && gap >= self.cell_m())
    }

    /// The larger side of one DEM cell, metres.
    pub fn cell_m(&self) -> f64 {
        let p = self.terrain.frame.p;
        p[0][0].hypot(p[1][0]).max(p[0][1].hypot(p[1][1]))
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

    /// The first terrain the view shows at or below `pixel` in its
    /// column, searched down to `max_rows` rows under it, and its row.
    /// The search goes on below the image's lower border by casting the
    /// rays of the rows there: a stroke cut by the frame stands on terrain
    /// the frame does not show (Gain et al. 2009, section 3.1: the terrain
    /// under a silhouette stroke's end points).
    pub fn terrain_at_or_below(&self, pixel: [f64; 2], max_rows: f64) -> Option<(TerrainHit, f64)> {
        let (w, h) = (self.camera.width, self.camera.height);
        if !(pixel[0].is_finite() && pixel[1].is_finite()) || w == 0 || h == 0 {
            return None;
        }
        let i = (pixel[0].floor().max(0.0) as usize).min(w - 1);
        let j0 = pixel[1].floor().max(0.0);
        let last = (pixel[1] + max_rows.max(0.0)).floor();
        let in_image = (j0 as usize).min(h - 1)..(last.max(0.0) as usize + 1).min(h);
        for j in in_image {
            if self.depth.triangle[j * w + i] != SKY {
                return self
                    .depth
                    .hit(&self.terrain, i, j)
                    .map(|hit| (hit, j as f64));
            }
        }
        let mut j = j0.max(h as f64);
        while j <= last {
            if let Some(hit) = pick(&self.terrain, &self.camera, i as f64 + 0.5, j + 0.5) {
                return Some((hit, j));
            }
            j += 1.0;
        }
        None
    }
}

/// For each of the `w` image columns, the `(curve, sample)` indices of the
/// silhouette samples in it.
fn samples_by_column(silhouettes: &Silhouettes, w: usize) -> Vec<Vec<(u32, u32)>> {
    let mut by_column = vec![Vec::new(); w];
    for (ci, c) in silhouettes.curves.iter().enumerate() {
        for (si, s) in c.samples.iter().enumerate() {
            let x = s.pixel[0].floor();
            if x >= 0.0 && (x as usize) < w {
                by_column[x as usize].push((ci as u32, si as u32));
            }
        }
    }
    by_column
}

/// For each image column, the row of its topmost terrain pixel (`None`:
/// all sky), found row by row (the buffer is row-major) until every
/// column has met the terrain.
fn skyline_rows(depth: &DepthBuffer) -> Vec<Option<usize>> {
    let w = depth.camera.width;
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
    skyline_row
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
