//! Matching a whole sketch, one view or several jointly (sections 5.2 and 7
//! of Tassé et al.): the entry point of the sketch module.
//!
//! For each view: the strokes are ordered in depth ([`order_strokes`]) and
//! each gets its priority list from the view's own features
//! ([`priority_list`]). The strokes of all views are then put in one list,
//! view after view (in file order) and front to back within a view, and a
//! single branch-and-bound ([`branch_and_bound`](super::branch_and_bound)) chooses all features at
//! once under two constraints:
//!
//! - within a view, a feature assigned to a nearer stroke is not hidden by
//!   the feature assigned to a farther stroke ([`occludes_within_view`]);
//! - across views, no feature assigned in one view lies between another
//!   view's camera and the feature assigned there ([`occludes_across_views`]).
//!
//! A feature (by id) is used at most once in the whole sketch. The strokes
//! are then placed in world space, unmatched ones embedded by the fallback,
//! and features completed down to the terrain.
//!
//! Sketches that intersect (a placed stroke of one view, seen from another
//! view, crosses a stroke of that view in front of it) are reported as an
//! error: the paper does not support them, and no deformation could satisfy
//! both. The test runs on each view matched on its own (what each sketch
//! means to its author: without it, the joint minimisation would silently
//! twist the matches or embed strokes to dodge the crossing) and again on
//! the joint result ([`check_intersections`]).

use rayon::prelude::*;

use super::branch_and_bound::{branch_and_bound_with_budget, Bound, Choice};
use super::candidates::{priority_list, Candidate, CandidateOptions, CostTerms, PriorityList};
use super::depth_order::{order_strokes, DepthOrdering};
use super::fallback::{embed_unmatched, placed_depth_at};
use super::file::SketchOptions;
use super::placement::{complete_feature, place_on_candidate, PlacedPoint, PointSource};
use super::projection::{FeatureKind, ViewFeature, ViewProjection};
use super::stroke::Stroke;

/// Distance used by the fallback when the terrain offers nothing, metres.
pub const DEFAULT_FALLBACK_DISTANCE_M: f64 = 1000.0;

/// One view to match: its prepared strokes, its features, its camera.
pub struct ViewInput<'a> {
    pub name: String,
    pub strokes: Vec<Stroke>,
    pub features: &'a [ViewFeature],
    pub projection: &'a dyn ViewProjection,
}

/// How a stroke was placed (the report's `match.kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MatchKind {
    Silhouette,
    Ridge,
    /// No feature: fallback 3D embedding.
    Embedded,
}

/// The result for one stroke.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StrokeMatch {
    pub id: String,
    pub source_id: String,
    /// Position in the view's depth order (0 = nearest).
    pub depth_rank: usize,
    pub kind: MatchKind,
    pub feature_id: Option<usize>,
    /// Index of the chosen candidate in the view's priority list of this
    /// stroke ([`ViewMatch::lists`]); `None` when embedded.
    #[serde(skip)]
    pub candidate: Option<usize>,
    pub costs: Option<CostTerms>,
    /// Length of the priority list used, and candidates before truncation.
    pub candidates: usize,
    pub considered: usize,
    /// The stroke in world space (with completion points at both ends when
    /// feature completion is on).
    pub points: Vec<PlacedPoint>,
}

/// The result for one view.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ViewMatch {
    pub name: String,
    pub ordering: DepthOrdering,
    /// In the order of the view's strokes.
    pub strokes: Vec<StrokeMatch>,
    #[serde(skip)]
    pub lists: Vec<PriorityList>,
}

/// The result of matching a sketch.
#[derive(Debug, Clone, serde::Serialize)]
pub struct SketchMatch {
    pub views: Vec<ViewMatch>,
    /// Total cost of the assignment (each stroke without a feature counts
    /// [`super::EMPTY_LIST_COST`]).
    pub total_cost: f64,
    /// Branch-and-bound nodes visited.
    pub nodes: u64,
    /// The node budget (`SketchOptions::node_budget`).
    pub node_budget: u64,
    /// Branch-and-bound ran out of its node budget: the assignment is the
    /// best found within it, not proven optimal.
    pub stopped_early: bool,
}

