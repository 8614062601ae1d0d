//! Strokes that already lie on the unedited terrain's silhouettes (issue 11,
//! Tassé et al. 2014 section 5.2: a stroke "already satisfied" by a feature
//! needs no deformation there).
//!
//! A person tracing a silhouette that is already right draws within about a
//! pixel of it, whichever feature the matcher then picks for the stroke and
//! at whatever depth it would place the rest. Those parts of a stroke are
//! *anchored*: each placed point whose pixel column of the unedited view
//! has an occlusion boundary within [`ON_SILHOUETTE_PX`] of it takes the
//! terrain point that forms that boundary (its position and depth), and
//! becomes a [`PointSource::Silhouette`] point. Where a column has several
//! boundaries that close (a crest grazing a farther skyline), the choice
//! keeps the stroke on one silhouette from point to point rather than
//! taking the nearest row each time ([`continuous_choice`]); a piece of a
//! run narrower than [`MIN_RUN_PX`] on another landform (a hand-drawn
//! stroke touching a foreground crest for a point or two) is the stroke
//! crossing that silhouette, and stays with the landform on either side of
//! it ([`crossings`]). A run between two free stretches that lies behind
//! the stroke's matched feature there is the stroke passing within a pixel
//! of a farther landform, which the feature raised to the stroke will hide:
//! it is freed and follows the feature ([`drop_runs_behind_feature`]).
//! The pipeline holds the
//! terrain under anchored points where it is (cell constraints at the input
//! heights) instead of constraining a curve there, so an edit whose strokes
//! all lie on existing silhouettes changes nothing, and a stroke that
//! follows the skyline except where a peak should rise moves only the
//! peak.
//!
//! Hand-drawn strokes wander: a short stretch (at most [`MAX_GAP_PX`] wide)
//! between anchored points, or between one and the stroke's end, is
//! anchored too where it stays within [`GAP_TOLERANCE_PX`] of a boundary;
//! so is a stretch between two anchors on one silhouette that is narrower
//! than one DEM cell seen from there (the DEM cannot draw such a detail),
//! unless it runs off the boundaries under it (`runs_off`): a whole
//! stretch a pixel or two over the silhouette asks to move it.
//! Feature completion at an anchored end is dropped: that end already sits
//! on the terrain. In the later passes of an edit the view is the terrain
//! the passes before made, whose silhouette beside a stroke is often their
//! own near miss of it: the two looser rules then hold only on boundaries
//! the view as drawn on showed there too ([`TracedBoundaries`]), so those
//! near misses are placed again rather than held as if traced.

use super::rendered_view::RenderedView;
use crate::sketch::{PlacedPoint, PointSource, SceneProjection, StrokeMatch, ViewProjection};

/// A stroke point lies on a silhouette when one is this close in its column:
/// the fit's own tolerance ([`super::fit::FIT_TOLERANCE_PX`]), so that no point is held where
/// the fit would count it unfitted.
pub const ON_SILHOUETTE_PX: f64 = super::fit::FIT_TOLERANCE_PX;
/// ... or this close, inside a short stretch next to anchored points.
pub const GAP_TOLERANCE_PX: f64 = 3.0;
/// The widest such stretch, pixels.
pub const MAX_GAP_PX: f64 = 40.0;

/// A boundary of a later pass's view within this many pixels of one the
/// view as drawn on showed in the same column is that boundary, not moved
/// by the passes before ([`TracedBoundaries`]).
pub const UNMOVED_PX: f64 = 0.25;

/// In a later pass, a stroke point in a short gap is still held on a
/// boundary the passes before moved when it lies this near it: the fit's
/// own tolerance (a column the fit counts is not placed again).
pub const MOVED_TOLERANCE_PX: f64 = ON_SILHOUETTE_PX;

/// The terrain point forming an occlusion boundary of a view.
#[derive(Debug, Clone, Copy)]
struct BoundaryPoint {
    /// Image row of the boundary.
    row: f64,
    /// Local frame of the view (eye at the origin), metres.
    local: [f64; 3],
    depth: f64,
    /// The row is a sub-pixel boundary (a silhouette sample), not the
    /// first terrain pixel row of the skyline.
    precise: bool,
}

/// Every boundary of `view`'s column under `pixel` within `tol` pixels of
/// it: the silhouette samples, then the skyline's first terrain row (from
/// the depth buffer) where it is nearer than every sample or where the
/// column has none (the walk can lose a stretch of the skyline where it
/// passes behind a nearer crest). Where several boundaries lie that close
/// (a crest grazing a farther skyline), the stroke alone does not say
/// which it follows; [`continuous_choice`] decides.
fn boundaries_near(view: &RenderedView, pixel: [f64; 2], tol: f64) -> Vec<BoundaryPoint> {
    let w = view.camera.width;
    if !(pixel[0] >= 0.0 && pixel[0].is_finite()) {
        return Vec::new();
    }
    let i = (pixel[0].floor() as usize).min(w.saturating_sub(1));
    let mut near: Vec<BoundaryPoint> = Vec::new();
    for &(c, s) in &view.by_column[i] {
        let sample = &view.silhouettes.curves[c as usize].samples[s as usize];
        // (the fit's own notion of a boundary: a point held on a crest the
        // fit does not count would stay unfitted)
        if !view.shows_as_boundary(sample) {
            continue;
        }
        let row = sample.pixel[1];
        if (row - pixel[1]).abs() <= tol {
            near.push(BoundaryPoint {
                row,
                local: sample.local,
                depth: sample.depth,
                precise: true,
            });
        }
    }
    let Some(j) = view.skyline_row[i].filter(|&j| j > 0) else {
        return near;
    };
    let dy = (j as f64 - pixel[1]).abs();
    let nearest_sample = near
        .iter()
        .map(|b| (b.row - pixel[1]).abs())
        .fold(f64::INFINITY, f64::min);
    if dy > tol || nearest_sample <= dy {
        return near;
    }
    if let Some(hit) = view.depth.hit(&view.terrain, i, j) {
        near.push(BoundaryPoint {
            row: j as f64,
            local: hit.local,
            depth: hit.distance,
            precise: false,
        });
    }
    near
}

