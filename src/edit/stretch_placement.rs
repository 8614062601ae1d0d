//! Where the parts of a stroke that are not on a silhouette go in depth
//! (issue 11, item 3: the depth a person means).
//!
//! After anchoring ([`super::on_silhouette`]) a stroke is a sequence of
//! anchored runs, which lie on the unedited terrain's silhouettes, and
//! *free stretches* between them (or between one and a stroke end), which
//! ask for new terrain. The matcher placed a free stretch at the depth of
//! its feature (Tassé et al. section 5.2.3). That depth is kept where the
//! feature lies near the stretch in the image (it is the landform being
//! reshaped) and no stroke end stands on terrain clearly nearer than it (a
//! new landform in front of a far one). Otherwise the
//! stretch is placed as Gain et al. (2009, section 3.1) place a silhouette
//! curve: on the vertical surface through the terrain points at its two
//! ends: the anchored silhouette points beside it, or, at a stroke end,
//! the first terrain the view shows at or below the end pixel. With
//! terrain under only one end, the stretch stands on the drawing plane
//! through that point (normal: the horizontal view direction). A person
//! raising a peak starts and ends the stroke on the shoulders that stay;
//! a person adding a hill in front of a far range starts and ends it on
//! the ground at its foot: either way the ends say where the landform is,
//! whatever far feature happens to lie near the stroke in the image. A
//! stretch drawn into the landform its two anchors lie on (a ridge cut
//! along a skyline) is placed on that landform even when a nearer feature
//! lies just under the stroke. A stroke end that stops on a silhouette
//! (within [`END_TOUCH_PX`] above it) is a T-junction (Tassé et al. section
//! 5.2.2: the outline that ends on another is occluded by it): that
//! silhouette is not the stroke's ground but a lower bound on its depth, so
//! the stretch goes through the other end's terrain point when that lies
//! behind the junction, and through the junction when it lies in front of
//! it; the junction never contradicts the matched feature, and a stretch
//! bounded by junctions only keeps its feature's depth. A stretch drawn in
//! the sky that leaves an anchored silhouette behind its feature, where
//! the feature does not run along that silhouette, goes with the landform
//! it leaves ([`leaves_farther_silhouette`]). A whole stroke drawn in the sky just over
//! its feature, narrower than one DEM cell at that feature's depth, is a
//! landform behind it that the DEM could not draw there: it goes behind,
//! to the skyline of the farther landform it is drawn over where it lies
//! over one, else to the nearest depth where it spans one cell; so does a
//! whole stroke whose two ends stop on its feature's silhouette
//! (T-junctions) and which rises over a farther skyline
//! (`behind_junctions`). A stretch drawn into the face just under a
//! crest (a cut) is placed at that crest (`crest_above`), and a stroke
//! end inside a face more than a pixel under its crest stands on it.

use super::rendered_view::RenderedView;
use crate::render::SKY;
use crate::sketch::projection::{dot, sub, FeatureSample};
use crate::sketch::{
    PlacedPoint, PointSource, SceneProjection, StrokeMatch, ViewFeature, ViewProjection,
};

/// The matched feature is near the stretch in the image when its mean
/// vertical distance to the stretch's points is at most this angle
/// (radians; about 1.5 degrees)...
pub const NEAR_IN_IMAGE_RAD: f64 = 0.026;
/// ... and it projects under at least this share of them.
pub const NEAR_COVERAGE: f64 = 0.5;
/// Terrain under a stroke end nearer than the feature by more than this
/// fraction of the feature's depth contradicts it: the stroke stands on
/// that nearer ground.
pub const AGREEMENT: f64 = 0.15;

/// How the free stretches of one stroke were placed.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct StretchPlacement {
    /// Points kept at their matched feature's depth.
    pub feature: usize,
    /// Points put on the vertical surface through the terrain at both ends.
    pub end_points: usize,
    /// Points put on the drawing plane through the terrain at one end.
    pub drawing_plane: usize,
    /// Points with no terrain at either end, left as matched.
    pub unsupported: usize,
    /// Points of a stretch drawn a pixel or two off a silhouette along its
    /// length, at that silhouette's depth (`on_silhouette`'s
    /// `NearSilhouette` points): it asks to move that silhouette.
    pub near_silhouette: usize,
    /// Points of a stretch drawn in the sky over its feature, narrower
    /// than one DEM cell at the feature's depth: put behind it, at the
    /// nearest depth where they span one cell ([`drawable_depth_behind`]).
    pub behind: usize,
}

/// A terrain point bounding a free stretch, in the world frame, and its
/// depth from the eye.
#[derive(Debug, Clone, Copy)]
struct Bound {
    world: [f64; 3],
    depth: f64,
    /// A stroke end that stops on a silhouette (a T-junction): the point
    /// is on the occluding silhouette, not the stroke's own ground, and
    /// its depth is a lower bound on the stroke's.
    junction: bool,
}

/// A stroke end stands on the terrain when the first terrain under it is
/// at most this many pixels lower.
pub const END_TOUCH_PX: f64 = 3.0;

/// The ground a stroke end stands on, in the view's own frame (point and
/// depth): the first terrain at or below the end pixel, when it is within
/// [`END_TOUCH_PX`] and not an occlusion boundary. An end that stops on a
/// nearer silhouette is a T-junction: the stroke goes on behind it, and
/// that silhouette only bounds its depth from the near side
/// ([`junction_under_end`]).
fn ground_under_end(view: &RenderedView, pixel: [f64; 2]) -> Option<([f64; 3], f64)> {
    let (local, depth, row) = terrain_below(view, pixel)?;
    if row - pixel[1] > END_TOUCH_PX {
        return None;
    }
    let i = (pixel[0].floor().max(0.0) as usize).min(view.camera.width.saturating_sub(1));
    // A boundary just under the terrain the end shows, or at it, leaves
    // the end ambiguous (on a crest, or on the farther ground just over
    // it); one more than the on-silhouette tolerance above it is the
    // crest of the face the end stands on.
    if view
        .boundaries(i)
        .any(|b| b - row <= END_TOUCH_PX && row - b <= JUNCTION_ABOVE_PX)
    {
        return None;
    }
    Some((local, depth))
}

/// The occluding silhouette a stroke end stops on (Tassé et al. section
/// 5.2.2: the stroke that ends on another is occluded by it): the topmost
/// occlusion boundary of the end's column from one pixel above the end
/// down to [`END_TOUCH_PX`] under it, as a point in the view's own frame
/// and its depth. The stroke's landform lies behind it.
fn junction_under_end(view: &RenderedView, pixel: [f64; 2]) -> Option<([f64; 3], f64)> {
    let w = view.camera.width;
    if !(pixel[0].is_finite() && pixel[1].is_finite()) || w == 0 {
        return None;
    }
    let i = (pixel[0].floor().max(0.0) as usize).min(w - 1);
    let within = |row: f64| row >= pixel[1] - JUNCTION_ABOVE_PX && row <= pixel[1] + END_TOUCH_PX;
    let mut best: Option<(f64, [f64; 3], f64)> = None;
    for &(c, k) in &view.by_column[i] {
        let sample = &view.silhouettes.curves[c as usize].samples[k as usize];
        let row = sample.pixel[1];
        if within(row) && best.is_none_or(|b| row < b.0) {
            best = Some((row, sample.local, sample.depth));
        }
    }
    if let Some(j) = view.skyline_row[i].filter(|&j| j > 0 && within(j as f64)) {
        if best.is_none_or(|b| (j as f64) < b.0) {
            if let Some(hit) = view.depth.hit(&view.terrain, i, j) {
                best = Some((j as f64, hit.local, hit.distance));
            }
        }
    }
    best.map(|(_, local, depth)| (local, depth))
}

/// A stroke end up to this many pixels under a silhouette still stops on
/// it (the on-silhouette tolerance).
pub const JUNCTION_ABOVE_PX: f64 = 1.0;

