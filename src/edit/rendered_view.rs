//! One rendering of a sketch view, as the edit pipeline uses it before and
//! after deformation: the local terrain it was cast against, the depth
//! buffer, the silhouettes, and per image column the occlusion boundaries
//! (silhouette samples and the skyline). Also the placed stroke curves the
//! fit measures and the lowering loop compare against.

use crate::features::{extract_silhouettes, FeatureError, SilhouetteParams, Silhouettes};
use crate::raster::HeightMap;
use crate::render::{DepthBuffer, LocalTerrain, SKY};
use crate::sketch::{PointSource, Stroke, StrokeMatch};
use crate::view::{Camera, LocalFrame};

/// The region of the view that the edit's re-renders need: the strokes'
/// columns widened by this many pixels on each side ...
pub const REGION_PAD_PX: f64 = 16.0;
/// ... from the top of the image down to this many pixels under the
/// strokes. Everything the lowering, the contour fitting and the fit
/// measure look at lies at or above a stroke (a boundary within
/// [`super::fit::FIT_TOLERANCE_PX`] of it, a protruding silhouette above
/// it, nearer terrain over it) and at most
/// [`super::lowering::LOWERING_PAD_PX`] beside it.
pub const REGION_BELOW_PX: f64 = 16.0;

/// The last image row to render in each of the `width` image columns (-1:
/// none) so that the region covers every stroke of `strokes` with the
/// margins [`REGION_PAD_PX`] and [`REGION_BELOW_PX`] (see
/// [`RenderedView::render_rows`]).
pub fn stroke_region(strokes: &[StrokeCurve], width: usize, height: usize) -> Vec<i32> {
    // The lowest stroke row in each column (its points and its centre) ...
    let mut lowest = vec![f64::NEG_INFINITY; width];
    for s in strokes {
        let (x0, x1) = s.stroke.x_range();
        if !(x0.is_finite() && x1.is_finite()) {
            continue;
        }
        let mut put = |x: f64, y: f64| {
            if x >= 0.0 && x < width as f64 && y.is_finite() {
                let l = &mut lowest[x as usize];
                *l = l.max(y);
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
            }
        }
    }
    // ... then the deepest of it within the padding on either side.
    let pad = REGION_PAD_PX.ceil() as usize;
    (0..width)
        .map(|i| {
            let y = lowest[i.saturating_sub(pad)..(i + pad + 1).min(width)]
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
        .collect()
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
        let terrain = LocalTerrain::new(map, frame, max_distance);
        Self::from_terrain(terrain, camera)
    }

    /// Render only the rows `0..=last_row[x]` of each column `x` (see
    /// [`DepthBuffer::render_rows`] and [`stroke_region`]): the silhouettes,
    /// boundaries and depths there are those of the whole view, except that
    /// a silhouette is cut where it leaves the region.
    pub fn render_rows(
        map: &HeightMap,
        frame: &LocalFrame,
        camera: &Camera,
        max_distance: Option<f64>,
        last_row: &[i32],
    ) -> Result<RenderedView, FeatureError> {
        let terrain = LocalTerrain::new(map, frame, max_distance);
        // The edit casts many rays on this terrain (silhouettes, hidden
        // strokes): the full cast index is built beside the render.
        let (depth, ()) = rayon::join(
            || DepthBuffer::render_rows(&terrain, camera, last_row),
            || terrain.build_cast_index(),
        );
        Self::from_depth(terrain, depth)
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
        Self::from_depth(terrain, depth)
    }

    /// Silhouettes and boundaries of a rendered depth buffer.
    fn from_depth(terrain: LocalTerrain, depth: DepthBuffer) -> Result<RenderedView, FeatureError> {
        let camera = depth.camera;
        let silhouettes = extract_silhouettes(&terrain, &depth, &SilhouetteParams::default())?;
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

/// A stroke as drawn (x-monotone, prepared) with the depth of its placed
/// 3D curve along image x.
#[derive(Debug, Clone)]
pub struct StrokeCurve {
    pub id: String,
    pub source_id: String,
    pub stroke: Stroke,
    /// `(pixel x, depth)` of the placed points on the stroke, sorted by x.
    pub depths: Vec<(f64, f64)>,
}

impl StrokeCurve {
    /// The stroke and its placement.
    pub fn new(stroke: &Stroke, placed: &StrokeMatch) -> StrokeCurve {
        let mut depths: Vec<(f64, f64)> = placed
            .points
            .iter()
            .filter(|p| p.source != PointSource::Completion)
            .filter_map(|p| p.pixel.map(|px| (px[0], p.depth)))
            .filter(|(x, d)| x.is_finite() && d.is_finite() && *d > 0.0)
            .collect();
        depths.sort_by(|a, b| a.0.total_cmp(&b.0));
        StrokeCurve {
            id: stroke.id.clone(),
            source_id: stroke.source_id.clone(),
            stroke: stroke.clone(),
            depths,
        }
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
