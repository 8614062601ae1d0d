//! Lowering protruding silhouettes (section 6.2 of Tassé et al. 2014).
//!
//! After deformation, terrain nearer than a sketched silhouette may hide it.
//! The edited terrain is re-rendered from the sketch's view and its visible
//! silhouettes found (section 5.1). A silhouette `s` is an *unwanted
//! protruding silhouette* when, on a pixel column of a stroke `g`, it is
//! nearer to the camera than `g`'s placed curve and its projection lies
//! higher in the image than `g` (above the stroke by more than the fit
//! tolerance): the mountain of `s` then hides `g` there. The height by which
//! `s` must come down is measured in the sketching plane: for each such
//! sample, how far its terrain point lies above the line of sight through
//! the stroke (plus a one-pixel margin, so that it ends up under it); `h` is
//! the maximum over the samples of `s`, and `s` is lowered uniformly by `h`.
//! The lowered samples become new curve constraints (DEM CRS, absolute
//! heights); the caller adds them to the sketch's constraints and deforms
//! again, repeating until no protruding silhouette remains.
//!
//! A column where the stroke is hidden but no extracted silhouette sample
//! lies above it (the extractor drops very short pieces) falls back to the
//! depth buffer: walking up from the stroke pixel through the nearer
//! terrain, the last pixel before it ends is the silhouette there; such
//! points of one stroke form one more protruding silhouette.
//!
//! The paper lowers the whole silhouette; here the lowered part is the
//! stretch of `s` over the columns where it hides a stroke, widened by
//! [`LOWERING_PAD_PX`] on each side: the rest of `s` hides nothing, and
//! constraining it would only add changes far from the sketch.
//!
//! Where a stroke already lies on a silhouette of the unedited view (its
//! anchored stretches, [`super::on_silhouette`]) the paper's rule does not
//! apply: what stands above such a stretch was there before and stays.
//! But the deformation that lifts the stroke's free part lifts the terrain
//! beside it too, and on real DEMs that new crest often stands a pixel or
//! three above the anchored part (the flank of a raised peak or of a
//! filled void along the ridge the stroke follows), so the stroke is no
//! longer the boundary there and no rule lowers it.
//! [`find_raised_over_anchored`] finds those crests: silhouette samples
//! more than [`BELOW_STROKE_PX`] above an anchored column whose pixel the
//! unedited view showed as sky or as terrain farther away (the edit raised
//! them, at whatever depth). Only those samples come down, each under the
//! stroke's sight line by its own need, not the whole silhouette by the
//! largest (the rest of it is often the landform the stroke asked for).
//! The refinement rounds try this last.

use super::fit::{is_hidden, HIDDEN_MARGIN};
use super::rendered_view::{RenderedView, StrokeCurve};
use crate::features::silhouettes::SilhouetteSample;
use crate::view::CameraModel;
use rayon::prelude::*;

/// Pixels of the protruding silhouette kept on each side of the hidden
/// columns when it is lowered.
pub const LOWERING_PAD_PX: f64 = 8.0;
/// The lowered silhouette is put this many pixels under the stroke.
pub const BELOW_STROKE_PX: f64 = 1.0;

/// One protruding silhouette and how it is lowered.
#[derive(Debug, Clone, PartialEq)]
pub struct Protrusion {
    /// Index of the silhouette curve in the rendered view (`usize::MAX`:
    /// points found in the depth buffer).
    pub curve: usize,
    /// Uniform lowering, metres.
    pub h: f64,
    /// Pixel columns of strokes it hides.
    pub hidden_columns: usize,
    /// The lowered samples: DEM CRS x, y and absolute height minus `h`.
    pub lowered: Vec<[f64; 3]>,
}

