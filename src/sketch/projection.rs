//! What matching needs from the rest of the pipeline, as plain data and one
//! small trait.
//!
//! Matching strokes to terrain features (section 5.2 of Tassé et al.) needs
//! two things: the terrain features as seen from the view ([`ViewFeature`],
//! produced by the `features` module from the renderer's silhouettes and the
//! ridge network) and a way to go between world and pixel coordinates
//! ([`ViewProjection`], implemented by the `view` module's camera). Keeping
//! them as plain data and a trait lets the sketch module be built and tested
//! without the renderer: [`SimplePinhole`] is a flat-earth pinhole over an
//! analytic height function, used by the tests and the benchmark to generate
//! synthetic views.
//!
//! World coordinates are the *local frame* of the viewpoint: metres, x east,
//! y north, z up (the `view` module's frame, curvature already applied).
//! Pixels follow `DESIGN.md`: origin at the top-left corner, x right, y down.
//! Depth is always the Euclidean distance from the eye, in metres.

use std::sync::Arc;

/// The two kinds of terrain features a stroke can be matched to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FeatureKind {
    /// A visible silhouette curve of the view (front/back face boundary).
    Silhouette,
    /// A ridge line of the terrain (PPA + spanning forest), seen from the view.
    Ridge,
}

/// One point of a terrain feature as seen from a view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureSample {
    /// Projection in the view, pixels (x right, y down).
    pub pixel: [f64; 2],
    /// Distance from the eye, metres.
    pub depth: f64,
    /// Position in the local metric frame (x east, y north, z up), metres.
    pub world: [f64; 3],
}

/// A terrain feature as seen from one view.
///
/// Contract for producers (the `features` module):
/// - `samples` are ordered by non-decreasing `pixel[0]`: a feature whose
///   projection folds back in x must be split into x-monotone pieces (a
///   terrain silhouette is single-valued across the image). Samples that go
///   back in x are ignored by matching.
/// - `id` identifies the feature in the whole sketch: the same ridge seen
///   from two views carries the same id (it is then used by at most one
///   stroke of a multi-view sketch); silhouettes, which are view-dependent,
///   get ids unique across views.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewFeature {
    pub id: usize,
    pub kind: FeatureKind,
    pub samples: Vec<FeatureSample>,
}

impl ViewFeature {
    /// Builds a feature from world points by projecting them with `proj`;
    /// points behind the camera are dropped and the rest sorted by pixel x.
    ///
    /// ```
    /// use demsketch::sketch::{FeatureKind, SimplePinhole, ViewFeature};
    /// let cam = SimplePinhole::new([0.0, 0.0, 0.0], 0.0, 0.0, 60.0, 800, 600);
    /// let f = ViewFeature::from_world(7, FeatureKind::Ridge,
    ///     &[[100.0, 1000.0, 50.0], [-100.0, 1000.0, 50.0]], &cam);
    /// assert_eq!(f.samples.len(), 2);
    /// assert!(f.samples[0].pixel[0] < f.samples[1].pixel[0]);
    /// ```
    pub fn from_world(
        id: usize,
        kind: FeatureKind,
        points: &[[f64; 3]],
        proj: &dyn ViewProjection,
    ) -> ViewFeature {
        let mut samples: Vec<FeatureSample> = points
            .iter()
            .filter_map(|&w| {
                proj.project(w).map(|(pixel, depth)| FeatureSample {
                    pixel,
                    depth,
                    world: w,
                })
            })
            .collect();
        samples.sort_by(|a, b| a.pixel[0].total_cmp(&b.pixel[0]));
        ViewFeature { id, kind, samples }
    }

    /// The x interval covered by the feature's projection, if it has samples.
    pub fn x_range(&self) -> Option<(f64, f64)> {
        let first = self.samples.first()?;
        let last = self.samples.last()?;
        Some((first.pixel[0], last.pixel[0]))
    }
}

/// What matching needs from a camera: world <-> pixel, the eye, and the
/// terrain height (for the fallback embedding and feature completion).
///
/// The `view` module's camera implements it; [`SimplePinhole`] is a
/// stand-alone implementation for synthetic views.
pub trait ViewProjection: Sync {
    /// Pixel and depth (distance from the eye, m) of a world point, or `None`
    /// when it is behind the camera.
    fn project(&self, p: [f64; 3]) -> Option<([f64; 2], f64)>;
    /// The world point at distance `depth` from the eye along the pixel's ray.
    fn unproject(&self, pixel: [f64; 2], depth: f64) -> [f64; 3];
    /// The eye position in the local frame.
    fn eye(&self) -> [f64; 3];
    /// Image width and height in pixels.
    fn image_size(&self) -> (u32, u32);
    /// Focal length in pixels (distance from the eye to the image plane);
    /// the principal point is the image centre.
    fn focal_px(&self) -> f64;
    /// Terrain height at a local-frame position, `None` outside the DEM or
    /// on nodata.
    fn terrain_height(&self, x: f64, y: f64) -> Option<f64>;
}

