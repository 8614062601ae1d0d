//! Sketches: the strokes a user draws over a first-person view, their depth
//! order (T-junctions) and their matching to terrain features (sections 4, 5
//! and 7 of Tassé et al., Computers & Graphics 2014).
//!
//! The steps, one module each:
//!
//! - [`file`]: the sketch file (serde) and its validation.
//! - [`stroke`]: stroke preparation: clockwise (left-to-right) orientation,
//!   fold-back splitting, resampling, tangents.
//! - [`depth_order`]: T-junction labelling and the left-to-right sweep that
//!   orders strokes from front to back.
//! - [`projection`]: what matching needs from the renderer and the camera,
//!   as plain data ([`ViewFeature`]) and a trait ([`ViewProjection`]).
//! - [`skyline`]: the skyline of a view as one candidate feature.
//! - [`candidates`]: truncated, extended, altitude-adjusted features with
//!   the four cost terms; one priority list per stroke.
//! - [`branch_and_bound`]: the energy minimisation (and the brute-force
//!   reference).
//! - [`placement`]: strokes in world space and feature completion.
//! - [`fallback`]: 3D embedding of strokes left without a feature.
//! - [`multi_view`]: the entry point, [`match_sketch`], which matches all
//!   views of a sketch jointly and detects intersecting sketches.
//! - [`view_input`]: the bridge from a real rendered view (scene, camera,
//!   silhouettes, ridges) to [`ViewInput`], and placed points back to the
//!   DEM's CRS.

pub mod branch_and_bound;
pub mod candidates;
pub mod depth_order;
pub mod fallback;
pub mod file;
pub mod multi_view;
pub mod placement;
pub mod projection;
pub mod skyline;
pub mod stroke;
pub mod view_input;

pub use branch_and_bound::{
    branch_and_bound, branch_and_bound_with_budget, brute_force, valid, Bound, Choice, Solution,
    DEFAULT_NODE_BUDGET, EMPTY_LIST_COST,
};
pub use candidates::{
    build_candidate, priority_list, Candidate, CandidateOptions, CandidatePoint, CostTerms,
    PriorityList,
};
pub use depth_order::{
    label_junctions, order_strokes, Cue, CueKind, DepthConflict, DepthOrdering, Junction,
    JunctionLabel, SortingStructure, SweepStep,
};
pub use fallback::{embed_on_plane, embed_unmatched, fallback_depths, terrain_touching_point};
pub use file::{
    CameraSpec, CostWeights, DepthSpec, EyeHeightSpec, FoldBackPolicy, SketchError, SketchFile,
    SketchOptions, StrokeSpec, ViewSpec, ViewpointSpec, MAX_ALT_M, MAX_CANDIDATES,
    MAX_COMPLETION_M, MAX_DEPTH_M, MAX_EYE_HEIGHT_M, MAX_FALLBACK_DEPTH_RATIO, MAX_IMAGE_SIDE_PX,
    MAX_INFLUENCE_M, MAX_NODE_BUDGET, MAX_OBSERVER_RADIUS_M, MAX_WEIGHT, MIN_ALT_M,
    MIN_COMPLETION_STEP_M, MIN_RESAMPLE_PX,
};
pub use multi_view::{
    check_intersections, match_sketch, match_view, occludes_across_views, occludes_within_view,
    ColumnProfile, MatchError, MatchKind, SketchMatch, StrokeMatch, ViewInput, ViewMatch,
    OCCLUSION_STEP_PX,
};
pub use placement::{
    complete_feature, place_on_candidate, place_with_depths, PlacedPoint, PointSource,
};
pub use projection::{
    FeatureKind, FeatureSample, HeightFn, SimplePinhole, ViewFeature, ViewProjection,
};
pub use skyline::{is_skyline, skyline_feature, SKYLINE_CURVE};
pub use stroke::{prepare_stroke, resample, Stroke, StrokeError};
pub use view_input::{
    ridge_features, silhouette_features, terrain_height_local, FeatureSource, SceneProjection,
    SceneView, ViewFeatureOptions, SILHOUETTE_ID_BASE,
};