/// Find the protruding silhouettes of `view` with respect to `strokes`.
pub fn find_protruding(view: &RenderedView, strokes: &[StrokeCurve]) -> Vec<Protrusion> {
    let n = view.silhouettes.curves.len();
    // Per curve: lowering needed and the x range of the hidden columns.
    let mut need = vec![0.0f64; n];
    let mut range = vec![(f64::INFINITY, f64::NEG_INFINITY); n];
    let mut hidden = vec![0usize; n];
    let mut extra = Vec::new();
    // Strokes in parallel (the casts of hidden columns dominate), merged in
    // stroke order.
    let per_stroke: Vec<StrokeHits> = strokes.par_iter().map(|g| stroke_hits(view, g)).collect();
    for hits in per_stroke {
        for (c, h, x) in hits.samples {
            need[c] = need[c].max(h);
            range[c] = (range[c].0.min(x), range[c].1.max(x));
            hidden[c] += 1;
        }
        let fallback = hits.fallback;
        if !fallback.is_empty() {
            let h = fallback.iter().fold(0.0f64, |a, p| a.max(p.1));
            extra.push(Protrusion {
                curve: usize::MAX,
                h,
                hidden_columns: fallback.len(),
                lowered: fallback
                    .iter()
                    .map(|(p, _)| [p[0], p[1], p[2] - h])
                    .collect(),
            });
        }
    }
    let mut out: Vec<Protrusion> = (0..n)
        .filter(|&c| hidden[c] > 0)
        .map(|c| {
            let (x0, x1) = (range[c].0 - LOWERING_PAD_PX, range[c].1 + LOWERING_PAD_PX);
            let lowered = view.silhouettes.curves[c]
                .samples
                .iter()
                .filter(|s| s.pixel[0] >= x0 && s.pixel[0] <= x1)
                .filter(|s| !carries_anchored_stroke(strokes, s.pixel))
                .map(|s| [s.world[0], s.world[1], s.world[2] - need[c]])
                .collect();
            Protrusion {
                curve: c,
                h: need[c],
                hidden_columns: hidden[c],
                lowered,
            }
        })
        .collect();
    out.extend(extra);
    out
}

/// A silhouette sample within [`ANCHORED_NEAR_PX`] of a stroke's anchored
/// stretch: the silhouette that stretch already lies on. Lowering it (the
/// padding of a protrusion next to the stretch reaches it) would pull the
/// silhouette from under a part of the stroke that needed no change.
fn carries_anchored_stroke(strokes: &[StrokeCurve], pixel: [f64; 2]) -> bool {
    strokes.iter().any(|g| {
        g.is_anchored(pixel[0])
            && g.stroke
                .y_at(pixel[0])
                .is_some_and(|y| (y - pixel[1]).abs() <= ANCHORED_NEAR_PX)
    })
}

/// How far a point (local frame) lies above the line of sight through
/// image point `(x, y + BELOW_STROKE_PX)`, in metres at the point's
/// horizontal distance: what lowering it under that line takes (negative
/// infinity for a vertical ray).
fn above_sight_line(view: &RenderedView, x: f64, y: f64) -> impl Fn([f64; 3]) -> f64 {
    let ray = view.camera.unproject([x, y + BELOW_STROKE_PX]);
    let rh = ray[0].hypot(ray[1]);
    move |p: [f64; 3]| {
        if rh > 0.0 {
            p[2] - ray[2] * p[0].hypot(p[1]) / rh
        } else {
            f64::NEG_INFINITY
        }
    }
}

/// Did the edit raise `sample` into view? The terrain pixel just under it
/// showed sky in the unedited view, or terrain farther than the sample by
/// more than [`HIDDEN_MARGIN`].
fn raised_by_edit(view: &RenderedView, before: &RenderedView, sample: &SilhouetteSample) -> bool {
    let [x, y] = sample.pixel;
    if !(x >= 0.0 && y >= 0.0) {
        return false;
    }
    let i = x.floor() as usize;
    let j = (y - 0.5).ceil().max(0.0) as usize;
    if i >= view.camera.width || j >= view.camera.height {
        return false;
    }
    let was = f64::from(before.depth.depth_at(i, j));
    was > sample.depth * (1.0 + HIDDEN_MARGIN)
}

/// How near (pixels, vertically) a silhouette sample must lie to an
/// anchored stretch of a stroke to count as the silhouette it lies on.
pub const ANCHORED_NEAR_PX: f64 = 3.0;

/// What one stroke finds: the silhouette samples over it that hide it
/// (curve, lowering needed, column centre) and the depth-buffer fallback
/// points (CRS point, lowering needed).
struct StrokeHits {
    samples: Vec<(usize, f64, f64)>,
    fallback: Vec<([f64; 3], f64)>,
}