/// Errors of matching.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MatchError {
    #[error("sketches of views \"{view_a}\" and \"{view_b}\" intersect: stroke \"{stroke_a}\" of \"{view_a}\", seen from \"{view_b}\", crosses stroke \"{stroke_b}\" in front of it near pixel ({x:.0}, {y:.0}); multi-view sketches must not cross (edit one view at a time instead)")]
    IntersectingSketches {
        view_a: String,
        stroke_a: String,
        view_b: String,
        stroke_b: String,
        x: f64,
        y: f64,
    },
}

/// Pixel step of the occlusion tests.
pub const OCCLUSION_STEP_PX: f64 = 2.0;
/// Tolerance on screen height in the occlusion tests, pixels.
const OCCLUSION_TOL_PX: f64 = 0.5;

/// A candidate of a stroke sampled on the global pixel-column grid
/// `x = k * OCCLUSION_STEP_PX`: the candidate's depth and the stroke's row
/// at each column of the candidate's x range (NaN where undefined). The
/// within-view occlusion test compares two profiles column by column.
#[derive(Debug, Clone, PartialEq)]
pub struct ColumnProfile {
    k0: i64,
    depth: Vec<f64>,
    y: Vec<f64>,
    min_depth: f64,
    max_depth: f64,
    min_y: f64,
    max_y: f64,
}

impl ColumnProfile {
    /// The profile of candidate `cand` of stroke `stroke`.
    pub fn new(stroke: &Stroke, cand: &Candidate) -> ColumnProfile {
        let (a0, a1) = cand.x_range();
        if !(a0.is_finite() && a1.is_finite() && a1 >= a0) {
            return ColumnProfile {
                k0: 0,
                depth: Vec::new(),
                y: Vec::new(),
                min_depth: f64::NAN,
                max_depth: f64::NAN,
                min_y: f64::NAN,
                max_y: f64::NAN,
            };
        }
        let k0 = (a0 / OCCLUSION_STEP_PX).ceil() as i64;
        let k1 = (a1 / OCCLUSION_STEP_PX).floor() as i64;
        let len = (k1 - k0 + 1).max(0) as usize;
        let (mut depth, mut y) = (Vec::with_capacity(len), Vec::with_capacity(len));
        // Both polylines are x-monotone: walk them with cursors (linear
        // interpolation, as `Candidate::depth_at` and `Stroke::y_at`).
        let cp = &cand.points;
        let sp = &stroke.points;
        let (sx0, sx1) = stroke.x_range();
        let (mut i, mut j) = (0usize, 0usize);
        for k in k0..=k1 {
            let x = k as f64 * OCCLUSION_STEP_PX;
            while i + 1 < cp.len() && cp[i + 1].deformed_pixel[0] < x {
                i += 1;
            }
            let d = if i + 1 < cp.len() {
                let (a, b) = (&cp[i], &cp[i + 1]);
                let dx = b.deformed_pixel[0] - a.deformed_pixel[0];
                if x <= a.deformed_pixel[0] {
                    a.depth
                } else if dx > 1e-12 {
                    a.depth + (x - a.deformed_pixel[0]) / dx * (b.depth - a.depth)
                } else {
                    b.depth
                }
            } else {
                cp.last().map_or(f64::NAN, |p| p.depth)
            };
            depth.push(d);
            let yv = if x >= sx0 && x <= sx1 && !sp.is_empty() {
                while j + 1 < sp.len() && sp[j + 1][0] < x {
                    j += 1;
                }
                if j + 1 < sp.len() {
                    let (a, b) = (sp[j], sp[j + 1]);
                    let dx = b[0] - a[0];
                    if x <= a[0] {
                        a[1]
                    } else if dx > 1e-12 {
                        a[1] + (x - a[0]) / dx * (b[1] - a[1])
                    } else {
                        b[1]
                    }
                } else {
                    sp[sp.len() - 1][1]
                }
            } else {
                f64::NAN
            };
            y.push(yv);
        }
        let fmin = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let fmax = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        ColumnProfile {
            k0,
            min_depth: fmin(&depth),
            max_depth: fmax(&depth),
            min_y: fmin(&y),
            max_y: fmax(&y),
            depth,
            y,
        }
    }

