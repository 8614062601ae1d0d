//! Depth ordering of the strokes of one view (section 4 of Tassé et al.):
//! which stroke is in front of which, from T-junctions and, where there is
//! no junction, from x-containment and the heights of the extremities.
//!
//! Steps, as in the paper:
//!
//! 1. **T-junctions** ([`label_junctions`]): an extremity `q_s` of stroke `s`
//!    is a T-junction when its distance to another stroke `r` is below a
//!    threshold. With strokes oriented clockwise (left to right) and the
//!    tangent of a *starting* point flipped, `q_s` is labelled
//!    `(occluded-by, r)` when the counterclockwise angle from the tangent of
//!    `s` to the tangent of `r` is below 180 degrees, else `(in-front-of, r)`.
//!    Angles are measured as seen on screen (y up).
//!    An extremity that meets the other stroke at one of *its* extremities
//!    is an end-to-end contact (one silhouette continuing another, common
//!    when tracing real views), not a T-junction, and gives no cue.
//! 2. **Cues without junctions**: where the two strokes share pixel columns
//!    and one is drawn above the other there, it is behind (the paper's
//!    first observation, "if a silhouette lies above another, it ...
//!    \[is\] farther away", applied column by column, where it is exact for a
//!    height field); otherwise, if the x interval of `r` lies inside that of
//!    `s`, `s` is behind `r`; otherwise the stroke whose lowest extremity is
//!    higher on screen is behind.
//! 3. **Sweep** ([`order_strokes`]): the extremities are visited from left to
//!    right; opening a stroke inserts it into the sorting structure
//!    ([`SortingStructure`]) with its start junction and, for each stroke
//!    already there with no junction met so far, the containment or height
//!    cue; closing it adds its end junction (which overrides an earlier
//!    containment or height cue that says otherwise). The structure keeps a
//!    front-to-back order consistent with the accepted cues, changing the
//!    existing order as little as possible.
//!
//! Contradictory cues are resolved deterministically: junction cues beat
//! above cues, which beat containment cues, which beat height cues, and
//! among cues of the same
//! strength the one met first in the sweep wins. A cue contradicted by a
//! stronger one is *overridden* (expected: a height cue is only a fallback);
//! a cue contradicted by cues of its own strength is a *conflict* and is
//! reported in [`DepthOrdering::conflicts`].

use super::stroke::Stroke;

/// Label of a T-junction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum JunctionLabel {
    /// The stroke ending here passes behind the other one.
    OccludedBy,
    /// The stroke ending here is in front of the other one.
    InFrontOf,
}

/// A labelled T-junction at an extremity of a stroke.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Junction {
    /// The stroke whose extremity touches another.
    pub stroke: usize,
    /// `true` at the stroke's end (right), `false` at its start (left).
    pub at_end: bool,
    /// The stroke touched.
    pub other: usize,
    pub label: JunctionLabel,
    /// The extremity, pixels.
    pub point: [f64; 2],
    /// Its distance to the other stroke, pixels.
    pub distance: f64,
    /// Counterclockwise angle from the (flipped at a start) tangent of the
    /// stroke to the tangent of the other, degrees in [0, 360).
    pub angle_deg: f64,
}

/// Strength of a depth cue, strongest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CueKind {
    Junction,
    /// Where two strokes share pixel columns, the one drawn above is behind
    /// (the paper's first observation, tested column by column).
    Above,
    Containment,
    Height,
}

/// All cue kinds, strongest first.
const CUE_KINDS: [CueKind; 4] = [
    CueKind::Junction,
    CueKind::Above,
    CueKind::Containment,
    CueKind::Height,
];

/// "`behind` lies behind `front`", with where it comes from.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Cue {
    pub behind: usize,
    pub front: usize,
    pub kind: CueKind,
    /// Order in which the sweep met it.
    pub seq: usize,
}

/// A cue rejected because cues of the same strength say the opposite.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DepthConflict {
    pub rejected: Cue,
    /// One line, naming the strokes by id.
    pub message: String,
}

/// One step of the sweep (for reports and debugging).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SweepStep {
    pub x: f64,
    pub stroke: usize,
    /// `true` when closing the stroke.
    pub close: bool,
    /// What was learnt, e.g. "in front of 1", "occluded by 2", "no relation".
    pub relations: Vec<(CueKind, String)>,
    /// Front-to-back order of the inserted strokes after the step.
    pub order: Vec<usize>,
}

