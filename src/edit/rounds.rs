//! Stage 5 of the edit pipeline, `lowering`: the refinement rounds after
//! the initial solve.
//!
//! Each round re-renders every view on the current terrain, lowers the
//! silhouettes that protrude above the strokes (section 6.2,
//! [`super::lowering`]) and puts the mesh vertices that decide the contour
//! along strokes that do not fit yet on the strokes' sight surfaces
//! ([`super::contour`]), collects the new constraints of all views and
//! solves once. It stops when no view asks for more, or when a round stops
//! helping; the best terrain so far is kept. When they stop short of a
//! full fit, one more try starts from the best round: the crests the edit
//! raised over the strokes' anchored stretches are lowered
//! ([`super::lowering::find_raised_over_anchored`]) and the rounds go on;
//! what that try brings is kept only when every stroke then fits at least
//! `min_fit` and the fit rose by at least [`RAISED_TRY_MIN_GAIN`], so it
//! is made only when it could get there ([`can_complete`]). Lone spikes of
//! the change field are flattened at the end ([`super::spikes`]).

use std::collections::{BTreeMap, HashSet};

use rayon::prelude::*;

use super::contour::contour_constraints;
use super::fit::fitted_fraction;
use super::lowering::{find_protruding, find_raised_over_anchored, Protrusion};
use super::pipeline::{render_edited_after, Edit, Placed, Solver, ViewState};
use super::rendered_view::{RenderedView, StrokeCurve, StrokeRegion};
use super::spikes::flatten_spikes;
use super::EditError;
use crate::deform::{CellConstraint, CurveConstraint, Deformation};

/// A cell constraint counts as new when its height moved by more than this
/// (metres).
const CELL_CHANGE_M: f64 = 0.01;

/// What the refinement rounds leave: the final terrain, its renders, and
/// per view how many rounds each kind of refinement took.
pub(super) struct Rounds {
    /// The final deformation (the best round's, spikes flattened).
    pub(super) deformation: Deformation,
    /// Each view rendered on it, within its [`super::rendered_view::StrokeRegion`].
    pub(super) rendered: Vec<RenderedView>,
    /// Per view: lowering rounds that found protruding silhouettes.
    pub(super) lowering_iterations: Vec<usize>,
    /// Per view: protruding silhouettes lowered, over all rounds.
    pub(super) silhouettes_lowered: Vec<usize>,
    /// Per view: contour rounds that moved a cell.
    pub(super) contour_iterations: Vec<usize>,
    /// Curve constraints the lowering added to the user's.
    pub(super) lowering_constraints: usize,
    /// No round fitted the strokes better than the unedited terrain does:
    /// the deformation was dropped and the DEM is left as it is.
    pub(super) kept_unedited: bool,
}

