//! Candidate features and their costs: the priority list of each stroke
//! (section 5.2.1 of Tassé et al.).
//!
//! For a stroke `s`, every view feature `f` whose projection covers enough
//! of the stroke's x interval is turned into a candidate:
//!
//! 1. **Truncation**: sweeping a vertical line across `s`, the parts of `f`
//!    whose projection never meets the line are removed (the feature is cut
//!    to the stroke's x interval, with interpolated end points).
//! 2. **Extension**: if `f` does not reach an end of `s`, it is extended
//!    along its 3D end tangent until its projection reaches the stroke's end
//!    (at constant depth when the tangent cannot get there).
//! 3. **Altitude adjustment**: each point `q` is moved vertically so that it
//!    projects onto the stroke:
//!    `q.z += k |q_p - q_p^s| |q - eye| / |q_p - eye|`, where `q_p` is the
//!    projection of `q` on the image plane, `q_p^s` the stroke point on the
//!    same vertical line, and `k` the sign that brings `q_p` to the stroke
//!    (the paper's "k = -1 if f_p is below s" reads in image coordinates, y
//!    down: a feature drawn above the stroke is lowered). Distances on the
//!    image plane are in pixels, `|q_p - eye|` uses the focal length.
//! 4. **Costs** of the adjusted (deformed) feature, equation (1):
//!    - `E_dis = w1 / CurveLength(f_p) * integral over f_p of h_fp`, with
//!      `h_fp` the vertical pixel distance between `f_p` and `s` (pixels);
//!    - `E_def = w2 / CurveLength(f) * integral over f of h_f`, with `h_f`
//!      the altitude difference between the deformed `f` and the terrain
//!      below it, seen from the eye: `h_f * focal / depth`, pixels (the
//!      paper gives metres; in metres a feature near the eye wins only
//!      because lifting it there is cheap, so the terms are put in one
//!      unit, that of `E_dis`);
//!    - `E_sam = w3 * LongestEdge(f) / max over the list of LongestEdge(g)`;
//!    - `E_ext = w4 * ExtendedCurveLength(f) / CurveLength(f)`.
//!
//! The candidates sorted by total cost form the stroke's priority list.

use rayon::prelude::*;

use super::file::CostWeights;
use super::projection::{add, dist, lerp3, scale, sub, FeatureKind, ViewFeature, ViewProjection};
use super::stroke::Stroke;

/// The four cost terms of a candidate and their sum.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct CostTerms {
    pub dissimilarity: f64,
    pub deformation: f64,
    pub sampling: f64,
    pub extension: f64,
    pub total: f64,
}

/// One point of a candidate (a truncated, extended, deformed feature).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidatePoint {
    /// Projection of the feature point before deformation.
    pub pixel: [f64; 2],
    /// Projection after deformation (on the stroke, up to the formula's
    /// approximation).
    pub deformed_pixel: [f64; 2],
    /// Distance of the deformed point from the eye, metres.
    pub depth: f64,
    /// The feature point before deformation.
    pub original: [f64; 3],
    /// The feature point after the altitude adjustment.
    pub deformed: [f64; 3],
    /// `true` for points added by extension.
    pub extended: bool,
}

/// A feature prepared for one stroke, with its costs.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    pub feature_id: usize,
    pub kind: FeatureKind,
    /// Points by increasing (deformed) pixel x.
    pub points: Vec<CandidatePoint>,
    pub costs: CostTerms,
    /// Share of the stroke's x extent covered by the feature itself.
    pub coverage: f64,
    /// Longest edge of the deformed curve, metres.
    pub longest_edge_m: f64,
    /// Length of the deformed curve, metres.
    pub length_m: f64,
    /// Length of its extended parts, metres.
    pub extended_length_m: f64,
}

impl Candidate {
    /// Depth (distance from the eye) of the deformed candidate at pixel
    /// column `x`, interpolated; `None` outside its x range.
    pub fn depth_at(&self, x: f64) -> Option<f64> {
        interp_by_x(&self.points, x, |p| p.deformed_pixel[0], |p| p.depth)
    }

