//! The bridge from a real rendered view to matching: builds the
//! [`ViewFeature`]s and the [`ViewProjection`] that
//! [`match_sketch`](super::match_sketch) / [`match_view`](super::match_view)
//! need from a [`Scene`] (georeference, local frame, local
//! terrain), a [`Camera`], the [`Silhouettes`] extracted from the view's
//! depth buffer and the [`RidgeNetwork`] of the DEM window, and converts
//! placed points back to the DEM's CRS for the deformation step.
//!
//! # Frames and units
//!
//! - **World frame** (what matching works in, the `world` of
//!   [`FeatureSample`] and [`PlacedPoint`]): a [`LocalFrame`]: metres, x
//!   east, y north (WGS84 tangent plane at its eye), z up *apparent* height
//!   relative to its eye, i.e. `z = h - eye_alt - (1 - k) d^2 / (2 R)` with
//!   `d` the horizontal distance from its eye. For a single view it is the
//!   view's own local frame (the eye is the origin, lines of sight are
//!   straight, projection is plain pinhole geometry). The views of a
//!   multi-view sketch must share one world frame (take the first view's
//!   [`Scene::frame`] and build every view with
//!   [`SceneView::in_world_frame`]): each view's projection then goes from
//!   the world frame to its own local frame through the DEM CRS (exact), so
//!   that a feature of one view can be projected into another. Distances
//!   from another view's eye measured in the world frame differ from true
//!   ones only by the difference of the two frames' curvature drops (about
//!   `(1 - k) s d / R`, under a metre for views `s` = 3 km apart looking
//!   `d` = 10 km away); `project` returns true distances.
//! - **DEM CRS** (what deformation works in): `[x, y, z]` with `x, y` in the
//!   DEM's CRS units (metres for projected CRSs, degrees for geographic
//!   ones) and `z` the absolute height in the DEM's vertical datum, metres.
//!   [`SceneProjection::local_to_dem`] and [`SceneProjection::dem_to_local`]
//!   convert between the two (exact inverses of each other; the horizontal
//!   map is the frame's affine tangent-plane map, see [`LocalFrame`]).
//! - **Pixels**: `DESIGN.md`'s convention, origin at the top-left corner, x
//!   right, y down; depth is the Euclidean distance from the eye in metres.
//!
//! # Feature ids
//!
//! Ids are stable (the same inputs give the same ids) and say where a
//! feature comes from ([`FeatureSource::of_id`] decodes them):
//!
//! - a ridge: `id = RidgeLine::id` (below [`SILHOUETTE_ID_BASE`]). The ridge
//!   network belongs to the terrain, not to a view, so the same ridge line
//!   seen from two views has the same id and is used by at most one stroke
//!   of a multi-view sketch. A ridge line whose projection folds back in x
//!   (or passes behind the camera) is split into x-monotone pieces; the
//!   pieces share the line's id, so one ridge line serves at most one
//!   stroke.
//! - a silhouette: `id = SILHOUETTE_ID_BASE + view_index * 2^32 +
//!   Silhouette::id`. Silhouettes depend on the view, so their ids are
//!   unique across the views of a sketch (`view_index` is the view's index
//!   in the sketch file).
//! - the skyline of a view as one feature
//!   ([`skyline_feature`](super::skyline::skyline_feature)): the
//!   silhouette id of curve [`SKYLINE_CURVE`](super::skyline::SKYLINE_CURVE).

use super::multi_view::ViewInput;
use super::placement::PlacedPoint;
use super::projection::{FeatureKind, FeatureSample, ViewFeature, ViewProjection};
use super::stroke::Stroke;
use crate::features::{RidgeNetwork, Silhouettes};
use crate::render::{LocalTerrain, Scene};
use crate::view::{Camera, CameraModel, LocalFrame};

/// Silhouette ids start here; ridge ids (ridge line ids, `u32`) lie below.
pub const SILHOUETTE_ID_BASE: usize = 1 << 40;

/// Points nearer than this along the camera axis (metres) are treated as
/// behind the camera when projecting ridges (their projection is unstable).
const MIN_CAMERA_DEPTH_M: f64 = 1.0;

