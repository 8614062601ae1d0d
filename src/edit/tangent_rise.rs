//! A stroke that rises out of one silhouette and falls back into it: a
//! landform appearing from behind that silhouette (issue 11, item 3).
//!
//! Both ends of such a stroke lie within the fit's pixel
//! ([`FIT_TOLERANCE_PX`]) of one occluding silhouette, and the stroke's
//! middle stands above it: both ends are T-junctions with it (Tassé et
//! al. section 5.2.2: an outline that ends on another is occluded by it;
//! Gain et al. 2009 read T-junctions as depth-order cues too). The
//! silhouette is then not the stroke's landform but a lower bound on its
//! depth. Equation (1) cannot see this: `E_dis` and `E_def` both measure
//! the vertical pixel offset between stroke and feature, and a feature
//! hidden behind the silhouette projects below it in every column, so the
//! occluder itself is always the cheaper match. Here the stroke is matched
//! again, to the cheapest candidate of its priority list (the usual costs)
//! that lies hidden behind the occluder in every column where both are
//! seen: farther than it by more than [`AGREEMENT`] and not above it in
//! the image. With no such candidate the match stands.
//!
//! The reading needs a stroke that comes out from behind the outline:
//! its highest point stands more than the fit's pixel above both its ends
//! ([`Occluder::falls_back`]; a stroke whose top is an end climbs with the
//! outline). And it needs an outline with no summit of its own under the
//! stroke's bump ([`Occluder::own_summit`]): where the outline peaks where
//! the stroke peaks, that summit raised is the reading that needs no
//! hidden landform (a raised own summit on a coarse DEM, which the
//! DEM's cells could draw no better than a hidden one); a flat skyline
//! under the bump has no landform there for the stroke to outline. The
//! points anchored on the outline then go with the landform behind
//! (`pipeline::demands`), and the stroke stands on the drawing plane
//! through the matched feature's point under its top
//! (`stretch_placement::summit_plane`): what shows over the outline is
//! the hidden summit, not the feature's whole crest.

use std::collections::HashMap;

use super::fit::FIT_TOLERANCE_PX;
use super::rendered_view::RenderedView;
use super::stretch_placement::{shape_cells, AGREEMENT, NEAR_IN_IMAGE_RAD};
use crate::render::SKY;
use crate::sketch::{
    complete_feature, place_on_candidate, Candidate, FeatureKind, MatchKind, PriorityList,
    SceneProjection, SketchOptions, Stroke, StrokeMatch, ViewProjection,
};

/// The silhouette a stroke rises out of and falls back into: its image
/// row and depth in each column it covers under the stroke.
#[derive(Debug, Clone)]
pub struct Occluder {
    /// Column -> (row, depth) of the curve's samples.
    rows: HashMap<usize, (f64, f64)>,
    /// Column -> the stroke's row there.
    stroke: HashMap<usize, f64>,
}

impl Occluder {
    /// The occluder's median depth under the stroke.
    pub fn depth(&self) -> f64 {
        let mut d: Vec<f64> = self.rows.values().map(|r| r.1).collect();
        d.sort_by(f64::total_cmp);
        d.get(d.len() / 2).copied().unwrap_or(f64::NAN)
    }

    /// The outline's and the stroke's profiles across the stroke's
    /// columns, left to right: (column, outline row, outline depth,
    /// stroke row).
    fn profile(&self) -> Vec<(usize, f64, f64, f64)> {
        let mut cols: Vec<usize> = self.rows.keys().copied().collect();
        cols.sort_unstable();
        cols.into_iter()
            .filter_map(|i| {
                let (r, d) = self.rows[&i];
                self.stroke.get(&i).map(|&y| (i, r, d, y))
            })
            .collect()
    }

    /// Whether the stroke falls back into the outline: its highest point
    /// stands more than the fit's pixel above both of its ends (a stroke
    /// whose top is an end meets the outline there rising with it, and
    /// does not come out from behind it).
    pub fn falls_back(&self) -> bool {
        let p = self.profile();
        let (Some(first), Some(last)) = (p.first(), p.last()) else {
            return false;
        };
        let top = p.iter().map(|q| q.3).fold(f64::INFINITY, f64::min);
        top < first.3.min(last.3) - FIT_TOLERANCE_PX
    }