/// The boundary of `view`'s column under `pixel` nearest to it, if within
/// `tol` pixels (the first of equally near ones in [`boundaries_near`]'s
/// order).
fn nearest_boundary(view: &RenderedView, pixel: [f64; 2], tol: f64) -> Option<BoundaryPoint> {
    nearest_of(&boundaries_near(view, pixel, tol), pixel[1])
}

fn nearest_of(near: &[BoundaryPoint], row: f64) -> Option<BoundaryPoint> {
    let mut best: Option<BoundaryPoint> = None;
    for b in near {
        if best.is_none_or(|a| (b.row - row).abs() < (a.row - row).abs()) {
            best = Some(*b);
        }
    }
    best
}

/// Two boundary points belong to one silhouette when their depths differ
/// by at most [`RUN_DEPTH_STEP`] of the nearer.
fn same_silhouette(a: &BoundaryPoint, b: &BoundaryPoint) -> bool {
    (a.depth - b.depth).abs() <= RUN_DEPTH_STEP * a.depth.min(b.depth)
}

/// What passing from one silhouette to another between neighbouring
/// stroke points costs the choice of anchors, in pixels of offset: the
/// on-silhouette tolerance, so that a boundary within the tolerance that
/// keeps the stroke on one silhouette is always preferred to a slightly
/// nearer one on another, and a single point is never sent to a farther
/// landform and back (that costs two steps).
pub const SILHOUETTE_STEP_PX: f64 = ON_SILHOUETTE_PX;

/// Chooses one boundary per stroke point among those near it (`near[k]`,
/// empty where none is), over each run of consecutive points that have
/// one: the choice that minimises the summed row offsets plus
/// [`SILHOUETTE_STEP_PX`] for every step from one silhouette to another
/// between neighbours (a Viterbi pass). A person tracing a crest follows
/// that crest; where it grazes a farther skyline within a pixel, the
/// nearest boundary alone would flick single points to the far landform,
/// kilometres behind. With one boundary per point this is the nearest
/// boundary.
fn continuous_choice(near: &[Vec<BoundaryPoint>], rows: &[f64]) -> Vec<Option<BoundaryPoint>> {
    let n = near.len();
    let mut out: Vec<Option<BoundaryPoint>> = vec![None; n];
    let mut a = 0;
    while a < n {
        if near[a].is_empty() {
            a += 1;
            continue;
        }
        let mut b = a + 1;
        while b < n && !near[b].is_empty() {
            b += 1;
        }
        // cost[k][c], back[k][c] over the run a..b
        let mut cost: Vec<Vec<f64>> = Vec::with_capacity(b - a);
        let mut back: Vec<Vec<usize>> = Vec::with_capacity(b - a);
        for k in a..b {
            let off = |c: &BoundaryPoint| (c.row - rows[k]).abs();
            if k == a {
                cost.push(near[k].iter().map(off).collect());
                back.push(vec![0; near[k].len()]);
                continue;
            }
            let prev = &cost[k - a - 1];
            let mut row_cost = Vec::with_capacity(near[k].len());
            let mut row_back = Vec::with_capacity(near[k].len());
            for c in &near[k] {
                let mut best = (f64::INFINITY, 0);
                for (p, pc) in near[k - 1].iter().enumerate() {
                    let step = if same_silhouette(pc, c) {
                        0.0
                    } else {
                        SILHOUETTE_STEP_PX
                    };
                    if prev[p] + step < best.0 {
                        best = (prev[p] + step, p);
                    }
                }
                row_cost.push(best.0 + off(c));
                row_back.push(best.1);
            }
            cost.push(row_cost);
            back.push(row_back);
        }
        let last = cost.len() - 1;
        let mut c = 0;
        for (m, &v) in cost[last].iter().enumerate() {
            if v < cost[last][c] {
                c = m;
            }
        }
        for k in (a..b).rev() {
            out[k] = Some(near[k][c]);
            c = back[k - a][c];
        }
        a = b;
    }
    out
}

/// Runs of anchored points narrower than this (pixels of x) are a stroke
/// crossing a silhouette, not following it, unless they are the whole
/// stroke.
pub const MIN_RUN_PX: f64 = 8.0;
/// Neighbouring anchored points follow one silhouette when their depths
/// differ by less than this fraction (used for the sub-cell stretches
/// between two anchors).
pub const RUN_DEPTH_STEP: f64 = 0.05;

/// Half-width (pixels of x) of the neighbourhood over which a stroke's
/// offset from the boundary it is anchored on is averaged.
pub const OFFSET_WINDOW_PX: f64 = 6.0;
/// A stroke runs off its boundary when its mean offset there exceeds this
/// (pixels): the fit tolerance of 1 px plus what tracing adds (a careful
/// hand wanders by up to 0.7 px, two renderers of one surface differ by a
/// few tenths).
pub const OFFSET_TOLERANCE_PX: f64 = 1.0;
/// ... over at least this much of image x.
pub const MIN_OFFSET_RUN_PX: f64 = 6.0;