/// The result of depth ordering.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DepthOrdering {
    /// Stroke indices from front (nearest) to back.
    pub order: Vec<usize>,
    /// `rank[i]`: position of stroke i in `order`.
    pub rank: Vec<usize>,
    pub junctions: Vec<Junction>,
    /// Cues kept.
    pub accepted: Vec<Cue>,
    /// Cues contradicted by stronger ones.
    pub overridden: Vec<Cue>,
    /// Cues contradicted by cues of the same strength.
    pub conflicts: Vec<DepthConflict>,
    pub steps: Vec<SweepStep>,
}

/// T-junction detection and labelling for all extremities.
pub fn label_junctions(strokes: &[Stroke], threshold: f64) -> Vec<Junction> {
    let mut out = Vec::new();
    let reach = 4.0 * threshold.max(2.0);
    for (s, st) in strokes.iter().enumerate() {
        for at_end in [false, true] {
            let q = if at_end { st.end() } else { st.start() };
            let mut best: Option<(f64, usize, [f64; 2])> = None;
            for (r, rt) in strokes.iter().enumerate() {
                if r == s || siblings(st, rt) {
                    continue;
                }
                // Meeting the other stroke at one of its own extremities is
                // an end-to-end contact (one silhouette continuing another),
                // not a T-junction: the tangent rule says nothing there.
                if dist2(q, rt.start()) < threshold || dist2(q, rt.end()) < threshold {
                    continue;
                }
                let (d, _, tr) = rt.closest(q);
                if d < threshold && best.is_none_or(|b| d < b.0) {
                    best = Some((d, r, tr));
                }
            }
            if let Some((d, r, tr)) = best {
                let mut ts = st.end_tangent(at_end, reach);
                if !at_end {
                    ts = [-ts[0], -ts[1]];
                }
                let angle = ccw_angle_deg(ts, tr);
                out.push(Junction {
                    stroke: s,
                    at_end,
                    other: r,
                    label: if angle < 180.0 {
                        JunctionLabel::OccludedBy
                    } else {
                        JunctionLabel::InFrontOf
                    },
                    point: q,
                    distance: d,
                    angle_deg: angle,
                });
            }
        }
    }
    out
}