/// Refine the initial `deformation` round by round until every stroke is
/// the occluding contour of its view, or the iteration limits
/// ([`super::EditOptions::max_lowering_iterations`],
/// [`super::EditOptions::max_contour_iterations`]) are reached, or a round
/// no longer raises the fit score ([`fit_score`]); then keep the best
/// round's terrain and flatten its lone spikes ([`flatten_final_spikes`]).
/// Every solve goes through `solver`, with the user's curve constraints of
/// `placed` plus the lowering curves and the contour cells gathered so far;
/// the result feeds the fit measurement and the write.
///
/// With `discard_unchanged` (a later pass, whose outcome the run drops
/// when it changes no cell: `second_pass` in the pipeline), the rounds
/// return `None` as soon as the terrain they end on is known to change
/// no cell, before rendering it again: nothing after that would be used.
pub(super) fn refine(
    edit: &Edit,
    views: &[ViewState],
    solver: &Solver,
    placed: &Placed,
    deformation: Deformation,
    discard_unchanged: bool,
) -> Result<Option<Rounds>, EditError> {
    let curves = &placed.demands.strokes;
    let regions = &placed.regions[..];
    edit.pb.set_message("lowering protruding silhouettes");
    let looped = run_rounds(edit, views, solver, placed, deformation)?;
    let gathered = looped.gathered;
    let mut end = looped.end.settle();
    if let Some(before) = looped.before_raised {
        drop_unworthy_raised_try(views, regions, curves, edit.opts.min_fit, before, &mut end)?;
    }
    let Settled {
        mut deformation,
        mut rendered,
        best_score,
        spare,
    } = end;
    drop(spare);
    // A terrain that changes no cell (as the write stores it) stays so
    // to the end: the unedited terrain is kept, or its spikes (none)
    // flattened. A later pass that ends there is dropped whatever it
    // measures, so it stops here.
    if discard_unchanged {
        let written = solver.as_written(&deformation);
        if changes_nothing(written.as_ref().unwrap_or(&deformation)) {
            return Ok(None);
        }
    }
    // From here on, the terrain is the one the write stores: on an integer
    // DEM the heights rounded to whole units. The test below and the
    // report measure the file a re-edit of the output will read.
    let best_score = match solver.as_written(&deformation) {
        Some(q) => {
            adopt(views, regions, &mut deformation, &mut rendered, q)?;
            fit_score(curves, &rendered)
        }
        None => best_score,
    };
    let kept_unedited = no_better_than_unedited(views, curves, best_score);
    // A later pass that keeps the terrain as it is changes no cell and
    // is dropped (see `discard_unchanged` above): it stops here, before
    // rendering the unedited terrain again.
    if kept_unedited && discard_unchanged {
        return Ok(None);
    }
    if kept_unedited {
        let before = unchanged(deformation.clone());
        adopt(views, regions, &mut deformation, &mut rendered, before)?;
    }
    // No spikes: a lone apex (or pit) of the change field gets a
    // neighbour behind it within half a cell.
    if flatten_final_spikes(views, &mut deformation, &placed.demands.fixed) > 0 {
        if let Some(q) = solver.as_written(&deformation) {
            deformation = q;
        }
        rendered = render_all(views, regions, &deformation, Some(&rendered))?;
    }
    Ok(Some(Rounds {
        deformation,
        rendered,
        lowering_iterations: gathered.iterations,
        silhouettes_lowered: gathered.lowered,
        contour_iterations: gathered.contour_rounds,
        lowering_constraints: gathered.constraints.len() - gathered.user_constraints,
        kept_unedited,
    }))
}

/// A terrain, its score and its renders.
type Scored = (f64, Deformation, Vec<RenderedView>);

/// Where the round loop ended: the terrain of the latest solve, the best
/// round (its score, terrain and renders) and the latest round's score
/// and renders when it is not the best.
struct LoopEnd {
    deformation: Deformation,
    best: Option<Scored>,
    last: Option<(f64, Vec<RenderedView>)>,
}

/// What [`run_rounds`] leaves: where the loop ended, what it gathered,
/// and, when the last try lowered raised crests (or would have been
/// dropped), the best round before it (score, terrain).
struct Looped {
    end: LoopEnd,
    gathered: Gathered,
    before_raised: Option<(f64, Deformation)>,
}

/// The terrain the rounds settle on, its renders and score, and the best
/// round's terrain and renders kept aside (`spare`) when the latest round
/// only equalled it: the edit may go back to that terrain, and it renders
/// the same.
struct Settled {
    deformation: Deformation,
    rendered: Vec<RenderedView>,
    best_score: f64,
    spare: Option<(Deformation, Vec<RenderedView>)>,
}