/// A height function for [`SimplePinhole`].
pub type HeightFn = Arc<dyn Fn(f64, f64) -> Option<f64> + Send + Sync>;

/// A flat-earth pinhole camera over an analytic terrain, following the
/// conventions of `DESIGN.md` (heading clockwise from north = +y, pitch up
/// positive, roll clockwise positive, hfov across the width, principal point
/// at the centre). Used for synthetic views in tests and benchmarks.
#[derive(Clone)]
pub struct SimplePinhole {
    eye: [f64; 3],
    forward: [f64; 3],
    right: [f64; 3],
    up: [f64; 3],
    focal: f64,
    width: u32,
    height: u32,
    terrain: Option<HeightFn>,
}

impl std::fmt::Debug for SimplePinhole {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimplePinhole")
            .field("eye", &self.eye)
            .field("forward", &self.forward)
            .field("focal", &self.focal)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish()
    }
}

impl SimplePinhole {
    /// A camera at `eye` with the given heading and pitch (degrees), no roll.
    pub fn new(
        eye: [f64; 3],
        heading_deg: f64,
        pitch_deg: f64,
        hfov_deg: f64,
        width: u32,
        height: u32,
    ) -> SimplePinhole {
        Self::with_roll(eye, heading_deg, pitch_deg, 0.0, hfov_deg, width, height)
    }

    /// A camera with roll (degrees, clockwise positive).
    pub fn with_roll(
        eye: [f64; 3],
        heading_deg: f64,
        pitch_deg: f64,
        roll_deg: f64,
        hfov_deg: f64,
        width: u32,
        height: u32,
    ) -> SimplePinhole {
        let (h, p, r) = (
            heading_deg.to_radians(),
            pitch_deg.to_radians(),
            roll_deg.to_radians(),
        );
        let forward = [h.sin() * p.cos(), h.cos() * p.cos(), p.sin()];
        let right0 = [h.cos(), -h.sin(), 0.0];
        let up0 = cross(right0, forward);
        // Rolling the camera clockwise turns the image content anticlockwise.
        let right = add(scale(right0, r.cos()), scale(up0, -r.sin()));
        let up = add(scale(up0, r.cos()), scale(right0, r.sin()));
        let focal = (width as f64 / 2.0) / (hfov_deg.to_radians() / 2.0).tan();
        SimplePinhole {
            eye,
            forward,
            right,
            up,
            focal,
            width,
            height,
            terrain: None,
        }
    }

    /// Attaches a terrain height function.
    pub fn with_terrain(mut self, terrain: HeightFn) -> SimplePinhole {
        self.terrain = Some(terrain);
        self
    }
}

impl ViewProjection for SimplePinhole {
    fn project(&self, p: [f64; 3]) -> Option<([f64; 2], f64)> {
        let d = sub(p, self.eye);
        let zc = dot(d, self.forward);
        if zc <= 1e-9 {
            return None;
        }
        let u = self.width as f64 / 2.0 + self.focal * dot(d, self.right) / zc;
        let v = self.height as f64 / 2.0 - self.focal * dot(d, self.up) / zc;
        Some(([u, v], norm(d)))
    }

    fn unproject(&self, pixel: [f64; 2], depth: f64) -> [f64; 3] {
        let a = (pixel[0] - self.width as f64 / 2.0) / self.focal;
        let b = (pixel[1] - self.height as f64 / 2.0) / self.focal;
        let dir = add(self.forward, add(scale(self.right, a), scale(self.up, -b)));
        let n = norm(dir);
        add(self.eye, scale(dir, depth / n))
    }

    fn eye(&self) -> [f64; 3] {
        self.eye
    }

    fn image_size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn focal_px(&self) -> f64 {
        self.focal
    }

    fn terrain_height(&self, x: f64, y: f64) -> Option<f64> {
        self.terrain.as_ref().and_then(|t| t(x, y))
    }
}

// Small vector helpers shared by the sketch submodules.

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
pub(crate) fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
pub(crate) fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
pub(crate) use crate::view::{cross, dot};
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
pub(crate) fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    norm(sub(a, b))
}
pub(crate) fn lerp3(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    add(a, scale(sub(b, a), t))
}
pub(crate) fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}