    /// Whether the outline's own landform has a summit under the stroke's
    /// own bump (the columns where the stroke stands more than half its
    /// largest height over the line through its two ends: where its shape
    /// peaks): the outline's highest point there has the outline more
    /// than the fit's pixel lower somewhere on each side of it within the
    /// stroke's columns. The outline then peaks where the stroke does,
    /// and raising that summit is the reading that needs no hidden
    /// landform; a flat outline under the stroke's bump, or one that only
    /// climbs across it, has no landform of its own there for the stroke
    /// to be the outline of.
    pub fn own_summit(&self) -> bool {
        let p = self.profile();
        let (Some(&first), Some(&last)) = (p.first(), p.last()) else {
            return false;
        };
        let chord = |i: usize| {
            let t = if last.0 > first.0 {
                (i - first.0) as f64 / (last.0 - first.0) as f64
            } else {
                0.0
            };
            first.3 + t * (last.3 - first.3)
        };
        let hmax = p.iter().map(|q| chord(q.0) - q.3).fold(0.0f64, f64::max);
        let Some((k, top)) = p
            .iter()
            .enumerate()
            .filter(|(_, q)| chord(q.0) - q.3 > 0.5 * hmax)
            .min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))
        else {
            return false;
        };
        let lower = |q: &(usize, f64, f64, f64)| q.1 > top.1 + FIT_TOLERANCE_PX;
        p[..k].iter().any(lower) && p[k + 1..].iter().any(lower)
    }

    fn at(&self, x: f64) -> Option<(f64, f64)> {
        if !(x.is_finite() && x >= 0.0) {
            return None;
        }
        self.rows.get(&(x.floor() as usize)).copied()
    }
}

/// Share of a candidate's own points that must lie in the stroke's
/// columns for it to count as hidden behind the outline there.
pub const OCCLUDER_COVERAGE: f64 = 0.5;

fn column(before: &RenderedView, x: f64) -> Option<usize> {
    let w = before.camera.width;
    (x.is_finite() && x >= 0.0 && w > 0).then(|| (x.floor() as usize).min(w - 1))
}

/// The outline the view shows under `pixel` in its column: the topmost
/// occlusion boundary (a silhouette sample showing as one, or the
/// skyline) at or below the pixel, within the fit's pixel above it, as
/// its row and depth. `None` when the pixel lies in the terrain (more
/// than that pixel under the outline) or nothing is under it.
fn outline_under(before: &RenderedView, pixel: [f64; 2]) -> Option<(f64, f64)> {
    let i = column(before, pixel[0])?;
    let (w, h) = (before.camera.width, before.camera.height);
    let top = pixel[1] - FIT_TOLERANCE_PX;
    if top >= 0.0 && (top as usize) < h && before.depth.triangle[top as usize * w + i] != SKY {
        return None;
    }
    let mut best: Option<(f64, f64)> = None;
    for &(c, k) in &before.by_column[i] {
        let s = &before.silhouettes.curves[c as usize].samples[k as usize];
        if s.pixel[1] >= top && before.shows_as_boundary(s) && best.is_none_or(|b| s.pixel[1] < b.0)
        {
            best = Some((s.pixel[1], s.depth));
        }
    }
    if let Some(j) = before.skyline_row[i].filter(|&j| j > 0 && j as f64 >= top) {
        if best.is_none_or(|b| (j as f64) < b.0) {
            let d = before.depth.depth[j * w + i] as f64;
            if d.is_finite() {
                best = Some((j as f64, d));
            }
        }
    }
    best
}

/// The outline a prepared stroke (left to right) rises out of and
/// falls back into: both its ends lie within [`FIT_TOLERANCE_PX`] of the
/// outline the view shows under them (a T-junction with it, tangential:
/// within the fit's pixel), the stroke stands above that outline (within
/// that pixel) in every column, and more than that pixel above it
/// somewhere. The outline is the topmost boundary under the stroke,
/// whichever silhouette curves make it up (a skyline of several crests
/// reads as one outline in the image).
pub fn occluder_of(before: &RenderedView, stroke: &Stroke) -> Option<Occluder> {
    let pixels = &stroke.points;
    let (first, last) = (*pixels.first()?, *pixels.last()?);
    let mut rows = HashMap::new();
    let mut stroke_rows = HashMap::new();
    let mut rise = 0.0f64;
    // Every column the stroke crosses, at the stroke's row there (its
    // points may lie several columns apart).
    let (i0, i1) = (column(before, first[0])?, column(before, last[0])?);
    for i in i0..=i1 {
        let x = i as f64 + 0.5;
        let y = stroke.y_at_clamped(x);
        let x = x.clamp(first[0], last[0]);
        let (row, depth) = outline_under(before, [x, y])?;
        rise = rise.max(row - y);
        rows.insert(i, (row, depth));
        stroke_rows.insert(i, y);
    }
    for p in pixels {
        let (row, _) = outline_under(before, *p)?;
        rise = rise.max(row - p[1]);
    }
    let on = |p: [f64; 2]| {
        column(before, p[0])
            .and_then(|i| rows.get(&i))
            .is_some_and(|r: &(f64, f64)| (r.0 - p[1]).abs() <= FIT_TOLERANCE_PX)
    };
    if !(on(first) && on(last) && rise > FIT_TOLERANCE_PX) {
        return None;
    }
    Some(Occluder {
        rows,
        stroke: stroke_rows,
    })
}