    /// Deformed world point at pixel column `x`.
    pub fn world_at(&self, x: f64) -> Option<[f64; 3]> {
        let pts = &self.points;
        let first = pts.first()?;
        let last = pts.last()?;
        if !(x >= first.deformed_pixel[0] && x <= last.deformed_pixel[0]) {
            return None;
        }
        let i = pts.partition_point(|p| p.deformed_pixel[0] < x);
        if i == 0 {
            return Some(first.deformed);
        }
        let (a, b) = (&pts[i - 1], &pts[i.min(pts.len() - 1)]);
        let dx = b.deformed_pixel[0] - a.deformed_pixel[0];
        let t = if dx > 1e-12 {
            (x - a.deformed_pixel[0]) / dx
        } else {
            1.0
        };
        Some(lerp3(a.deformed, b.deformed, t))
    }

    /// x range of the deformed projection.
    pub fn x_range(&self) -> (f64, f64) {
        match (self.points.first(), self.points.last()) {
            (Some(a), Some(b)) => (a.deformed_pixel[0], b.deformed_pixel[0]),
            _ => (f64::NAN, f64::NAN),
        }
    }
}

pub(crate) fn interp_by_x<T>(
    pts: &[T],
    x: f64,
    key: impl Fn(&T) -> f64,
    val: impl Fn(&T) -> f64,
) -> Option<f64> {
    let first = pts.first()?;
    let last = pts.last()?;
    if !(x >= key(first) && x <= key(last)) {
        return None;
    }
    let i = pts.partition_point(|p| key(p) < x);
    if i == 0 {
        return Some(val(first));
    }
    let (a, b) = (&pts[i - 1], &pts[i.min(pts.len() - 1)]);
    let dx = key(b) - key(a);
    let t = if dx > 1e-12 { (x - key(a)) / dx } else { 1.0 };
    Some(val(a) + t * (val(b) - val(a)))
}

/// The priority list of one stroke: candidates by increasing total cost.
#[derive(Debug, Clone, PartialEq)]
pub struct PriorityList {
    pub candidates: Vec<Candidate>,
    /// Candidates before truncation of the list to `max_candidates`.
    pub considered: usize,
}

/// Options of candidate construction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CandidateOptions {
    pub weights: CostWeights,
    /// Minimum share of the stroke's x extent the feature must cover.
    pub min_coverage: f64,
    /// Length of the priority list kept.
    pub max_candidates: usize,
    /// Pixel step of extension samples.
    pub extension_step_px: f64,
}

impl Default for CandidateOptions {
    fn default() -> Self {
        CandidateOptions {
            weights: CostWeights::default(),
            min_coverage: 0.5,
            max_candidates: 32,
            extension_step_px: 4.0,
        }
    }
}

/// Builds the priority list of `stroke` among `features`.
pub fn priority_list(
    stroke: &Stroke,
    features: &[ViewFeature],
    proj: &dyn ViewProjection,
    opts: &CandidateOptions,
) -> PriorityList {
    let mut cands: Vec<Candidate> = features
        .par_iter()
        .filter_map(|f| build_candidate(stroke, f, proj, opts))
        .collect();
    finish_list(&mut cands, opts);
    let considered = cands.len();
    cands.truncate(opts.max_candidates);
    PriorityList {
        candidates: cands,
        considered,
    }
}

/// Adds the sampling term (normalised by the longest edge in the list) and
/// sorts by total cost (ties by feature id).
fn finish_list(cands: &mut [Candidate], opts: &CandidateOptions) {
    let max_edge = cands
        .iter()
        .map(|c| c.longest_edge_m)
        .fold(0.0_f64, f64::max);
    for c in cands.iter_mut() {
        c.costs.sampling = if max_edge > 0.0 {
            opts.weights.sampling * c.longest_edge_m / max_edge
        } else {
            0.0
        };
        c.costs.total =
            c.costs.dissimilarity + c.costs.deformation + c.costs.sampling + c.costs.extension;
    }
    cands.sort_by(|a, b| {
        a.costs
            .total
            .total_cmp(&b.costs.total)
            .then(a.feature_id.cmp(&b.feature_id))
    });
}

