//! Energy minimisation of stroke-feature matching (section 5.2.2 of Tassé
//! et al.): choose one candidate from each stroke's priority list so that
//! the total cost is minimal, a feature is used by at most one stroke, and a
//! feature assigned to a nearer stroke is not hidden by one assigned to a
//! farther stroke.
//!
//! Strokes are processed from front to back. Choosing a feature for stroke
//! `i` removes from the lists of the strokes after it the same feature and
//! the candidates incompatible with it (the caller's `conflicts` predicate:
//! occlusion within a view, and across views for multi-view sketches). A
//! stroke whose list has been emptied gets no feature (it will be embedded
//! by the fallback) at the cost [`EMPTY_LIST_COST`], the paper's "very high
//! cost": a configuration that keeps every list non-empty wins whenever one
//! exists.
//!
//! [`branch_and_bound`] explores that tree depth first, candidates in
//! priority order, and prunes a branch as soon as its cost can no longer
//! beat the best complete solution found ([`Bound::PartialCost`], the
//! paper's bound); [`Bound::LowerBound`] also adds, for the strokes not yet
//! assigned, the cheapest cost they could get, which prunes earlier and is
//! still exact; [`Bound::ForwardChecking`] (the default) filters the lists
//! of the strokes behind after each choice and bounds with the cheapest
//! entry left in each, the tightest of the three. [`brute_force`] enumerates every combination
//! and is the reference the tests compare against.
//!
//! ```
//! use demsketch::sketch::{branch_and_bound, brute_force, Bound, Choice};
//! let lists = vec![
//!     vec![Choice { feature: 0, cost: 1.0 }, Choice { feature: 1, cost: 2.0 }],
//!     vec![Choice { feature: 0, cost: 0.5 }, Choice { feature: 2, cost: 5.0 }],
//! ];
//! let none = |_: usize, _: usize, _: usize, _: usize| false;
//! let bb = branch_and_bound(&lists, &none, Bound::LowerBound);
//! let bf = brute_force(&lists, &none);
//! assert_eq!(bb.choice, vec![Some(1), Some(0)]); // features 1 and 0: cost 2.5
//! assert!((bb.cost - bf.cost).abs() < 1e-12);
//! ```

/// Search nodes [`branch_and_bound`] visits at most by default
/// ([`branch_and_bound_with_budget`]): once that many are visited and a
/// complete solution is known, the search stops and keeps the best solution
/// found ([`Solution::stopped_early`]). With [`Bound::ForwardChecking`]
/// each compatibility row computed (one per candidate tried, cached) counts
/// as a node too. The first solution (every stroke
/// takes its cheapest available entry, front to back) is always completed,
/// whatever the budget.
pub const DEFAULT_NODE_BUDGET: u64 = 20_000;

/// Cost of a stroke left with an empty priority list (effectively infinite,
/// but finite so that solutions with fewer empty lists are preferred).
pub const EMPTY_LIST_COST: f64 = 1.0e9;

/// One entry of a priority list.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Choice {
    /// Feature id (a feature is used at most once).
    pub feature: usize,
    pub cost: f64,
}

/// Which bound prunes the search.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Bound {
    /// Partial cost against the best solution (the paper).
    PartialCost,
    /// Partial cost plus the cheapest possible cost of the remaining strokes.
    LowerBound,
    /// Forward checking: after each choice the lists of the strokes behind
    /// are filtered at once (features used, conflicts), and the bound adds,
    /// for each remaining stroke, the cheapest entry still in its filtered
    /// list (or [`EMPTY_LIST_COST`] when it is empty). Lists are bit sets,
    /// the compatibility of a choice with the lists behind is computed once
    /// per choice (in parallel) and reused. Exact, and the tightest bound.
    #[default]
    ForwardChecking,
    /// No pruning: exhaustive search of the feasible tree.
    None,
}

/// An assignment: for each stroke (front to back), the index of the chosen
/// candidate in its list, or `None` when its list was emptied.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    pub choice: Vec<Option<usize>>,
    pub cost: f64,
    /// Search nodes visited (partial assignments created).
    pub nodes: u64,
    /// Strokes left without a feature.
    pub empty: usize,
    /// The node budget ran out before the search could prove the solution
    /// optimal: `choice` is the best found within the budget.
    pub stopped_early: bool,
}