/// Removes the anchors of points around which the stroke runs off its
/// boundary systematically: where the mean signed offset (stroke row minus
/// boundary row) of the anchored points within [`OFFSET_WINDOW_PX`] of x
/// exceeds [`OFFSET_TOLERANCE_PX`] over at least [`MIN_OFFSET_RUN_PX`] of
/// x. Only sub-pixel
/// boundaries (silhouette samples) count; the skyline's first terrain row
/// is a pixel coarse. A person tracing a silhouette that is right wanders
/// to both sides of it, and that averages out over a few pixels; a stretch
/// drawn consistently a pixel or two above or below it asks for a change,
/// which the fit would otherwise report as missing while anchoring held
/// the terrain. Returns which points were refused, so that the looser gap
/// tolerance does not anchor them again.
fn drop_offset_stretches(hits: &mut [Option<BoundaryPoint>], pixels: &[[f64; 2]]) -> Vec<bool> {
    let n = hits.len();
    let mut refused = vec![false; n];
    for k in 0..n {
        if !hits[k].is_some_and(|h| h.precise) {
            continue;
        }
        let (mut sum, mut count) = (0.0, 0usize);
        for m in 0..n {
            if let Some(h) = hits[m].filter(|h| h.precise) {
                if (pixels[m][0] - pixels[k][0]).abs() <= OFFSET_WINDOW_PX {
                    sum += pixels[m][1] - h.row;
                    count += 1;
                }
            }
        }
        refused[k] = (sum / count.max(1) as f64).abs() > OFFSET_TOLERANCE_PX;
    }
    // A stretch narrower than a few pixels is a wobble of the hand or a
    // step between two boundaries, not a change asked for.
    let mut a = 0;
    while a < n {
        if !refused[a] {
            a += 1;
            continue;
        }
        let mut b = a + 1;
        while b < n && refused[b] {
            b += 1;
        }
        if (pixels[b - 1][0] - pixels[a][0]).abs() < MIN_OFFSET_RUN_PX {
            refused[a..b].fill(false);
        }
        a = b;
    }
    for (h, &r) in hits.iter_mut().zip(&refused) {
        if r {
            *h = None;
        }
    }
    refused
}

/// True when the stroke points `pixels` run off the boundary rows `rows`
/// beside them (one row per point): a mean distance over
/// [`OFFSET_TOLERANCE_PX`] on a stretch at least [`MIN_OFFSET_RUN_PX`]
/// wide. The looser anchoring of gaps between anchors uses it: a stretch
/// 2 px under the skyline between two points on it is a cut asked for,
/// not a wandering hand, and so is a stretch that crosses from under one
/// boundary to over the next (a ridge cut through between them). Most of
/// such a stretch would be more than the fit's pixel off the boundary, so
/// anchoring it could only leave the stroke unfitted.
fn runs_off(pixels: &[[f64; 2]], rows: &[f64]) -> bool {
    let (Some(first), Some(last)) = (pixels.first(), pixels.last()) else {
        return false;
    };
    if (last[0] - first[0]).abs() < MIN_OFFSET_RUN_PX || rows.len() != pixels.len() {
        return false;
    }
    let mean = pixels
        .iter()
        .zip(rows)
        .map(|(p, r)| (p[1] - r).abs())
        .sum::<f64>()
        / rows.len() as f64;
    mean > OFFSET_TOLERANCE_PX
}

/// Keeps `found` (one boundary per point of an unanchored stretch) as the
/// silhouette the stretch runs off when every point has one and they lie
/// on one landform (depths within [`RUN_DEPTH_STEP`]): a stroke drawn a
/// pixel or two off a silhouette along its length asks to move that
/// silhouette by the offset. Placed anywhere else (another feature the
/// matcher found near it), the edit would turn the pixel between
/// anchoring and not into tens of metres of terrain (a Zion identity case
/// whose stroke ran 1.00 px off its silhouette on average changed nothing,
/// and 53 m on the same DEM with +-5 cm of noise).
fn keep_near(near_of: &mut [Option<BoundaryPoint>], found: &[Option<BoundaryPoint>]) {
    let depths: Vec<f64> = found.iter().flatten().map(|h| h.depth).collect();
    if depths.len() != found.len() || depths.is_empty() {
        return;
    }
    // A point at either end of the stretch may lie on the landform beside
    // it (the stretch starts where the silhouette passes from one
    // landform to the other): it moves that landform's silhouette.
    let mut sorted = depths.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let off = |d: f64| (d - median).abs() > RUN_DEPTH_STEP * median;
    let first = depths.iter().position(|&d| !off(d)).unwrap_or(0);
    let last = depths.iter().rposition(|&d| !off(d)).unwrap_or(0);
    if first > 1 || depths.len() - 1 - last > 1 {
        return;
    }
    let inner = &depths[first..=last];
    let lo = inner.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = inner.iter().copied().fold(0.0, f64::max);
    if hi - lo <= RUN_DEPTH_STEP * lo {
        near_of.copy_from_slice(found);
    }
}

/// Removes the anchors of runs (consecutive anchored points) that span less
/// than [`MIN_RUN_PX`] of image x, unless a run is the whole stroke: a
/// stroke crossing a silhouette is not drawn along it. A run may pass from
/// one boundary to another: where cells look large, neighbouring columns'
/// boundaries are formed by different cells at different depths, within a
/// pixel of each other in the image. `xs` are the points' image x.
fn drop_short_runs(hits: &mut [Option<BoundaryPoint>], xs: &[f64]) {
    let n = hits.len();
    for (a, b) in anchored_runs(hits) {
        let whole = a == 0 && b == n;
        if !whole && (xs[b - 1] - xs[a]).abs() < MIN_RUN_PX {
            for h in &mut hits[a..b] {
                *h = None;
            }
        }
    }
}

/// The runs of consecutive anchored points (`Some`) of `hits`, as
/// half-open index ranges `(first, end)`, in order.
fn anchored_runs(hits: &[Option<BoundaryPoint>]) -> Vec<(usize, usize)> {
    let n = hits.len();
    let mut runs = Vec::new();
    let mut a = 0;
    while a < n {
        if hits[a].is_none() {
            a += 1;
            continue;
        }
        let mut b = a + 1;
        while b < n && hits[b].is_some() {
            b += 1;
        }
        runs.push((a, b));
        a = b;
    }
    runs
}

/// Neighbouring anchored points lie on different landforms when their
/// depths differ by more than this fraction of the nearer (the placement's
/// agreement, [`super::stretch_placement::AGREEMENT`]).
pub const CROSSING_DEPTH_STEP: f64 = 0.15;

/// What [`crossings`] makes of a piece of an anchored run that crosses
/// another landform's silhouette.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Crossing {
    /// Not a crossing.
    No,
    /// Between two pieces of the run on one landform: the stroke goes on
    /// along that landform, interpolated between them.
    Between,
    /// At the run's edge: the point is free (placed with the stretch
    /// beside it), never anchored on that silhouette again.
    Edge,
}