/// Truncates, extends and deforms one feature for one stroke and computes
/// its dissimilarity, deformation and extension costs (the sampling cost
/// needs the whole list). `None` when the feature does not cover enough of
/// the stroke.
pub fn build_candidate(
    stroke: &Stroke,
    feature: &ViewFeature,
    proj: &dyn ViewProjection,
    opts: &CandidateOptions,
) -> Option<Candidate> {
    let (sx0, sx1) = stroke.x_range();
    let span = sx1 - sx0;
    if span <= 0.0 {
        return None;
    }
    // Quick rejection on the feature's x range (most features of a view do
    // not cover a given stroke).
    let (fa, fb) = feature.x_range()?;
    if !(fb.min(sx1) - fa.max(sx0) >= opts.min_coverage * span) {
        return None;
    }
    let samples = monotone_samples(feature);
    if samples.len() < 2 {
        return None;
    }
    let fx0 = samples[0].0;
    let fx1 = samples[samples.len() - 1].0;
    let overlap = fx1.min(sx1) - fx0.max(sx0);
    if overlap <= 0.0 {
        return None;
    }
    let coverage = overlap / span;
    if coverage < opts.min_coverage {
        return None;
    }
    // 1. Truncation to [sx0, sx1].
    let mut pts = truncate(proj, &samples, (sx0, sx1));
    if pts.len() < 2 {
        return None;
    }
    // 2. Extension to cover the stroke.
    extend_to_cover(proj, &mut pts, (sx0, sx1), opts.extension_step_px.max(0.5));
    // 3. Altitude adjustment.
    let (cpoints, hfp, hf) = adjust_altitude(stroke, proj, &pts);
    // 4. Costs.
    let c = cost_integrals(&cpoints, &hfp, &hf);
    let costs = CostTerms {
        dissimilarity: opts.weights.dissimilarity * c.dissimilarity,
        deformation: opts.weights.deformation * c.deformation,
        sampling: 0.0,
        extension: opts.weights.extension * c.extension,
        total: 0.0,
    };
    Some(Candidate {
        feature_id: feature.id,
        kind: feature.kind,
        points: cpoints,
        costs,
        coverage: coverage.min(1.0),
        longest_edge_m: c.longest,
        length_m: c.length,
        extended_length_m: c.extended_length,
    })
}

/// A point of a truncated (and extended) feature: its pixel and depth,
/// its world point, and whether the extension made it.
type FeaturePoint = (([f64; 2], f64), [f64; 3], bool);

/// The feature's finite samples, keeping them x-monotone (the producer's
/// contract), each with its pixel column.
fn monotone_samples(feature: &ViewFeature) -> Vec<(f64, &super::projection::FeatureSample)> {
    let mut samples = Vec::with_capacity(feature.samples.len());
    for s in &feature.samples {
        if !(s.pixel[0].is_finite() && s.pixel[1].is_finite() && s.depth.is_finite()) {
            continue;
        }
        match samples.last() {
            Some(&(p, _)) if s.pixel[0] < p => {}
            _ => samples.push((s.pixel[0], s)),
        }
    }
    samples
}

/// The feature truncated to the stroke's columns `sx0..sx1`, its ends cut
/// where it crosses them (interpolated in the world and projected).
fn truncate(
    proj: &dyn ViewProjection,
    samples: &[(f64, &super::projection::FeatureSample)],
    (sx0, sx1): (f64, f64),
) -> Vec<FeaturePoint> {
    let mut pts: Vec<FeaturePoint> = Vec::new();
    let cut = |a: &super::projection::FeatureSample,
               b: &super::projection::FeatureSample,
               x: f64|
     -> (([f64; 2], f64), [f64; 3]) {
        let dx = b.pixel[0] - a.pixel[0];
        let t = if dx > 1e-12 {
            (x - a.pixel[0]) / dx
        } else {
            0.0
        };
        let w = lerp3(a.world, b.world, t);
        match proj.project(w) {
            Some((p, d)) => (([x, p[1]], d), w),
            None => (
                (
                    [x, a.pixel[1] + t * (b.pixel[1] - a.pixel[1])],
                    a.depth + t * (b.depth - a.depth),
                ),
                w,
            ),
        }
    };
    for k in 0..samples.len() {
        let s = samples[k].1;
        let x = s.pixel[0];
        if x < sx0 {
            if k + 1 < samples.len() && samples[k + 1].0 > sx0 {
                let (pd, w) = cut(s, samples[k + 1].1, sx0);
                pts.push((pd, w, false));
            }
            continue;
        }
        if x > sx1 {
            if k > 0 && samples[k - 1].0 < sx1 {
                let (pd, w) = cut(samples[k - 1].1, s, sx1);
                pts.push((pd, w, false));
            }
            break;
        }
        pts.push(((s.pixel, s.depth), s.world, false));
    }
    pts
}