/// Minimises the total cost by branch-and-bound. `lists[i]` is stroke i's
/// priority list (strokes front to back; lists need not be sorted);
/// `conflicts(i, a, j, b)` with `i < j` says that candidate `a` of stroke `i`
/// and candidate `b` of stroke `j` cannot both be chosen. Visits at most
/// [`DEFAULT_NODE_BUDGET`] nodes.
pub fn branch_and_bound<F>(lists: &[Vec<Choice>], conflicts: &F, bound: Bound) -> Solution
where
    F: Fn(usize, usize, usize, usize) -> bool + Sync + ?Sized,
{
    branch_and_bound_with_budget(lists, conflicts, bound, DEFAULT_NODE_BUDGET)
}

/// [`branch_and_bound`] with a node budget: the search stops once `budget`
/// nodes are visited and a complete solution is known, keeping the best one
/// found, and says so in [`Solution::stopped_early`] (`u64::MAX`: exact).
pub fn branch_and_bound_with_budget<F>(
    lists: &[Vec<Choice>],
    conflicts: &F,
    bound: Bound,
    budget: u64,
) -> Solution
where
    F: Fn(usize, usize, usize, usize) -> bool + Sync + ?Sized,
{
    if bound == Bound::ForwardChecking {
        return forward_checking(lists, conflicts, budget);
    }
    let n = lists.len();
    // Candidate indices of each list by increasing cost.
    let sorted: Vec<Vec<usize>> = lists
        .iter()
        .map(|l| {
            let mut idx: Vec<usize> = (0..l.len()).collect();
            idx.sort_by(|&a, &b| l[a].cost.total_cmp(&l[b].cost).then(a.cmp(&b)));
            idx
        })
        .collect();
    // suffix[i]: lower bound of the cost of strokes i.. .
    let mut suffix = vec![0.0; n + 1];
    if bound == Bound::LowerBound {
        for i in (0..n).rev() {
            let best = lists[i]
                .iter()
                .map(|c| c.cost)
                .fold(EMPTY_LIST_COST, f64::min);
            suffix[i] = suffix[i + 1] + best;
        }
    }
    let mut st = Search {
        lists,
        sorted: &sorted,
        conflicts,
        suffix: &suffix,
        prune: bound != Bound::None,
        current: vec![None; n],
        best: vec![None; n],
        best_cost: f64::INFINITY,
        nodes: 0,
        budget,
        stopped: false,
    };
    st.visit(0, 0.0);
    let empty = st.best.iter().filter(|c| c.is_none()).count();
    Solution {
        choice: st.best,
        cost: st.best_cost,
        nodes: st.nodes,
        empty,
        stopped_early: st.stopped,
    }
}

struct Search<'a, F: ?Sized> {
    lists: &'a [Vec<Choice>],
    sorted: &'a [Vec<usize>],
    conflicts: &'a F,
    suffix: &'a [f64],
    prune: bool,
    current: Vec<Option<usize>>,
    best: Vec<Option<usize>>,
    best_cost: f64,
    nodes: u64,
    budget: u64,
    stopped: bool,
}

/// Out of budget: `nodes` visited and a complete solution known (the first
/// descent always completes).
fn out_of_budget(nodes: u64, budget: u64, best_cost: f64) -> bool {
    nodes >= budget && best_cost.is_finite()
}

impl<F> Search<'_, F>
where
    F: Fn(usize, usize, usize, usize) -> bool + ?Sized,
{
    fn visit(&mut self, depth: usize, cost: f64) {
        let n = self.lists.len();
        if depth == n {
            if cost < self.best_cost {
                self.best_cost = cost;
                self.best.clone_from(&self.current);
            }
            return;
        }
        let mut any = false;
        for k in 0..self.sorted[depth].len() {
            if self.stopped {
                return;
            }
            let b = self.sorted[depth][k];
            if !self.available(depth, b) {
                continue;
            }
            any = true;
            let c = cost + self.lists[depth][b].cost;
            if self.prune && c + self.suffix[depth + 1] >= self.best_cost {
                // Lists are visited by increasing cost: the rest is worse.
                break;
            }
            if out_of_budget(self.nodes, self.budget, self.best_cost) {
                self.stopped = true;
                return;
            }
            self.nodes += 1;
            self.current[depth] = Some(b);
            self.visit(depth + 1, c);
            self.current[depth] = None;
        }
        if !any && !self.stopped {
            let c = cost + EMPTY_LIST_COST;
            if self.prune && c + self.suffix[depth + 1] >= self.best_cost {
                return;
            }
            if out_of_budget(self.nodes, self.budget, self.best_cost) {
                self.stopped = true;
                return;
            }
            self.nodes += 1;
            self.visit(depth + 1, c);
        }
    }

    /// Is candidate `b` of stroke `j` still in its list given the choices of
    /// the strokes in front?
    fn available(&self, j: usize, b: usize) -> bool {
        let fb = self.lists[j][b].feature;
        (0..j).all(|i| match self.current[i] {
            Some(a) => self.lists[i][a].feature != fb && !(self.conflicts)(i, a, j, b),
            None => true,
        })
    }
}