/// The protruding samples and fallback points over the columns of `g`.
fn stroke_hits(view: &RenderedView, g: &StrokeCurve) -> StrokeHits {
    let mut samples = Vec::new();
    // Depth-buffer fallback for this stroke: (CRS point, h).
    let mut fallback: Vec<([f64; 3], f64)> = Vec::new();
    // Anchored columns lie on a silhouette of the unedited terrain that
    // nothing hid: what is above them stays.
    for (i, y, d) in g.free_columns(view.camera.width) {
        let x = i as f64 + 0.5;
        let above_ray = above_sight_line(view, x, y);
        let mut found = false;
        for &(c, s) in &view.by_column[i] {
            let sample = &view.silhouettes.curves[c as usize].samples[s as usize];
            if sample.pixel[1] >= y || sample.depth >= d * (1.0 - HIDDEN_MARGIN) {
                continue;
            }
            let h = above_ray(sample.local);
            if h.is_finite() && h > 0.0 {
                if sample.pixel[1] < y - BELOW_STROKE_PX {
                    samples.push((c as usize, h, x));
                }
                found = true;
            }
        }
        if found || !is_hidden(view, x, y, d) {
            continue;
        }
        // Walk up from the stroke pixel through the nearer terrain.
        let limit = (d * (1.0 - HIDDEN_MARGIN)) as f32;
        let mut j = (y.floor().max(0.0) as usize).min(view.depth.height - 1);
        while j > 0 && view.depth.depth_at(i, j - 1) < limit {
            j -= 1;
        }
        if view.depth.depth_at(i, j) >= limit {
            continue;
        }
        if let Some(hit) = view.depth.hit(&view.terrain, i, j) {
            let h = above_ray(hit.local);
            if h.is_finite() && h > 0.0 {
                fallback.push(([hit.x, hit.y, hit.z], h));
            }
        }
    }
    StrokeHits { samples, fallback }
}

/// Crests the edit raised over the anchored stretches of `strokes`
/// (`raised_over_anchored`), per stroke, as protrusions: one per run of
/// adjacent columns on one silhouette, each point lowered by its own need
/// (`hidden_columns`: the run's length). The refinement rounds try these
/// last, from their best terrain.
pub fn find_raised_over_anchored(
    view: &RenderedView,
    before: &RenderedView,
    strokes: &[StrokeCurve],
) -> Vec<Vec<Protrusion>> {
    strokes
        .par_iter()
        .map(|g| {
            raised_over_anchored(view, before, g)
                .into_iter()
                .map(|run| Protrusion {
                    curve: usize::MAX,
                    h: run.iter().fold(0.0f64, |a, p| a.max(p.1)),
                    hidden_columns: run.len(),
                    lowered: run.iter().map(|(p, h)| [p[0], p[1], p[2] - h]).collect(),
                })
                .collect()
        })
        .collect()
}

/// Anchored columns lie on a silhouette of the unedited terrain, and what
/// stood above them then stays; but a crest the edit itself raised above
/// such a column, more than the fit's pixel over the stroke (the flank of
/// a landform lifted beside an anchored stretch, at whatever depth), puts
/// the stroke under it. Those samples, and only those (the rest of their
/// silhouette is often the very landform the free part of the stroke
/// asked for), come down each under the stroke's sight line: (CRS point,
/// lowering), in runs of adjacent columns on one silhouette (each run one
/// curve constraint: a gap must not be bridged by a line through the
/// terrain between).
fn raised_over_anchored(
    view: &RenderedView,
    before: &RenderedView,
    g: &StrokeCurve,
) -> Vec<Vec<([f64; 3], f64)>> {
    let debug = std::env::var_os("DEMSKETCH_DEBUG").is_some();
    let mut found: Vec<(u32, usize, [f64; 3], f64)> = Vec::new();
    for (i, y, _) in g.columns(view.camera.width) {
        let x = i as f64 + 0.5;
        if !g.is_anchored(x) {
            continue;
        }
        let above_ray = above_sight_line(view, x, y);
        for &(c, s) in &view.by_column[i] {
            let sample = &view.silhouettes.curves[c as usize].samples[s as usize];
            if sample.pixel[1] >= y - BELOW_STROKE_PX || !raised_by_edit(view, before, sample) {
                continue;
            }
            let h = above_ray(sample.local);
            if h.is_finite() && h > 0.0 {
                if debug {
                    eprintln!(
                        "raised over anchored: {} x {x:.1} stroke y {y:.1} sample y {:.1} depth {:.0} stroke depth {:.0} h {h:.1}",
                        g.id, sample.pixel[1], sample.depth, g.depth_at(x).unwrap_or(f64::NAN)
                    );
                }
                found.push((c, i, sample.world, h));
            }
        }
    }
    found.sort_by_key(|f| (f.0, f.1));
    let mut out: Vec<Vec<([f64; 3], f64)>> = Vec::new();
    for (k, &(c, i, p, h)) in found.iter().enumerate() {
        let continues = k > 0 && found[k - 1].0 == c && found[k - 1].1 + 1 == i;
        match out.last_mut() {
            Some(run) if continues => run.push((p, h)),
            _ => out.push(vec![(p, h)]),
        }
    }
    out
}