/// The rounds: render every view, score the fit, keep the best round,
/// gather the next round's constraints and solve, until a round stops
/// helping ([`STALLED_ROUNDS`]) or no view asks for more; then, once, the
/// try that lowers the crests raised over anchored stretches
/// ([`lower_raised_crests`]).
fn run_rounds(
    edit: &Edit,
    views: &[ViewState],
    solver: &Solver,
    placed: &Placed,
    mut deformation: Deformation,
) -> Result<Looped, EditError> {
    let opts = edit.opts;
    let curves = &placed.demands.strokes;
    let regions = &placed.regions[..];
    let mut gathered = Gathered::new(placed.demands.curves.clone(), views.len());
    // The best round so far: its score, terrain and renders (kept, so
    // that going back to it renders nothing again), and the renders of the
    // latest round when it is not the best.
    let mut best: Option<Scored> = None;
    // The constraints that made the best round's terrain, for the last
    // try below.
    let mut best_made_by = gathered.made_by();
    let mut raised_tried = false;
    // The best round before that try: (score, terrain).
    let mut before_raised: Option<(f64, Deformation)> = None;
    let perfect = perfect_score(curves);
    let mut last: Option<(f64, Vec<RenderedView>)> = None;
    let mut stalled = 0;
    loop {
        // The latest round's renders: the best's unless it did worse.
        let latest = match (&last, &best) {
            (Some((_, r)), _) | (None, Some((_, _, r))) => Some(&r[..]),
            (None, None) => None,
        };
        let renders = render_all(views, regions, &deformation, latest)?;
        let score = fit_score(curves, &renders);
        if debug() {
            print_unfitted(curves, &renders);
        }
        if debug() {
            eprintln!(
                "round: fit score {score:.3} (best {:?}), lowering {:?}, contour {:?}",
                best.as_ref().map(|b| b.0),
                gathered.iterations,
                gathered.contour_rounds
            );
        }
        let stopped = match &best {
            Some((b, _, _)) if score <= *b + 1e-9 => {
                stalled += 1;
                let stop = score < *b - 1e-9 || stalled >= STALLED_ROUNDS;
                last = Some((score, renders));
                stop
            }
            _ => {
                stalled = 0;
                last = None;
                best = Some((score, deformation.clone(), renders));
                best_made_by = gathered.made_by();
                false
            }
        };
        let rendered = match (&last, &best) {
            (Some((_, r)), _) | (None, Some((_, _, r))) => r,
            (None, None) => unreachable!("a round's renders are kept"),
        };
        // A stopped round adds nothing: the last try below, or the end.
        let changed = !stopped && gathered.round(views, rendered, curves, opts);
        if !changed {
            match lower_raised_crests(
                &mut raised_tried,
                views,
                curves,
                best.as_ref(),
                perfect,
                opts.min_fit,
            ) {
                RaisedTry::Lower(next) => {
                    before_raised = best.as_ref().map(|b| (b.0, b.1.clone()));
                    gathered.restart(&best_made_by, next);
                    deformation = gathered.solve(solver)?;
                    stalled = 0;
                    continue;
                }
                // The try would be dropped: the edit ends where a dropped
                // try leaves it, on the best round's terrain.
                RaisedTry::CannotComplete => {
                    before_raised = best.as_ref().map(|b| (b.0, b.1.clone()));
                }
                RaisedTry::Nothing => {}
            }
            break;
        }
        edit.pb.set_message(format!(
            "lowering protruding silhouettes, fitting contours: round {}",
            gathered.rounds()
        ));
        deformation = gathered.solve(solver)?;
    }
    Ok(Looped {
        end: LoopEnd {
            deformation,
            best,
            last,
        },
        gathered,
        before_raised,
    })
}

impl LoopEnd {
    /// The best round's terrain and renders, if a later one did worse.
    /// When the latest round only equalled it, the best round's terrain
    /// and renders are kept aside ([`Settled::spare`]).
    fn settle(self) -> Settled {
        let LoopEnd {
            deformation,
            best,
            last,
        } = self;
        let best_score = best.as_ref().map_or(0.0, |b| b.0);
        let (deformation, rendered, spare) = match (last, best) {
            (Some((score, r)), Some((b, d, best_r))) => {
                if score < b - 1e-9 {
                    (d, best_r, None)
                } else {
                    (deformation, r, Some((d, best_r)))
                }
            }
            (None, Some((_, _, r))) | (Some((_, r)), None) => (deformation, r, None),
            (None, None) => unreachable!("the loop renders at least once"),
        };
        Settled {
            deformation,
            rendered,
            best_score,
            spare,
        }
    }
}