/// Reference solver: enumerates every combination of one entry (or none)
/// per list and keeps the cheapest valid one. Valid: features distinct,
/// chosen pairs not in conflict, and a stroke has no feature only when every
/// entry of its list is taken or in conflict with the strokes in front.
/// `nodes` counts the nodes of the full enumeration tree.
pub fn brute_force<F>(lists: &[Vec<Choice>], conflicts: &F) -> Solution
where
    F: Fn(usize, usize, usize, usize) -> bool + ?Sized,
{
    let n = lists.len();
    let mut idx = vec![0usize; n]; // 0 = none, k = entry k-1
    let mut best: Option<(f64, Vec<Option<usize>>)> = None;
    let mut nodes: u64 = 0;
    let mut prod: u64 = 1;
    for l in lists {
        prod = prod.saturating_mul(l.len() as u64 + 1);
        nodes = nodes.saturating_add(prod);
    }
    loop {
        let choice: Vec<Option<usize>> = idx.iter().map(|&k| k.checked_sub(1)).collect();
        if valid(lists, conflicts, &choice) {
            let cost: f64 = choice
                .iter()
                .enumerate()
                .map(|(i, c)| c.map_or(EMPTY_LIST_COST, |a| lists[i][a].cost))
                .sum();
            if best.as_ref().is_none_or(|b| cost < b.0) {
                best = Some((cost, choice));
            }
        }
        // Odometer.
        let mut i = 0;
        loop {
            if i == n {
                let (cost, choice) = best.unwrap_or((f64::INFINITY, vec![None; n]));
                let empty = choice.iter().filter(|c| c.is_none()).count();
                return Solution {
                    choice,
                    cost,
                    nodes,
                    empty,
                    stopped_early: false,
                };
            }
            idx[i] += 1;
            if idx[i] <= lists[i].len() {
                break;
            }
            idx[i] = 0;
            i += 1;
        }
    }
}

/// Checks the constraints of an assignment (see [`brute_force`]).
pub fn valid<F>(lists: &[Vec<Choice>], conflicts: &F, choice: &[Option<usize>]) -> bool
where
    F: Fn(usize, usize, usize, usize) -> bool + ?Sized,
{
    let n = lists.len();
    for j in 0..n {
        match choice[j] {
            Some(b) => {
                for i in 0..j {
                    if let Some(a) = choice[i] {
                        if lists[i][a].feature == lists[j][b].feature || conflicts(i, a, j, b) {
                            return false;
                        }
                    }
                }
            }
            None => {
                // Every entry must be blocked by a stroke in front.
                let blocked = (0..lists[j].len()).all(|b| {
                    (0..j).any(|i| match choice[i] {
                        Some(a) => {
                            lists[i][a].feature == lists[j][b].feature || conflicts(i, a, j, b)
                        }
                        None => false,
                    })
                });
                if !blocked {
                    return false;
                }
            }
        }
    }
    true
}

/// Bit set over the (cost-sorted) entries of one list.
type Mask = Vec<u64>;

fn mask_first(m: &[u64]) -> Option<usize> {
    m.iter()
        .enumerate()
        .find(|(_, w)| **w != 0)
        .map(|(k, w)| 64 * k + w.trailing_zeros() as usize)
}

struct Forward<'a, F: ?Sized> {
    lists: &'a [Vec<Choice>],
    /// `sorted[j][r]`: index in `lists[j]` of the entry of rank `r`.
    sorted: Vec<Vec<usize>>,
    conflicts: &'a F,
    /// Compatibility rows, computed on first use: for choice (i, rank r),
    /// the masks of the entries of strokes `i+1..` that stay available.
    rows: Vec<Vec<Option<std::sync::Arc<Vec<Mask>>>>>,
    current: Vec<Option<usize>>,
    best: Vec<Option<usize>>,
    best_cost: f64,
    nodes: u64,
    /// Compatibility rows computed: each costs about as much as a node
    /// (more, on long lists) and counts against the budget too.
    rows_computed: u64,
    budget: u64,
    stopped: bool,
}

