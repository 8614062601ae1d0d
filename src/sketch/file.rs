//! The sketch file: what `edit` and `view` read (format in `DESIGN.md`).
//!
//! A sketch file holds one or more views (a viewpoint, a camera and the
//! strokes drawn over that view) and options for matching and deformation.
//! Several views make a multi-view sketch, matched jointly. An optional
//! `map_features` member (older name: `corrections`) holds map-view corrections (a GeoJSON
//! FeatureCollection) applied in the same edit. This module only
//! parses and validates: every problem becomes a [`SketchError`] value whose
//! one-line message names the file, the view, the stroke and the problem.
//!
//! ```
//! use demsketch::sketch::{SketchError, SketchFile};
//! # fn main() -> Result<(), SketchError> {
//! let text = r#"{"views": [{"name": "rim",
//!   "viewpoint": {"lon": 6.5, "lat": 45.9},
//!   "camera": {"heading_deg": 180.0, "hfov_deg": 50.0, "width": 800, "height": 600},
//!   "strokes": [{"id": "dome", "points": [[10.0, 300.0], [200.0, 250.5]]}]}]}"#;
//! let sketch = SketchFile::from_json_str(text, "demo.json")?;
//! assert_eq!(sketch.views[0].strokes[0].id, "dome");
//! assert_eq!(sketch.options.weights.dissimilarity, 1.0);
//!
//! let bad = text.replace("200.0, 250.5", "900.0, 250.5");
//! let err = SketchFile::from_json_str(&bad, "demo.json").unwrap_err();
//! assert!(err.to_string().starts_with("demo.json: view \"rim\" stroke \"dome\" point 2"));
//! # Ok(())
//! # }
//! ```

use crate::num::Num;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::Path;

/// Errors of reading and validating a sketch file (one line each).
#[derive(Debug, thiserror::Error)]
pub enum SketchError {
    #[error("{path}: cannot read sketch file: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a valid sketch file (line {line}, column {column}): {message}")]
    Json {
        path: String,
        line: usize,
        column: usize,
        message: String,
    },
    #[error("{path}: {location}: {problem}")]
    Invalid {
        path: String,
        location: String,
        problem: String,
    },
}

/// A whole sketch file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SketchFile {
    pub views: Vec<ViewSpec>,
    #[serde(default)]
    pub options: SketchOptions,
    /// Map-view corrections applied in the same edit: a GeoJSON
    /// FeatureCollection as `demsketch correct --features` reads it (lakes,
    /// rivers, control curves, breaklines; see `demsketch::correct`).
    /// Checked against the DEM when the edit loads it.
    /// Read from `map_features` (the name in the sketch format) or, as
    /// written by demsketch before 2026-12-02, `corrections`.
    #[serde(
        default,
        rename = "map_features",
        alias = "corrections",
        skip_serializing_if = "Option::is_none"
    )]
    pub corrections: Option<serde_json::Value>,
    /// The views as the file gives them, when [`SketchFile::split_map_feature_strokes`]
    /// took the strokes the landforms and noise regions of `map_features`
    /// name out of `views` (they are placed by those features, not matched
    /// as first-person strokes). Not part of the file.
    #[serde(skip)]
    pub map_feature_views: Option<Vec<ViewSpec>>,
}

impl SketchFile {
    /// Takes the strokes that the `landform` and `noise_region` features of
    /// `map_features` name (`silhouette`, `noise_stroke`: `{"view",
    /// "stroke"}`) out of `views`, keeping the views as given in
    /// [`SketchFile::map_feature_views`]: those strokes are drawn for the
    /// map-view features, which place them themselves, and are not matched
    /// as first-person strokes of the edit. Nothing changes when no such
    /// feature names a stroke.
    pub fn split_map_feature_strokes(&mut self) {
        let Some(fc) = &self.corrections else { return };
        let mut named: HashSet<(String, String)> = HashSet::new();
        for f in fc
            .get("features")
            .and_then(|f| f.as_array())
            .into_iter()
            .flatten()
        {
            let Some(p) = f.get("properties").and_then(|p| p.as_object()) else {
                continue;
            };
            let key = match p.get("kind").and_then(|k| k.as_str()) {
                Some("landform") => "silhouette",
                Some("noise_region") => "noise_stroke",
                _ => continue,
            };
            let r = p.get(key);
            let field = |k: &str| r.and_then(|r| r.get(k)).and_then(|v| v.as_str());
            if let (Some(v), Some(s)) = (field("view"), field("stroke")) {
                named.insert((v.to_string(), s.to_string()));
            }
        }
        if named.is_empty() {
            return;
        }
        self.map_feature_views = Some(self.views.clone());
        for v in &mut self.views {
            let name = v.name.clone();
            v.strokes
                .retain(|s| !named.contains(&(name.clone(), s.id.clone())));
        }
    }
}