/// The median depth of a candidate's own (not extended) points.
fn candidate_depth(c: &Candidate) -> f64 {
    let mut d: Vec<f64> = c
        .points
        .iter()
        .filter(|p| !p.extended)
        .map(|p| p.depth)
        .collect();
    d.sort_by(f64::total_cmp);
    d.get(d.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Whether a candidate lies behind the outline: none of its own points in
/// the stroke's columns lies in front of the outline there by more than
/// [`AGREEMENT`] or projects above it by more than the fit's pixel (the
/// outline bounds it from the near side; where the candidate itself makes
/// the outline, it is on it), its median depth is beyond the outline's by
/// more than [`AGREEMENT`], and at least [`OCCLUDER_COVERAGE`] of its own
/// points lie in the stroke's columns.
fn hidden_behind(occ: &Occluder, c: &Candidate, near_px: f64) -> bool {
    let own: Vec<_> = c.points.iter().filter(|p| !p.extended).collect();
    let mut seen = 0usize;
    for p in &own {
        let Some((row, depth)) = occ.at(p.pixel[0]) else {
            continue;
        };
        seen += 1;
        if !(p.depth >= depth * (1.0 - AGREEMENT) && p.pixel[1] >= row - FIT_TOLERANCE_PX) {
            return false;
        }
    }
    // Near the stroke in the image (as `stretch_placement` asks of a
    // feature that describes a stretch): a feature far under it is not
    // what it outlines.
    let offset = own
        .iter()
        .map(|p| (p.pixel[1] - p.deformed_pixel[1]).abs())
        .sum::<f64>()
        / own.len().max(1) as f64;
    seen > 0
        && seen as f64 >= OCCLUDER_COVERAGE * own.len() as f64
        && candidate_depth(c) > occ.depth() * (1.0 + AGREEMENT)
        && offset <= near_px
}

/// Matches again a stroke that rises out of one silhouette and falls back
/// into it (see the module documentation), when it was matched on or in
/// front of that silhouette: to the cheapest candidate of its priority
/// list hidden behind it. Returns the occluder's depth (a lower bound on
/// the stroke's) when the stroke was matched again.
pub fn match_behind_occluder(
    before: &RenderedView,
    proj: &SceneProjection,
    stroke: &Stroke,
    list: &PriorityList,
    options: &SketchOptions,
    placed: &mut StrokeMatch,
) -> Option<f64> {
    let debug = std::env::var_os("DEMSKETCH_DEBUG").is_some();
    let occ = occluder_of(before, stroke)?;
    let near_px = NEAR_IN_IMAGE_RAD * proj.focal_px();
    let occ_depth = occ.depth();
    let current = placed.candidate.and_then(|a| list.candidates.get(a));
    let current_depth = current.map(candidate_depth);
    if debug {
        eprintln!(
            "tangent rise {}: occluder depth {:.0}, matched {:?} at {:?}",
            stroke.id,
            occ_depth,
            placed.feature_id.map(|f| f % (1 << 40)),
            current_depth.map(|d| d.round())
        );
    }
    if debug && std::env::var_os("DEMSKETCH_DEBUG_PROFILE").is_some() {
        for (i, r, d, y) in occ.profile() {
            eprintln!(
                "profile {} {i} outline {r:.1} depth {d:.0} stroke {y:.1}",
                stroke.id
            );
        }
    }
    if current_depth.is_some_and(|d| d > occ_depth * (1.0 + AGREEMENT)) {
        return None;
    }
    let (falls_back, own_summit) = (occ.falls_back(), occ.own_summit());
    if debug {
        eprintln!(
            "tangent rise {}: falls back {falls_back}, outline's own summit under it {own_summit}",
            stroke.id
        );
    }
    if !falls_back || own_summit {
        return None;
    }
    // The outline's own landform, raised, is the reading that needs no
    // hidden one (the paper's preference for the nearer feature): kept
    // where the DEM's cells at the outline's depth can draw the stroke's
    // shape ([`shape_cells`]: as many cells as its outline needs steps).
    let (x0, x1) = (stroke.points.first()?[0], stroke.points.last()?[0]);
    let cells_across = (x1 - x0).abs() / before.cell_px(occ_depth);
    let needed = shape_cells(&stroke.points);
    if debug {
        eprintln!(
            "tangent rise {}: {:.2} cells across at the outline's depth, shape needs {:?}",
            stroke.id, cells_across, needed
        );
    }
    if !needed.is_some_and(|m| cells_across < m as f64) {
        return None;
    }
    let (a, cand) = list
        .candidates
        .iter()
        .enumerate()
        .find(|(_, c)| hidden_behind(&occ, c, near_px))?;
    let mut pts = place_on_candidate(stroke, cand, proj);
    if pts.is_empty() {
        return None;
    }
    if options.feature_completion {
        pts = complete_feature(
            &pts,
            proj,
            options.completion_step_m,
            options.completion_max_m,
            0.25,
        );
    }
    if debug {
        eprintln!(
            "tangent rise {}: matched behind to feature {} {:?} at {:.0} m, cost {:.2}",
            stroke.id,
            cand.feature_id % (1 << 40),
            cand.kind,
            candidate_depth(cand),
            cand.costs.total
        );
    }
    placed.kind = match cand.kind {
        FeatureKind::Silhouette => MatchKind::Silhouette,
        FeatureKind::Ridge => MatchKind::Ridge,
    };
    placed.feature_id = Some(cand.feature_id);
    placed.candidate = Some(a);
    placed.costs = Some(cand.costs);
    placed.points = pts;
    Some(occ_depth)
}