/// The lowered crests are kept only when they complete the edit (every
/// stroke fitted at least `min_fit`) and are worth their change (the fit
/// rose by at least [`RAISED_TRY_MIN_GAIN`] over `before`, the best round
/// before the try). Short of that, the rounds' terrain before the try
/// stands: a partial gain there moved terrain that a second edit of the
/// output would move again, and a gain of a column or two does not
/// justify lowering a crest by tens of metres.
fn drop_unworthy_raised_try(
    views: &[ViewState],
    regions: &[StrokeRegion],
    curves: &[Vec<StrokeCurve>],
    min_fit: f64,
    (score_before, d): (f64, Deformation),
    end: &mut Settled,
) -> Result<(), EditError> {
    // (the rounds keep a later round that only equals the best, so the
    // terrain may be the try's even when the score did not rise)
    let worth = end.best_score >= score_before + RAISED_TRY_MIN_GAIN
        && worst_stroke_fit(curves, &end.rendered) >= min_fit;
    if !worth {
        // (`rendered` is `deformation`'s render: when that is the best
        // round's terrain already, it is not rendered again; when it is
        // the spare's, the spare's renders are taken)
        let spare = end.spare.take();
        adopt_rendered(
            views,
            regions,
            (&mut end.deformation, &mut end.rendered),
            d,
            spare,
        )?;
        end.best_score = score_before;
    }
    Ok(())
}

/// Do no harm: the edit fits the strokes no better than the terrain as it
/// is (the strokes already lie where its silhouettes are, to within what
/// this edit can reach), so nothing is to be changed.
fn no_better_than_unedited(
    views: &[ViewState],
    curves: &[Vec<StrokeCurve>],
    best_score: f64,
) -> bool {
    let unedited: f64 = curves
        .iter()
        .zip(views)
        .map(|(cs, v)| view_fit(cs, &v.before))
        .sum();
    let kept_unedited = unedited >= best_score - 1e-9 && best_score < perfect_score(curves) - 1e-9;
    if debug() {
        eprintln!("rounds: unedited fit {unedited:.3}, best {best_score:.3}, kept unedited {kept_unedited}");
    }
    kept_unedited
}

/// The score of every stroke fitted whole ([`fit_score`]'s most).
fn perfect_score(curves: &[Vec<StrokeCurve>]) -> f64 {
    curves.iter().map(Vec::len).sum::<usize>() as f64
}

/// `DEMSKETCH_DEBUG` is set: the rounds print what they do on stderr.
fn debug() -> bool {
    std::env::var_os("DEMSKETCH_DEBUG").is_some()
}

/// Every stroke's unfitted columns on stderr: column (`a`: anchored) and
/// the distance to its nearest boundary, pixels.
fn print_unfitted(curves: &[Vec<StrokeCurve>], renders: &[RenderedView]) {
    for (cs, r) in curves.iter().zip(renders) {
        for c in cs {
            let missed: Vec<String> = c
                .columns(r.camera.width)
                .into_iter()
                .filter_map(|(i, y, _)| {
                    let (near, within) = r.boundary_near(i, y, super::fit::FIT_TOLERANCE_PX);
                    let anchored = if c.is_anchored(i as f64 + 0.5) {
                        "a"
                    } else {
                        ""
                    };
                    (!within).then(|| format!("{i}{anchored}:{near:.1}"))
                })
                .collect();
            eprintln!("unfitted {}: {}", c.id, missed.join(" "));
        }
    }
}

/// Each view's region on `deformation`'s terrain, taking from the views'
/// `earlier` renders what the change since cannot reach (most of the
/// image after a round that changed little).
fn render_all(
    views: &[ViewState],
    regions: &[StrokeRegion],
    deformation: &Deformation,
    earlier: Option<&[RenderedView]>,
) -> Result<Vec<RenderedView>, EditError> {
    views
        .iter()
        .zip(regions)
        .enumerate()
        .map(|(k, (v, r))| {
            render_edited_after(v, deformation, Some(r), earlier.and_then(|e| e.get(k)))
        })
        .collect()
}

/// Makes `next` the rounds' terrain, rendering it only when it differs
/// from the one `rendered` shows (the same terrain renders the same).
fn adopt(
    views: &[ViewState],
    regions: &[StrokeRegion],
    deformation: &mut Deformation,
    rendered: &mut Vec<RenderedView>,
    next: Deformation,
) -> Result<(), EditError> {
    adopt_rendered(views, regions, (deformation, rendered), next, None)
}

/// [`adopt`], also taking `spare`'s renders (an earlier round's terrain
/// and its renders) when `next` is that terrain.
fn adopt_rendered(
    views: &[ViewState],
    regions: &[StrokeRegion],
    (deformation, rendered): (&mut Deformation, &mut Vec<RenderedView>),
    next: Deformation,
    spare: Option<(Deformation, Vec<RenderedView>)>,
) -> Result<(), EditError> {
    if !same_terrain(deformation, &next) {
        *rendered = match spare {
            Some((d, r)) if same_terrain(&d, &next) => r,
            _ => render_all(views, regions, &next, Some(rendered))?,
        };
    }
    *deformation = next;
    Ok(())
}