/// Where a feature id comes from (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FeatureSource {
    /// Ridge line `line` of the ridge network.
    Ridge { line: u32 },
    /// Silhouette curve `curve` of view `view`.
    Silhouette { view: usize, curve: u32 },
}

impl FeatureSource {
    /// The feature id of this source.
    pub fn id(self) -> usize {
        match self {
            FeatureSource::Ridge { line } => line as usize,
            FeatureSource::Silhouette { view, curve } => {
                SILHOUETTE_ID_BASE + (view << 32) + curve as usize
            }
        }
    }

    /// Decodes a feature id built by this module.
    pub fn of_id(id: usize) -> FeatureSource {
        if id < SILHOUETTE_ID_BASE {
            FeatureSource::Ridge { line: id as u32 }
        } else {
            let rest = id - SILHOUETTE_ID_BASE;
            FeatureSource::Silhouette {
                view: rest >> 32,
                curve: (rest & 0xffff_ffff) as u32,
            }
        }
    }
}

/// [`ViewProjection`] of a real view: the pinhole [`Camera`] in the
/// viewpoint's [`LocalFrame`] (eye at its origin) over the exact
/// triangulated [`LocalTerrain`] it was rendered from, seen from a world
/// frame (the view's own frame, or one shared by the views of a sketch; see
/// the module documentation).
#[derive(Debug, Clone, Copy)]
pub struct SceneProjection<'a> {
    pub camera: Camera,
    pub terrain: &'a LocalTerrain,
    /// The world frame when it is not the view's own frame.
    world: Option<LocalFrame>,
}

impl<'a> SceneProjection<'a> {
    /// The projection of `camera` over `terrain` in the view's own frame
    /// (the terrain carries it).
    pub fn new(camera: Camera, terrain: &'a LocalTerrain) -> Self {
        SceneProjection {
            camera,
            terrain,
            world: None,
        }
    }

    /// The same projection with `world` as the world frame (for multi-view
    /// sketches: the frame all views share).
    pub fn in_world_frame(mut self, world: LocalFrame) -> Self {
        self.world = (world != self.terrain.frame).then_some(world);
        self
    }

    /// The view's own local frame (eye at the origin).
    pub fn own_frame(&self) -> &LocalFrame {
        &self.terrain.frame
    }

    /// The world frame matching works in.
    pub fn world_frame(&self) -> &LocalFrame {
        self.world.as_ref().unwrap_or(&self.terrain.frame)
    }

    /// World-frame point of a point of the view's own frame.
    #[inline]
    pub fn own_to_world(&self, p: [f64; 3]) -> [f64; 3] {
        match &self.world {
            None => p,
            Some(w) => {
                let (x, y, h) = self.terrain.frame.local_to_crs(p);
                w.crs_to_local(x, y, h)
            }
        }
    }

    /// Own-frame point of a world-frame point.
    #[inline]
    pub fn world_to_own(&self, p: [f64; 3]) -> [f64; 3] {
        match &self.world {
            None => p,
            Some(w) => {
                let (x, y, h) = w.local_to_crs(p);
                self.terrain.frame.crs_to_local(x, y, h)
            }
        }
    }

    /// DEM CRS point `[x, y, z]` (CRS units, absolute height in metres) of
    /// a world-frame point (metres, apparent height).
    pub fn local_to_dem(&self, p: [f64; 3]) -> [f64; 3] {
        let (x, y, z) = self.world_frame().local_to_crs(p);
        [x, y, z]
    }

    /// World-frame point of a DEM CRS point `[x, y, z]`.
    pub fn dem_to_local(&self, p: [f64; 3]) -> [f64; 3] {
        self.world_frame().crs_to_local(p[0], p[1], p[2])
    }

    /// The DEM CRS points of placed stroke points (for the deformation
    /// step), in the same order.
    pub fn placed_to_dem(&self, points: &[PlacedPoint]) -> Vec<[f64; 3]> {
        points.iter().map(|p| self.local_to_dem(p.world)).collect()
    }