/// One view of a sketch: where the eye is, the camera, the strokes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewSpec {
    pub name: String,
    pub viewpoint: ViewpointSpec,
    pub camera: CameraSpec,
    #[serde(default)]
    pub strokes: Vec<StrokeSpec>,
}

/// Viewpoint: lon/lat in degrees WGS84 and either a height above the DEM
/// surface (`eye_height_m`, default 1.7) or an absolute altitude (`alt_m`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewpointSpec {
    pub lon: f64,
    pub lat: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eye_height_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alt_m: Option<f64>,
}

/// How high the eye is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EyeHeightSpec {
    /// Metres above the DEM surface at the viewpoint.
    AboveSurface(f64),
    /// Absolute altitude in the DEM's vertical datum.
    Absolute(f64),
}

impl ViewpointSpec {
    /// The eye height, resolving the default (1.7 m above the surface).
    pub fn height(&self) -> EyeHeightSpec {
        match (self.alt_m, self.eye_height_m) {
            (Some(a), _) => EyeHeightSpec::Absolute(a),
            (None, Some(h)) => EyeHeightSpec::AboveSurface(h),
            (None, None) => EyeHeightSpec::AboveSurface(1.7),
        }
    }
}

/// Camera of a view (defaults as the command line's camera flags).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    #[serde(default)]
    pub heading_deg: f64,
    #[serde(default)]
    pub pitch_deg: f64,
    #[serde(default)]
    pub roll_deg: f64,
    #[serde(default = "default_hfov")]
    pub hfov_deg: f64,
    #[serde(default = "default_width")]
    pub width: u32,
    #[serde(default = "default_height")]
    pub height: u32,
}

impl Default for CameraSpec {
    /// The defaults of a sketch's camera, and of the command line's camera
    /// flags: heading, pitch and roll 0, 60 degrees across, 1600 x 900.
    fn default() -> Self {
        CameraSpec {
            heading_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            hfov_deg: default_hfov(),
            width: default_width(),
            height: default_height(),
        }
    }
}

fn default_hfov() -> f64 {
    60.0
}
fn default_width() -> u32 {
    1600
}
fn default_height() -> u32 {
    900
}

/// One stroke: an id unique within its view and a polyline in pixels,
/// optionally with the distance from the eye the author means (`depth_m`),
/// for a landform drawn where nothing in the image says how far it is.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StrokeSpec {
    pub id: String,
    pub points: Vec<[f64; 2]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_m: Option<DepthSpec>,
}

/// A stroke's depth: one distance from the eye, or a `[near, far]` range,
/// metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum DepthSpec {
    Distance(f64),
    Range([f64; 2]),
}

impl DepthSpec {
    /// `[near, far]` (equal for a single distance).
    pub fn range(self) -> [f64; 2] {
        match self {
            DepthSpec::Distance(d) => [d, d],
            DepthSpec::Range(r) => r,
        }
    }
}