/// What the rounds have gathered: the curve constraints (the user's
/// first, then the lowered silhouettes), the contour cells, and per view
/// how many rounds of each kind found something.
struct Gathered {
    constraints: Vec<CurveConstraint>,
    /// How many of `constraints` are the user's.
    user_constraints: usize,
    cells: BTreeMap<(i64, i64), f64>,
    /// Per view: lowering rounds that found protruding silhouettes.
    iterations: Vec<usize>,
    /// Per view: protruding silhouettes lowered, over all rounds.
    lowered: Vec<usize>,
    /// Per view: contour rounds that moved a cell.
    contour_rounds: Vec<usize>,
}

/// The constraints that made a round's terrain: the curve list's length
/// then (it only grows) and the contour cells.
type MadeBy = (usize, BTreeMap<(i64, i64), f64>);

impl Gathered {
    fn new(user: Vec<CurveConstraint>, views: usize) -> Gathered {
        Gathered {
            user_constraints: user.len(),
            constraints: user,
            cells: BTreeMap::new(),
            iterations: vec![0; views],
            lowered: vec![0; views],
            contour_rounds: vec![0; views],
        }
    }

    fn made_by(&self) -> MadeBy {
        (self.constraints.len(), self.cells.clone())
    }

    /// The most rounds any view has taken of either kind.
    fn rounds(&self) -> usize {
        self.iterations
            .iter()
            .chain(&self.contour_rounds)
            .max()
            .copied()
            .unwrap_or(0)
    }

    /// One round over every view's renders: the protruding silhouettes
    /// lowered and the contour cells moved, each within its iteration
    /// limit. True when any view asks for more.
    fn round(
        &mut self,
        views: &[ViewState],
        rendered: &[RenderedView],
        curves: &[Vec<StrokeCurve>],
        opts: &super::EditOptions,
    ) -> bool {
        let mut changed = false;
        for (k, (v, after)) in views.iter().zip(rendered).enumerate() {
            if self.iterations[k] < opts.max_lowering_iterations {
                changed |= self.lower_protruding(k, after, &curves[k]);
            }
            if self.contour_rounds[k] < opts.max_contour_iterations {
                changed |= self.fit_contours(k, v, after, &curves[k]);
            }
        }
        changed
    }

    /// Section 6.2: the silhouettes of view `k` that protrude above its
    /// strokes, lowered by the paper's `h`. True when there were any.
    fn lower_protruding(&mut self, k: usize, after: &RenderedView, curves: &[StrokeCurve]) -> bool {
        let protruding = find_protruding(after, curves);
        if protruding.is_empty() {
            return false;
        }
        for p in &protruding {
            if debug() {
                let z: Vec<f64> = p.lowered.iter().map(|q| q[2]).collect();
                eprintln!(
                    "lowering: curve {} h {:.1} m, {} points, first {:?} last {:?}, z {:.0}..{:.0}",
                    p.curve,
                    p.h,
                    p.lowered.len(),
                    p.lowered.first(),
                    p.lowered.last(),
                    z.iter().cloned().fold(f64::INFINITY, f64::min),
                    z.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
                );
            }
            if !p.lowered.is_empty() {
                self.constraints.push(CurveConstraint {
                    points: p.lowered.clone(),
                });
            }
        }
        self.lowered[k] += protruding.len();
        self.iterations[k] += 1;
        true
    }

    /// The contour cells of view `k`'s unfitted strokes
    /// ([`contour_constraints`]), the lowest height where two strokes ask
    /// for one cell. True when a cell is new or moved by more than
    /// [`CELL_CHANGE_M`].
    fn fit_contours(
        &mut self,
        k: usize,
        view: &ViewState,
        after: &RenderedView,
        curves: &[StrokeCurve],
    ) -> bool {
        let mut round: BTreeMap<(i64, i64), f64> = BTreeMap::new();
        let cells = &self.cells;
        let known = |col: i64, row: i64| cells.contains_key(&(col, row));
        for c in contour_constraints(after, curves, view.window_offset, &known) {
            let h = round.entry((c.col, c.row)).or_insert(c.height);
            *h = h.min(c.height);
        }
        let mut moved = false;
        for (&(col, row), &height) in &round {
            if debug() {
                eprintln!("contour cell: col {col} row {row} height {height:.1}");
            }
            let old = self.cells.insert((col, row), height);
            moved |= old.is_none_or(|h| (h - height).abs() > CELL_CHANGE_M);
        }
        if moved {
            self.contour_rounds[k] += 1;
        }
        moved
    }

