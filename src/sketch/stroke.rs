//! Stroke preparation: from the polyline a user drew to the oriented,
//! resampled, x-monotone curve that depth ordering and matching work on.
//!
//! The paper orients every stroke clockwise (footnote 1 of section 4): a
//! silhouette bounds the terrain below it, and going clockwise around that
//! region runs along its top from left to right. Prepared strokes therefore
//! run by increasing pixel x, whatever direction they were drawn in, and
//! their tangents do not depend on the drawing direction. A terrain
//! silhouette is single-valued over the horizon axis, so a stroke that folds
//! back in x is split into x-monotone pieces (or rejected, by option); small
//! back-steps below a tolerance are drawing jitter and are dropped.
//!
//! ```
//! use demsketch::sketch::{prepare_stroke, FoldBackPolicy, StrokeError};
//! # fn main() -> Result<(), StrokeError> {
//! // Drawn right to left: prepared strokes run left to right.
//! let pieces = prepare_stroke("a", 0, &[[100.0, 50.0], [0.0, 60.0]], 2.0, 1.0,
//!     FoldBackPolicy::Split)?;
//! assert_eq!(pieces.len(), 1);
//! assert_eq!(pieces[0].points[0], [0.0, 60.0]);
//! assert!(pieces[0].y_at(50.0).is_some_and(|y| (y - 55.0).abs() < 1e-9));
//! # Ok(())
//! # }
//! ```

use super::file::FoldBackPolicy;
use super::projection::dist2;

/// A prepared stroke: x-monotone, oriented left to right, resampled.
#[derive(Debug, Clone, PartialEq)]
pub struct Stroke {
    /// Id of the stroke; pieces of a split stroke are `id#1`, `id#2`, ...
    pub id: String,
    /// Id in the sketch file.
    pub source_id: String,
    /// Index of the stroke in its view's stroke list in the file.
    pub source_index: usize,
    /// Piece number of a split stroke (0 when not split).
    pub piece: usize,
    /// Resampled points, pixels, non-decreasing x.
    pub points: Vec<[f64; 2]>,
    /// Unit tangents at the points (pixel frame, y down), pointing along the
    /// stroke (towards increasing x).
    pub tangents: Vec<[f64; 2]>,
}

/// A stroke that cannot be used, with the reason.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("stroke \"{id}\": {problem}")]
pub struct StrokeError {
    pub id: String,
    pub problem: String,
}

impl Stroke {
    /// First and last x.
    pub fn x_range(&self) -> (f64, f64) {
        (self.points[0][0], self.points[self.points.len() - 1][0])
    }

    /// Start point (leftmost).
    pub fn start(&self) -> [f64; 2] {
        self.points[0]
    }

    /// End point (rightmost).
    pub fn end(&self) -> [f64; 2] {
        self.points[self.points.len() - 1]
    }

    /// The stroke's y at pixel column x (the intersection with the vertical
    /// line through x), or `None` outside its x range.
    pub fn y_at(&self, x: f64) -> Option<f64> {
        let (x0, x1) = self.x_range();
        if !(x >= x0 && x <= x1) {
            return None;
        }
        let i = self.points.partition_point(|p| p[0] < x);
        if i == 0 {
            return Some(self.points[0][1]);
        }
        let (a, b) = (
            self.points[i - 1],
            self.points[i.min(self.points.len() - 1)],
        );
        if b[0] - a[0] <= 1e-12 {
            return Some(b[1]);
        }
        let t = (x - a[0]) / (b[0] - a[0]);
        Some(a[1] + t * (b[1] - a[1]))
    }

    /// Like [`Stroke::y_at`] but clamped to the end points outside the range.
    pub fn y_at_clamped(&self, x: f64) -> f64 {
        let (x0, x1) = self.x_range();
        self.y_at(x.clamp(x0, x1)).unwrap_or(self.points[0][1])
    }