fn dist2(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

fn siblings(a: &Stroke, b: &Stroke) -> bool {
    a.piece > 0 && b.piece > 0 && a.source_index == b.source_index
}

/// Counterclockwise angle on screen (y up) from `a` to `b`, given in pixel
/// coordinates (y down), in [0, 360).
fn ccw_angle_deg(a: [f64; 2], b: [f64; 2]) -> f64 {
    let (ax, ay) = (a[0], -a[1]);
    let (bx, by) = (b[0], -b[1]);
    let ang = (ax * by - ay * bx).atan2(ax * bx + ay * by).to_degrees();
    if ang < 0.0 {
        ang + 360.0
    } else {
        ang
    }
}

/// The sorting structure of the sweep: strokes in front-to-back order, kept
/// consistent with the accepted cues.
///
/// Cues are resolved strongest kind first, then in sweep order
/// ([`SortingStructure::resolve`]). The resolution is kept per kind (the
/// state after each kind's cues), so that a new cue only replays the cues
/// of weaker kinds: the same result as resolving every cue from scratch
/// after each one, without its quadratic cost in the number of cues (100
/// overlapping strokes took seconds).
#[derive(Debug, Clone, Default)]
pub struct SortingStructure {
    /// Strokes in insertion order.
    inserted: Vec<usize>,
    /// Cues by kind (index in [`CUE_KINDS`]), each in sweep order.
    groups: [Vec<Cue>; 4],
    /// `stages[g]`: the resolution after the cues of kinds `0..=g`.
    stages: [Resolution; 4],
    order: Vec<usize>,
}

/// Cues resolved up to some kind: the accepted cue graph of every kind so
/// far (edges front -> behind) and what became of the cues of that kind.
#[derive(Debug, Clone, Default)]
struct Resolution {
    adj: Vec<Vec<(usize, CueKind)>>,
    acc: Vec<Cue>,
    over: Vec<Cue>,
    conf: Vec<(Cue, CueKind)>,
}

impl Resolution {
    /// Resolve one more cue (weaker than, or as strong as and later than,
    /// every cue resolved so far). True when it joined the graph.
    fn push(&mut self, c: &Cue) -> bool {
        if c.behind == c.front {
            return false;
        }
        let need = c.behind.max(c.front) + 1;
        if self.adj.len() < need {
            self.adj.resize(need, Vec::new());
        }
        if self.adj[c.front].iter().any(|&(b, _)| b == c.behind) {
            return false; // duplicate
        }
        // Would front -> behind close a cycle, i.e. does behind already
        // reach front? Find the weakest cue on such a path.
        match weakest_on_path(&self.adj, c.behind, c.front) {
            None => {
                self.adj[c.front].push((c.behind, c.kind));
                self.acc.push(c.clone());
                true
            }
            Some(weakest) => {
                if weakest < c.kind {
                    self.over.push(c.clone());
                } else {
                    self.conf.push((c.clone(), weakest));
                }
                false
            }
        }
    }
}

fn kind_index(k: CueKind) -> usize {
    CUE_KINDS
        .iter()
        .position(|&c| c == k)
        .unwrap_or(CUE_KINDS.len() - 1)
}

impl SortingStructure {
    /// Inserts a stroke (at the back when no cue places it).
    pub fn insert(&mut self, s: usize) {
        if !self.inserted.contains(&s) {
            self.inserted.push(s);
            self.order.push(s);
        }
    }

    /// Adds a cue and re-sorts.
    pub fn add(&mut self, cue: Cue) {
        let g = kind_index(cue.kind);
        // Cues of a kind are resolved in sweep order (ties: in the order
        // added): a cue later than the others of its kind extends that
        // kind's resolution, else the kind is replayed.
        let at = self.groups[g].partition_point(|c| c.seq <= cue.seq);
        let last = at == self.groups[g].len();
        self.groups[g].insert(at, cue);
        let joined = if last {
            let c = self.groups[g][at].clone();
            self.stages[g].push(&c)
        } else {
            self.replay(g);
            true
        };
        // A cue left out of the graph changes nothing for weaker kinds.
        if joined {
            for h in g + 1..CUE_KINDS.len() {
                self.replay(h);
            }
        }
        self.resort();
    }

    /// Recompute the resolution of kind `g` from the one before it.
    fn replay(&mut self, g: usize) {
        let mut st = Resolution {
            adj: if g == 0 {
                Vec::new()
            } else {
                self.stages[g - 1].adj.clone()
            },
            ..Resolution::default()
        };
        for c in &self.groups[g] {
            st.push(c);
        }
        self.stages[g] = st;
    }

    /// Current front-to-back order.
    pub fn order(&self) -> &[usize] {
        &self.order
    }

    /// Resolves cues (strongest first, then sweep order) into an acyclic
    /// set and orders the inserted strokes by it, breaking ties by the
    /// previous order. Returns (accepted, overridden, conflicts).
    fn resolve(&self) -> (Vec<Cue>, Vec<Cue>, Vec<(Cue, CueKind)>) {
        let st = &self.stages;
        (
            st.iter().flat_map(|s| s.acc.iter().cloned()).collect(),
            st.iter().flat_map(|s| s.over.iter().cloned()).collect(),
            st.iter().flat_map(|s| s.conf.iter().cloned()).collect(),
        )
    }

    fn resort(&mut self) {
        let acc: Vec<Cue> = self
            .stages
            .iter()
            .flat_map(|s| s.acc.iter().cloned())
            .collect();
        self.order = topo_order(&self.order, &acc);
    }
}

/// Path from `from` to `to` in the cue graph (edges front -> behind):
/// returns the weakest kind on the strongest such path (so that a cue is
/// only a conflict when no path made of stronger cues exists).
fn weakest_on_path(adj: &[Vec<(usize, CueKind)>], from: usize, to: usize) -> Option<CueKind> {
    // No path at all (the common case): one search instead of four.
    if !reaches(adj, from, to, CueKind::Height) {
        return None;
    }
    // Search with increasing allowed weakness.
    CUE_KINDS
        .into_iter()
        .find(|&limit| reaches(adj, from, to, limit))
}

/// Is `to` reachable from `from` over edges no weaker than `limit`?
fn reaches(adj: &[Vec<(usize, CueKind)>], from: usize, to: usize, limit: CueKind) -> bool {
    let mut seen = vec![false; adj.len()];
    let mut stack = vec![from];
    seen[from] = true;
    while let Some(u) = stack.pop() {
        if u == to {
            return true;
        }
        for &(v, k) in &adj[u] {
            if k <= limit && !seen[v] {
                seen[v] = true;
                stack.push(v);
            }
        }
    }
    false
}

/// Kahn's algorithm on `cues` over the strokes of `prev`, always taking the
/// available stroke that comes first in `prev`.
fn topo_order(prev: &[usize], cues: &[Cue]) -> Vec<usize> {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    // Position of each stroke in `prev` (the first, as `position` would).
    let top = prev.iter().copied().max().map_or(0, |m| m + 1);
    let mut at = vec![usize::MAX; top];
    for (i, &s) in prev.iter().enumerate().rev() {
        at[s] = i;
    }
    let pos = |s: usize| at.get(s).copied().filter(|&i| i != usize::MAX);
    let mut indeg = vec![0usize; prev.len()];
    let mut succ: Vec<Vec<usize>> = vec![Vec::new(); prev.len()];
    for c in cues {
        if let (Some(f), Some(b)) = (pos(c.front), pos(c.behind)) {
            succ[f].push(b);
            indeg[b] += 1;
        }
    }
    // Always the available stroke that comes first in `prev`.
    let mut ready: BinaryHeap<Reverse<usize>> = (0..prev.len())
        .filter(|&i| indeg[i] == 0)
        .map(Reverse)
        .collect();
    let mut out = Vec::with_capacity(prev.len());
    while let Some(Reverse(i)) = ready.pop() {
        out.push(prev[i]);
        for &b in &succ[i] {
            indeg[b] -= 1;
            if indeg[b] == 0 {
                ready.push(Reverse(b));
            }
        }
    }
    out
}

/// Orders the strokes of a view from front to back by the sweep of
/// section 4. `threshold` is the T-junction distance in pixels.
///
/// ```
/// use demsketch::sketch::{order_strokes, prepare_stroke, FoldBackPolicy, StrokeError};
/// # fn main() -> Result<(), StrokeError> {
/// let mk = |id: &str, i, p: &[[f64; 2]]| {
///     prepare_stroke(id, i, p, 2.0, 1.0, FoldBackPolicy::Split).map(|mut v| v.remove(0))
/// };
/// // A far ridge descending into a nearer hill: a T-junction.
/// let far = mk("far", 0, &[[0.0, 100.0], [100.0, 200.0]])?;
/// let near = mk("near", 1, &[[50.0, 300.0], [100.0, 200.0], [200.0, 150.0]])?;
/// let o = order_strokes(&[far, near], 4.0);
/// assert_eq!(o.order, vec![1, 0]);
/// # Ok(())
/// # }
/// ```
pub fn order_strokes(strokes: &[Stroke], threshold: f64) -> DepthOrdering {
    let junctions = label_junctions(strokes, threshold);
    let n = strokes.len();
    // Junctions met so far by the sweep, per pair.
    let mut known = vec![vec![false; n]; n];
    // Events: (x, close?, stroke).
    let mut events: Vec<(f64, bool, usize)> = Vec::with_capacity(2 * n);
    for (i, s) in strokes.iter().enumerate() {
        let (x0, x1) = s.x_range();
        events.push((x0, false, i));
        events.push((x1, true, i));
    }
    events.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));

    let mut st = SortingStructure::default();
    let mut seq = 0usize;
    let mut steps = Vec::new();
    for &(x, close, s) in &events {
        let mut rel = Vec::new();
        let mut new_cues = Vec::new();
        if !close {
            st.insert(s);
        }
        for j in junctions
            .iter()
            .filter(|j| j.stroke == s && j.at_end == close)
        {
            let (behind, front, text) = match j.label {
                JunctionLabel::OccludedBy => (s, j.other, "occluded by"),
                JunctionLabel::InFrontOf => (j.other, s, "in front of"),
            };
            new_cues.push((behind, front, CueKind::Junction));
            known[j.stroke][j.other] = true;
            known[j.other][j.stroke] = true;
            rel.push((CueKind::Junction, format!("{text} {}", strokes[j.other].id)));
        }
        if !close {
            let present: Vec<usize> = st.inserted.iter().copied().filter(|&r| r != s).collect();
            for r in present {
                if known[s][r] || siblings(&strokes[s], &strokes[r]) {
                    continue;
                }
                if let Some((behind, front, kind)) = weak_cue(&strokes[s], s, &strokes[r], r) {
                    let text = if behind == s { "behind" } else { "in front of" };
                    new_cues.push((behind, front, kind));
                    rel.push((kind, format!("{text} {}", strokes[r].id)));
                }
            }
        }
        for (behind, front, kind) in new_cues {
            st.add(Cue {
                behind,
                front,
                kind,
                seq,
            });
            seq += 1;
        }
        if rel.is_empty() {
            rel.push((CueKind::Height, "no relation".into()));
        }
        steps.push(SweepStep {
            x,
            stroke: s,
            close,
            relations: rel,
            order: st.order().to_vec(),
        });
    }
    let (accepted, overridden, conf) = st.resolve();
    let conflicts = conf
        .into_iter()
        .map(|(c, _)| DepthConflict {
            message: format!(
                "contradictory depth cues: {:?} cue says \"{}\" is behind \"{}\" but cues of the same strength met earlier say otherwise; kept the earlier ones",
                c.kind, strokes[c.behind].id, strokes[c.front].id
            ),
            rejected: c,
        })
        .collect();
    let order = st.order().to_vec();
    let mut rank = vec![0usize; n];
    for (k, &s) in order.iter().enumerate() {
        rank[s] = k;
    }
    DepthOrdering {
        order,
        rank,
        junctions,
        accepted,
        overridden,
        conflicts,
        steps,
    }
}