    /// Back to the constraints that made the best round's terrain
    /// (`made_by`), plus the lowered crests of `next`, counted per view.
    fn restart(&mut self, made_by: &MadeBy, next: Vec<Vec<Protrusion>>) {
        self.constraints.truncate(made_by.0);
        self.cells.clone_from(&made_by.1);
        for (k, protrusions) in next.into_iter().enumerate() {
            if protrusions.is_empty() {
                continue;
            }
            self.lowered[k] += protrusions.len();
            self.iterations[k] += 1;
            self.constraints.extend(
                protrusions
                    .into_iter()
                    .filter(|p| !p.lowered.is_empty())
                    .map(|p| CurveConstraint { points: p.lowered }),
            );
        }
    }

    /// The terrain of everything gathered.
    fn solve(&self, solver: &Solver) -> Result<Deformation, EditError> {
        let cell_list: Vec<CellConstraint> = self
            .cells
            .iter()
            .map(|(&(col, row), &height)| CellConstraint { col, row, height })
            .collect();
        solver.solve(&self.constraints, &cell_list)
    }
}

/// Whether `a` and `b` give every view the same terrain: the same window,
/// base heights and displacements, to the bit (a view's terrain is the
/// base plus the displacement where that is finite and not zero).
fn same_terrain(a: &Deformation, b: &Deformation) -> bool {
    let bits = |x: &[f32], y: &[f32]| {
        x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits())
    };
    a.window == b.window
        && bits(&a.base.data, &b.base.data)
        && bits(&a.displacement, &b.displacement)
}

/// Whether `d` changes no cell: every displacement zero (or nodata), and
/// counted so ([`crate::deform::DeformStats::changed_cells`]). Such a
/// deformation has no spikes to flatten and stays unchanged to the end of
/// the rounds.
fn changes_nothing(d: &Deformation) -> bool {
    d.stats.changed_cells == 0 && d.displacement.iter().all(|m| *m == 0.0 || m.is_nan())
}

/// What the last try of the rounds does ([`lower_raised_crests`]).
enum RaisedTry {
    /// Lower these crests, per view, and go on from the best round.
    Lower(Vec<Vec<Protrusion>>),
    /// There are crests, but lowering them cannot bring every stroke to
    /// `min_fit` ([`can_complete`]): the try would be dropped, so it is
    /// not made, and the edit ends where a dropped try leaves it.
    CannotComplete,
    /// No try: made already, the best round fits every stroke, or the
    /// edit raised no crest over an anchored stretch.
    Nothing,
}

/// The last try of the rounds, once they stop short of a perfect fit:
/// the crests the edit raised over the strokes' anchored stretches in the
/// best round's renders ([`find_raised_over_anchored`]), per view. What
/// the try brings is kept only when every stroke then fits `min_fit`, so
/// a try that cannot get there ([`can_complete`]) is not made: it would
/// only cost its solve and renders. Tried once, from the best round, after
/// the paper's lowering and the contour rounds have done what they can:
/// where they reach a full fit it never runs, and a try that does not
/// raise the fit is dropped like any other round.
fn lower_raised_crests(
    tried: &mut bool,
    views: &[ViewState],
    curves: &[Vec<StrokeCurve>],
    best: Option<&(f64, Deformation, Vec<RenderedView>)>,
    perfect: f64,
    min_fit: f64,
) -> RaisedTry {
    let Some((score, _, renders)) = best else {
        return RaisedTry::Nothing;
    };
    if *tried || *score >= perfect - 1e-9 {
        return RaisedTry::Nothing;
    }
    *tried = true;
    let per_stroke: Vec<Vec<Vec<Protrusion>>> = views
        .iter()
        .zip(renders)
        .zip(curves)
        .map(|((v, after), cs)| find_raised_over_anchored(after, &v.before, cs))
        .collect();
    if per_stroke.iter().flatten().all(Vec::is_empty) {
        return RaisedTry::Nothing;
    }
    if !can_complete(curves, renders, &per_stroke, min_fit) {
        return RaisedTry::CannotComplete;
    }
    RaisedTry::Lower(
        per_stroke
            .into_iter()
            .map(|strokes| strokes.into_iter().flatten().collect())
            .collect(),
    )
}