/// Pieces of anchored runs that cross another landform's silhouette
/// (Tassé et al. section 5.2.3: a stroke is one feature, each point at
/// that feature's depth). A run is cut where neighbouring points' depths
/// differ by more than [`CROSSING_DEPTH_STEP`]; a piece narrower than
/// [`MIN_RUN_PX`] of image x, in a run that also has a piece at least that
/// wide, is the stroke passing over a nearer (or farther) silhouette that
/// comes within the on-silhouette tolerance of it for a few pixels (a
/// hand-drawn stroke touching a foreground crest, a skyline trace passing
/// a nearer peak's tip), as [`drop_short_runs`] reads a short run on its
/// own. Such a piece between two wide pieces whose depths agree is
/// [`Crossing::Between`]; at the edge of a run, next to a free stretch,
/// beside a wide piece, it is [`Crossing::Edge`]. A narrow piece between
/// two pieces at different depths, or at a stroke's end, is left anchored:
/// a skyline traced where a farther range shows between two nearer crests
/// (or at the end of one) steps through every depth on the way.
fn crossings(hits: &[Option<BoundaryPoint>], xs: &[f64]) -> Vec<Crossing> {
    let n = hits.len();
    let mut out = vec![Crossing::No; n];
    let apart = |a: &BoundaryPoint, b: &BoundaryPoint| {
        (a.depth - b.depth).abs() > CROSSING_DEPTH_STEP * a.depth.min(b.depth)
    };
    for (a, b) in anchored_runs(hits) {
        // Pieces of the run a..b, cut at depth steps.
        let mut pieces: Vec<(usize, usize)> = Vec::new();
        let mut start = a;
        for k in a + 1..b {
            if let (Some(p), Some(q)) = (hits[k - 1], hits[k]) {
                if apart(&p, &q) {
                    pieces.push((start, k));
                    start = k;
                }
            }
        }
        pieces.push((start, b));
        let wide = |&(s, e): &(usize, usize)| (xs[e - 1] - xs[s]).abs() >= MIN_RUN_PX;
        if pieces.len() > 1 && pieces.iter().any(wide) {
            for (j, piece) in pieces.iter().enumerate() {
                if wide(piece) {
                    continue;
                }
                let (s, e) = *piece;
                let left = (j > 0).then(|| pieces[j - 1]);
                let right = pieces.get(j + 1).copied();
                let kind = match (left, right) {
                    // Between two pieces on one landform.
                    (Some(l), Some(r)) if wide(&l) && wide(&r) => {
                        match (hits[l.1 - 1], hits[r.0]) {
                            (Some(p), Some(q)) if !apart(&p, &q) => Crossing::Between,
                            _ => Crossing::No,
                        }
                    }
                    // At the run's edge next to a free stretch, the rest
                    // of the run on another landform.
                    (None, Some(r)) if s > 0 && wide(&r) => Crossing::Edge,
                    (Some(l), None) if e < n && wide(&l) => Crossing::Edge,
                    _ => Crossing::No,
                };
                out[s..e].fill(kind);
            }
        }
    }
    out
}

/// Applies [`crossings`] to `hits`: points of a piece between two on one
/// landform take the interpolation of that landform's two nearest anchored
/// points (as a sub-cell stretch between two anchors does); points of a
/// piece at a run's edge lose their anchor and are marked in `refused`,
/// so that the looser gap tolerance does not anchor them on that
/// silhouette again.
fn drop_crossings(hits: &mut [Option<BoundaryPoint>], xs: &[f64], refused: &mut [bool]) {
    let kinds = crossings(hits, xs);
    let n = hits.len();
    let mut a = 0;
    while a < n {
        if kinds[a] == Crossing::No {
            a += 1;
            continue;
        }
        let mut b = a + 1;
        while b < n && kinds[b] == kinds[a] {
            b += 1;
        }
        match kinds[a] {
            Crossing::Between => {
                if let (Some(l), Some(r)) = (hits[a - 1], hits[b]) {
                    let (x0, x1) = (xs[a - 1], xs[b]);
                    for m in a..b {
                        hits[m] = Some(between(&l, &r, (xs[m] - x0) / (x1 - x0).max(1e-9)));
                    }
                }
            }
            _ => {
                for m in a..b {
                    hits[m] = None;
                    refused[m] = true;
                }
            }
        }
        a = b;
    }
}

/// Removes the anchors of a run that lies between two free stretches at
/// least [`MIN_RUN_PX`] wide, where every anchored point is more than
/// [`CROSSING_DEPTH_STEP`] behind the stroke's matched feature at that
/// point (`feature_depths`: the depth the matched feature gives each point,
/// `None` where it gives none). Tassé et al. (5.2.3) place every point of
/// a stroke at its one feature's depth: the feature, raised to the stroke
/// on both sides of the run, stands in front of that farther silhouette
/// and hides it, so the stroke outlines the feature there too; the run is
/// the stroke passing within a pixel of the farther landform, not tracing
/// it.
fn drop_runs_behind_feature(
    hits: &mut [Option<BoundaryPoint>],
    xs: &[f64],
    feature_depths: &[Option<f64>],
) {
    let n = hits.len();
    let free_width = |a: usize, b: usize| (xs[b - 1] - xs[a]).abs();
    // Maximal runs of anchored points.
    let runs = anchored_runs(hits);
    let mut freed: Vec<(usize, usize)> = Vec::new();
    for (j, &(a, b)) in runs.iter().enumerate() {
        if a == 0 || b == n {
            continue;
        }
        let left_end = if j > 0 { runs[j - 1].1 } else { 0 };
        let right_end = runs.get(j + 1).map_or(n, |r| r.0);
        if free_width(left_end, a) < MIN_RUN_PX || free_width(b, right_end) < MIN_RUN_PX {
            continue;
        }
        let behind = (a..b).all(|m| match (hits[m], feature_depths[m]) {
            (Some(h), Some(f)) => h.depth > (1.0 + CROSSING_DEPTH_STEP) * f,
            _ => false,
        });
        if behind {
            freed.push((a, b));
        }
    }
    for (a, b) in freed {
        for h in &mut hits[a..b] {
            *h = None;
        }
    }
}