    /// Does the candidate of `back` (a farther stroke) hide the candidate of
    /// `front`? See [`occludes_within_view`].
    pub fn hides(back: &ColumnProfile, front: &ColumnProfile) -> bool {
        // Quick rejection: `back` nowhere nearer than `front`, or nowhere
        // high enough.
        if !(back.min_depth < front.max_depth * (1.0 - 1e-9) - 1e-6)
            || !(back.min_y <= front.max_y + OCCLUSION_TOL_PX)
        {
            return false;
        }
        let lo = back.k0.max(front.k0);
        let hi = (back.k0 + back.depth.len() as i64).min(front.k0 + front.depth.len() as i64);
        (lo..hi).any(|k| {
            let (i, j) = ((k - front.k0) as usize, (k - back.k0) as usize);
            let (da, db, ya, yb) = (front.depth[i], back.depth[j], front.y[i], back.y[j]);
            // NaN compares false: undefined columns never occlude.
            db < da * (1.0 - 1e-9) - 1e-6 && yb <= ya + OCCLUSION_TOL_PX
        })
    }
}

/// Within one view: does candidate `back` of the farther stroke `s_back`
/// hide candidate `front` of the nearer stroke `s_front`? True when, on a
/// common pixel column (every [`OCCLUSION_STEP_PX`] pixels), `back` is
/// nearer to the eye than `front` while its stroke is drawn at or above
/// `s_front` (after deformation each candidate lies on its stroke).
pub fn occludes_within_view(
    s_front: &Stroke,
    front: &Candidate,
    s_back: &Stroke,
    back: &Candidate,
) -> bool {
    ColumnProfile::hides(
        &ColumnProfile::new(s_back, back),
        &ColumnProfile::new(s_front, front),
    )
}

/// Across views: does `other` (a deformed candidate of another view, given
/// by its deformed world points) lie between the eye of `proj` and
/// candidate `cand` of stroke `s` of that view? True when a point of `other`
/// projects onto the column range of `cand`, nearer than it, at or above
/// the stroke.
pub fn occludes_across_views(
    s: &Stroke,
    cand: &Candidate,
    proj: &dyn ViewProjection,
    other: &[[f64; 3]],
) -> bool {
    let projected: Vec<Option<([f64; 2], f64)>> = other.iter().map(|&w| proj.project(w)).collect();
    occludes_projected(s, cand, &projected)
}

fn occludes_projected(s: &Stroke, cand: &Candidate, projected: &[Option<([f64; 2], f64)>]) -> bool {
    let (a0, a1) = cand.x_range();
    projected.iter().flatten().any(|&(p, d)| {
        if !(p[0] >= a0 && p[0] <= a1) {
            return false;
        }
        match (cand.depth_at(p[0]), s.y_at(p[0])) {
            (Some(da), Some(ys)) => d < da * (1.0 - 1e-9) - 1e-6 && p[1] <= ys + OCCLUSION_TOL_PX,
            _ => false,
        }
    })
}

/// Matches one view (see [`match_sketch`]).
pub fn match_view(view: &ViewInput, opts: &SketchOptions) -> Result<ViewMatch, MatchError> {
    let mut m = match_sketch(std::slice::from_ref(view), opts)?;
    Ok(m.views.remove(0))
}

/// Matches all views of a sketch jointly; see the module documentation.
pub fn match_sketch(views: &[ViewInput], opts: &SketchOptions) -> Result<SketchMatch, MatchError> {
    let copts = CandidateOptions {
        weights: opts.weights,
        min_coverage: opts.min_coverage,
        max_candidates: opts.max_candidates,
        ..CandidateOptions::default()
    };
    // Per view: depth order and priority lists.
    let orderings: Vec<DepthOrdering> = views
        .iter()
        .map(|v| order_strokes(&v.strokes, opts.t_junction_px))
        .collect();
    let lists: Vec<Vec<PriorityList>> = views
        .iter()
        .map(|v| {
            v.strokes
                .iter()
                .map(|s| priority_list(s, v.features, v.projection, &copts))
                .collect()
        })
        .collect();
    // Sketches that intersect: each view matched on its own (the features
    // its author would get drawing it alone) must not cross another view's
    // strokes; otherwise the joint assignment could only avoid the
    // conflict by twisting the matches (section 7: not supported).
    if views.len() > 1 {
        let mut alone: Vec<Vec<Option<usize>>> = Vec::with_capacity(views.len());
        for t in 0..views.len() {
            let (a, _) = solve(views, &orderings, &lists, &[t], opts.node_budget);
            alone.push(a.into_iter().nth(t).unwrap_or_default());
        }
        let placed = place_views(views, &orderings, &lists, &alone, opts);
        let m = SketchMatch {
            views: placed,
            total_cost: 0.0,
            nodes: 0,
            node_budget: opts.node_budget,
            stopped_early: false,
        };
        check_intersections(views, &m)?;
    }
    let all: Vec<usize> = (0..views.len()).collect();
    let (assigned, sol) = solve(views, &orderings, &lists, &all, opts.node_budget);
    let mut out_views = place_views(views, &orderings, &lists, &assigned, opts);
    for (t, l) in lists.into_iter().enumerate() {
        out_views[t].lists = l;
    }
    let result = SketchMatch {
        views: out_views,
        total_cost: sol.cost,
        nodes: sol.nodes,
        node_budget: opts.node_budget,
        stopped_early: sol.stopped_early,
    };
    check_intersections(views, &result)?;
    Ok(result)
}