    /// Pixel and distance of a point of the view's own frame.
    #[inline]
    fn project_own(&self, p: [f64; 3]) -> Option<([f64; 2], f64)> {
        let px = self.camera.project(p)?;
        Some((px, (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()))
    }
}

impl ViewProjection for SceneProjection<'_> {
    fn project(&self, p: [f64; 3]) -> Option<([f64; 2], f64)> {
        self.project_own(self.world_to_own(p))
    }

    fn unproject(&self, pixel: [f64; 2], depth: f64) -> [f64; 3] {
        let d = self.camera.unproject(pixel);
        self.own_to_world([d[0] * depth, d[1] * depth, d[2] * depth])
    }

    fn eye(&self) -> [f64; 3] {
        self.own_to_world([0.0, 0.0, 0.0])
    }

    fn image_size(&self) -> (u32, u32) {
        (self.camera.width as u32, self.camera.height as u32)
    }

    fn focal_px(&self) -> f64 {
        self.camera.focal_px
    }

    /// Apparent height (world frame) of the triangulated surface at world
    /// `(east, north)`: exactly the planar triangles the renderer casts
    /// rays against. `None` outside the terrain or on a hole.
    fn terrain_height(&self, x: f64, y: f64) -> Option<f64> {
        match &self.world {
            None => terrain_height_local(self.terrain, x, y),
            Some(w) => {
                let own = &self.terrain.frame;
                let (cx, cy) = w.en_to_crs(x, y);
                let (e, n) = own.crs_to_en(cx, cy);
                let z = terrain_height_local(self.terrain, e, n)?;
                let h = z + own.eye_alt + own.curvature.drop(e.hypot(n));
                Some(h - w.eye_alt - w.curvature.drop(x.hypot(y)))
            }
        }
    }
}

/// Apparent height of the triangulated surface of `t` at local
/// `(east, north)` (see [`LocalTerrain`] for the triangulation).
pub fn terrain_height_local(t: &LocalTerrain, e: f64, n: f64) -> Option<f64> {
    let (vx, vy) = t.en_to_v(e, n);
    if !(vx >= 0.0 && vy >= 0.0) {
        return None;
    }
    let (c, r) = (vx.floor() as usize, vy.floor() as usize);
    // The last row / column of vertices: stay on the last cell.
    let c = c.min(t.nx.saturating_sub(2));
    let r = r.min(t.ny.saturating_sub(2));
    let (fx, fy) = (vx - c as f64, vy - r as f64);
    if fx > 1.0 + 1e-9 || fy > 1.0 + 1e-9 {
        return None;
    }
    let z00 = t.vertex_z(c, r)?;
    let z11 = t.vertex_z(c + 1, r + 1)?;
    if fx >= fy {
        let z10 = t.vertex_z(c + 1, r)?;
        Some(z00 + fx * (z10 - z00) + fy * (z11 - z10))
    } else {
        let z01 = t.vertex_z(c, r + 1)?;
        Some(z00 + fy * (z01 - z00) + fx * (z11 - z01))
    }
}

/// Options of feature construction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewFeatureOptions {
    /// Include the silhouettes of the view.
    pub silhouettes: bool,
    /// Include the ridge lines.
    pub ridges: bool,
    /// Ridge pieces whose projection spans fewer pixels in x are dropped.
    pub min_ridge_span_px: f64,
    /// Ridge pieces entirely farther than this many pixels left or right of
    /// the image are dropped (they cannot cover a stroke).
    pub image_margin_px: f64,
    /// Feature samples nearer to the eye than this (metres) are dropped,
    /// the feature cut into pieces there: the edit holds the observer's
    /// ground, so a stroke placed on a feature within it could never be
    /// fitted (issue 11, item 1). 0 keeps every sample.
    pub min_depth_m: f64,
    /// Include each view's skyline as one feature
    /// ([`skyline_feature`](super::skyline::skyline_feature)).
    pub skyline: bool,
}

impl Default for ViewFeatureOptions {
    fn default() -> Self {
        ViewFeatureOptions {
            silhouettes: true,
            ridges: true,
            min_ridge_span_px: 2.0,
            image_margin_px: 0.0,
            min_depth_m: 0.0,
            skyline: true,
        }
    }
}