/// The point a share `t` (clamped to 0..1) of the way from boundary `l` to
/// boundary `r`, in row, position and depth.
fn between(l: &BoundaryPoint, r: &BoundaryPoint, t: f64) -> BoundaryPoint {
    let t = t.clamp(0.0, 1.0);
    let lerp = |u: f64, v: f64| u + t * (v - u);
    BoundaryPoint {
        row: lerp(l.row, r.row),
        local: [
            lerp(l.local[0], r.local[0]),
            lerp(l.local[1], r.local[1]),
            lerp(l.local[2], r.local[2]),
        ],
        depth: lerp(l.depth, r.depth),
        precise: false,
    }
}

/// The rows, column by column, of the boundaries a view showed before an
/// edit changed anything: where the sketcher may have traced a silhouette.
/// A later pass of an edit renders the terrain the passes before made; a
/// boundary there within [`GAP_TOLERANCE_PX`] of a stroke may be the
/// edit's own near miss of it, not a silhouette the hand traced, and is
/// taken with the looser tolerance only where the view as drawn on showed
/// that boundary there too, within [`UNMOVED_PX`] ([`anchor_on_silhouettes`]).
#[derive(Debug, Clone, Default)]
pub struct TracedBoundaries {
    rows: Vec<Vec<f32>>,
}

impl TracedBoundaries {
    /// The boundaries of `view` (those the fit counts, and the skyline).
    pub fn of(view: &RenderedView) -> Self {
        let rows = (0..view.camera.width)
            .map(|i| {
                let mut r: Vec<f32> = view.by_column[i]
                    .iter()
                    .map(|&(c, s)| &view.silhouettes.curves[c as usize].samples[s as usize])
                    .filter(|sample| view.shows_as_boundary(sample))
                    .map(|sample| sample.pixel[1] as f32)
                    .collect();
                if let Some(j) = view.skyline_row[i].filter(|&j| j > 0) {
                    r.push(j as f32);
                }
                r
            })
            .collect();
        TracedBoundaries { rows }
    }

    /// True when a boundary lies within `tol` pixels of `pixel`'s row in
    /// its column.
    fn near(&self, pixel: [f64; 2], tol: f64) -> bool {
        if !(pixel[0] >= 0.0 && pixel[0].is_finite()) || self.rows.is_empty() {
            return false;
        }
        let i = (pixel[0].floor() as usize).min(self.rows.len() - 1);
        self.rows[i]
            .iter()
            .any(|&r| (r as f64 - pixel[1]).abs() <= tol)
    }
}