    /// Closest point of the stroke to `p`: (distance, point, unit tangent).
    pub fn closest(&self, p: [f64; 2]) -> (f64, [f64; 2], [f64; 2]) {
        let mut best = (f64::INFINITY, self.points[0], self.tangents[0]);
        for i in 0..self.points.len().saturating_sub(1) {
            let (a, b) = (self.points[i], self.points[i + 1]);
            let d = [b[0] - a[0], b[1] - a[1]];
            let l2 = d[0] * d[0] + d[1] * d[1];
            let t = if l2 > 0.0 {
                (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let q = [a[0] + t * d[0], a[1] + t * d[1]];
            let dist = dist2(p, q);
            if dist < best.0 {
                let ta = self.tangents[i];
                let tb = self.tangents[i + 1];
                best = (
                    dist,
                    q,
                    normalize2([ta[0] + tb[0], ta[1] + tb[1]]).unwrap_or(ta),
                );
            }
        }
        best
    }

    /// Tangent at an end, estimated over about `reach` pixels of arc
    /// length, pointing along the stroke (increasing x).
    pub fn end_tangent(&self, at_end: bool, reach: f64) -> [f64; 2] {
        let n = self.points.len();
        let (anchor, iter): (usize, Box<dyn Iterator<Item = usize>>) = if at_end {
            (n - 1, Box::new((0..n - 1).rev()))
        } else {
            (0, Box::new(1..n))
        };
        let a = self.points[anchor];
        let mut other = self.points[if at_end { n - 2 } else { 1 }];
        for i in iter {
            other = self.points[i];
            if dist2(a, other) >= reach {
                break;
            }
        }
        let d = if at_end {
            [a[0] - other[0], a[1] - other[1]]
        } else {
            [other[0] - a[0], other[1] - a[1]]
        };
        normalize2(d).unwrap_or([1.0, 0.0])
    }

    /// Arc length in pixels.
    pub fn length(&self) -> f64 {
        self.points.windows(2).map(|w| dist2(w[0], w[1])).sum()
    }
}

pub(crate) fn normalize2(v: [f64; 2]) -> Option<[f64; 2]> {
    let n = (v[0] * v[0] + v[1] * v[1]).sqrt();
    if n > 1e-12 && n.is_finite() {
        Some([v[0] / n, v[1] / n])
    } else {
        None
    }
}

/// Prepares one stroke: orientation, fold-back handling, resampling at
/// `spacing` pixels, tangents. Returns one stroke, or several pieces when it
/// folds back in x and the policy is [`FoldBackPolicy::Split`].
pub fn prepare_stroke(
    id: &str,
    source_index: usize,
    points: &[[f64; 2]],
    spacing: f64,
    fold_tolerance: f64,
    policy: FoldBackPolicy,
) -> Result<Vec<Stroke>, StrokeError> {
    let err = |problem: String| StrokeError {
        id: id.to_string(),
        problem,
    };
    let mut pts: Vec<[f64; 2]> = Vec::with_capacity(points.len());
    for &p in points {
        if !(p[0].is_finite() && p[1].is_finite()) {
            return Err(err("has a non-finite coordinate".into()));
        }
        if pts.last().is_none_or(|&q| dist2(p, q) > 1e-9) {
            pts.push(p);
        }
    }
    if pts.len() < 2 {
        return Err(err("has fewer than two distinct points".into()));
    }
    // Clockwise orientation: the stroke runs by increasing x overall.
    if pts[pts.len() - 1][0] < pts[0][0] {
        pts.reverse();
    }
    let runs = monotone_runs(&pts, fold_tolerance);
    if runs.len() > 1 && policy == FoldBackPolicy::Reject {
        let turn = pts[runs[0].1];
        return Err(err(format!(
            "folds back in x at pixel ({:.1}, {:.1}); a terrain silhouette has one height per image column",
            turn[0], turn[1]
        )));
    }
    let mut out = Vec::new();
    let multi = runs.len() > 1;
    for (k, &(a, b, dir)) in runs.iter().enumerate() {
        let mut run: Vec<[f64; 2]> = pts[a..=b].to_vec();
        if dir < 0 {
            run.reverse();
        }
        // Drop jitter back-steps: keep x non-decreasing.
        let mut mono: Vec<[f64; 2]> = Vec::with_capacity(run.len());
        for p in run {
            match mono.last() {
                Some(q) if p[0] < q[0] => {}
                _ => mono.push(p),
            }
        }
        if mono.len() < 2 || mono[mono.len() - 1][0] - mono[0][0] <= fold_tolerance.max(1e-9) {
            continue;
        }
        let points = resample(&mono, spacing);
        let tangents = tangents(&points);
        out.push(Stroke {
            id: if multi {
                format!("{id}#{}", k + 1)
            } else {
                id.to_string()
            },
            source_id: id.to_string(),
            source_index,
            piece: if multi { k + 1 } else { 0 },
            points,
            tangents,
        });
    }
    if out.is_empty() {
        return Err(err("spans no horizontal extent".into()));
    }
    Ok(out)
}

/// Splits a polyline into maximal runs monotone in x (with hysteresis
/// `tol`): (first index, last index, direction +1 / -1).
fn monotone_runs(pts: &[[f64; 2]], tol: f64) -> Vec<(usize, usize, i8)> {
    let mut runs = Vec::new();
    let mut start = 0usize;
    let mut dir: i8 = 1;
    let mut ext = 0usize; // index of the extreme x of the current run
    for i in 1..pts.len() {
        let x = pts[i][0];
        let e = pts[ext][0];
        let beyond = if dir > 0 { x >= e } else { x <= e };
        if beyond {
            ext = i;
            continue;
        }
        let back = if dir > 0 { e - x } else { x - e };
        if back > tol {
            runs.push((start, ext, dir));
            start = ext;
            dir = -dir;
            // The new run's extreme so far is the lowest (or highest) point
            // reached since the turn.
            ext = (ext..=i)
                .max_by(|&a, &b| {
                    let (xa, xb) = (pts[a][0], pts[b][0]);
                    if dir > 0 {
                        xa.total_cmp(&xb)
                    } else {
                        xb.total_cmp(&xa)
                    }
                })
                .unwrap_or(i);
        }
    }
    runs.push((start, pts.len() - 1, dir));
    // A run that ends before its extreme (trailing jitter) keeps its points.
    runs
}

/// Resamples a polyline at uniform arc length `spacing` (the last point is
/// always kept).
pub fn resample(pts: &[[f64; 2]], spacing: f64) -> Vec<[f64; 2]> {
    let total: f64 = pts.windows(2).map(|w| dist2(w[0], w[1])).sum();
    if total <= 0.0 || pts.len() < 2 {
        return pts.to_vec();
    }
    let n = ((total / spacing).ceil() as usize).max(1);
    let step = total / n as f64;
    let mut out = Vec::with_capacity(n + 1);
    out.push(pts[0]);
    let mut seg = 0usize;
    let mut seg_start = 0.0;
    for k in 1..n {
        let s = k as f64 * step;
        while seg + 1 < pts.len() - 1 && seg_start + dist2(pts[seg], pts[seg + 1]) < s {
            seg_start += dist2(pts[seg], pts[seg + 1]);
            seg += 1;
        }
        let l = dist2(pts[seg], pts[seg + 1]);
        let t = if l > 0.0 {
            ((s - seg_start) / l).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (a, b) = (pts[seg], pts[seg + 1]);
        out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
    }
    out.push(pts[pts.len() - 1]);
    out
}

fn tangents(pts: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let a = pts[i.saturating_sub(1)];
            let b = pts[(i + 1).min(n - 1)];
            normalize2([b[0] - a[0], b[1] - a[1]]).unwrap_or([1.0, 0.0])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fold_back_is_split_or_rejected() {
        let z = [[0.0, 0.0], [100.0, 0.0], [50.0, 20.0], [150.0, 40.0]];
        let pieces = prepare_stroke("z", 0, &z, 2.0, 3.0, FoldBackPolicy::Split).unwrap();
        assert_eq!(pieces.len(), 3);
        for p in &pieces {
            assert!(p.points.windows(2).all(|w| w[1][0] >= w[0][0]));
        }
        let e = prepare_stroke("z", 0, &z, 2.0, 3.0, FoldBackPolicy::Reject).unwrap_err();
        assert!(e.to_string().contains("folds back in x"), "{e}");
    }

    #[test]
    fn jitter_is_not_a_fold() {
        let p = [[0.0, 0.0], [50.0, 1.0], [49.0, 2.0], [100.0, 3.0]];
        let s = prepare_stroke("j", 0, &p, 2.0, 3.0, FoldBackPolicy::Reject).unwrap();
        assert_eq!(s.len(), 1);
        assert!(s[0].points.windows(2).all(|w| w[1][0] >= w[0][0]));
    }

    #[test]
    fn resampling_is_uniform() {
        let s = resample(&[[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]], 2.0);
        assert_eq!(s.len(), 11);
        for w in s.windows(2) {
            assert!((dist2(w[0], w[1]) - 2.0).abs() < 1e-9);
        }
    }
}