/// The first terrain point within [`END_TOUCH_PX`] at or below `pixel`
/// (in the image, then under its lower border), in the view's own frame,
/// its depth and image row.
fn terrain_below(view: &RenderedView, pixel: [f64; 2]) -> Option<([f64; 3], f64, f64)> {
    let (hit, row) = view.terrain_at_or_below(pixel, END_TOUCH_PX)?;
    Some((hit.local, hit.distance, row))
}

/// Re-places the free stretches of `placed` (see the module
/// documentation) on the unedited view `before`.
pub fn place_free_stretches(
    before: &RenderedView,
    proj: &SceneProjection,
    features: &[ViewFeature],
    observer_radius_m: f64,
    occluder: Option<f64>,
    placed: &mut StrokeMatch,
) -> StretchPlacement {
    let feature = placed
        .feature_id
        .and_then(|id| features.iter().find(|f| f.id == id));
    let near_px = NEAR_IN_IMAGE_RAD * proj.focal_px();
    let mut out = StretchPlacement::default();
    let on: Vec<usize> = (0..placed.points.len())
        .filter(|&k| {
            placed.points[k].source != PointSource::Completion && placed.points[k].pixel.is_some()
        })
        .collect();
    let n = on.len();
    if let Some(surface) = occluder.and_then(|d| summit_plane(proj, placed, &on, d)) {
        let free: Vec<usize> = on
            .iter()
            .copied()
            .filter(|&k| placed.points[k].source != PointSource::Silhouette)
            .collect();
        put_at_depths(proj, placed, &free, |_, px| surface.depth(proj, px));
        out.drawing_plane += free.len();
        let end_free = |k: usize| placed.points[k].source != PointSource::Silhouette;
        let ends = (
            on.first().is_some_and(|&k| end_free(k)),
            on.last().is_some_and(|&k| end_free(k)),
        );
        drop_completions_at_ends(placed, &on, ends);
        return out;
    }
    // The free runs and their bounds (the anchors beside them, or the
    // terrain under the stroke's end); then whether the matched depth
    // agrees.
    let mut spans = free_spans(before, proj, observer_radius_m, placed, &on);
    drop_passed_anchors(placed, &on, &mut spans);
    if let Some(d) = occluder {
        occluded_bounds(&mut spans, d);
    }
    let runs: Vec<(Span, bool)> = spans
        .into_iter()
        .map(|span| {
            let ok = keeps_feature(before, feature, near_px, placed, &on, span);
            (span, ok)
        })
        .collect();
    let mut replaced_ends = (false, false);
    for ((a, b, left, right), feature_ok) in runs {
        let count = b - a;
        if on[a..b]
            .iter()
            .all(|&k| placed.points[k].source == PointSource::NearSilhouette)
        {
            out.near_silhouette += count;
            continue;
        }
        if feature_ok {
            let whole = a == 0 && b == n;
            let behind = whole
                .then(|| {
                    drawable_depth_behind(before, proj, placed, &on[a..b], near_px).or_else(|| {
                        behind_junctions(before, proj, placed, &on[a..b], (left, right), near_px)
                    })
                })
                .flatten();
            if let Some(surface) = behind {
                put_at_depths(proj, placed, &on[a..b], |_, px| surface.depth(proj, px));
                out.behind += count;
                replaced_ends.0 |= a == 0;
                replaced_ends.1 |= b == n;
                continue;
            }
            out.feature += count;
            keep_on_feature(proj, placed, &on[a..b], (left, right));
            hold_background_ends(before, proj, placed, &on[a..b], (a == 0, b == n));
            continue;
        }
        // A stretch bounded by junctions only: nothing says where it stands.
        let real = |q: Option<Bound>| q.filter(|q| !q.junction);
        if real(left).is_none() && real(right).is_none() {
            let whole = a == 0 && b == n && placed.feature_id.is_none();
            let behind = whole
                .then(|| behind_occluder(before, proj, placed, &on[a..b], near_px))
                .flatten();
            if let Some(surface) = behind {
                put_at_depths(proj, placed, &on[a..b], |_, px| surface.depth(proj, px));
                out.behind += count;
                replaced_ends = (true, true);
                continue;
            }
            out.unsupported += count;
            continue;
        }
        if stands_on_background(placed, &on[a..b], (left, right), (a == 0, b == n)) {
            out.feature += count;
            keep_on_feature(proj, placed, &on[a..b], (left, right));
            continue;
        }
        let surface = Surface::new(proj, left, right);
        let cut = cut_depths(before, &on[a..b], placed, near_px);
        put_at_depths(proj, placed, &on[a..b], |j, px| {
            cut[j].or_else(|| surface.depth(proj, px))
        });
        if real(left).is_some() && real(right).is_some() {
            out.end_points += count;
        } else {
            out.drawing_plane += count;
        }
        replaced_ends.0 |= a == 0;
        replaced_ends.1 |= b == n;
    }
    drop_completions_at_ends(placed, &on, replaced_ends);
    out
}

/// A free stretch of a stroke: its first and one-past-last index into the
/// stroke's drawn points (`on`), and the terrain points bounding it on
/// the left and the right.
type Span = (usize, usize, Option<Bound>, Option<Bound>);

/// The free stretches of the stroke's drawn points `on` (indices into
/// `placed.points` of the points that are not completions), each with
/// its bounds: the anchored point beside it, or at a stroke end the
/// ground the end stands on or, failing that, the silhouette it stops on
/// (a junction). Nothing on the observer's fixed ground is a landform's
/// foot.
fn free_spans(
    before: &RenderedView,
    proj: &SceneProjection,
    observer_radius_m: f64,
    placed: &StrokeMatch,
    on: &[usize],
) -> Vec<Span> {
    let n = on.len();
    let anchored = |k: usize| placed.points[k].source == PointSource::Silhouette;
    let bound_at = |k: usize, end: bool| -> Option<Bound> {
        let p = &placed.points[k];
        if anchored(k) {
            return (p.depth > observer_radius_m).then_some(Bound {
                world: p.world,
                depth: p.depth,
                junction: false,
            });
        }
        if !end {
            return None;
        }
        let px = p.pixel?;
        if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
            eprintln!(
                "end {px:?}: terrain below {:?}, ground {:?}, junction {:?}",
                terrain_below(before, px).map(|t| (t.1, t.2)),
                ground_under_end(before, px).map(|g| g.1),
                junction_under_end(before, px).map(|g| g.1)
            );
        }
        let (local, depth, junction) = match ground_under_end(before, px) {
            Some((local, depth)) => (local, depth, false),
            None => {
                let (local, depth) = junction_under_end(before, px)?;
                (local, depth, true)
            }
        };
        (depth > observer_radius_m).then_some(Bound {
            world: proj.own_to_world(local),
            depth,
            junction,
        })
    };
    let mut spans = Vec::new();
    let mut a = 0;
    while a < n {
        if anchored(on[a]) {
            a += 1;
            continue;
        }
        let mut b = a;
        while b < n && !anchored(on[b]) {
            b += 1;
        }
        let left = if a > 0 {
            bound_at(on[a - 1], false)
        } else {
            bound_at(on[a], true)
        };
        let right = if b < n {
            bound_at(on[b], false)
        } else {
            bound_at(on[b - 1], true)
        };
        spans.push((a, b, left, right));
        a = b;
    }
    spans
}

/// A stroke matched behind the silhouette it rises out of and falls back
/// into ([`super::tangent_rise`]): the anchors and ends on that silhouette
/// (at most [`AGREEMENT`] behind its depth `occluder`) are T-junctions,
/// lower bounds on the stroke's depth, not its ground.
fn occluded_bounds(spans: &mut [Span], occluder: f64) {
    for (_, _, left, right) in spans.iter_mut() {
        for q in [left, right].into_iter().flatten() {
            if q.depth <= occluder * (1.0 + AGREEMENT) {
                q.junction = true;
            }
        }
    }
}