/// Largest `eye_height_m` accepted, metres (higher eyes: give `alt_m`).
pub const MAX_EYE_HEIGHT_M: f64 = 10_000.0;
/// Largest `influence_m` accepted, metres: the default `--max-distance`
/// (the edit never reads farther from a viewpoint than that by default).
pub const MAX_INFLUENCE_M: f64 = 50_000.0;
/// Largest `observer_radius_m` accepted, metres.
pub const MAX_OBSERVER_RADIUS_M: f64 = 10_000.0;
/// Lowest `alt_m` accepted, metres: below the deepest point of the Earth's
/// surface (-10,935 m).
pub const MIN_ALT_M: f64 = -11_000.0;
/// Highest `alt_m` accepted, metres: above the highest ground (8,849 m)
/// plus the highest eye height ([`MAX_EYE_HEIGHT_M`]).
pub const MAX_ALT_M: f64 = 20_000.0;
/// Largest image side (`width`, `height`) accepted, pixels: what the
/// camera model takes ([`crate::view::Camera::new`]).
pub const MAX_IMAGE_SIDE_PX: u32 = 65_535;
/// Largest `depth_m` accepted, metres: no terrain seen from an eye at most
/// [`MAX_ALT_M`] high lies farther (the eye's horizon, about 505 km, plus
/// the highest ground's, about 336 km).
pub const MAX_DEPTH_M: f64 = 1_000_000.0;
/// Largest cost weight accepted (the paper uses 1 for all; the weights
/// only matter relative to each other).
pub const MAX_WEIGHT: f64 = 1e6;
/// Finest `resample_px` accepted, pixels: strokes are drawn to a pixel, a
/// finer step adds samples, not shape.
pub const MIN_RESAMPLE_PX: f64 = 0.1;
/// Largest `fallback_depth_ratio` accepted.
pub const MAX_FALLBACK_DEPTH_RATIO: f64 = 100.0;
/// Longest priority list accepted (`max_candidates`; default 32): a list
/// holds at most one candidate per feature of the view, and the matching's
/// forward checking keeps, for every candidate it tries, a row of bits over
/// every candidate of the strokes behind (time and memory grow with the
/// square of the candidates in all lists: 100 strokes of 1,000 are rows of
/// 100,000 bits each), so a longer list only adds cost where it matters.
pub const MAX_CANDIDATES: usize = 1_000;
/// Largest `node_budget` accepted (default 20,000,
/// [`super::branch_and_bound::DEFAULT_NODE_BUDGET`]): 500 times the
/// default, far beyond what real sketches search, while a typo such as
/// 1e12 nodes would keep the search running for hours.
pub const MAX_NODE_BUDGET: u64 = 10_000_000;
/// Finest `completion_step_m` accepted, metres.
pub const MIN_COMPLETION_STEP_M: f64 = 0.1;
/// Largest `completion_step_m` and `completion_max_m` accepted, metres.
pub const MAX_COMPLETION_M: f64 = 100_000.0;

/// Weights w1..w4 of the four matching cost terms (section 5.2.1); the paper
/// uses 1 for all.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CostWeights {
    #[serde(default = "one")]
    pub dissimilarity: f64,
    #[serde(default = "one")]
    pub deformation: f64,
    #[serde(default = "one")]
    pub sampling: f64,
    #[serde(default = "one")]
    pub extension: f64,
}

fn one() -> f64 {
    1.0
}

impl Default for CostWeights {
    fn default() -> Self {
        CostWeights {
            dissimilarity: 1.0,
            deformation: 1.0,
            sampling: 1.0,
            extension: 1.0,
        }
    }
}

/// What to do with a stroke that folds back in x.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum FoldBackPolicy {
    /// Split it into x-monotone pieces, each matched as a stroke (reported).
    #[default]
    Split,
    /// Reject the sketch with a message.
    Reject,
}

/// Options of a sketch. Unknown keys are an error, as everywhere else in
/// the sketch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SketchOptions {
    /// Radius of influence of the deformation, metres (read by `deform`),
    /// in `(0, MAX_INFLUENCE_M]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub influence_m: Option<f64>,
    /// Radius around each viewpoint within which the ground is held at its
    /// input height, metres (the observer stands on it). `None`: 100 m, and
    /// at least two cells.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub observer_radius_m: Option<f64>,
    /// Weights of the matching cost terms.
    #[serde(default)]
    pub weights: CostWeights,
    /// Distance under which a stroke end touching another stroke is a
    /// T-junction, pixels.
    #[serde(default = "default_t_junction")]
    pub t_junction_px: f64,
    /// Stroke resampling step, pixels.
    #[serde(default = "default_resample")]
    pub resample_px: f64,
    /// Back-steps in x smaller than this are drawing jitter, pixels.
    #[serde(default = "default_fold_tolerance")]
    pub fold_back_tolerance_px: f64,
    /// Policy for strokes that fold back in x.
    #[serde(default)]
    pub fold_back: FoldBackPolicy,
    /// A feature is a candidate for a stroke when its projection covers at
    /// least this fraction of the stroke's x extent (the rest is extended).
    #[serde(default = "default_min_coverage")]
    pub min_coverage: f64,
    /// Length of each stroke's priority list after sorting by cost.
    #[serde(default = "default_max_candidates")]
    pub max_candidates: usize,
    /// Most branch-and-bound search nodes of the matching; once spent, the
    /// best assignment found is kept and the report says the search stopped
    /// early.
    #[serde(default = "default_node_budget")]
    pub node_budget: u64,
    /// Fallback embedding without a neighbour on one side: depth ratio to the
    /// neighbour on the other side.
    #[serde(default = "default_fallback_ratio")]
    pub fallback_depth_ratio: f64,
    /// Extend matched features down to the terrain (section 5.3).
    #[serde(default = "default_true")]
    pub feature_completion: bool,
    /// Step of feature completion, metres.
    #[serde(default = "default_completion_step")]
    pub completion_step_m: f64,
    /// Longest completion at each end, metres.
    #[serde(default = "default_completion_max")]
    pub completion_max_m: f64,
}

