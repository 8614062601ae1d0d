//! The positional constraints of a control curve as a least-squares fit
//! (Maquettier section III-B, equations 3 and 4): the heights of the
//! constrained cells are chosen so that the bilinear surface between cell
//! centres passes through the curve at sample points every tenth of a cell,
//!
//! `min sum_q (sum_c w_c(q) h_c - z(q))^2 + lambda sum_c (h_c - h0_c)^2`,
//!
//! where `w_c(q)` are the bilinear weights of the four cells around `q`
//! (all of them constrained by the rasteriser's rule), `h0` the start
//! (the curve's height at each cell's closest curve point) and the small
//! damping `lambda` keeps the system well posed where the samples do not
//! determine a cell. Solved directly by [`super::sparse_lsq`] (normal
//! equations, envelope Cholesky): the joint fit of a curve and its
//! cross-sections weighs rows 1000 times apart, and CGLS (used before)
//! stopped on its 5000-iteration cap, 14 times slower on the benchmark of
//! `tools/bench_control_curve.sh`, with the same answer where it converged.

/// One sample: the window indices and weights of its bilinear stencil and
/// the height it asks for.
struct Sample {
    cells: [usize; 4],
    weights: [f64; 4],
    z: f64,
}

/// Damping `lambda` of the fit.
const DAMPING: f64 = 1e-8;

/// Samples every tenth of a cell along the curve whose four stencil cells
/// are all unknowns.
fn samples(w: usize, h: usize, unknown: &[usize], px: &[[f64; 3]]) -> Vec<Sample> {
    let mut out = Vec::new();
    let mut add = |x: f64, y: f64, z: f64| {
        let (fx0, fy0) = (x - 0.5, y - 0.5);
        if fx0 < 0.0 || fy0 < 0.0 {
            return;
        }
        let (c0, r0) = (fx0.floor() as usize, fy0.floor() as usize);
        let (fx, fy) = (fx0 - c0 as f64, fy0 - r0 as f64);
        let (c1, r1) = (c0 + 1, r0 + 1);
        if c1 >= w || r1 >= h {
            return;
        }
        let cells = [r0 * w + c0, r0 * w + c1, r1 * w + c0, r1 * w + c1];
        let weights = [
            (1.0 - fx) * (1.0 - fy),
            fx * (1.0 - fy),
            (1.0 - fx) * fy,
            fx * fy,
        ];
        // A corner with zero weight need not be an unknown.
        if (0..4).any(|k| weights[k] > 0.0 && unknown[cells[k]] == usize::MAX) {
            return;
        }
        let mut weights = weights;
        let mut cells = cells;
        for k in 0..4 {
            if unknown[cells[k]] == usize::MAX {
                weights[k] = 0.0;
                cells[k] = cells
                    .iter()
                    .copied()
                    .find(|&c| unknown[c] != usize::MAX)
                    .unwrap_or(cells[k]);
            }
        }
        out.push(Sample { cells, weights, z });
    };
    if px.len() == 1 {
        add(px[0][0], px[0][1], px[0][2]);
    }
    for seg in px.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / 0.1).ceil().max(1.0) as usize;
        for k in 0..=n {
            let t = k as f64 / n as f64;
            add(
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            );
        }
    }
    out
}

/// Fits the heights of the constrained cells (`h0[i]` for `constrained[i]`,
/// window of width `w`) to the curves `lines` (window pixel space,
/// `[x, y, z]`, each with the weight of its samples in the sum of squares).
/// Returns the fitted heights (same indexing as `h0`; unconstrained cells
/// unchanged) and the largest remaining `|bilinear - z|` at the samples.
pub fn fit(
    w: usize,
    h: usize,
    constrained: &[bool],
    h0: &[f64],
    lines: &[(&[[f64; 3]], f64)],
) -> Result<(Vec<f64>, f64), super::sparse_lsq::LsqError> {
    let mut unknown = vec![usize::MAX; constrained.len()];
    let mut cells = Vec::new();
    for (i, &k) in constrained.iter().enumerate() {
        if k {
            unknown[i] = cells.len();
            cells.push(i);
        }
    }
    let mut problem = super::sparse_lsq::Problem::new(cells.len());
    let mut rows = Vec::new();
    for &(px, weight) in lines {
        for s in samples(w, h, &unknown, px) {
            let terms: Vec<(usize, f64)> = (0..4)
                .map(|k| (unknown[s.cells[k]], s.weights[k]))
                .collect();
            let start: f64 = (0..4).map(|k| s.weights[k] * h0[s.cells[k]]).sum();
            problem.add_row(&terms, s.z - start, weight);
            rows.push((terms, s.z - start));
        }
    }
    for k in 0..cells.len() {
        problem.add_row(&[(k, 1.0)], 0.0, DAMPING);
    }
    let d = problem.solve()?;
    let worst = rows
        .iter()
        .map(|(t, r)| (t.iter().map(|&(k, a)| a * d[k]).sum::<f64>() - r).abs())
        .fold(0.0, f64::max);
    let mut out = h0.to_vec();
    for (k, &i) in cells.iter().enumerate() {
        out[i] += d[k];
    }
    Ok((out, worst))
}
