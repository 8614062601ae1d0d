//! How well the edited terrain shows a stroke, rendered from the stroke's
//! view (the report's `fit` and `visible_fraction`, DESIGN.md):
//!
//! - `fitted_fraction`: share of the stroke's pixel columns where the edited
//!   terrain has an occlusion boundary (a silhouette sample) or the skyline
//!   within [`FIT_TOLERANCE_PX`] of the stroke, as the renderer draws the
//!   bilinear surface of DESIGN.md;
//! - `mean_px`, `max_px`: distance from the stroke to the nearest boundary
//!   of each column that has one;
//! - `visible_fraction`: share of the stroke's columns where the ray through
//!   the stroke point reaches the placed curve, i.e. no terrain nearer than
//!   the curve (by more than [`HIDDEN_MARGIN`] of its depth) covers it.

use super::rendered_view::{RenderedView, StrokeCurve};
use crate::view::CameraModel;

/// A column is fitted when a boundary lies within this many pixels.
pub const FIT_TOLERANCE_PX: f64 = 1.0;
/// Terrain nearer than `(1 - HIDDEN_MARGIN) * depth` of the placed curve
/// hides it.
pub const HIDDEN_MARGIN: f64 = 0.02;

/// Fit figures of one stroke.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct StrokeFit {
    pub fitted_fraction: f64,
    pub mean_px: f64,
    pub max_px: f64,
    /// Pixel columns measured.
    pub columns: usize,
}

/// [`measure`]'s `fitted_fraction` alone (no visibility casts): what the
/// refinement rounds compare.
pub fn fitted_fraction(stroke: &StrokeCurve, view: &RenderedView) -> f64 {
    let cols = stroke.columns(view.camera.width);
    if cols.is_empty() {
        return 0.0;
    }
    let fitted = cols
        .iter()
        .filter(|&&(i, y, _)| view.boundary_near(i, y, FIT_TOLERANCE_PX).1)
        .count();
    fitted as f64 / cols.len() as f64
}

/// Measure the fit and visibility of `stroke` in `view`.
pub fn measure(stroke: &StrokeCurve, view: &RenderedView) -> (StrokeFit, f64) {
    let cols = stroke.columns(view.camera.width);
    if cols.is_empty() {
        return (
            StrokeFit {
                fitted_fraction: 0.0,
                mean_px: f64::NAN,
                max_px: f64::NAN,
                columns: 0,
            },
            0.0,
        );
    }
    let (mut fitted, mut visible, mut sum, mut max, mut measured) =
        (0usize, 0usize, 0.0, 0.0f64, 0);
    for &(i, y, d) in &cols {
        let (nearest, within) = view.boundary_near(i, y, FIT_TOLERANCE_PX);
        // (a crest within the tolerance that does not show as a boundary:
        // what lies beyond it is too near, see `shows_as_boundary`)
        if !within && std::env::var_os("DEMSKETCH_DEBUG").is_some() {
            for &(c, s) in &view.by_column[i] {
                let s = &view.silhouettes.curves[c as usize].samples[s as usize];
                if (s.pixel[1] - y).abs() <= FIT_TOLERANCE_PX {
                    eprintln!(
                        "fit: column {i} stroke y {y:.1}: crest y {:.1} at {:.0} m, terrain behind at {:.0} m (cell {:.0} m): not a boundary",
                        s.pixel[1], s.depth, s.depth_behind, view.cell_m()
                    );
                }
            }
        }
        if nearest.is_finite() {
            measured += 1;
            sum += nearest;
            max = max.max(nearest);
            if within {
                fitted += 1;
            }
        }
        if !is_hidden(view, i as f64 + 0.5, y, d) {
            visible += 1;
        }
    }
    let n = cols.len() as f64;
    (
        StrokeFit {
            fitted_fraction: fitted as f64 / n,
            mean_px: if measured > 0 {
                sum / measured as f64
            } else {
                f64::NAN
            },
            max_px: if measured > 0 { max } else { f64::NAN },
            columns: cols.len(),
        },
        visible as f64 / n,
    )
}

/// Is the point of depth `d` on the ray through pixel `(x, y)` hidden by
/// nearer terrain?
pub fn is_hidden(view: &RenderedView, x: f64, y: f64, d: f64) -> bool {
    let dir = view.camera.unproject([x, y]);
    view.terrain
        .cast_within(dir, d * (1.0 - HIDDEN_MARGIN))
        .is_some()
}
