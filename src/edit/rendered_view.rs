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

    /// Render an already built terrain.
    pub fn from_terrain(
        terrain: LocalTerrain,
        camera: &Camera,
    ) -> Result<RenderedView, FeatureError> {
        let depth = DepthBuffer::render(&terrain, camera);
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
            camera: *camera,
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
