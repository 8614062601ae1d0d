//! The skyline of a view as one candidate feature (issue 11 item 2: a
//! stroke matched to a chain of silhouette pieces that continue each
//! other).
//!
//! The silhouette extractor splits the skyline where its depth jumps (a
//! far range showing beside a nearer crest), so a stroke drawn along the
//! whole skyline may cover no single piece's half (`min_coverage`) and be
//! left with ridges only. [`skyline_feature`] offers the skyline itself:
//! in each pixel column, the silhouette sample with sky behind it that
//! lies highest in the image (samples on the observer's own ground left
//! out). Tassé et al. (section 5.2.3) give a stroke point the depth of the
//! feature point on its own pixel column; between two columns of one
//! piece that depth is interpolated, but between the last column of one
//! piece and the first of the next there is no terrain at any depth in
//! between: a point placed there would stand in mid-air between the two
//! landforms and pull up the valley between them. So at every *join* (a
//! column where the highest sample passes to another piece) each piece
//! keeps its own depth up to the middle of the gap
//! ([`hold_depth_to_joins`]): a stroke point takes the depth of the piece
//! on its side of the join, never one in between.
//!
//! The skyline mixes landforms, and a stroke above it in the image may
//! outline a nearer one rising over it (a new hill, a raised peak in front
//! of a far range): the matching costs cannot tell the two apart, the
//! stroke's fit on the edited terrain can. So where a stroke matched to a
//! skyline is left unfitted or hidden, the edit (`edit::pipeline`) tries
//! the match without the skylines, and keeps it where it fits the strokes
//! better, in all or where their placed curves are visible: in each pass
//! (`edit_pass`), and for the edit as a whole (its passes run again
//! without the skylines in `run_opened`), since a pass that fits less may
//! be completed by the next.

use std::collections::BTreeMap;

use super::projection::{FeatureKind, FeatureSample, ViewFeature, ViewProjection};
use super::view_input::{FeatureSource, SceneProjection};
use crate::features::Silhouettes;

/// The curve number of a view's whole skyline as one feature
/// ([`skyline_feature`]); extracted curves are numbered from 0.
pub const SKYLINE_CURVE: u32 = u32::MAX;

/// True when `id` is the id of a view's skyline feature.
pub fn is_skyline(id: usize) -> bool {
    matches!(
        FeatureSource::of_id(id),
        FeatureSource::Silhouette {
            curve: SKYLINE_CURVE,
            ..
        }
    )
}

/// The skyline of view `view_index` as one feature, when it is made of
/// two or more silhouette curves (one curve is a feature already); see
/// the module documentation. `min_depth_m`: samples nearer than this (the
/// observer's ground) are left out.
pub fn skyline_feature(
    view_index: usize,
    sil: &Silhouettes,
    proj: &SceneProjection,
    min_depth_m: f64,
) -> Option<ViewFeature> {
    let columns = highest_sky_samples(sil, proj, min_depth_m);
    let pieces = count_pieces(&columns);
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        eprintln!(
            "skyline feature: {} columns, {} pieces",
            columns.len(),
            pieces
        );
    }
    if pieces < 2 {
        return None;
    }
    Some(ViewFeature {
        id: FeatureSource::Silhouette {
            view: view_index,
            curve: SKYLINE_CURVE,
        }
        .id(),
        kind: FeatureKind::Silhouette,
        samples: hold_depth_to_joins(&columns, proj),
    })
}

/// Per pixel column, by increasing column: the curve id and the sample of
/// the highest (smallest image row) silhouette sample with sky behind it
/// and at least `min_depth_m` away.
fn highest_sky_samples(
    sil: &Silhouettes,
    proj: &SceneProjection,
    min_depth_m: f64,
) -> Vec<(u32, FeatureSample)> {
    let mut by_column: BTreeMap<i64, (u32, FeatureSample)> = BTreeMap::new();
    for c in &sil.curves {
        for s in &c.samples {
            if !(s.pixel[0].is_finite() && s.pixel[1].is_finite() && s.depth.is_finite())
                || s.depth_behind.is_finite()
                || s.depth < min_depth_m
            {
                continue;
            }
            let column = s.pixel[0].floor() as i64;
            if by_column
                .get(&column)
                .is_some_and(|(_, best)| best.pixel[1] <= s.pixel[1])
            {
                continue;
            }
            let sample = FeatureSample {
                pixel: s.pixel,
                depth: s.depth,
                world: proj.own_to_world(s.local),
            };
            by_column.insert(column, (c.id, sample));
        }
    }
    by_column.into_values().collect()
}

/// Number of pieces of the skyline: runs of consecutive columns from one
/// curve (a curve showing twice, with another in between, counts twice).
fn count_pieces(columns: &[(u32, FeatureSample)]) -> usize {
    if columns.is_empty() {
        return 0;
    }
    1 + columns.windows(2).filter(|w| w[0].0 != w[1].0).count()
}

/// The samples of the skyline, with each join (consecutive columns from
/// two curves) bridged by the two pieces' end samples carried, at their
/// own depths, to the middle of the gap: both at the same image x, so that
/// interpolation by x (the candidate's `depth_at`) takes one piece's depth
/// on each side of the join and none in between.
fn hold_depth_to_joins(
    columns: &[(u32, FeatureSample)],
    proj: &dyn ViewProjection,
) -> Vec<FeatureSample> {
    let mut out: Vec<FeatureSample> = Vec::with_capacity(columns.len() + 8);
    for (k, (curve, s)) in columns.iter().enumerate() {
        if let Some((prev_curve, prev)) = k.checked_sub(1).map(|j| &columns[j]) {
            if prev_curve != curve {
                let x = 0.5 * (prev.pixel[0] + s.pixel[0]);
                let y = 0.5 * (prev.pixel[1] + s.pixel[1]);
                out.push(carried_to(prev, [x, y], proj));
                out.push(carried_to(s, [x, y], proj));
            }
        }
        out.push(*s);
    }
    out
}

/// `s` moved along the image to `pixel` at its own depth.
fn carried_to(s: &FeatureSample, pixel: [f64; 2], proj: &dyn ViewProjection) -> FeatureSample {
    FeatureSample {
        pixel,
        depth: s.depth,
        world: proj.unproject(pixel, s.depth),
    }
}