/// Whether lowering the raised crests `raised` (per view, per stroke)
/// could bring every stroke to `min_fit`: a stroke's columns fitted now
/// plus those the try lowers a crest over (counted per run, so a column
/// under two crests counts twice: an upper bound) must reach `min_fit`
/// of its columns. The lowering moves terrain only near the crests, so a
/// stroke short of that bound stays short and the try would be dropped.
fn can_complete(
    curves: &[Vec<StrokeCurve>],
    renders: &[RenderedView],
    raised: &[Vec<Vec<Protrusion>>],
    min_fit: f64,
) -> bool {
    curves
        .iter()
        .zip(renders)
        .zip(raised)
        .all(|((cs, view), per_stroke)| {
            cs.iter().zip(per_stroke).all(|(c, runs)| {
                let columns = c.columns(view.camera.width).len();
                if columns == 0 {
                    return false;
                }
                let fitted = fitted_fraction(c, view) * columns as f64;
                let lowered: usize = runs.iter().map(|p| p.hidden_columns).sum();
                (fitted + lowered as f64) / columns as f64 >= min_fit - 1e-9
            })
        })
}

/// The lowest fitted fraction of any stroke of any view.
fn worst_stroke_fit(curves: &[Vec<StrokeCurve>], rendered: &[RenderedView]) -> f64 {
    curves
        .iter()
        .zip(rendered)
        .flat_map(|(cs, view)| cs.iter().map(move |c| fitted_fraction(c, view)))
        .fold(f64::INFINITY, f64::min)
}

/// `d` with no displacement anywhere (nodata stays NaN).
fn unchanged(mut d: Deformation) -> Deformation {
    for m in d.displacement.iter_mut().filter(|m| !m.is_nan()) {
        *m = 0.0;
    }
    d.stats.changed_cells = 0;
    d.stats.max_abs_displacement_m = 0.0;
    d
}

/// [`flatten_spikes`] on the final deformation, with the viewpoints as
/// eyes and the constrained and fixed cells held.
fn flatten_final_spikes(
    views: &[ViewState],
    deformation: &mut Deformation,
    fixed: &[CellConstraint],
) -> usize {
    let gt = &deformation.base.geotransform;
    let eyes: Vec<(f64, f64)> = views
        .iter()
        .filter_map(|v| gt.crs_to_pixel(v.frame.eye_crs.0, v.frame.eye_crs.1))
        .collect();
    let w = deformation.window;
    let fixed: HashSet<(i64, i64)> = fixed.iter().map(|c| (c.col, c.row)).collect();
    let constrained = deformation.constrained.clone();
    let held = |c: usize, r: usize| {
        constrained[r * w.width + c] || fixed.contains(&(w.col + c as i64, w.row + r as i64))
    };
    flatten_spikes(deformation, &eyes, &held)
}

/// The least rise of the summed fit ([`fit_score`]: a share of one
/// stroke's columns) for which the lowered raised crests are kept.
pub const RAISED_TRY_MIN_GAIN: f64 = 0.01;

/// The rounds stop at the first one that does not improve the strokes'
/// fit (the best terrain so far is kept).
pub const STALLED_ROUNDS: usize = 1;

/// Share of the strokes' columns fitted, summed over all views' strokes:
/// what a round of lowering or contour fitting must improve.
fn fit_score(curves: &[Vec<StrokeCurve>], rendered: &[RenderedView]) -> f64 {
    curves
        .iter()
        .zip(rendered)
        .map(|(cs, view)| view_fit(cs, view))
        .sum()
}

/// [`fit_score`] of one view's strokes.
fn view_fit(strokes: &[StrokeCurve], view: &RenderedView) -> f64 {
    strokes.par_iter().map(|c| fitted_fraction(c, view)).sum()
}