/// Branch-and-bound over the strokes of the views `which` (in that order,
/// front to back within a view) with the within-view and cross-view
/// occlusion constraints, within `budget` search nodes. Returns the chosen
/// candidate per view and stroke (`None` for views not in `which` and for
/// emptied lists).
fn solve(
    views: &[ViewInput],
    orderings: &[DepthOrdering],
    lists: &[Vec<PriorityList>],
    which: &[usize],
    budget: u64,
) -> (Vec<Vec<Option<usize>>>, super::branch_and_bound::Solution) {
    // Global stroke list: (view, stroke), view by view, front to back.
    let global: Vec<(usize, usize)> = which
        .iter()
        .flat_map(|&t| orderings[t].order.iter().map(move |&s| (t, s)))
        .collect();
    let choices: Vec<Vec<Choice>> = global
        .iter()
        .map(|&(t, s)| {
            lists[t][s]
                .candidates
                .iter()
                .map(|c| Choice {
                    feature: c.feature_id,
                    cost: c.costs.total,
                })
                .collect()
        })
        .collect();
    // Column profiles of every candidate (within-view tests) and, for
    // multi-view sketches, the projection of every deformed candidate into
    // the other views (cross-view tests), computed once and in parallel so
    // that the constraint test is a pure function the search can call from
    // several threads.
    let profiles: Vec<Vec<ColumnProfile>> = global
        .par_iter()
        .map(|&(t, s)| {
            lists[t][s]
                .candidates
                .iter()
                .map(|c| ColumnProfile::new(&views[t].strokes[s], c))
                .collect()
        })
        .collect();
    type Projected = Vec<Option<([f64; 2], f64)>>;
    let projected: Vec<Vec<Vec<Projected>>> = if which.len() > 1 {
        global
            .par_iter()
            .map(|&(t, s)| {
                lists[t][s]
                    .candidates
                    .iter()
                    .map(|c| {
                        which
                            .iter()
                            .map(|&u| {
                                if u == t {
                                    Vec::new()
                                } else {
                                    c.points
                                        .iter()
                                        .map(|p| views[u].projection.project(p.deformed))
                                        .collect()
                                }
                            })
                            .collect()
                    })
                    .collect()
            })
            .collect()
    } else {
        Vec::new()
    };
    let slot = |u: usize| which.iter().position(|&w| w == u).unwrap_or(0);
    let conflicts = |i: usize, a: usize, j: usize, b: usize| -> bool {
        let (ti, si) = global[i];
        let (tj, sj) = global[j];
        if ti == tj {
            // i is in front of j (same view, front to back).
            ColumnProfile::hides(&profiles[j][b], &profiles[i][a])
        } else {
            let ca = &lists[ti][si].candidates[a];
            let cb = &lists[tj][sj].candidates[b];
            occludes_projected(&views[ti].strokes[si], ca, &projected[j][b][slot(ti)])
                || occludes_projected(&views[tj].strokes[sj], cb, &projected[i][a][slot(tj)])
        }
    };
    let sol = branch_and_bound_with_budget(&choices, &conflicts, Bound::ForwardChecking, budget);

    let mut assigned: Vec<Vec<Option<usize>>> =
        views.iter().map(|v| vec![None; v.strokes.len()]).collect();
    for (g, &(t, s)) in global.iter().enumerate() {
        assigned[t][s] = sol.choice[g];
    }
    (assigned, sol)
}