fn default_t_junction() -> f64 {
    6.0
}
fn default_resample() -> f64 {
    2.0
}
fn default_fold_tolerance() -> f64 {
    3.0
}
fn default_min_coverage() -> f64 {
    0.5
}
fn default_max_candidates() -> usize {
    32
}
fn default_node_budget() -> u64 {
    super::branch_and_bound::DEFAULT_NODE_BUDGET
}
fn default_fallback_ratio() -> f64 {
    1.25
}
fn default_true() -> bool {
    true
}
fn default_completion_step() -> f64 {
    5.0
}
fn default_completion_max() -> f64 {
    3000.0
}

impl Default for SketchOptions {
    fn default() -> Self {
        SketchOptions {
            influence_m: None,
            observer_radius_m: None,
            weights: CostWeights::default(),
            t_junction_px: default_t_junction(),
            resample_px: default_resample(),
            fold_back_tolerance_px: default_fold_tolerance(),
            fold_back: FoldBackPolicy::Split,
            min_coverage: default_min_coverage(),
            max_candidates: default_max_candidates(),
            node_budget: default_node_budget(),
            fallback_depth_ratio: default_fallback_ratio(),
            feature_completion: true,
            completion_step_m: default_completion_step(),
            completion_max_m: default_completion_max(),
        }
    }
}