/// The drawing plane of a stroke matched behind the outline it rises out
/// of and falls back into ([`super::tangent_rise`]): through the matched
/// feature's point under the stroke's highest point (farther than the
/// outline's depth `occluder` by more than [`AGREEMENT`]). What shows over
/// the outline is the hidden landform's summit, and its outline lies
/// across the line of sight there (Gain et al. 2009, section 3.1: a
/// silhouette stroke with no terrain under its ends stands on the plane
/// facing the viewer), not along the feature's crest, which may run in
/// depth far beyond the part that shows.
fn summit_plane(
    proj: &SceneProjection,
    placed: &StrokeMatch,
    on: &[usize],
    occluder: f64,
) -> Option<Surface> {
    let top = on
        .iter()
        .map(|&k| &placed.points[k])
        .filter(|p| {
            matches!(p.source, PointSource::Feature | PointSource::Tangent)
                && p.depth > occluder * (1.0 + AGREEMENT)
        })
        .filter_map(|p| p.pixel.map(|px| (px[1], p)))
        .min_by(|a, b| a.0.total_cmp(&b.0))?
        .1;
    Some(Surface::drawing_plane(
        proj.eye(),
        Bound {
            world: top.world,
            depth: top.depth,
            junction: false,
        },
    ))
}

/// Whether a free stretch keeps its matched feature's depth (see the
/// module documentation): most of its points lie on the feature, the
/// feature lies near it in the image or an anchor beside it agrees with
/// it, no stroke end stands on nearer ground, and the stretch neither cuts
/// the landform its anchors lie on nor leaves a farther silhouette into
/// the sky.
fn keeps_feature(
    before: &RenderedView,
    feature: Option<&ViewFeature>,
    near_px: f64,
    placed: &StrokeMatch,
    on: &[usize],
    (a, b, left_all, right_all): Span,
) -> bool {
    let n = on.len();
    // A junction bounds the stretch only from the near side: it
    // neither contradicts the feature nor names a landform it cuts.
    let (left, right) = (
        left_all.filter(|q| !q.junction),
        right_all.filter(|q| !q.junction),
    );
    // Stroke ends (not anchors) standing on nearer ground contradict.
    let contradicts = |bound: Option<Bound>, k: usize, is_end: bool| {
        let p = &placed.points[k];
        is_end && bound.is_some_and(|q| q.depth < p.depth * (1.0 - AGREEMENT))
    };
    let run_points: Vec<&PlacedPoint> = on[a..b].iter().map(|&k| &placed.points[k]).collect();
    let on_feature = run_points
        .iter()
        .filter(|p| p.source == PointSource::Feature)
        .count();
    // An anchor beside the stretch at the feature's depth: the stroke
    // leaves that silhouette along the feature's landform.
    let meets_anchor = |bound: Option<Bound>, k: usize, is_end: bool| {
        let p = &placed.points[k];
        !is_end
            && p.source == PointSource::Feature
            && bound.is_some_and(|q| (q.depth - p.depth).abs() <= AGREEMENT * q.depth)
    };
    let feature_ok = on_feature as f64 >= NEAR_COVERAGE * run_points.len() as f64
        && (feature.is_some_and(|f| near_in_image(f, &run_points, near_px))
            || meets_anchor(left, on[a], a == 0)
            || meets_anchor(right, on[b - 1], b == n))
        && !contradicts(left, on[a], a == 0)
        && !contradicts(right, on[b - 1], b == n)
        && !cuts_anchored_landform(before, &run_points, left, right)
        && !leaves_farther_silhouette(
            before,
            feature,
            &run_points,
            (
                left,
                (a > 0).then(|| placed.points[on[a - 1]].pixel).flatten(),
            ),
            (right, (b < n).then(|| placed.points[on[b]].pixel).flatten()),
        );
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        eprintln!(
            "stretch {a}..{b} of {n} (x {:?}..{:?}): on_feature {on_feature} near {:?} left {:?} right {:?} depth {} {}",
            placed.points[on[a]].pixel.map(|p| p[0]),
            placed.points[on[b - 1]].pixel.map(|p| p[0]),
            feature.map(|f| near_in_image(f, &run_points, near_px)),
            left.map(|q| q.depth),
            right.map(|q| q.depth),
            placed.points[on[a]].depth,
            placed.points[on[b - 1]].depth
        );
    }
    feature_ok
}

/// Puts the points `run` (indices into `placed.points`) at the depths
/// `depth_of(j, pixel)` gives the `j`-th of them, as fallback points;
/// a point with no depth stays as it was.
fn put_at_depths(
    proj: &SceneProjection,
    placed: &mut StrokeMatch,
    run: &[usize],
    depth_of: impl Fn(usize, [f64; 2]) -> Option<f64>,
) {
    for (j, &k) in run.iter().enumerate() {
        let Some(px) = placed.points[k].pixel else {
            continue;
        };
        if let Some(depth) = depth_of(j, px) {
            placed.points[k] = PlacedPoint {
                pixel: Some(px),
                world: proj.unproject(px, depth),
                depth,
                source: PointSource::Fallback,
            };
        }
    }
}

/// Drops the completion beyond a re-placed stroke end (`replaced_ends`:
/// the first, the last): that end stands on the terrain.
fn drop_completions_at_ends(placed: &mut StrokeMatch, on: &[usize], replaced_ends: (bool, bool)) {
    let n = on.len();
    if n > 0 && (replaced_ends.0 || replaced_ends.1) {
        let (first, last) = (on[0], on[n - 1]);
        let mut k = 0;
        placed.points.retain(|p| {
            let drop = p.source == PointSource::Completion
                && ((k < first && replaced_ends.0) || (k > last && replaced_ends.1));
            k += 1;
            !drop
        });
    }
}

/// A free stretch narrower than this many DEM cells at the depth of its
/// feature is finer than the DEM can draw there (the one-cell rule of
/// [`super::on_silhouette`], which anchors such stretches between two
/// anchors on one silhouette).
pub const DRAWABLE_CELLS: f64 = 1.0;