/// Places the strokes of every view on their assigned candidates, embeds
/// the others and completes the features (`lists` of the result are left
/// empty).
fn place_views(
    views: &[ViewInput],
    orderings: &[DepthOrdering],
    lists: &[Vec<PriorityList>],
    assigned: &[Vec<Option<usize>>],
    opts: &SketchOptions,
) -> Vec<ViewMatch> {
    // Placement.
    let mut out_views = Vec::with_capacity(views.len());
    for (t, view) in views.iter().enumerate() {
        let proj = view.projection;
        let mut placed: Vec<Option<Vec<PlacedPoint>>> = view
            .strokes
            .iter()
            .enumerate()
            .map(|(s, st)| {
                assigned[t][s].map(|a| place_on_candidate(st, &lists[t][s].candidates[a], proj))
            })
            .collect();
        // A placement that failed (no depth anywhere) falls back too.
        for p in placed.iter_mut() {
            if p.as_ref().is_some_and(|v| v.is_empty()) {
                *p = None;
            }
        }
        let matched: Vec<bool> = placed.iter().map(|p| p.is_some()).collect();
        embed_unmatched(
            &view.strokes,
            &orderings[t].order,
            &mut placed,
            proj,
            opts.fallback_depth_ratio,
            DEFAULT_FALLBACK_DISTANCE_M,
        );
        let strokes = view
            .strokes
            .iter()
            .enumerate()
            .map(|(s, st)| {
                let mut pts = placed[s].take().unwrap_or_default();
                if opts.feature_completion {
                    pts = complete_feature(
                        &pts,
                        proj,
                        opts.completion_step_m,
                        opts.completion_max_m,
                        0.25,
                    );
                }
                let chosen = assigned[t][s].filter(|_| matched[s]);
                let cand = chosen.map(|a| &lists[t][s].candidates[a]);
                StrokeMatch {
                    id: st.id.clone(),
                    source_id: st.source_id.clone(),
                    depth_rank: orderings[t].rank[s],
                    kind: match cand.map(|c| c.kind) {
                        Some(FeatureKind::Silhouette) => MatchKind::Silhouette,
                        Some(FeatureKind::Ridge) => MatchKind::Ridge,
                        None => MatchKind::Embedded,
                    },
                    feature_id: cand.map(|c| c.feature_id),
                    candidate: chosen,
                    costs: cand.map(|c| c.costs),
                    candidates: lists[t][s].candidates.len(),
                    considered: lists[t][s].considered,
                    points: pts,
                }
            })
            .collect();
        out_views.push(ViewMatch {
            name: view.name.clone(),
            ordering: orderings[t].clone(),
            strokes,
            lists: Vec::new(),
        });
    }
    out_views
}

/// Reports the first pair of sketches that intersect (see the module
/// documentation).
pub fn check_intersections(views: &[ViewInput], m: &SketchMatch) -> Result<(), MatchError> {
    for (t, vt) in m.views.iter().enumerate() {
        for (u, vu) in m.views.iter().enumerate() {
            if t == u {
                continue;
            }
            let proj = views[u].projection;
            for st in &vt.strokes {
                let pr: Vec<([f64; 2], f64)> = st
                    .points
                    .iter()
                    .filter(|p| p.source != PointSource::Completion)
                    .filter_map(|p| proj.project(p.world))
                    .collect();
                for (r, su) in vu.strokes.iter().enumerate() {
                    let stroke_r = &views[u].strokes[r];
                    let (x0, x1) = stroke_r.x_range();
                    let mut prev: Option<(f64, [f64; 2], f64)> = None;
                    for &(p, d) in &pr {
                        let cur = if p[0] >= x0 && p[0] <= x1 {
                            stroke_r.y_at(p[0]).map(|y| (p[1] - y, p, d))
                        } else {
                            None
                        };
                        if let (Some((da, pa, depa)), Some((db, pb, depb))) = (prev, cur) {
                            if (da > 0.0) != (db > 0.0) && da != db {
                                let w = da / (da - db);
                                let x = pa[0] + w * (pb[0] - pa[0]);
                                let y = pa[1] + w * (pb[1] - pa[1]);
                                let dep = depa + w * (depb - depa);
                                if let Some(dr) = placed_depth_at(&su.points, x) {
                                    if dep < dr * 0.99 {
                                        return Err(MatchError::IntersectingSketches {
                                            view_a: vt.name.clone(),
                                            stroke_a: st.id.clone(),
                                            view_b: vu.name.clone(),
                                            stroke_b: su.id.clone(),
                                            x,
                                            y,
                                        });
                                    }
                                }
                            }
                        }
                        prev = cur;
                    }
                }
            }
        }
    }
    Ok(())
}