impl SketchFile {
    /// Reads, parses and validates a sketch file.
    pub fn from_path(path: &Path) -> Result<SketchFile, SketchError> {
        let label = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| SketchError::Io {
            path: label.clone(),
            source,
        })?;
        Self::from_json_str(&text, &label)
    }

    /// Parses and validates sketch JSON; `path` names it in messages.
    pub fn from_json_str(text: &str, path: &str) -> Result<SketchFile, SketchError> {
        let file: SketchFile = serde_json::from_str(text).map_err(|e| SketchError::Json {
            path: path.to_string(),
            line: e.line(),
            column: e.column(),
            message: strip_position(&e.to_string()),
        })?;
        file.validate(path)?;
        Ok(file)
    }

    /// Checks everything matching relies on; the first problem is returned.
    pub fn validate(&self, path: &str) -> Result<(), SketchError> {
        let err = |location: String, problem: String| SketchError::Invalid {
            path: path.to_string(),
            location,
            problem,
        };
        if self.views.is_empty() {
            return Err(err("views".into(), "the sketch has no views".into()));
        }
        validate_options(&self.options).map_err(|p| err("options".into(), p))?;
        if let Some(c) = &self.corrections {
            if c.get("type").and_then(|t| t.as_str()) != Some("FeatureCollection") {
                return Err(err(
                    "map_features".into(),
                    "must be a GeoJSON FeatureCollection".into(),
                ));
            }
        }
        let mut names = HashSet::new();
        for (vi, view) in self.views.iter().enumerate() {
            if view.name.trim().is_empty() {
                return Err(err(format!("view {}", vi + 1), "view name is empty".into()));
            }
            let vloc = format!("view \"{}\"", view.name);
            if !names.insert(view.name.as_str()) {
                return Err(err(vloc, "view name is used twice".into()));
            }
            let at = format!("views[{vi}]");
            validate_viewpoint(
                &view.viewpoint,
                ViewpointNames::Path(&format!("{at}.viewpoint")),
            )
            .map_err(|p| err(vloc.clone(), p))?;
            validate_camera(&view.camera, &format!("{at}.camera"))
                .map_err(|p| err(vloc.clone(), p))?;
            let (w, h) = (view.camera.width as f64, view.camera.height as f64);
            let mut ids = HashSet::new();
            for (si, stroke) in view.strokes.iter().enumerate() {
                if stroke.id.trim().is_empty() {
                    return Err(err(
                        format!("{vloc} stroke {}", si + 1),
                        "stroke id is empty".into(),
                    ));
                }
                let sloc = format!("{vloc} stroke \"{}\"", stroke.id);
                if !ids.insert(stroke.id.as_str()) {
                    return Err(err(sloc, "stroke id is used twice in this view".into()));
                }
                if stroke.points.len() < 2 {
                    return Err(err(
                        sloc,
                        format!("has {} point(s), needs at least 2", stroke.points.len()),
                    ));
                }
                for (pi, p) in stroke.points.iter().enumerate() {
                    let ploc = format!("{sloc} point {}", pi + 1);
                    if !p[0].is_finite() || !p[1].is_finite() {
                        return Err(err(ploc, "coordinates are not finite numbers".into()));
                    }
                    if p[0] < 0.0 || p[0] > w || p[1] < 0.0 || p[1] > h {
                        return Err(err(
                            ploc,
                            format!(
                                "({}, {}) lies outside the {}x{} image",
                                Num(p[0]),
                                Num(p[1]),
                                view.camera.width,
                                view.camera.height
                            ),
                        ));
                    }
                }
                if let Some(d) = stroke.depth_m {
                    let [near, far] = d.range();
                    let ok = |v: f64| v.is_finite() && v > 0.0 && v <= MAX_DEPTH_M;
                    if !(ok(near) && ok(far) && far >= near) {
                        return Err(err(
                            sloc,
                            format!(
                                "views[{vi}].strokes[{si}].depth_m {}..{} is not a distance in (0, {}] metres (or a [near, far] range of them with near <= far)",
                                Num(near),
                                Num(far),
                                Num(MAX_DEPTH_M)
                            ),
                        ));
                    }
                }
                let (x0, x1) = stroke
                    .points
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                        (a.min(p[0]), b.max(p[0]))
                    });
                if x1 - x0 <= 0.0 {
                    return Err(err(
                        sloc,
                        "spans no horizontal extent (a silhouette runs across the image)".into(),
                    ));
                }
            }
        }
        Ok(())
    }
}

fn strip_position(msg: &str) -> String {
    match msg.rfind(" at line ") {
        Some(i) => msg[..i].to_string(),
        None => msg.to_string(),
    }
}

impl ViewpointSpec {
    /// The sketch format's ranges (lon, lat, `eye_height_m`, `alt_m`; one
    /// of the last two): the problem, naming the field as `at.FIELD`.
    pub fn check_ranges(&self, at: &str) -> Result<(), String> {
        validate_viewpoint(self, ViewpointNames::Path(at))
    }

    /// The viewpoint, its eye height resolved ([`ViewpointSpec::height`]).
    pub fn resolved(&self) -> crate::view::Viewpoint {
        crate::view::Viewpoint {
            lon: self.lon,
            lat: self.lat,
            height: match self.height() {
                EyeHeightSpec::AboveSurface(h) => crate::view::EyeHeight::AboveSurface(h),
                EyeHeightSpec::Absolute(a) => crate::view::EyeHeight::Absolute(a),
            },
        }
    }

    /// The same ranges for a viewpoint given on the command line (`--lon`,
    /// `--lat`, `--eye-height`, `--alt`), named in its words: `viewpoint
    /// lon 200 is not in [-180, 180]`, `viewpoint eye height 0 is not in
    /// (0, 10000] metres above the ground (for a higher eye give --alt)`,
    /// `viewpoint altitude NaN is not in [-11000, 20000] metres`.
    pub fn check_flag_ranges(&self) -> Result<(), String> {
        validate_viewpoint(self, ViewpointNames::Flags)
    }
}

/// How a message names a viewpoint's fields.
#[derive(Debug, Clone, Copy)]
enum ViewpointNames<'a> {
    /// Their path in the sketch format: `at.lon`, `at.eye_height_m`.
    Path(&'a str),
    /// The command line's words: `viewpoint lon`, `viewpoint eye height`,
    /// `viewpoint altitude`.
    Flags,
}