/// Shared columns needed for the [`CueKind::Above`] cue, pixels.
const ABOVE_MIN_OVERLAP_PX: f64 = 4.0;
/// Vertical separation that counts as "above", pixels.
const ABOVE_TOLERANCE_PX: f64 = 1.0;

/// "Above" cue: over the pixel columns both strokes cover, one is drawn
/// above the other everywhere (by more than a pixel somewhere and below it
/// nowhere): it is behind, since along a column of a terrain view the
/// visible depth grows upwards (section 4's first observation, exact where
/// the strokes share columns). `None` when they share too few columns, touch
/// only, or cross.
fn above_cue(s: &Stroke, si: usize, r: &Stroke, ri: usize) -> Option<(usize, usize, CueKind)> {
    let (s0, s1) = s.x_range();
    let (r0, r1) = r.x_range();
    let (lo, hi) = (s0.max(r0), s1.min(r1));
    if !(hi - lo >= ABOVE_MIN_OVERLAP_PX) {
        return None;
    }
    let n = ((hi - lo) / 2.0).ceil().max(2.0) as usize;
    let (mut s_above, mut r_above) = (0usize, 0usize);
    for k in 0..=n {
        let x = lo + (hi - lo) * k as f64 / n as f64;
        let (Some(ys), Some(yr)) = (s.y_at(x), r.y_at(x)) else {
            continue;
        };
        if ys < yr - ABOVE_TOLERANCE_PX {
            s_above += 1;
        } else if yr < ys - ABOVE_TOLERANCE_PX {
            r_above += 1;
        }
    }
    match (s_above > 0, r_above > 0) {
        (true, false) => Some((si, ri, CueKind::Above)),
        (false, true) => Some((ri, si, CueKind::Above)),
        _ => None,
    }
}

/// The above cue, else containment, else the height cue between two
/// strokes with no junction: (behind, front, kind).
fn weak_cue(s: &Stroke, si: usize, r: &Stroke, ri: usize) -> Option<(usize, usize, CueKind)> {
    if let Some(c) = above_cue(s, si, r, ri) {
        return Some(c);
    }
    let (s0, s1) = s.x_range();
    let (r0, r1) = r.x_range();
    let eps = 1e-9;
    let s_contains_r = r0 >= s0 - eps && r1 <= s1 + eps;
    let r_contains_s = s0 >= r0 - eps && s1 <= r1 + eps;
    if s_contains_r && !r_contains_s {
        return Some((si, ri, CueKind::Containment));
    }
    if r_contains_s && !s_contains_r {
        return Some((ri, si, CueKind::Containment));
    }
    // Height on screen is -y: the smallest height of the endpoints is the
    // largest y.
    let low_s = s.start()[1].max(s.end()[1]);
    let low_r = r.start()[1].max(r.end()[1]);
    if low_s < low_r - eps {
        Some((si, ri, CueKind::Height))
    } else if low_r < low_s - eps {
        Some((ri, si, CueKind::Height))
    } else {
        None
    }
}
