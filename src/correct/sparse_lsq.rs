//! A small sparse weighted linear least-squares solver for the corrections
//! that need one (the cells under a control curve and its cross-sections,
//! the cells beside a hard breakline): `min sum_r w_r (a_r . x - b_r)^2`
//! over a few thousand unknowns, each row touching a handful of them. The
//! normal equations `A^T W A x = A^T W b` are assembled sparse, the
//! unknowns renumbered by reverse Cuthill-McKee (so the matrix's nonzeros
//! lie in a narrow envelope around the diagonal, as they do for cells along
//! a curve) and the system factored by an envelope (skyline) Cholesky in
//! `f64`. A direct solve is used rather than an iterative one because the
//! rows carry weights many orders of magnitude apart (the control curve
//! before its cross-sections before the curvature term), which leaves the
//! normal equations too ill-conditioned for conjugate gradients to reach
//! the curve's centimetres in a bounded number of iterations.

use std::collections::HashMap;

/// Why the system could not be solved (the program's fault: callers add a
/// damping row for every unknown, which keeps the matrix definite).
#[derive(Debug, thiserror::Error)]
pub enum LsqError {
    #[error("least squares: the normal equations are not positive definite at unknown {0}")]
    NotDefinite(usize),
    #[error("least squares: a row has a non-finite coefficient, value or weight")]
    NotFinite,
}

/// The rows of a least-squares problem over `n` unknowns.
#[derive(Debug, Clone, Default)]
pub struct Problem {
    n: usize,
    /// The normal matrix's lower triangle, `(row, col)` with `col <= row`.
    normal: HashMap<(usize, usize), f64>,
    rhs: Vec<f64>,
    finite: bool,
}

impl Problem {
    /// An empty problem over `n` unknowns.
    pub fn new(n: usize) -> Problem {
        Problem {
            n,
            normal: HashMap::new(),
            rhs: vec![0.0; n],
            finite: true,
        }
    }

    /// Number of unknowns.
    pub fn len(&self) -> usize {
        self.n
    }

    /// True when there are no unknowns.
    pub fn is_empty(&self) -> bool {
        self.n == 0
    }

    /// Adds the row `w (sum_k coef_k x_{idx_k} - b)^2` (indices may repeat:
    /// their coefficients add up).
    pub fn add_row(&mut self, terms: &[(usize, f64)], b: f64, w: f64) {
        if !(b.is_finite() && w.is_finite() && terms.iter().all(|t| t.1.is_finite())) {
            self.finite = false;
            return;
        }
        let mut merged: Vec<(usize, f64)> = Vec::with_capacity(terms.len());
        for &(i, a) in terms {
            match merged.iter_mut().find(|m| m.0 == i) {
                Some(m) => m.1 += a,
                None => merged.push((i, a)),
            }
        }
        for (k, &(i, a)) in merged.iter().enumerate() {
            self.rhs[i] += w * a * b;
            for &(j, c) in &merged[..=k] {
                let key = if j <= i { (i, j) } else { (j, i) };
                *self.normal.entry(key).or_insert(0.0) += w * a * c;
            }
        }
    }

    /// The least-squares solution.
    pub fn solve(&self) -> Result<Vec<f64>, LsqError> {
        if !self.finite {
            return Err(LsqError::NotFinite);
        }
        let n = self.n;
        if n == 0 {
            return Ok(Vec::new());
        }
        let order = rcm_order(n, &self.normal);
        let mut pos = vec![0usize; n];
        for (p, &i) in order.iter().enumerate() {
            pos[i] = p;
        }
        // Envelope: the first column of each (permuted) row.
        let mut first: Vec<usize> = (0..n).collect();
        for &(i, j) in self.normal.keys() {
            let (pi, pj) = (pos[i], pos[j]);
            let (r, c) = if pi >= pj { (pi, pj) } else { (pj, pi) };
            first[r] = first[r].min(c);
        }
        let mut start = vec![0usize; n + 1];
        for r in 0..n {
            start[r + 1] = start[r] + (r - first[r] + 1);
        }
        let mut env = vec![0f64; start[n]];
        for (&(i, j), &v) in &self.normal {
            let (pi, pj) = (pos[i], pos[j]);
            let (r, c) = if pi >= pj { (pi, pj) } else { (pj, pi) };
            env[start[r] + c - first[r]] += v;
        }
        // In-place Cholesky of the envelope: row r holds L[r][first[r]..=r].
        for r in 0..n {
            for c in first[r]..=r {
                let lo = first[r].max(first[c]);
                let mut s = env[start[r] + c - first[r]];
                for k in lo..c {
                    s -= env[start[r] + k - first[r]] * env[start[c] + k - first[c]];
                }
                if c < r {
                    env[start[r] + c - first[r]] = s / env[start[c] + c - first[c]];
                } else if s > 0.0 && s.is_finite() {
                    env[start[r] + r - first[r]] = s.sqrt();
                } else {
                    return Err(LsqError::NotDefinite(order[r]));
                }
            }
        }
        // Forward then backward substitution in the permuted numbering.
        let mut y: Vec<f64> = order.iter().map(|&i| self.rhs[i]).collect();
        for r in 0..n {
            let mut s = y[r];
            for k in first[r]..r {
                s -= env[start[r] + k - first[r]] * y[k];
            }
            y[r] = s / env[start[r] + r - first[r]];
        }
        for r in (0..n).rev() {
            y[r] /= env[start[r] + r - first[r]];
            let yr = y[r];
            for k in first[r]..r {
                y[k] -= env[start[r] + k - first[r]] * yr;
            }
        }
        let mut x = vec![0f64; n];
        for (p, &i) in order.iter().enumerate() {
            x[i] = y[p];
        }
        Ok(x)
    }
}