impl<F> Forward<'_, F>
where
    F: Fn(usize, usize, usize, usize) -> bool + Sync + ?Sized,
{
    fn row(&mut self, i: usize, r: usize) -> std::sync::Arc<Vec<Mask>> {
        if let Some(row) = &self.rows[i][r] {
            return row.clone();
        }
        use rayon::prelude::*;
        let n = self.lists.len();
        let a = self.sorted[i][r];
        let fa = self.lists[i][a].feature;
        let (lists, sorted, conflicts) = (self.lists, &self.sorted, self.conflicts);
        let row: Vec<Mask> = (i + 1..n)
            .into_par_iter()
            .map(|j| {
                let m = sorted[j].len();
                let mut mask = vec![0u64; m.div_ceil(64)];
                for (rb, &b) in sorted[j].iter().enumerate() {
                    if lists[j][b].feature != fa && !conflicts(i, a, j, b) {
                        mask[rb / 64] |= 1 << (rb % 64);
                    }
                }
                mask
            })
            .collect();
        let row = std::sync::Arc::new(row);
        self.rows_computed += 1;
        self.rows[i][r] = Some(row.clone());
        row
    }

    /// Lower bound of the cost of strokes `from..` given their masks.
    fn remaining(&self, from: usize, masks: &[Mask]) -> f64 {
        (from..self.lists.len())
            .map(|j| match mask_first(&masks[j - from]) {
                Some(r) => self.lists[j][self.sorted[j][r]].cost,
                None => EMPTY_LIST_COST,
            })
            .sum()
    }

    /// `masks[k]`: available entries of stroke `depth + k`.
    fn visit(&mut self, depth: usize, cost: f64, masks: &[Mask]) {
        let n = self.lists.len();
        if depth == n {
            if cost < self.best_cost {
                self.best_cost = cost;
                self.best.clone_from(&self.current);
            }
            return;
        }
        if self.stopped {
            return;
        }
        let rest = self.remaining(depth + 1, &masks[1..]);
        let here = masks[0].clone();
        if mask_first(&here).is_none() {
            let c = cost + EMPTY_LIST_COST;
            if c + rest >= self.best_cost {
                return;
            }
            if out_of_budget(self.nodes + self.rows_computed, self.budget, self.best_cost) {
                self.stopped = true;
                return;
            }
            self.nodes += 1;
            self.visit(depth + 1, c, &masks[1..]);
            return;
        }
        for (w, &word) in here.iter().enumerate() {
            let mut bits = word;
            while bits != 0 {
                if self.stopped {
                    return;
                }
                let r = 64 * w + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let c = cost + self.lists[depth][self.sorted[depth][r]].cost;
                // Entries come by increasing cost and `rest` only grows
                // once the lists behind are filtered: stop here.
                if c + rest >= self.best_cost {
                    return;
                }
                if self.rows[depth][r].is_none()
                    && out_of_budget(self.nodes + self.rows_computed, self.budget, self.best_cost)
                {
                    self.stopped = true;
                    return;
                }
                let row = self.row(depth, r);
                let next: Vec<Mask> = masks[1..]
                    .iter()
                    .zip(row.iter())
                    .map(|(m, f)| m.iter().zip(f).map(|(x, y)| x & y).collect())
                    .collect();
                if c + self.remaining(depth + 1, &next) >= self.best_cost {
                    continue;
                }
                if out_of_budget(self.nodes + self.rows_computed, self.budget, self.best_cost) {
                    self.stopped = true;
                    return;
                }
                self.nodes += 1;
                self.current[depth] = Some(self.sorted[depth][r]);
                self.visit(depth + 1, c, &next);
                self.current[depth] = None;
            }
        }
    }
}

fn forward_checking<F>(lists: &[Vec<Choice>], conflicts: &F, budget: u64) -> Solution
where
    F: Fn(usize, usize, usize, usize) -> bool + Sync + ?Sized,
{
    let n = lists.len();
    let sorted: Vec<Vec<usize>> = lists
        .iter()
        .map(|l| {
            let mut idx: Vec<usize> = (0..l.len()).collect();
            idx.sort_by(|&a, &b| l[a].cost.total_cmp(&l[b].cost).then(a.cmp(&b)));
            idx
        })
        .collect();
    let masks: Vec<Mask> = lists
        .iter()
        .map(|l| {
            let mut m = vec![0u64; l.len().div_ceil(64)];
            for r in 0..l.len() {
                m[r / 64] |= 1 << (r % 64);
            }
            m
        })
        .collect();
    let rows = lists.iter().map(|l| vec![None; l.len()]).collect();
    let mut st = Forward {
        lists,
        sorted,
        conflicts,
        rows,
        current: vec![None; n],
        best: vec![None; n],
        best_cost: f64::INFINITY,
        nodes: 0,
        rows_computed: 0,
        budget,
        stopped: false,
    };
    st.visit(0, 0.0, &masks);
    let empty = st.best.iter().filter(|c| c.is_none()).count();
    Solution {
        choice: st.best,
        cost: st.best_cost,
        nodes: st.nodes,
        empty,
        stopped_early: st.stopped,
    }
}
