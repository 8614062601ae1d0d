//! One edit end to end (`demsketch edit`): a DEM and a sketch file in,
//! corrected tiles, a report and pictures out (the pipeline of DESIGN.md).
//!
//! [`run`] loads the DEM and the sketch, renders every view (reading only
//! the DEM within the maximum view distance, the eye resolved once above
//! the drawn surface), extracts its silhouettes and the ridge network, and
//! matches the strokes of all views jointly. What a stroke draws where the
//! unedited view already has a silhouette is kept as it is
//! ([`on_silhouette`]); the rest is placed at the depth the evidence gives
//! ([`stretch_placement`]) and turned into curve constraints in the DEM's
//! CRS, with the observer's ground and the anchored cells held, and the DEM
//! is deformed ([`pipeline`]). It then re-renders each view and lowers protruding
//! silhouettes until every stroke is visible ([`lowering`], in the rounds
//! of `rounds`), measures how well the edited terrain shows each stroke
//! ([`fit`]) after removing lone spikes of the change ([`spikes`]),
//! writes the affected tiles back atomically, and finally the
//! pictures ([`renders`]) and the report ([`report`]) (`outputs`). Nothing
//! is written unless every step succeeded.

pub mod contour;
pub mod fit;
pub mod guard;
pub mod lowering;
pub mod on_silhouette;
mod outputs;
pub(crate) use outputs::StagedDir;
pub mod pipeline;
pub mod rendered_view;
pub mod renders;
pub mod report;
mod rerender;
mod rounds;
pub mod spikes;
pub mod stretch_placement;
pub mod tangent_rise;

pub use outputs::picture_stem;
pub use pipeline::{run, run_opened, EditOptions, DEFAULT_MIN_FIT};
pub use report::{EditReport, MatchingReport, StrokeStatus};

/// Errors of an edit. One line naming the file and the problem. (The
/// sources of other stages are boxed where they are large: every `Result`
/// of an edit carries the largest variant's size.)
#[derive(Debug, thiserror::Error)]
pub enum EditError {
    #[error(transparent)]
    Sketch(#[from] crate::sketch::SketchError),
    #[error(transparent)]
    Raster(#[from] crate::raster::RasterError),
    #[error("{sketch}: view \"{view}\": {source}")]
    View {
        sketch: String,
        view: String,
        #[source]
        source: Box<crate::render::RenderError>,
    },
    #[error("{sketch}: {source}")]
    Match {
        sketch: String,
        #[source]
        source: Box<crate::sketch::MatchError>,
    },
    #[error("{sketch}: {message}")]
    Unusable { sketch: String, message: String },
    #[error("{dem}: deformation: {source}")]
    Deform {
        dem: String,
        #[source]
        source: crate::deform::DeformError,
    },
    /// A stroke's fit is below the minimum: nothing was written (but the
    /// report and pictures were). Exit code 3.
    #[error("{sketch}: view \"{view}\" stroke \"{stroke}\": {reason}; nothing written (the report says why for every stroke; --allow-partial writes anyway)")]
    BelowMinFit {
        sketch: String,
        view: String,
        stroke: String,
        fit: f64,
        min_fit: f64,
        reason: String,
        report: Box<EditReport>,
    },
    #[error("{path}: cannot write: {message}")]
    Write { path: String, message: String },
    /// An option the caller gave is out of its range (nothing read).
    #[error("edit options: {0}")]
    Options(String),
    /// A failure of the program rather than of the input.
    #[error("internal error: {0}")]
    Internal(String),
}

impl EditError {
    /// True when the input (DEM, sketch, paths) is at fault: exit code 1.
    pub fn is_user_error(&self) -> bool {
        match self {
            EditError::Raster(e) => e.is_user_error(),
            EditError::Internal(_) => false,
            EditError::Deform { source, .. } => !matches!(
                source,
                crate::deform::DeformError::Solver(_) | crate::deform::DeformError::BadOption(_)
            ),
            _ => true,
        }
    }
}