impl ViewpointNames<'_> {
    /// The name of `field` (`lon`, `lat`, `eye_height_m`, `alt_m`).
    fn of(self, field: &str) -> String {
        match self {
            ViewpointNames::Path(at) => format!("{at}.{field}"),
            ViewpointNames::Flags => match field {
                "eye_height_m" => "viewpoint eye height".into(),
                "alt_m" => "viewpoint altitude".into(),
                f => format!("viewpoint {f}"),
            },
        }
    }

    /// How a higher eye than `eye_height_m` allows is given.
    fn alt(self) -> &'static str {
        match self {
            ViewpointNames::Path(_) => "alt_m",
            ViewpointNames::Flags => "--alt",
        }
    }
}

impl CameraSpec {
    /// The sketch format's ranges (heading, pitch, roll, field of view,
    /// image size): the problem, naming the field as `at.FIELD`.
    pub fn check_ranges(&self, at: &str) -> Result<(), String> {
        validate_camera(self, at)
    }
}

/// `{path} {v} is not in {range}{unit}` unless `ok(v)` (NaN and infinities
/// fail every range); `v` is printed compactly ([`Num`]).
fn check_range(path: &str, v: f64, ok: bool, range: &str, unit: &str) -> Result<(), String> {
    if v.is_finite() && ok {
        Ok(())
    } else {
        Err(format!("{path} {} is not in {range}{unit}", Num(v)))
    }
}