/// Where a free stretch drawn in the sky just over its feature goes when
/// the DEM cannot draw it at that feature's depth: it spans fewer than
/// [`DRAWABLE_CELLS`] cells there, so no change of that landform makes
/// the stroke's shape (the edit would change nothing and leave it
/// unfitted). A stretch over a silhouette that the DEM cannot draw there
/// is a landform behind it showing over it (Tassé et al. section 4: a
/// stroke that ends on another is occluded by it); it goes on the drawing
/// plane at the nearest depth where it spans one cell, the least the DEM
/// can draw. Only for a whole stroke (no part of it on an existing
/// silhouette: a short free stretch beside an anchored one is a detail of
/// the landform it leaves, not a landform), not one drawn over terrain (a
/// cut), nor one whose new depth lies off the DEM. `None`: the stretch
/// stays.
fn drawable_depth_behind(
    before: &RenderedView,
    proj: &SceneProjection,
    placed: &StrokeMatch,
    run: &[usize],
    near_px: f64,
) -> Option<Surface> {
    let pixels: Vec<[f64; 2]> = run.iter().filter_map(|&k| placed.points[k].pixel).collect();
    let (first, last) = (pixels.first()?, pixels.last()?);
    let wide = (last[0] - first[0]).abs();
    let mut depths: Vec<f64> = run
        .iter()
        .map(|&k| placed.points[k].depth)
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    if depths.is_empty() || !(wide > 0.0) {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let depth = depths[depths.len() / 2];
    let cell = DRAWABLE_CELLS * before.cell_px(depth);
    if !(cell.is_finite() && wide < cell) {
        return None;
    }
    if !mostly_in_sky(before, &pixels) {
        return None;
    }
    // A stroke straight within the fit's tolerance is drawn by the edge
    // of one cell, however much wider the cell is: the DEM can draw it at
    // its feature's depth.
    if chord_deviation_px(&pixels) <= super::fit::FIT_TOLERANCE_PX {
        return None;
    }
    // cell_px falls as 1 / depth: it equals `wide` at this depth.
    let drawable = depth * cell / wide;
    let behind =
        skyline_behind(before, &pixels, drawable, near_px, NEAR_COVERAGE).unwrap_or(drawable);
    drawing_plane_over_ground(proj, &pixels, behind)
}

/// The drawing plane at `depth` through the middle of `pixels`, when the
/// stroke's middle point there lies over the DEM and above its ground.
fn drawing_plane_over_ground(
    proj: &SceneProjection,
    pixels: &[[f64; 2]],
    depth: f64,
) -> Option<Surface> {
    let mid = pixels.get(pixels.len() / 2)?;
    let world = proj.unproject(*mid, depth);
    let ground = proj.terrain_height(world[0], world[1])?;
    if !(ground < world[2]) {
        return None;
    }
    Some(Surface::drawing_plane(
        proj.eye(),
        Bound {
            world,
            depth,
            junction: false,
        },
    ))
}

/// Share of a stroke between two T-junctions that must lie just over a
/// farther skyline for it to go there ([`behind_junctions`]): its ends
/// stop on the nearer silhouette, so only its middle can show over the
/// farther landform.
pub const JUNCTION_SKYLINE_SHARE: f64 = 0.25;

/// Where a whole stroke drawn in the sky goes when both its ends stop on
/// the silhouette of its own matched feature (T-junctions, Tassé et al.
/// section 5.2.2: an outline that ends on another is occluded by it) and
/// part of it (at least [`JUNCTION_SKYLINE_SHARE`]) lies just over a
/// skyline farther than that silhouette by more than [`AGREEMENT`]: the
/// stroke outlines that farther landform, raised behind the nearer one,
/// and goes on the drawing plane at its skyline's depth
/// ([`skyline_behind`]). `None`: the stroke keeps its feature's depth.
fn behind_junctions(
    before: &RenderedView,
    proj: &SceneProjection,
    placed: &StrokeMatch,
    run: &[usize],
    (left, right): (Option<Bound>, Option<Bound>),
    near_px: f64,
) -> Option<Surface> {
    let (Some(l), Some(r)) = (left, right) else {
        return None;
    };
    if !(l.junction && r.junction) {
        return None;
    }
    let on_feature = |q: Bound, k: usize| {
        let d = placed.points[k].depth;
        (q.depth - d).abs() <= AGREEMENT * q.depth
    };
    let (first, last) = (*run.first()?, *run.last()?);
    if !(on_feature(l, first) && on_feature(r, last)) {
        return None;
    }
    let pixels: Vec<[f64; 2]> = run.iter().filter_map(|&k| placed.points[k].pixel).collect();
    if !mostly_in_sky(before, &pixels) {
        return None;
    }
    let beyond = l.depth.max(r.depth) * (1.0 + AGREEMENT);
    let depth = skyline_behind(before, &pixels, beyond, near_px, JUNCTION_SKYLINE_SHARE)?;
    drawing_plane_over_ground(proj, &pixels, depth)
}

/// The largest distance, in pixels, of `pixels` from the straight line
/// through the first and the last (infinite where they coincide).
fn chord_deviation_px(pixels: &[[f64; 2]]) -> f64 {
    let (Some(a), Some(b)) = (pixels.first(), pixels.last()) else {
        return f64::INFINITY;
    };
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len = dx.hypot(dy);
    if !(len > 0.0) {
        return f64::INFINITY;
    }
    pixels
        .iter()
        .map(|p| ((p[0] - a[0]) * dy - (p[1] - a[1]) * dx).abs() / len)
        .fold(0.0, f64::max)
}

/// The largest distance, in pixels, by which a stroke may leave the
/// piecewise-linear outline through its heights at equal steps across it
/// and still count as drawn by cells that wide ([`shape_cells`]): half the
/// fit's one-pixel tolerance, the other half left to the surface between
/// the cells.
pub const SHAPE_TOLERANCE_PX: f64 = 0.5;

/// The most cells across [`shape_cells`] asks for.
pub const MAX_SHAPE_CELLS: usize = 64;

/// The fewest equal steps across a stroke (its `pixels`, drawn left to
/// right or right to left, one height per column) at which the
/// piecewise-linear outline through its heights at those steps stays
/// within [`SHAPE_TOLERANCE_PX`] of it: how many DEM cells across the
/// stroke must span for the terrain to draw its shape. `None` when the
/// stroke turns back on itself in the image or is not one pixel wide.
pub(super) fn shape_cells(pixels: &[[f64; 2]]) -> Option<usize> {
    let mut pts: Vec<[f64; 2]> = pixels.to_vec();
    if pts.first()?[0] > pts.last()?[0] {
        pts.reverse();
    }
    if pts.windows(2).any(|w| !(w[1][0] >= w[0][0])) {
        return None;
    }
    let (x0, x1) = (pts.first()?[0], pts.last()?[0]);
    let wide = x1 - x0;
    if !(wide >= 1.0) {
        return None;
    }
    let height_at = |x: f64| {
        let k = pts.partition_point(|p| p[0] < x).clamp(1, pts.len() - 1);
        let (p, q) = (pts[k - 1], pts[k]);
        let t = if q[0] > p[0] {
            (x - p[0]) / (q[0] - p[0])
        } else {
            0.0
        };
        p[1] + t.clamp(0.0, 1.0) * (q[1] - p[1])
    };
    (1..=MAX_SHAPE_CELLS).find(|&m| {
        let step = wide / m as f64;
        let knots: Vec<f64> = (0..=m).map(|j| height_at(x0 + j as f64 * step)).collect();
        pts.iter().all(|p| {
            let u = ((p[0] - x0) / step).clamp(0.0, m as f64);
            let j = (u.floor() as usize).min(m - 1);
            let t = u - j as f64;
            let line = knots[j] + t * (knots[j + 1] - knots[j]);
            (line - p[1]).abs() <= SHAPE_TOLERANCE_PX
        })
    })
}

/// Where a whole stroke drawn in the sky goes when neither end stands on
/// terrain and one or both stop on a silhouette (T-junctions, Tassé et
/// al. section 5.2.2: an outline that ends on another is occluded by it),
/// and no feature was matched near it: the landform lies behind those
/// silhouettes, also where they are the observer's own fixed ground. Over
/// a farther skyline (at least [`JUNCTION_SKYLINE_SHARE`] of it, beyond
/// the junctions by more than [`AGREEMENT`]) it outlines that landform
/// ([`skyline_behind`]); otherwise nothing in the image says how far
/// behind, and it goes to the nearest depth behind the junctions where
/// the DEM's cells can draw its shape ([`shape_cells`]). The paper's
/// fallback would keep it at the occluder's depth, where a landform a few
/// pixels tall and a fraction of a cell wide cannot be drawn: the edit
/// then changed nothing (a hill drawn over a plain's skyline, which the
/// ground 100 m from an eye 1.7 m up forms). `None`: the stroke stays
/// where the matcher put it.
fn behind_occluder(
    before: &RenderedView,
    proj: &SceneProjection,
    placed: &StrokeMatch,
    run: &[usize],
    near_px: f64,
) -> Option<Surface> {
    let ends = [
        placed.points[*run.first()?].pixel?,
        placed.points[*run.last()?].pixel?,
    ];
    if ends
        .iter()
        .any(|&px| ground_under_end(before, px).is_some())
    {
        return None;
    }
    let occluder = ends
        .iter()
        .filter_map(|&px| junction_under_end(before, px).map(|j| j.1))
        .fold(None, |m: Option<f64>, d| Some(m.map_or(d, |m| m.max(d))))?;
    let pixels: Vec<[f64; 2]> = run.iter().filter_map(|&k| placed.points[k].pixel).collect();
    if !mostly_in_sky(before, &pixels) {
        return None;
    }
    let beyond = occluder * (1.0 + AGREEMENT);
    let depth = match skyline_behind(before, &pixels, beyond, near_px, JUNCTION_SKYLINE_SHARE) {
        Some(d) => d,
        None => {
            let (first, last) = (pixels.first()?, pixels.last()?);
            let wide = (last[0] - first[0]).abs();
            let cells = shape_cells(&pixels)? as f64;
            // cell_px falls as 1 / depth: the stroke spans `cells` cells
            // where one cell is wide / cells pixels.
            let drawable = before.cell_px(1.0) * cells / wide;
            if !drawable.is_finite() {
                return None;
            }
            drawable.max(beyond)
        }
    };
    drawing_plane_over_ground(proj, &pixels, depth)
}

/// The depth of a farther skyline a stroke is drawn over: the median
/// depth of the skyline just under the stroke's points (within `near_px`
/// below each), where at least `share` of the points have one at
/// `min_depth` or farther. The stroke outlines that landform, raised over
/// the nearer one its ends stop on (Tassé et al. section 5.2.2: an outline
/// that ends on another is occluded by it), rather than a landform at the
/// least depth the DEM could draw it.
fn skyline_behind(
    before: &RenderedView,
    pixels: &[[f64; 2]],
    min_depth: f64,
    near_px: f64,
    share: f64,
) -> Option<f64> {
    let (w, h) = (before.camera.width, before.camera.height);
    let mut farther: Vec<f64> = pixels
        .iter()
        .filter_map(|&[x, y]| {
            if !(x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64) {
                return None;
            }
            let i = x as usize;
            let top = before.skyline_row[i]?;
            let below = top as f64 + 0.5 - y;
            (below >= 0.0 && below <= near_px).then(|| before.depth.depth[top * w + i] as f64)
        })
        .filter(|&d| d.is_finite() && d >= min_depth)
        .collect();
    if farther.is_empty() || (farther.len() as f64) < share * pixels.len() as f64 {
        return None;
    }
    farther.sort_by(f64::total_cmp);
    Some(farther[farther.len() / 2])
}

/// Anchors a stroke only passes: when both ends of the stroke are free
/// (neither starts on an existing silhouette), an anchored run inside it
/// whose free neighbours were both matched nearer than it (by more than
/// [`AGREEMENT`]) is a silhouette the new landform's outline happens to
/// run along for a few pixels (a hill in front of a far range whose
/// outline crosses an inner ridge of it), not a shoulder the stroke
/// leaves from: it bounds neither neighbour. Gain et al. (2009, section
/// 3.1) place a silhouette by the terrain under its *end points*; a
/// stroke whose ends stand on a silhouette keeps its anchors as bounds.
fn drop_passed_anchors(
    placed: &StrokeMatch,
    on: &[usize],
    spans: &mut [(usize, usize, Option<Bound>, Option<Bound>)],
) {
    let n = on.len();
    let is_anchor = |k: usize| placed.points[k].source == PointSource::Silhouette;
    if n == 0 || is_anchor(on[0]) || is_anchor(on[n - 1]) {
        return;
    }
    let matched_depth = |a: usize, b: usize| -> Option<f64> {
        let mut d: Vec<f64> = on[a..b]
            .iter()
            .map(|&k| &placed.points[k])
            .filter(|p| p.source == PointSource::Feature)
            .map(|p| p.depth)
            .collect();
        if d.is_empty() {
            return None;
        }
        d.sort_by(f64::total_cmp);
        Some(d[d.len() / 2])
    };
    for j in 1..spans.len() {
        let (a1, b1, ..) = spans[j - 1];
        let (a2, b2, ..) = spans[j];
        let anchor = placed.points[on[b1]].depth;
        let nearer = |d: Option<f64>| d.is_some_and(|d| d < anchor * (1.0 - AGREEMENT));
        if nearer(matched_depth(a1, b1)) && nearer(matched_depth(a2, b2)) {
            spans[j - 1].3 = None;
            spans[j].2 = None;
        }
    }
}

/// True when a stretch between two anchors on one landform (their depths
/// agree within [`AGREEMENT`]) is drawn into that landform: at most of its
/// points the unedited view shows terrain at the anchors' depth, while the
/// stretch's matched depth is another. The stroke then leaves the
/// silhouette and comes back to it lower: that landform is cut (Gain et
/// al. 2009, section 3.1: the vertical surface through the two anchors).
/// Raising a nearer feature to the stroke instead would leave the cut
/// terrain standing behind it as well (the ridge cut drawn along a
/// skyline that a near slope nearly meets).
fn cuts_anchored_landform(
    before: &RenderedView,
    run: &[&PlacedPoint],
    left: Option<Bound>,
    right: Option<Bound>,
) -> bool {
    let (Some(l), Some(r)) = (left, right) else {
        return false;
    };
    if (l.depth - r.depth).abs() > AGREEMENT * l.depth.min(r.depth) || run.is_empty() {
        return false;
    }
    let w = before.camera.width;
    let n = run.len();
    let (mut inside, mut elsewhere) = (0usize, 0usize);
    for (k, p) in run.iter().enumerate() {
        let anchor = l.depth + (r.depth - l.depth) * (k as f64 + 0.5) / n as f64;
        if (p.depth - anchor).abs() > SAME_LANDFORM * anchor {
            elsewhere += 1;
        }
        let Some((i, j)) = terrain_pixel(before, p.pixel) else {
            continue;
        };
        let d = before.depth.depth[j * w + i] as f64;
        if (d - anchor).abs() <= AGREEMENT * anchor {
            inside += 1;
        }
    }
    inside as f64 >= NEAR_COVERAGE * n as f64 && elsewhere as f64 >= NEAR_COVERAGE * n as f64
}

/// True when a stretch drawn in the sky (a raise: the unedited view shows
/// sky over at least [`NEAR_COVERAGE`] of its points) leaves an anchored
/// silhouette that lies behind its matched feature by more than
/// [`AGREEMENT`], where the feature does not itself run along that
/// silhouette (its depth at the anchor's column is not the anchor's), and
/// no anchor beside the stretch agrees with the feature. The stroke goes
/// on from that silhouette into the sky without a break, and the feature
/// it was matched to is another landform, nearer, that only lies under it
/// in the image: the stretch outlines the landform it leaves (Gain et al.
/// 2009, section 3.1: a silhouette stands on the terrain at its ends; a
/// person raising a peak starts and ends the stroke on the shoulders that
/// stay). Equation (1) prefers the nearer feature because the lift it
/// needs looks small in the image; raising it would hide the very
/// silhouette the stroke is anchored on. Where the feature does run along
/// the anchor (a skyline candidate that steps from the anchor's landform
/// to a nearer one at a T-junction, which the stroke follows), the match
/// stands. `left` and `right`: each bound with the pixel of the anchored
/// point it comes from (`None` at a stroke end).
fn leaves_farther_silhouette(
    before: &RenderedView,
    feature: Option<&ViewFeature>,
    run: &[&PlacedPoint],
    left: (Option<Bound>, Option<[f64; 2]>),
    right: (Option<Bound>, Option<[f64; 2]>),
) -> bool {
    let (Some(first), Some(last), Some(feature)) = (run.first(), run.last(), feature) else {
        return false;
    };
    // Some(true): the anchor lies behind the feature, which does not run
    // along the anchor's silhouette; Some(false): they agree somewhere.
    let relation = |bound: (Option<Bound>, Option<[f64; 2]>), p: &PlacedPoint| -> Option<bool> {
        let (Some(q), Some(at)) = bound else {
            return None;
        };
        if p.source != PointSource::Feature || q.junction {
            return None;
        }
        let along = feature_depth_at(feature, at[0])
            .is_some_and(|d| (d - q.depth).abs() <= AGREEMENT * q.depth);
        Some(p.depth < q.depth * (1.0 - AGREEMENT) && !along)
    };
    let (l, r) = (relation(left, first), relation(right, last));
    let behind = l == Some(true) || r == Some(true);
    let agrees = l == Some(false) || r == Some(false);
    if !behind || agrees {
        return false;
    }
    let in_sky = run
        .iter()
        .filter(|p| p.pixel.is_some() && terrain_pixel(before, p.pixel).is_none())
        .count();
    in_sky as f64 >= NEAR_COVERAGE * run.len() as f64
}

/// True when at least [`NEAR_COVERAGE`] of `pixels` show sky in the
/// unedited view: the stroke raises terrain there, it does not cut it.
fn mostly_in_sky(before: &RenderedView, pixels: &[[f64; 2]]) -> bool {
    let in_sky = pixels
        .iter()
        .filter(|&&p| terrain_pixel(before, Some(p)).is_none())
        .count();
    in_sky as f64 >= NEAR_COVERAGE * pixels.len() as f64
}

/// The depth of `feature` where it projects at image column `x`
/// (interpolated between its samples); `None` outside its span.
fn feature_depth_at(feature: &ViewFeature, x: f64) -> Option<f64> {
    let s = &feature.samples;
    let k = s.partition_point(|q| q.pixel[0] < x);
    if k == 0 {
        return s.first().filter(|q| !(q.pixel[0] > x)).map(|q| q.depth);
    }
    between_samples(s, k, x, |q| q.depth)
}

/// `value` of the feature samples `s` interpolated at image column `x`
/// between samples `k - 1` and `k` (`k` from a partition of `s` at `x`);
/// `None` when `k` is not inside `s`.
fn between_samples(
    s: &[FeatureSample],
    k: usize,
    x: f64,
    value: impl Fn(&FeatureSample) -> f64,
) -> Option<f64> {
    if k == 0 || k >= s.len() {
        return None;
    }
    let (l, r) = (&s[k - 1], &s[k]);
    let t = if r.pixel[0] > l.pixel[0] {
        (x - l.pixel[0]) / (r.pixel[0] - l.pixel[0])
    } else {
        0.0
    };
    Some(value(l) + t * (value(r) - value(l)))
}

/// The image pixel (column, row) under `pixel` when it lies in the view
/// and shows terrain, not sky.
fn terrain_pixel(before: &RenderedView, pixel: Option<[f64; 2]>) -> Option<(usize, usize)> {
    let [x, y] = pixel?;
    let (w, h) = (before.camera.width, before.camera.height);
    if !(x >= 0.0 && y >= 0.0 && x < w as f64 && y < h as f64) {
        return None;
    }
    let (i, j) = (x as usize, y as usize);
    (before.depth.triangle[j * w + i] != SKY).then_some((i, j))
}

/// A matched depth within this fraction of the anchors' is their
/// landform; one farther off, where the stroke's own pixels show the
/// anchors' landform, is another (at 2 km, 100 m: more than a cell of
/// the 30 to 90 m DEMs), which the stroke does not outline there.
pub const SAME_LANDFORM: f64 = 0.05;

/// Half-width (points) of the running median that smooths [`cut_depths`].
pub const CUT_MEDIAN_HALF: usize = 3;

/// For a free run drawn into the terrain (the unedited view shows terrain,
/// not sky, under at least [`NEAR_COVERAGE`] of its points, and the crest
/// of that terrain lies within `near_px` above them): per point, the
/// depth of the crest above it ([`crest_above`]: the skyline, or the
/// silhouette of a nearer landform), which is what the stroke cuts (the
/// crest is lowered onto the stroke at its own depth, as Tassé et al.
/// section 5.2.1 lower a feature drawn above the stroke; nearer terrain
/// left above the stroke is lowered by the rounds as protruding),
/// smoothed by a running median over the run. `None` everywhere for a run
/// drawn in the sky (a raise), and at points over sky.
fn cut_depths(
    before: &RenderedView,
    run: &[usize],
    placed: &StrokeMatch,
    near_px: f64,
) -> Vec<Option<f64>> {
    let shown: Vec<Option<f64>> = run
        .iter()
        .map(|&k| {
            let (i, j) = terrain_pixel(before, placed.points[k].pixel)?;
            // The crest above: the silhouette of the surface the stroke's
            // pixel shows, within `near_px` of the stroke (a stroke drawn
            // far under a crest does not cut it: at the crest's depth its
            // ray runs far under that landform's ground).
            let (row, depth) = crest_above(before, i, j)?;
            (j as f64 - row <= near_px).then_some(depth)
        })
        .collect();
    let inside = shown.iter().flatten().count();
    if run.is_empty() || (inside as f64) < NEAR_COVERAGE * run.len() as f64 {
        return vec![None; run.len()];
    }
    (0..shown.len())
        .map(|j| {
            shown[j]?;
            let lo = j.saturating_sub(CUT_MEDIAN_HALF);
            let hi = (j + CUT_MEDIAN_HALF + 1).min(shown.len());
            let mut near: Vec<f64> = shown[lo..hi].iter().flatten().copied().collect();
            near.sort_by(f64::total_cmp);
            Some(near[near.len() / 2])
        })
        .collect()
}

/// The crest of the surface that pixel `(i, j)` shows: the nearest
/// occlusion boundary above it in its column (a silhouette sample that
/// shows as a boundary, or the skyline), as its row and depth.
fn crest_above(view: &RenderedView, i: usize, j: usize) -> Option<(f64, f64)> {
    let w = view.camera.width;
    let y = j as f64 + 0.5;
    let mut best: Option<(f64, f64)> = view
        .skyline_row
        .get(i)
        .copied()
        .flatten()
        .filter(|&top| top <= j)
        .map(|top| (top as f64, view.depth.depth[top * w + i] as f64));
    for &(c, k) in &view.by_column[i] {
        let s = &view.silhouettes.curves[c as usize].samples[k as usize];
        if s.pixel[1] <= y && view.shows_as_boundary(s) && best.is_none_or(|b| s.pixel[1] > b.0) {
            best = Some((s.pixel[1], s.depth));
        }
    }
    best
}

/// Points of a run beyond its feature's ends (placed along the feature's
/// 3D end tangent by the matcher) keep the depth of the nearest point on
/// the feature instead: the feature says nothing about where its tangent
/// goes, and a tangent that runs toward or away from the eye builds walls.
fn hold_extension_depth(proj: &SceneProjection, placed: &mut StrokeMatch, run: &[usize]) {
    let on_feature: Vec<usize> = run
        .iter()
        .copied()
        .filter(|&k| placed.points[k].source == PointSource::Feature)
        .collect();
    for &k in run {
        if placed.points[k].source == PointSource::Feature {
            continue;
        }
        let Some(&nearest) = on_feature.iter().min_by_key(|&&j| j.abs_diff(k)) else {
            continue;
        };
        let depth = placed.points[nearest].depth;
        if let Some(px) = placed.points[k].pixel {
            placed.points[k] = PlacedPoint {
                pixel: Some(px),
                world: proj.unproject(px, depth),
                depth,
                source: PointSource::Tangent,
            };
        }
    }
}

/// A stretch kept at its matched feature's depth: its extension points
/// keep the depth of the feature's end ([`hold_extension_depth`]) and the
/// gaps through which a farther landform shows are bridged
/// ([`bridge_farther_gaps`]).
fn keep_on_feature(
    proj: &SceneProjection,
    placed: &mut StrokeMatch,
    run: &[usize],
    bounds: (Option<Bound>, Option<Bound>),
) {
    hold_extension_depth(proj, placed, run);
    bridge_farther_gaps(proj, placed, run, bounds);
}

/// A stroke end stands on the background it is drawn against, not on the
/// landform's foot, when its ground lies this many times farther than the
/// stretch's matched feature (see [`stands_on_background`]).
pub const BACKGROUND_RATIO: f64 = 2.0;

/// True when a stretch bounded by a junction at one end and ground at the
/// other has its matched feature at or behind the junction (the junction
/// bounds the depth from the near side) but the ground lies more than
/// [`BACKGROUND_RATIO`] times farther than the feature anywhere: the
/// outline comes down onto far ground seen past the landform (the valley
/// floor behind a new hill), which it occludes there. The drawing plane
/// through that ground (Gain et al.'s end rule) would make the landform as
/// many times taller to show so (hold-out 4's Vinschgau new hill: a hill
/// of +175 m 2.6-3.6 km away, its stroke's right end on ground 13.9 km
/// away, became 2,878 m of terrain); the feature between the junction and
/// the ground is the landform, as Tassé et al. place a stroke.
fn stands_on_background(
    placed: &StrokeMatch,
    run: &[usize],
    (left, right): (Option<Bound>, Option<Bound>),
    ends: (bool, bool),
) -> bool {
    // The ground must be a stroke end's (an anchor beside the stretch is
    // the landform's own silhouette, Gain et al.'s end point).
    let (junction, ground) = match (left, right) {
        (Some(j), Some(q)) if j.junction && !q.junction && ends.1 => (j, q),
        (Some(q), Some(j)) if j.junction && !q.junction && ends.0 => (j, q),
        _ => return false,
    };
    let depths: Vec<f64> = run
        .iter()
        .map(|&k| &placed.points[k])
        .filter(|p| p.source == PointSource::Feature)
        .map(|p| p.depth)
        .collect();
    if (depths.len() as f64) < NEAR_COVERAGE * run.len() as f64 || depths.is_empty() {
        return false;
    }
    let lo = depths.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = depths.iter().copied().fold(0.0, f64::max);
    lo >= junction.depth * (1.0 - AGREEMENT) && ground.depth > BACKGROUND_RATIO * hi
}

/// The points at a stroke end of a stretch kept on its feature (`ends`:
/// the stretch holds the stroke's first point, its last) that lie on a
/// piece of the feature at least [`GAP_BEHIND`] farther than the point
/// before them keep the nearer point's depth when the end stands on
/// ground that far (the stroke comes down there onto the ground seen past
/// the landform it outlines, the valley floor behind a new hill: its end
/// on that ground says the landform stands in front of it, an upper
/// bound, as a junction is a lower one), or when the end pixel shows
/// terrain nearer than the far piece by [`GAP_BEHIND`] (the gap is closed
/// on the end's side, as [`bridge_farther_gaps`] bridges a gap closed on
/// both). Placed on the far piece, the last points build a wall at the
/// background's depth, beyond the influence of the landform drawn (the
/// later passes of hold-out 4's Vinschgau new hill, whose re-matched
/// skyline runs from the raised hill 3 km away onto the valley 14.5 km
/// away at the stroke's last columns). A junction at the far piece's depth
/// is a lower bound the piece agrees with: the stroke goes on behind it
/// (a raised peak's shoulder), and the piece stays.
fn hold_background_ends(
    before: &RenderedView,
    proj: &SceneProjection,
    placed: &mut StrokeMatch,
    run: &[usize],
    ends: (bool, bool),
) {
    let n = run.len();
    if n < 2 {
        return;
    }
    for (is_end, order) in [
        (ends.0, (0..n).collect::<Vec<usize>>()),
        (ends.1, (0..n).rev().collect()),
    ] {
        if !is_end {
            continue;
        }
        // From the stroke end inward: the far run, then the nearer point.
        let depth = |i: usize| placed.points[run[order[i]]].depth;
        let Some(end_px) = placed.points[run[order[0]]].pixel else {
            continue;
        };
        let Some(m) = (1..n).find(|&i| depth(i) * (1.0 + GAP_BEHIND) <= depth(i - 1)) else {
            continue;
        };
        let near = depth(m);
        if !(0..m).all(|i| depth(i) >= near * (1.0 + GAP_BEHIND)) {
            continue;
        }
        // The end pixel shows that far ground (the stroke comes down onto
        // it), or nearer terrain that closes the gap on the end's side.
        let far = (0..m).map(depth).fold(f64::INFINITY, f64::min);
        // (a junction at the far run's depth is a lower bound the run
        // agrees with: the stroke goes on behind it)
        let on_far_ground =
            ground_under_end(before, end_px).is_some_and(|(_, d)| d >= near * (1.0 + GAP_BEHIND));
        let closes =
            terrain_below(before, end_px).is_some_and(|(_, d, _)| d * (1.0 + GAP_BEHIND) <= far);
        let shows = on_far_ground || closes;
        if !shows {
            continue;
        }
        let held: Vec<usize> = order[..m].iter().map(|&i| run[i]).collect();
        put_at_depths(proj, placed, &held, |_, _| Some(near));
    }
}

/// A gap of a stretch kept on its feature lies this fraction or more
/// behind the stretch's depth on both sides of it (a farther landform
/// seen through a gap in the nearer one; see [`bridge_farther_gaps`]).
pub const GAP_BEHIND: f64 = 0.3;

/// Points of a stretch kept on its feature that lie on a farther piece of
/// it, seen through a gap of the nearer landform the rest of the stretch
/// is on (at least [`GAP_BEHIND`] behind the stretch's nearer points, or
/// the anchors beside it, on both sides), are put at the depth between
/// those sides, linearly in image x. The stroke is one outline drawn in
/// the sky over both: where it does not leave the nearer landform in the
/// image (it is free, not on a silhouette), it outlines that landform
/// grown over the gap, as the paper's deformation cost prefers (the far
/// landform would have to rise by the depth ratio more for the same
/// outline, and every stroke point there would build a wall in the
/// valley between the two).
fn bridge_farther_gaps(
    proj: &SceneProjection,
    placed: &mut StrokeMatch,
    run: &[usize],
    (left, right): (Option<Bound>, Option<Bound>),
) {
    let real = |q: Option<Bound>| q.filter(|q| !q.junction);
    let side = |q: Option<Bound>, x: Option<f64>| real(q).zip(x).map(|(q, x)| (x, q.depth));
    let x_of = |k: usize| placed.points[k].pixel.map(|p| p[0]);
    let n = run.len();
    let mut bridged = Vec::new();
    let mut i = 0;
    while i < n {
        // The nearer side before point i: the previous point, or the
        // left anchor at the stretch's first point's x.
        let before = if i > 0 {
            x_of(run[i - 1]).map(|x| (x, placed.points[run[i - 1]].depth))
        } else {
            side(left, x_of(run[0]))
        };
        let Some((x0, d0)) = before else {
            i += 1;
            continue;
        };
        if placed.points[run[i]].depth < d0 * (1.0 + GAP_BEHIND) {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < n && placed.points[run[j]].depth >= d0 * (1.0 + GAP_BEHIND) {
            j += 1;
        }
        if j == i {
            // A depth that compares with nothing (not finite): no gap.
            i += 1;
            continue;
        }
        let after = if j < n {
            x_of(run[j]).map(|x| (x, placed.points[run[j]].depth))
        } else {
            side(right, x_of(run[n - 1]))
        };
        let Some((x1, d1)) = after else {
            i = j;
            continue;
        };
        let gap_min = run[i..j]
            .iter()
            .map(|&k| placed.points[k].depth)
            .fold(f64::INFINITY, f64::min);
        if gap_min < d1 * (1.0 + GAP_BEHIND) {
            i = j;
            continue;
        }
        for &k in &run[i..j] {
            if let Some(px) = placed.points[k].pixel {
                let t = if x1 != x0 {
                    ((px[0] - x0) / (x1 - x0)).clamp(0.0, 1.0)
                } else {
                    0.5
                };
                bridged.push((k, px, d0 + t * (d1 - d0)));
            }
        }
        i = j;
    }
    for (k, px, depth) in bridged {
        placed.points[k] = PlacedPoint {
            pixel: Some(px),
            world: proj.unproject(px, depth),
            depth,
            source: PointSource::Fallback,
        };
    }
}

/// True when `feature` projects under at least [`NEAR_COVERAGE`] of the
/// points, at a mean vertical distance of at most `near_px`.
fn near_in_image(feature: &ViewFeature, points: &[&PlacedPoint], near_px: f64) -> bool {
    let s = &feature.samples;
    let (mut sum, mut count) = (0.0, 0usize);
    for p in points {
        let Some([x, y]) = p.pixel else { continue };
        let k = s.partition_point(|q| q.pixel[0] < x);
        let Some(fy) = between_samples(s, k, x, |q| q.pixel[1]) else {
            continue;
        };
        sum += (fy - y).abs();
        count += 1;
    }
    count > 0
        && count as f64 >= NEAR_COVERAGE * points.len() as f64
        && sum / count as f64 <= near_px
}

/// The surface a free stretch is placed on: the vertical plane through two
/// terrain points, or the drawing plane through one.
struct Surface {
    point: [f64; 3],
    normal: [f64; 3],
    /// Depth used where a ray runs parallel to the surface.
    depth: f64,
    /// Depths the surface may give: on the vertical surface between two
    /// terrain points, those of the two points (widened by
    /// [`AGREEMENT`]). A ray that meets the plane beyond them (the two
    /// points nearly in line with the eye, or a stretch reaching past
    /// them) would otherwise place the stroke kilometres away, far under
    /// the terrain.
    range: (f64, f64),
}

impl Surface {
    fn new(proj: &SceneProjection, left: Option<Bound>, right: Option<Bound>) -> Surface {
        let eye = proj.eye();
        let horizontal = |v: [f64; 3]| [v[0], v[1], 0.0];
        // A junction is a lower bound: with a terrain point (an anchor or
        // the ground under the other end) as the other bound, the stretch
        // stands on the drawing plane through that point when it lies
        // behind the junction (or agrees with it), and through the
        // junction when the point is nearer than the silhouette that
        // occludes the stroke (an occluder is nearer than what it hides;
        // the nearer point is then itself a silhouette the stroke passes
        // in front of, as `Surface::new` reads two far-apart ends). With
        // junctions at both ends: through the farther.
        let (left, right) = match (left, right) {
            (Some(j), Some(q)) | (Some(q), Some(j)) if j.junction && !q.junction => {
                let at = if j.depth > q.depth * (1.0 + AGREEMENT) {
                    j
                } else {
                    q
                };
                return Self::drawing_plane(eye, at);
            }
            (Some(j), Some(k)) if j.junction && k.junction => {
                return Self::drawing_plane(eye, if j.depth > k.depth { j } else { k });
            }
            other => other,
        };
        match (left, right) {
            // Ends far apart in depth: the nearer is a silhouette the
            // stroke passes behind (a T-junction), the farther its own
            // landform.
            (Some(l), Some(r)) if (l.depth - r.depth).abs() > AGREEMENT * l.depth.min(r.depth) => {
                Self::drawing_plane(eye, if l.depth > r.depth { l } else { r })
            }
            (Some(l), Some(r)) => {
                let along = horizontal(sub(r.world, l.world));
                let len = along[0].hypot(along[1]);
                // Two points on one line of sight: the drawing plane
                // through the nearer.
                if len > 1e-6 * l.depth.max(r.depth) {
                    return Surface {
                        point: l.world,
                        normal: [-along[1] / len, along[0] / len, 0.0],
                        depth: 0.5 * (l.depth + r.depth),
                        range: (
                            l.depth.min(r.depth) * (1.0 - AGREEMENT),
                            l.depth.max(r.depth) * (1.0 + AGREEMENT),
                        ),
                    };
                }
                let near = if l.depth <= r.depth { l } else { r };
                Self::drawing_plane(eye, near)
            }
            (Some(q), None) | (None, Some(q)) => Self::drawing_plane(eye, q),
            (None, None) => Surface {
                point: eye,
                normal: [0.0, 0.0, 1.0],
                depth: 1.0,
                range: (0.0, f64::INFINITY),
            },
        }
    }

    /// The vertical plane through `q` facing the eye.
    fn drawing_plane(eye: [f64; 3], q: Bound) -> Surface {
        let v = sub(q.world, eye);
        let len = v[0].hypot(v[1]).max(1e-9);
        Surface {
            point: q.world,
            normal: [v[0] / len, v[1] / len, 0.0],
            depth: q.depth,
            range: (0.0, f64::INFINITY),
        }
    }

    /// Depth along the ray of `pixel` where it meets the surface.
    fn depth(&self, proj: &SceneProjection, pixel: [f64; 2]) -> Option<f64> {
        let eye = proj.eye();
        let dir = sub(proj.unproject(pixel, 1.0), eye);
        let den = dot(dir, self.normal);
        let t = if den.abs() > 1e-9 {
            dot(sub(self.point, eye), self.normal) / den
        } else {
            self.depth
        };
        (t.is_finite() && t > 0.0).then(|| t.clamp(self.range.0, self.range.1))
    }
}

/// What [`place_on_end_surface`] gives: per pixel, the world point and its
/// depth; and whether both ends stood on terrain.
pub type EndSurfacePlacement = (Vec<([f64; 3], f64)>, bool);

/// Where a whole stroke of `pixels` goes when it is placed as Gain et al.
/// (2009, section 3.1) place a silhouette stroke: on the vertical surface
/// through the terrain points under its two end pixels (the first terrain
/// at or below each, within [`END_TOUCH_PX`]), or on the drawing plane
/// through the one end that stands on terrain. Per pixel, the world point
/// and its depth; `None` when neither end stands on terrain beyond
/// `observer_radius_m`. The second value says whether both ends did. The
/// map-view landforms of [`crate::correct::landform`] place their
/// silhouettes with it, by the same geometry as the free stretches here.
pub fn place_on_end_surface(
    before: &RenderedView,
    proj: &SceneProjection,
    pixels: &[[f64; 2]],
    observer_radius_m: f64,
) -> Option<EndSurfacePlacement> {
    let bound = |px: [f64; 2]| {
        let (local, depth) = ground_under_end(before, px)?;
        (depth > observer_radius_m).then_some(Bound {
            world: proj.own_to_world(local),
            depth,
            junction: false,
        })
    };
    let (left, right) = (bound(*pixels.first()?), bound(*pixels.last()?));
    if left.is_none() && right.is_none() {
        return None;
    }
    let surface = Surface::new(proj, left, right);
    let placed = pixels
        .iter()
        .map(|&px| {
            let depth = surface.depth(proj, px)?;
            Some((proj.unproject(px, depth), depth))
        })
        .collect::<Option<Vec<_>>>()?;
    Some((placed, left.is_some() && right.is_some()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chords_deviation_is_the_farthest_point_from_it() {
        // a 3 px bump; its ends on the chord
        let pixels = [[0.0, 0.0], [5.0, 3.0], [10.0, 0.0]];
        assert!((chord_deviation_px(&pixels) - 3.0).abs() < 1e-12);
        let slanted = [[0.0, 0.0], [3.0, 4.0], [6.0, 8.0]];
        assert!(chord_deviation_px(&slanted) < 1e-12);
        assert!(chord_deviation_px(&[[1.0, 1.0], [1.0, 1.0]]).is_infinite());
        assert!(chord_deviation_px(&[]).is_infinite());
    }

    /// A parabola 14 px tall and 162 px wide: its chord error over m
    /// equal steps is 14 / m^2 px, within half a pixel from m = 6.
    #[test]
    fn shape_cells_of_a_parabola() {
        let pixels: Vec<[f64; 2]> = (0..=162)
            .map(|i| {
                let u = i as f64 / 81.0 - 1.0;
                [100.0 + i as f64, 170.0 - 14.0 * (1.0 - u * u)]
            })
            .collect();
        assert_eq!(shape_cells(&pixels), Some(6));
        let mut back = pixels.clone();
        back.reverse();
        assert_eq!(shape_cells(&back), Some(6));
    }

    /// A straight stroke needs one cell; one that turns back in the image
    /// has no single height per column.
    #[test]
    fn shape_cells_of_a_line_and_a_loop() {
        assert_eq!(
            shape_cells(&[[0.0, 10.0], [50.0, 20.0], [100.0, 30.0]]),
            Some(1)
        );
        assert_eq!(
            shape_cells(&[[0.0, 10.0], [50.0, 20.0], [40.0, 30.0]]),
            None
        );
    }
}