/// `features` with the samples nearer than `min_depth_m` removed: each
/// feature is cut where its samples come nearer, and the pieces of at
/// least two samples keep the feature's id and kind (like the x-monotone
/// pieces of a ridge line).
pub fn without_near_samples(features: Vec<ViewFeature>, min_depth_m: f64) -> Vec<ViewFeature> {
    if !(min_depth_m > 0.0) {
        return features;
    }
    let mut out = Vec::with_capacity(features.len());
    for f in features {
        if f.samples.iter().all(|s| s.depth >= min_depth_m) {
            out.push(f);
            continue;
        }
        for piece in f.samples.split(|s| s.depth < min_depth_m) {
            if piece.len() >= 2 {
                out.push(ViewFeature {
                    id: f.id,
                    kind: f.kind,
                    samples: piece.to_vec(),
                });
            }
        }
    }
    out
}

/// The silhouettes of view `view_index` as features (ids in the module
/// documentation). Samples are the extractor's: pixel, depth (distance
/// from the eye, m) and the terrain point forming the silhouette, taken to
/// the world frame of `proj`; samples that go back in x are skipped.
pub fn silhouette_features(
    view_index: usize,
    sil: &Silhouettes,
    proj: &SceneProjection,
) -> Vec<ViewFeature> {
    sil.curves
        .iter()
        .filter_map(|c| {
            let mut samples: Vec<FeatureSample> = Vec::with_capacity(c.samples.len());
            for s in &c.samples {
                if !(s.pixel[0].is_finite() && s.pixel[1].is_finite() && s.depth.is_finite()) {
                    continue;
                }
                if samples.last().is_some_and(|l| s.pixel[0] < l.pixel[0]) {
                    continue;
                }
                samples.push(FeatureSample {
                    pixel: s.pixel,
                    depth: s.depth,
                    world: proj.own_to_world(s.local),
                });
            }
            (samples.len() >= 2).then(|| ViewFeature {
                id: FeatureSource::Silhouette {
                    view: view_index,
                    curve: c.id,
                }
                .id(),
                kind: FeatureKind::Silhouette,
                samples,
            })
        })
        .collect()
}

/// The ridge lines of `ridges` (DEM CRS, absolute heights) as features of
/// the view of `proj`: each vertex is taken to the view's frame and
/// projected (its `world` point is in the world frame); the line is cut where it passes behind the camera and where
/// its projection turns back in x, giving x-monotone pieces (ordered by
/// increasing x) that all carry the line's id. Hidden ridges are kept: the
/// paper projects all terrain features, deformation can bring them into
/// view.
pub fn ridge_features(
    ridges: &RidgeNetwork,
    proj: &SceneProjection,
    opts: &ViewFeatureOptions,
) -> Vec<ViewFeature> {
    let w = proj.camera.width as f64;
    let mut out = Vec::new();
    for line in &ridges.lines {
        let id = FeatureSource::Ridge { line: line.id }.id();
        let mut piece: Vec<FeatureSample> = Vec::new();
        let mut dir = 0.0_f64; // sign of the piece's x direction, 0 = unknown
        let mut flush = |piece: &mut Vec<FeatureSample>, dir: f64| {
            let mut p = std::mem::take(piece);
            if p.len() < 2 {
                return;
            }
            if dir < 0.0 {
                p.reverse();
            }
            let (x0, x1) = (p[0].pixel[0], p[p.len() - 1].pixel[0]);
            if x1 - x0 < opts.min_ridge_span_px
                || x1 < -opts.image_margin_px
                || x0 > w + opts.image_margin_px
            {
                return;
            }
            out.push(ViewFeature {
                id,
                kind: FeatureKind::Ridge,
                samples: p,
            });
        };
        for q in ridges.line_points(line) {
            let own = proj.own_frame().crs_to_local(q[0], q[1], q[2]);
            let cam_z = own[0] * proj.camera.forward[0]
                + own[1] * proj.camera.forward[1]
                + own[2] * proj.camera.forward[2];
            let s = if cam_z >= MIN_CAMERA_DEPTH_M {
                proj.project_own(own).map(|(pixel, depth)| FeatureSample {
                    pixel,
                    depth,
                    world: proj.dem_to_local(*q),
                })
            } else {
                None
            };
            let Some(s) = s else {
                flush(&mut piece, dir);
                dir = 0.0;
                continue;
            };
            if let Some(last) = piece.last().copied() {
                let dx = s.pixel[0] - last.pixel[0];
                if dx != 0.0 {
                    let d = dx.signum();
                    if dir == 0.0 {
                        dir = d;
                    } else if d != dir {
                        // Turns back in x: the turning point ends this piece
                        // and starts the next.
                        flush(&mut piece, dir);
                        piece.push(last);
                        dir = d;
                    }
                }
            }
            piece.push(s);
        }
        flush(&mut piece, dir);
    }
    out
}