/// Extends the truncated feature `pts` (at least two points) along its
/// end directions until it covers the stroke's columns `sx0..sx1`, a
/// point every `step` pixels.
fn extend_to_cover(
    proj: &dyn ViewProjection,
    pts: &mut Vec<FeaturePoint>,
    (sx0, sx1): (f64, f64),
    step: f64,
) {
    if pts[0].0 .0[0] > sx0 + 1e-6 {
        let ext = extend(proj, pts[0].1, pts[1].1, pts[0].0, sx0, step);
        let mut front: Vec<_> = ext.into_iter().rev().map(|(pd, w)| (pd, w, true)).collect();
        front.append(pts);
        *pts = front;
    }
    let n = pts.len();
    if pts[n - 1].0 .0[0] < sx1 - 1e-6 {
        let ext = extend(proj, pts[n - 1].1, pts[n - 2].1, pts[n - 1].0, sx1, step);
        pts.extend(ext.into_iter().map(|(pd, w)| (pd, w, true)));
    }
}

/// Each feature point raised or lowered onto the stroke's sight line (the
/// paper's altitude adjustment), with per point the stroke-to-feature
/// distance in pixels and the lift seen from the eye in pixels.
fn adjust_altitude(
    stroke: &Stroke,
    proj: &dyn ViewProjection,
    pts: &[FeaturePoint],
) -> (Vec<CandidatePoint>, Vec<f64>, Vec<f64>) {
    let (w, h) = proj.image_size();
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let f = proj.focal_px();
    let eye = proj.eye();
    let mut cpoints: Vec<CandidatePoint> = Vec::with_capacity(pts.len());
    let mut hfp = Vec::with_capacity(pts.len());
    let mut hf = Vec::with_capacity(pts.len());
    for &((pixel, _), world, extended) in pts {
        let ys = stroke.y_at_clamped(pixel[0]);
        // Signed pixel offset: positive when the feature is drawn below the
        // stroke on screen (it must be raised).
        let dv = pixel[1] - ys;
        let qp_eye = (f * f + (pixel[0] - cx).powi(2) + (pixel[1] - cy).powi(2)).sqrt();
        let dz = dv * dist(world, eye) / qp_eye;
        let deformed = [world[0], world[1], world[2] + dz];
        let (deformed_pixel, depth) = proj
            .project(deformed)
            .unwrap_or(([pixel[0], ys], dist(deformed, eye)));
        let ground = proj.terrain_height(world[0], world[1]).unwrap_or(world[2]);
        hfp.push(dv.abs());
        // In pixels (the lift seen from the eye): in metres a near feature
        // would win only because lifting it is cheap close to the eye.
        hf.push((deformed[2] - ground).abs() * f / depth.max(1e-9));
        cpoints.push(CandidatePoint {
            pixel,
            deformed_pixel,
            depth,
            original: world,
            deformed,
            extended,
        });
    }
    // Keep the deformed projection x-monotone (it moves slightly with pitch).
    for i in 1..cpoints.len() {
        if cpoints[i].deformed_pixel[0] < cpoints[i - 1].deformed_pixel[0] {
            cpoints[i].deformed_pixel[0] = cpoints[i - 1].deformed_pixel[0];
        }
    }
    (cpoints, hfp, hf)
}

/// The unweighted cost terms of a candidate, and its lengths.
struct CostIntegrals {
    /// Mean pixel distance to the stroke along the feature's image length.
    dissimilarity: f64,
    /// Mean lift (pixels) along the deformed feature's length.
    deformation: f64,
    /// Share of the deformed length that is extension.
    extension: f64,
    longest: f64,
    length: f64,
    extended_length: f64,
}