/// `v` within the closed range `[lo, hi]`, named `path`.
fn check_closed(path: &str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<(), String> {
    check_range(
        path,
        v,
        (lo..=hi).contains(&v),
        &format!("[{}, {}]", Num(lo), Num(hi)),
        unit,
    )
}

/// The viewpoint's ranges, the one rule for a sketch's viewpoint, the
/// browser app's and the command line's.
fn validate_viewpoint(v: &ViewpointSpec, names: ViewpointNames) -> Result<(), String> {
    check_closed(&names.of("lon"), v.lon, -180.0, 180.0, "")?;
    check_closed(&names.of("lat"), v.lat, -90.0, 90.0, "")?;
    if v.eye_height_m.is_some() && v.alt_m.is_some() {
        let at = match names {
            ViewpointNames::Path(at) => at,
            ViewpointNames::Flags => "viewpoint",
        };
        return Err(format!("{at} gives both eye_height_m and alt_m; give one"));
    }
    if let Some(h) = v.eye_height_m {
        check_range(
            &names.of("eye_height_m"),
            h,
            h > 0.0 && h <= MAX_EYE_HEIGHT_M,
            &format!("(0, {}]", Num(MAX_EYE_HEIGHT_M)),
            &format!(
                " metres above the ground (for a higher eye give {})",
                names.alt()
            ),
        )?;
    }
    if let Some(a) = v.alt_m {
        check_closed(&names.of("alt_m"), a, MIN_ALT_M, MAX_ALT_M, " metres")?;
    }
    Ok(())
}

fn validate_camera(c: &CameraSpec, at: &str) -> Result<(), String> {
    check_closed(
        &format!("{at}.heading_deg"),
        c.heading_deg,
        -360.0,
        360.0,
        " degrees",
    )?;
    check_closed(
        &format!("{at}.pitch_deg"),
        c.pitch_deg,
        -90.0,
        90.0,
        " degrees",
    )?;
    check_closed(
        &format!("{at}.roll_deg"),
        c.roll_deg,
        -180.0,
        180.0,
        " degrees",
    )?;
    check_range(
        &format!("{at}.hfov_deg"),
        c.hfov_deg,
        c.hfov_deg > 0.0 && c.hfov_deg < 180.0,
        "(0, 180)",
        " degrees",
    )?;
    for (name, n) in [("width", c.width), ("height", c.height)] {
        if !(1..=MAX_IMAGE_SIDE_PX).contains(&n) {
            return Err(format!(
                "{at}.{name} {n} is not in [1, {MAX_IMAGE_SIDE_PX}] pixels"
            ));
        }
    }
    Ok(())
}

fn validate_options(o: &SketchOptions) -> Result<(), String> {
    if let Some(r) = o.influence_m {
        check_range(
            "options.influence_m",
            r,
            r > 0.0 && r <= MAX_INFLUENCE_M,
            &format!("(0, {}]", Num(MAX_INFLUENCE_M)),
            " metres",
        )?;
    }
    if let Some(r) = o.observer_radius_m {
        check_closed(
            "options.observer_radius_m",
            r,
            0.0,
            MAX_OBSERVER_RADIUS_M,
            " metres",
        )?;
    }
    let w = &o.weights;
    for (name, v) in [
        ("dissimilarity", w.dissimilarity),
        ("deformation", w.deformation),
        ("sampling", w.sampling),
        ("extension", w.extension),
    ] {
        check_closed(&format!("options.weights.{name}"), v, 0.0, MAX_WEIGHT, "")?;
    }
    let side = MAX_IMAGE_SIDE_PX as f64;
    check_range(
        "options.t_junction_px",
        o.t_junction_px,
        o.t_junction_px > 0.0 && o.t_junction_px <= side,
        &format!("(0, {}]", Num(side)),
        " pixels",
    )?;
    check_closed(
        "options.resample_px",
        o.resample_px,
        MIN_RESAMPLE_PX,
        side,
        " pixels",
    )?;
    check_closed(
        "options.fold_back_tolerance_px",
        o.fold_back_tolerance_px,
        0.0,
        side,
        " pixels",
    )?;
    check_range(
        "options.min_coverage",
        o.min_coverage,
        o.min_coverage > 0.0 && o.min_coverage <= 1.0,
        "(0, 1]",
        "",
    )?;
    if !(1..=MAX_CANDIDATES).contains(&o.max_candidates) {
        return Err(format!(
            "options.max_candidates {} is not in [1, {MAX_CANDIDATES}]",
            o.max_candidates
        ));
    }
    if !(1..=MAX_NODE_BUDGET).contains(&o.node_budget) {
        return Err(format!(
            "options.node_budget {} is not in [1, {MAX_NODE_BUDGET}]",
            o.node_budget
        ));
    }
    check_range(
        "options.fallback_depth_ratio",
        o.fallback_depth_ratio,
        o.fallback_depth_ratio > 1.0 && o.fallback_depth_ratio <= MAX_FALLBACK_DEPTH_RATIO,
        &format!("(1, {}]", Num(MAX_FALLBACK_DEPTH_RATIO)),
        "",
    )?;
    check_closed(
        "options.completion_step_m",
        o.completion_step_m,
        MIN_COMPLETION_STEP_M,
        MAX_COMPLETION_M,
        " metres",
    )?;
    check_closed(
        "options.completion_max_m",
        o.completion_max_m,
        0.0,
        MAX_COMPLETION_M,
        " metres",
    )?;
    Ok(())
}

impl ViewSpec {
    /// The viewpoint of this view, its eye height resolved.
    pub fn eye(&self) -> crate::view::Viewpoint {
        self.viewpoint.resolved()
    }

    /// The camera of this view.
    pub fn pinhole(&self) -> Result<crate::view::Camera, crate::view::ViewError> {
        let c = &self.camera;
        crate::view::Camera::new(
            c.width as usize,
            c.height as usize,
            c.heading_deg,
            c.pitch_deg,
            c.roll_deg,
            c.hfov_deg,
        )
    }

    /// Prepares this view's strokes (orientation, fold-back handling,
    /// resampling, tangents) with the sketch's options. Returns the strokes
    /// and notes about split strokes; a rejected fold-back is an error that
    /// names the file, view and stroke.
    pub fn prepared_strokes(
        &self,
        options: &SketchOptions,
        path: &str,
    ) -> Result<(Vec<super::Stroke>, Vec<String>), SketchError> {
        let mut strokes = Vec::new();
        let mut notes = Vec::new();
        for (i, s) in self.strokes.iter().enumerate() {
            let pieces = super::prepare_stroke(
                &s.id,
                i,
                &s.points,
                options.resample_px,
                options.fold_back_tolerance_px,
                options.fold_back,
            )
            .map_err(|e| SketchError::Invalid {
                path: path.to_string(),
                location: format!("view \"{}\" stroke \"{}\"", self.name, s.id),
                problem: e.problem,
            })?;
            if pieces.len() > 1 {
                notes.push(format!(
                    "view \"{}\" stroke \"{}\" folds back in x: split into {} pieces",
                    self.name,
                    s.id,
                    pieces.len()
                ));
            }
            strokes.extend(pieces);
        }
        Ok((strokes, notes))
    }
}