/// Anchors the points of `placed` that lie on a boundary of `before` (the
/// view the stroke is placed on; see the module documentation).
/// `traced`: in a later pass of an edit, the boundaries of the view as the
/// sketcher drew on it; the looser tolerance of short gaps then holds only
/// on boundaries it showed there too ([`TracedBoundaries`]). `None`: `before`
/// is that view. Returns the share of the stroke's points anchored (0 to
/// 1).
pub fn anchor_on_silhouettes(
    before: &RenderedView,
    proj: &SceneProjection,
    placed: &mut StrokeMatch,
    traced: Option<&TracedBoundaries>,
) -> f64 {
    let on_stroke: Vec<usize> = (0..placed.points.len())
        .filter(|&k| placed.points[k].source != PointSource::Completion)
        .filter(|&k| placed.points[k].pixel.is_some())
        .collect();
    if on_stroke.is_empty() {
        return 0.0;
    }
    let px = |k: usize| placed.points[k].pixel.unwrap_or([f64::NAN; 2]);
    let n = on_stroke.len();
    let pixels: Vec<[f64; 2]> = on_stroke.iter().map(|&k| px(k)).collect();
    let near: Vec<Vec<BoundaryPoint>> = pixels
        .iter()
        .map(|&p| boundaries_near(before, p, ON_SILHOUETTE_PX))
        .collect();
    let mut hits = continuous_choice(&near, &pixels.iter().map(|p| p[1]).collect::<Vec<_>>());
    let dbg = |what: &str, hits: &[Option<BoundaryPoint>]| {
        if std::env::var_os("DEMSKETCH_DEBUG_ANCHOR").is_some() {
            let s: String = hits
                .iter()
                .map(|h| if h.is_some() { '#' } else { '.' })
                .collect();
            eprintln!("anchor {what:>10}: {s}");
        }
    };
    dbg("choice", &hits);
    let chosen = hits.clone();
    let mut refused = drop_offset_stretches(&mut hits, &pixels);
    dbg("offset", &hits);
    let xs: Vec<f64> = pixels.iter().map(|p| p[0]).collect();
    drop_short_runs(&mut hits, &xs);
    dbg("short", &hits);
    drop_crossings(&mut hits, &xs, &mut refused);
    dbg("crossings", &hits);
    // Short stretches beside anchored points, within the looser tolerance.
    // Those that run off a silhouette instead (refused above, or failing
    // `runs_off` here) keep that silhouette in `near_of`.
    let mut near_of: Vec<Option<BoundaryPoint>> = vec![None; n];
    let mut a = 0;
    while a < n {
        if hits[a].is_some() {
            a += 1;
            continue;
        }
        let mut b = a;
        while b < n && hits[b].is_none() {
            b += 1;
        }
        // Unanchored run a..b, bounded by anchors (or the stroke's ends).
        let left = if a > 0 { Some(a - 1) } else { None };
        let right = (b < n).then_some(b);
        let x0 = px(on_stroke[left.unwrap_or(a)])[0];
        let x1 = px(on_stroke[right.unwrap_or(b - 1)])[0];
        let refused_here = refused[a..b].iter().any(|&r| r);
        // The stretch runs off the silhouettes beside it (every point has
        // one within the gap tolerance): it asks to move them.
        let mut runs_off_here = false;
        if !refused_here && (left.is_some() || right.is_some()) && (x1 - x0).abs() <= MAX_GAP_PX {
            let loose: Vec<Option<BoundaryPoint>> = (a..b)
                .map(|m| nearest_boundary(before, px(on_stroke[m]), GAP_TOLERANCE_PX))
                .collect();
            let rows: Vec<f64> = loose.iter().flatten().map(|h| h.row).collect();
            if std::env::var_os("DEMSKETCH_DEBUG_ANCHOR").is_some() {
                let d: Vec<String> = (a..b)
                    .zip(&loose)
                    .map(|(m, h)| {
                        let p = px(on_stroke[m]);
                        h.map_or(format!("{:.1}:-", p[0]), |h| {
                            format!("{:.1}:{:+.2}@{:.0}", p[0], h.row - p[1], h.depth)
                        })
                    })
                    .collect();
                eprintln!(
                    "gap {a}..{b}: {} runs_off {}",
                    d.join(" "),
                    runs_off(&pixels[a..b], &rows)
                );
            }
            // In a later pass, a boundary the view as drawn on showed there
            // too; one the passes before moved only within
            // [`MOVED_TOLERANCE_PX`].
            let drawn_on = traced.is_none_or(|t| {
                (a..b).zip(&loose).all(|(m, h)| {
                    let p = px(on_stroke[m]);
                    h.is_some_and(|h| {
                        (h.row - p[1]).abs() <= MOVED_TOLERANCE_PX
                            || t.near([p[0], h.row], UNMOVED_PX)
                    })
                })
            });
            let all_found = loose.iter().all(|h| h.is_some());
            runs_off_here = all_found && runs_off(&pixels[a..b], &rows);
            if drawn_on && all_found && !runs_off_here {
                for (m, h) in (a..b).zip(loose) {
                    hits[m] = h;
                }
                a = b;
                continue;
            }
            if traced.is_none() && all_found {
                keep_near(&mut near_of[a..b], &loose);
            }
        } else if traced.is_none() && refused_here {
            keep_near(&mut near_of[a..b], &chosen[a..b]);
        }
        // Narrower than one cell of the DEM seen from there, between two
        // anchors on one silhouette: the DEM cannot draw such a detail, so
        // the stretch stays as the silhouette beside it has it.
        if let (Some(l), Some(r)) = (left.and_then(|l| hits[l]), right.and_then(|r| hits[r])) {
            let same = (l.depth - r.depth).abs() <= RUN_DEPTH_STEP * l.depth.min(r.depth);
            // (The straight line between the anchors' rows is not the
            // silhouette inside a cell, which the bilinear patch curves: a
            // stroke traced on it may stand off that line by pixels.)
            // In a later pass, only between anchors on boundaries the view
            // as drawn on showed there too: where the passes before moved
            // the silhouette, the stretch is their near miss, not a detail
            // the sketcher traced.
            let drawn_on = traced
                .is_none_or(|t| t.near([x0, l.row], UNMOVED_PX) && t.near([x1, r.row], UNMOVED_PX));
            if same
                && drawn_on
                && !refused_here
                && !runs_off_here
                && (x1 - x0).abs() < before.cell_px(0.5 * (l.depth + r.depth))
            {
                for m in a..b {
                    let t = (px(on_stroke[m])[0] - x0) / (x1 - x0).max(1e-9);
                    hits[m] = Some(between(&l, &r, t));
                }
            }
        }
        a = b;
    }
    // The depth the matched feature gave each point, before anchoring.
    let feature_depths: Vec<Option<f64>> = on_stroke
        .iter()
        .map(|&k| {
            let p = &placed.points[k];
            (p.source == PointSource::Feature && p.depth.is_finite()).then_some(p.depth)
        })
        .collect();
    dbg("gaps", &hits);
    drop_runs_behind_feature(&mut hits, &xs, &feature_depths);
    dbg("behind", &hits);
    let mut anchored = 0;
    for ((&k, hit), near) in on_stroke.iter().zip(&hits).zip(&near_of) {
        if let Some(h) = hit {
            let p = &mut placed.points[k];
            *p = PlacedPoint {
                pixel: p.pixel,
                world: proj.own_to_world(h.local),
                depth: h.depth,
                source: PointSource::Silhouette,
            };
            anchored += 1;
        } else if let (Some(h), Some(px)) = (near, placed.points[k].pixel) {
            placed.points[k] = PlacedPoint {
                pixel: Some(px),
                world: proj.unproject(px, h.depth),
                depth: h.depth,
                source: PointSource::NearSilhouette,
            };
        }
    }
    // Completion at an anchored end: that end is on the terrain already.
    let first_anchored = hits.first().is_some_and(|h| h.is_some());
    let last_anchored = hits.last().is_some_and(|h| h.is_some());
    let (first, last) = (on_stroke[0], on_stroke[n - 1]);
    let mut k = 0;
    placed.points.retain(|p| {
        let keep = p.source != PointSource::Completion
            || !((k < first && first_anchored) || (k > last && last_anchored));
        k += 1;
        keep
    });
    anchored as f64 / n as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn boundary(row: f64) -> Option<BoundaryPoint> {
        Some(BoundaryPoint {
            row,
            local: [0.0, 1000.0, 0.0],
            depth: 1000.0,
            precise: true,
        })
    }

    /// A stroke traced along a boundary at row 100 with the given offsets,
    /// one point every 2 px.
    fn traced(offsets: &[f64]) -> (Vec<Option<BoundaryPoint>>, Vec<[f64; 2]>) {
        let hits = offsets.iter().map(|_| boundary(100.0)).collect();
        let pixels = offsets
            .iter()
            .enumerate()
            .map(|(k, o)| [10.0 + 2.0 * k as f64, 100.0 + o])
            .collect();
        (hits, pixels)
    }

    #[test]
    fn jitter_to_both_sides_stays_anchored() {
        let offsets: Vec<f64> = (0..40)
            .map(|k| if k % 2 == 0 { 0.7 } else { -0.6 })
            .collect();
        let (mut hits, pixels) = traced(&offsets);
        let refused = drop_offset_stretches(&mut hits, &pixels);
        assert!(refused.iter().all(|r| !r));
        assert!(hits.iter().all(|h| h.is_some()));
    }

    #[test]
    fn a_stretch_drawn_consistently_below_is_refused() {
        // On the boundary, then 1.3 px below it over 30 px, then on it again.
        let offsets: Vec<f64> = (0..60)
            .map(|k| if (20..35).contains(&k) { 1.3 } else { 0.1 })
            .collect();
        let (mut hits, pixels) = traced(&offsets);
        let refused = drop_offset_stretches(&mut hits, &pixels);
        assert!(refused[24..31].iter().all(|&r| r));
        assert!(refused[..15].iter().all(|&r| !r) && refused[42..].iter().all(|&r| !r));
        assert!(hits[27].is_none() && hits[5].is_some());
    }

    #[test]
    fn a_gap_drawn_under_the_boundary_runs_off() {
        // 2 px under the boundary over 20 px: a cut asked for.
        let pixels: Vec<[f64; 2]> = (0..10).map(|k| [10.0 + 2.0 * k as f64, 102.0]).collect();
        assert!(runs_off(&pixels, &[100.0; 10]));
        // Under one boundary, then over the next: off too.
        let across: Vec<f64> = (0..10).map(|k| if k < 6 { 100.0 } else { 104.0 }).collect();
        assert!(runs_off(&pixels, &across));
        // Wandering half a pixel to both sides is a hand's.
        let wander: Vec<[f64; 2]> = (0..10)
            .map(|k| [10.0 + 2.0 * k as f64, if k % 2 == 0 { 100.5 } else { 99.4 }])
            .collect();
        assert!(!runs_off(&wander, &[100.0; 10]));
        // Narrower than MIN_OFFSET_RUN_PX: a wobble.
        assert!(!runs_off(&pixels[..2], &[100.0; 2]));
    }

    #[test]
    fn a_short_step_off_the_boundary_stays_anchored() {
        // 1.5 px off over 4 px of x (three points): a wobble, not a change.
        let offsets: Vec<f64> = (0..40)
            .map(|k| if (18..21).contains(&k) { 1.5 } else { 0.0 })
            .collect();
        let (mut hits, pixels) = traced(&offsets);
        let refused = drop_offset_stretches(&mut hits, &pixels);
        assert!(refused.iter().all(|r| !r), "{refused:?}");
        assert!(hits.iter().all(|h| h.is_some()));
    }

    fn at(row: f64, depth: f64) -> BoundaryPoint {
        BoundaryPoint {
            row,
            local: [0.0, depth, 0.0],
            depth,
            precise: true,
        }
    }

    #[test]
    fn a_crest_grazing_a_farther_skyline_keeps_its_depth() {
        // A stroke along a crest 9.6 km away (row 100) that grazes a
        // skyline 15 km away (row 100.6) at points 3 and 6, where the
        // stroke happens to lie nearer the skyline.
        let rows = [100.1, 100.0, 100.2, 100.5, 100.1, 100.0, 100.45, 100.1];
        let near: Vec<Vec<BoundaryPoint>> = rows
            .iter()
            .enumerate()
            .map(|(k, _)| {
                let mut v = vec![at(100.0, 9600.0 + k as f64)];
                if k == 3 || k == 6 {
                    v.push(at(100.6, 15000.0));
                }
                v
            })
            .collect();
        let nearest: Vec<f64> = (0..rows.len())
            .map(|k| nearest_of(&near[k], rows[k]).map_or(0.0, |b| b.depth))
            .collect();
        assert_eq!(
            nearest[3], 15000.0,
            "the nearest boundary flicks to the skyline"
        );
        let chosen = continuous_choice(&near, &rows);
        assert!(chosen.iter().all(|b| b.is_some_and(|b| b.depth < 9700.0)));
    }

    #[test]
    fn a_stroke_passing_from_one_silhouette_to_another_follows_both() {
        // Points 0-4 on a near crest only, 5-9 on a far one only, and
        // both near at the join: the step is taken once, where the offsets
        // say.
        let rows = [50.0; 10];
        let near: Vec<Vec<BoundaryPoint>> = (0..10)
            .map(|k| match k {
                0..=3 => vec![at(50.1, 2000.0)],
                4 => vec![at(50.2, 2000.0), at(50.9, 8000.0)],
                5 => vec![at(50.8, 2000.0), at(50.1, 8000.0)],
                _ => vec![at(50.0, 8000.0)],
            })
            .collect();
        let chosen: Vec<f64> = continuous_choice(&near, &rows)
            .iter()
            .map(|b| b.map_or(0.0, |b| b.depth))
            .collect();
        assert_eq!(
            chosen,
            vec![2000.0, 2000.0, 2000.0, 2000.0, 2000.0, 8000.0, 8000.0, 8000.0, 8000.0, 8000.0]
        );
        // Points with no boundary near split the runs.
        let mut gap = near.clone();
        gap[2].clear();
        let chosen = continuous_choice(&gap, &rows);
        assert!(chosen[2].is_none() && chosen[1].is_some() && chosen[3].is_some());
    }

    /// Anchored points every 2 px from x = 10 at the given depths.
    fn run_at(depths: &[f64]) -> (Vec<Option<BoundaryPoint>>, Vec<f64>) {
        let hits = depths.iter().map(|&d| Some(at(50.0, d))).collect();
        let xs = (0..depths.len()).map(|k| 10.0 + 2.0 * k as f64).collect();
        (hits, xs)
    }

    #[test]
    fn a_stroke_touching_a_nearer_crest_for_one_point_stays_on_its_landform() {
        // Ten points on a ridge 3 km away, one on a foreground crest at
        // 70 m, ten more on the ridge: the one point is interpolated
        // between its neighbours, not held on the foreground.
        let mut depths = vec![3000.0; 21];
        depths[10] = 70.0;
        let (mut hits, xs) = run_at(&depths);
        let mut refused = vec![false; 21];
        drop_crossings(&mut hits, &xs, &mut refused);
        let d = hits[10].map(|h| h.depth).unwrap_or(0.0);
        assert!((d - 3000.0).abs() < 1.0, "depth {d}");
        assert!(!refused.iter().any(|&r| r));
    }

    #[test]
    fn a_crossing_at_a_runs_edge_is_freed_and_a_wide_step_is_kept() {
        // Two points at 950 m before twelve at 1.47 km (the stroke leaves
        // a near hill's tip onto the far landform): the two are freed and
        // not anchored again.
        let mut depths = vec![1470.0; 15];
        depths[1] = 950.0;
        depths[2] = 988.0;
        let (mut hits, xs) = run_at(&depths);
        hits[0] = None;
        let mut refused = vec![false; 15];
        drop_crossings(&mut hits, &xs, &mut refused);
        assert!(hits[1].is_none() && hits[2].is_none() && hits[3].is_some());
        assert!(refused[1] && refused[2] && !refused[3]);
        // At the stroke's end, or between two pieces at different depths
        // (a skyline stepping through a farther range), it stays.
        let (mut hits, xs) = run_at(&depths[1..]);
        let mut refused = vec![false; 14];
        drop_crossings(&mut hits, &xs, &mut refused);
        assert!(hits.iter().all(|h| h.is_some()));
        let mut steps = vec![9800.0; 8];
        steps.extend([37000.0; 8]);
        steps.extend([48000.0; 3]);
        steps.extend([9600.0; 8]);
        let (mut hits, xs) = run_at(&steps);
        let mut refused = vec![false; steps.len()];
        drop_crossings(&mut hits, &xs, &mut refused);
        assert!(hits.iter().all(|h| h.is_some()));
        // A stroke passing from one landform to another along both (each
        // piece at least MIN_RUN_PX wide) keeps both.
        let depths: Vec<f64> = (0..12)
            .map(|k| if k < 6 { 2000.0 } else { 8000.0 })
            .collect();
        let (mut hits, xs) = run_at(&depths);
        let mut refused = vec![false; 12];
        drop_crossings(&mut hits, &xs, &mut refused);
        assert!(hits.iter().all(|h| h.is_some()));
    }

    /// Free stretch (5 points, 8 px), an anchored run at `run_depth` (6
    /// points), free stretch (5 points): x every 2 px; the matched feature
    /// at `feature_depth` everywhere.
    fn free_run_free(
        run_depth: f64,
        feature_depth: f64,
    ) -> (Vec<Option<BoundaryPoint>>, Vec<f64>, Vec<Option<f64>>) {
        let n = 16;
        let hits = (0..n)
            .map(|k| (5..11).contains(&k).then(|| at(50.0, run_depth)))
            .collect();
        let xs = (0..n).map(|k| 10.0 + 2.0 * k as f64).collect();
        (hits, xs, vec![Some(feature_depth); n])
    }

    #[test]
    fn a_run_between_two_free_stretches_behind_the_feature_is_freed() {
        // The Arenal raised peak: the stroke outlines a peak at 1.2 km
        // and touches the volcano's skyline at 1.7 km in between.
        let (mut hits, xs, feature) = free_run_free(1700.0, 1200.0);
        drop_runs_behind_feature(&mut hits, &xs, &feature);
        assert!(hits.iter().all(|h| h.is_none()));
    }

    #[test]
    fn a_run_on_the_feature_or_in_front_of_it_stays_anchored() {
        for run_depth in [1250.0, 900.0] {
            let (mut hits, xs, feature) = free_run_free(run_depth, 1200.0);
            drop_runs_behind_feature(&mut hits, &xs, &feature);
            assert_eq!(hits.iter().filter(|h| h.is_some()).count(), 6);
        }
    }

    #[test]
    fn a_run_at_a_stroke_end_or_beside_a_narrow_gap_stays_anchored() {
        // At the stroke's end: the stroke may go on along the farther
        // landform.
        let mut hits: Vec<Option<BoundaryPoint>> =
            (0..8).map(|k| (k >= 4).then(|| at(50.0, 1700.0))).collect();
        let xs: Vec<f64> = (0..8).map(|k| 10.0 + 4.0 * k as f64).collect();
        drop_runs_behind_feature(&mut hits, &xs, &[Some(1200.0); 8]);
        assert_eq!(hits.iter().filter(|h| h.is_some()).count(), 4);
        // A free gap narrower than MIN_RUN_PX on one side.
        let (mut hits, mut xs, feature) = free_run_free(1700.0, 1200.0);
        for (k, x) in xs.iter_mut().enumerate().take(5) {
            *x = 19.0 + 0.25 * k as f64;
        }
        drop_runs_behind_feature(&mut hits, &xs, &feature);
        assert_eq!(hits.iter().filter(|h| h.is_some()).count(), 6);
    }

    fn at_depth(depth: f64) -> Option<BoundaryPoint> {
        boundary(100.0).map(|b| BoundaryPoint { depth, ..b })
    }

    /// A stretch running off one landform's silhouette keeps it, also when
    /// its first point lies on the landform beside it (where the
    /// silhouette passes from one to the other); two such points are two
    /// landforms.
    #[test]
    fn keep_near_allows_one_point_of_the_landform_beside() {
        let found: Vec<_> = [369.0, 440.0, 441.0, 443.0, 438.0]
            .iter()
            .map(|&d| at_depth(d))
            .collect();
        let mut near = vec![None; found.len()];
        keep_near(&mut near, &found);
        assert!(near.iter().all(|h| h.is_some()));
        let found: Vec<_> = [369.0, 300.0, 441.0, 443.0, 438.0]
            .iter()
            .map(|&d| at_depth(d))
            .collect();
        let mut near = vec![None; found.len()];
        keep_near(&mut near, &found);
        assert!(near.iter().all(|h| h.is_none()));
    }
}