/// Reverse Cuthill-McKee order of the graph of the matrix's nonzeros: a
/// breadth-first search from a pseudo-peripheral unknown of each connected
/// component, neighbours by increasing degree, reversed.
fn rcm_order(n: usize, normal: &HashMap<(usize, usize), f64>) -> Vec<usize> {
    let mut adj: Vec<Vec<usize>> = vec![Vec::new(); n];
    for &(i, j) in normal.keys() {
        if i != j {
            adj[i].push(j);
            adj[j].push(i);
        }
    }
    for a in adj.iter_mut() {
        a.sort_unstable();
        a.dedup();
    }
    let mut seen = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut level = vec![usize::MAX; n];
    for s in 0..n {
        if seen[s] {
            continue;
        }
        // Pseudo-peripheral start: repeat a BFS from the farthest unknown.
        let mut root = s;
        let mut depth = 0;
        for _ in 0..4 {
            let (far, d) = farthest(root, &adj, &mut level);
            if d <= depth {
                break;
            }
            root = far;
            depth = d;
        }
        let begin = order.len();
        order.push(root);
        seen[root] = true;
        let mut head = begin;
        while head < order.len() {
            let v = order[head];
            head += 1;
            let mut next: Vec<usize> = adj[v].iter().copied().filter(|&u| !seen[u]).collect();
            next.sort_by_key(|&u| (adj[u].len(), u));
            for u in next {
                seen[u] = true;
                order.push(u);
            }
        }
        order[begin..].reverse();
    }
    order
}

/// The unknown farthest (in edges) from `root` in its component, and its
/// distance; `level` is scratch space (reset for the visited unknowns).
fn farthest(root: usize, adj: &[Vec<usize>], level: &mut [usize]) -> (usize, usize) {
    let mut queue = vec![root];
    level[root] = 0;
    let mut head = 0;
    let mut best = (root, 0);
    while head < queue.len() {
        let v = queue[head];
        head += 1;
        let l = level[v];
        if l > best.1 || (l == best.1 && adj[v].len() < adj[best.0].len()) {
            best = (v, l);
        }
        for &u in &adj[v] {
            if level[u] == usize::MAX {
                level[u] = l + 1;
                queue.push(u);
            }
        }
    }
    for &v in &queue {
        level[v] = usize::MAX;
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_an_overdetermined_line_fit() {
        // y = 2 + 3 t through five points, unknowns (a, b).
        let mut p = Problem::new(2);
        for t in 0..5 {
            let t = t as f64;
            p.add_row(&[(0, 1.0), (1, t)], 2.0 + 3.0 * t, 1.0);
        }
        let x = p.solve().unwrap();
        assert!(
            (x[0] - 2.0).abs() < 1e-12 && (x[1] - 3.0).abs() < 1e-12,
            "{x:?}"
        );
    }

    #[test]
    fn weighted_rows_win() {
        // x = 1 (weight 1e6) against x = 0 (weight 1).
        let mut p = Problem::new(1);
        p.add_row(&[(0, 1.0)], 1.0, 1e6);
        p.add_row(&[(0, 1.0)], 0.0, 1.0);
        let x = p.solve().unwrap();
        assert!((x[0] - 1e6 / (1e6 + 1.0)).abs() < 1e-12);
    }

    #[test]
    fn a_chain_in_scrambled_order_is_solved() {
        // Second differences zero, ends held: a straight line.
        let n = 50;
        let perm = |i: usize| (i * 17) % n;
        let mut p = Problem::new(n);
        for i in 1..n - 1 {
            p.add_row(
                &[(perm(i - 1), 1.0), (perm(i), -2.0), (perm(i + 1), 1.0)],
                0.0,
                1.0,
            );
        }
        p.add_row(&[(perm(0), 1.0)], 0.0, 1e4);
        p.add_row(&[(perm(n - 1), 1.0)], 49.0, 1e4);
        let x = p.solve().unwrap();
        for i in 0..n {
            assert!((x[perm(i)] - i as f64).abs() < 1e-6, "{i}: {}", x[perm(i)]);
        }
    }

    #[test]
    fn repeated_indices_add_up() {
        // (x + x - 2)^2: x = 1.
        let mut p = Problem::new(1);
        p.add_row(&[(0, 1.0), (0, 1.0)], 2.0, 1.0);
        let x = p.solve().unwrap();
        assert!((x[0] - 1.0).abs() < 1e-12, "{x:?}");
    }
}