/// A real view ready for matching: its projection and its features.
pub struct SceneView<'a> {
    /// The view's name (the sketch file's `views[].name`).
    pub name: String,
    pub projection: SceneProjection<'a>,
    pub features: Vec<ViewFeature>,
}

impl<'a> SceneView<'a> {
    /// Builds the view `view_index` of a sketch in its own frame: `camera`
    /// over the scene's terrain, with the silhouettes extracted from its
    /// depth buffer and the ridges of the scene's DEM window.
    pub fn new(
        name: &str,
        view_index: usize,
        scene: &'a Scene,
        camera: Camera,
        silhouettes: &Silhouettes,
        ridges: &RidgeNetwork,
        opts: &ViewFeatureOptions,
    ) -> SceneView<'a> {
        Self::build(
            name,
            view_index,
            SceneProjection::new(camera, &scene.terrain),
            silhouettes,
            ridges,
            opts,
        )
    }

    /// As [`SceneView::new`] with a world frame shared by all views of a
    /// multi-view sketch (e.g. the first view's [`Scene::frame`]).
    #[allow(clippy::too_many_arguments)]
    pub fn in_world_frame(
        name: &str,
        view_index: usize,
        scene: &'a Scene,
        camera: Camera,
        silhouettes: &Silhouettes,
        ridges: &RidgeNetwork,
        opts: &ViewFeatureOptions,
        world: LocalFrame,
    ) -> SceneView<'a> {
        Self::build(
            name,
            view_index,
            SceneProjection::new(camera, &scene.terrain).in_world_frame(world),
            silhouettes,
            ridges,
            opts,
        )
    }

    /// Builds a view from its projection (any terrain, any world frame).
    pub fn build(
        name: &str,
        view_index: usize,
        projection: SceneProjection<'a>,
        silhouettes: &Silhouettes,
        ridges: &RidgeNetwork,
        opts: &ViewFeatureOptions,
    ) -> SceneView<'a> {
        let mut features = Vec::new();
        if opts.silhouettes {
            features.extend(silhouette_features(view_index, silhouettes, &projection));
            if opts.skyline {
                features.extend(super::skyline::skyline_feature(
                    view_index,
                    silhouettes,
                    &projection,
                    opts.min_depth_m,
                ));
            }
        }
        if opts.ridges {
            features.extend(ridge_features(ridges, &projection, opts));
        }
        let features = without_near_samples(features, opts.min_depth_m);
        SceneView {
            name: name.to_string(),
            projection,
            features,
        }
    }

    /// The [`ViewInput`] of this view with the given prepared strokes.
    pub fn input(&self, strokes: Vec<Stroke>) -> ViewInput<'_> {
        ViewInput {
            name: self.name.clone(),
            strokes,
            features: &self.features,
            projection: &self.projection,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn feature_ids_round_trip() {
        for s in [
            FeatureSource::Ridge { line: 0 },
            FeatureSource::Ridge { line: u32::MAX },
            FeatureSource::Silhouette { view: 0, curve: 0 },
            FeatureSource::Silhouette {
                view: 3,
                curve: 12345,
            },
        ] {
            assert_eq!(FeatureSource::of_id(s.id()), s);
        }
    }
}