/// The integrals of equation (1)'s terms over the candidate's points,
/// each normalised by its length (the mean where a length is zero).
fn cost_integrals(cpoints: &[CandidatePoint], hfp: &[f64], hf: &[f64]) -> CostIntegrals {
    let mut len_p = 0.0;
    let mut int_p = 0.0;
    let mut len = 0.0;
    let mut int_f = 0.0;
    let mut ext_len = 0.0;
    let mut longest = 0.0_f64;
    for i in 1..cpoints.len() {
        let (a, b) = (&cpoints[i - 1], &cpoints[i]);
        let lp = super::projection::dist2(a.pixel, b.pixel);
        len_p += lp;
        int_p += lp * 0.5 * (hfp[i - 1] + hfp[i]);
        let l = dist(a.deformed, b.deformed);
        len += l;
        int_f += l * 0.5 * (hf[i - 1] + hf[i]);
        if a.extended || b.extended {
            ext_len += l;
        }
        longest = longest.max(l);
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    CostIntegrals {
        dissimilarity: if len_p > 0.0 {
            int_p / len_p
        } else {
            mean(hfp)
        },
        deformation: if len > 0.0 { int_f / len } else { mean(hf) },
        extension: if len > 0.0 { ext_len / len } else { 0.0 },
        longest,
        length: len,
        extended_length: ext_len,
    }
}

/// A point [`extend`] adds: ((pixel, depth), world).
type ExtendedPoint = (([f64; 2], f64), [f64; 3]);

/// Extends a feature from its end `end` (with `prev` the point before it)
/// until its projection reaches pixel column `target`. Returns the added
/// points, from the end outwards, as ((pixel, depth), world).
fn extend(
    proj: &dyn ViewProjection,
    end: [f64; 3],
    prev: [f64; 3],
    end_pd: ([f64; 2], f64),
    target: f64,
    step_px: f64,
) -> Vec<ExtendedPoint> {
    let x_end = end_pd.0[0];
    let dir = sub(end, prev);
    let dlen = crate::sketch::projection::norm(dir);
    let toward = |x: f64| (target - x_end) * (x - x_end) > 0.0;
    let mut out = Vec::new();
    // Along the 3D tangent: find t with projected x reaching target.
    if dlen > 1e-9 {
        let u = scale(dir, 1.0 / dlen);
        let at = |t: f64| proj.project(add(end, scale(u, t)));
        let mut lo = 0.0;
        let mut hi = dlen.max(1.0);
        let mut found = false;
        for _ in 0..60 {
            match at(hi) {
                Some((p, _)) if toward(p[0]) => {
                    if (p[0] - target) * (target - x_end) >= 0.0 {
                        found = true;
                        break;
                    }
                    lo = hi;
                    hi *= 2.0;
                }
                _ => break,
            }
        }
        if found {
            for _ in 0..60 {
                let mid = 0.5 * (lo + hi);
                match at(mid) {
                    Some((p, _)) if (p[0] - target) * (target - x_end) < 0.0 => lo = mid,
                    _ => hi = mid,
                }
            }
            let k = (((target - x_end).abs() / step_px).ceil() as usize).max(1);
            let mut ok = true;
            let mut pts = Vec::with_capacity(k);
            for i in 1..=k {
                let t = hi * i as f64 / k as f64;
                let w = add(end, scale(u, t));
                match proj.project(w) {
                    Some((mut p, d)) => {
                        if i == k {
                            p[0] = target;
                        }
                        pts.push(((p, d), w));
                    }
                    None => {
                        ok = false;
                        break;
                    }
                }
            }
            if ok {
                return pts;
            }
        }
    }
    // Constant depth at the end's image height.
    let k = (((target - x_end).abs() / step_px).ceil() as usize).max(1);
    for i in 1..=k {
        let x = x_end + (target - x_end) * i as f64 / k as f64;
        let px = [x, end_pd.0[1]];
        let w = proj.unproject(px, end_pd.1);
        out.push(((px, end_pd.1), w));
    }
    out
}
