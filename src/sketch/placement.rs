//! Placing strokes in world space (section 5.2.3 of Tassé et al.) and
//! completing the placed features down to the terrain (section 5.3).
//!
//! A stroke point `q_s = (x_s, y_s)` takes the depth of the point of its
//! matched feature that projects on the same pixel column, and is
//! unprojected at that depth: the stroke becomes a 3D curve that projects
//! exactly onto what the user drew. Stroke points that the feature does not
//! reach (at the borders) follow the stroke's tangent in world space: they
//! are put on their pixel's ray where it comes closest to the line through
//! the last two placed points. Feature completion then extends both ends
//! along their 3D tangents until they reach the terrain, so that silhouettes
//! do not start abruptly in mid-air where a stroke ends at a T-junction.

use super::candidates::Candidate;
use super::projection::{add, dot, norm, scale, sub, ViewProjection};
use super::stroke::Stroke;

/// Where a placed point's depth comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PointSource {
    /// Depth of the matched feature on the same pixel column.
    Feature,
    /// Outside the feature: follows the stroke tangent in world space.
    Tangent,
    /// Fallback 3D embedding of an unmatched stroke.
    Fallback,
    /// Feature completion down to the terrain (not on the stroke).
    Completion,
    /// The stroke lies on a silhouette of the unedited terrain here: the
    /// point is the terrain point forming it, kept where it is (see
    /// `edit::on_silhouette`).
    Silhouette,
    /// The stroke runs off a silhouette of the unedited terrain here by
    /// more than the fit's pixel on average, within the looser gap
    /// tolerance: the point is at that silhouette's depth, which the
    /// stroke asks to move by its offset (see `edit::on_silhouette`).
    NearSilhouette,
}

/// One point of a stroke placed in world space.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PlacedPoint {
    /// The stroke pixel (for completion points: the projection, if any).
    pub pixel: Option<[f64; 2]>,
    /// Local frame, metres.
    pub world: [f64; 3],
    /// Distance from the eye, metres.
    pub depth: f64,
    pub source: PointSource,
}

/// Places a stroke on its matched candidate.
pub fn place_on_candidate(
    stroke: &Stroke,
    cand: &Candidate,
    proj: &dyn ViewProjection,
) -> Vec<PlacedPoint> {
    let depths: Vec<Option<f64>> = stroke.points.iter().map(|p| cand.depth_at(p[0])).collect();
    place_with_depths(stroke, &depths, PointSource::Feature, proj)
}

/// Unprojects the stroke points with the given depths; points without a
/// depth follow the stroke tangent in world space from the nearest placed
/// points. If no point has a depth, the result is empty.
pub fn place_with_depths(
    stroke: &Stroke,
    depths: &[Option<f64>],
    source: PointSource,
    proj: &dyn ViewProjection,
) -> Vec<PlacedPoint> {
    let n = stroke.points.len();
    let known: Vec<usize> = (0..n)
        .filter(|&i| {
            depths
                .get(i)
                .copied()
                .flatten()
                .is_some_and(|d| d.is_finite() && d > 0.0)
        })
        .collect();
    let (Some(&first), Some(&last)) = (known.first(), known.last()) else {
        return Vec::new();
    };
    let mut out: Vec<Option<PlacedPoint>> = vec![None; n];
    for &i in &known {
        let d = depths[i].unwrap_or(1.0);
        let px = stroke.points[i];
        out[i] = Some(PlacedPoint {
            pixel: Some(px),
            world: proj.unproject(px, d),
            depth: d,
            source,
        });
    }
    // Interior gaps: interpolate depth.
    for w in known.windows(2) {
        let (a, b) = (w[0], w[1]);
        for (i, slot) in out.iter_mut().enumerate().take(b).skip(a + 1) {
            let t = (i - a) as f64 / (b - a) as f64;
            let d = depths[a].unwrap_or(1.0) * (1.0 - t) + depths[b].unwrap_or(1.0) * t;
            let px = stroke.points[i];
            *slot = Some(PlacedPoint {
                pixel: Some(px),
                world: proj.unproject(px, d),
                depth: d,
                source,
            });
        }
    }
    let eye = proj.eye();
    // Borders: follow the world tangent.
    let follow = |anchor: &PlacedPoint, inner: &PlacedPoint, px: [f64; 2]| -> PlacedPoint {
        let dir = sub(anchor.world, inner.world);
        let ray = sub(proj.unproject(px, 1.0), eye);
        let d = closest_on_ray(eye, ray, anchor.world, dir).unwrap_or(anchor.depth);
        PlacedPoint {
            pixel: Some(px),
            world: proj.unproject(px, d),
            depth: d,
            source: PointSource::Tangent,
        }
    };
    if first > 0 {
        let anchor = out[first].unwrap_or_else(unreachable_point);
        let inner = out[(first + 1).min(last)].unwrap_or(anchor);
        for i in (0..first).rev() {
            out[i] = Some(follow(&anchor, &inner, stroke.points[i]));
        }
    }
    if last + 1 < n {
        let anchor = out[last].unwrap_or_else(unreachable_point);
        let inner = out[last.saturating_sub(1).max(first)].unwrap_or(anchor);
        for (slot, &px) in out.iter_mut().zip(&stroke.points).skip(last + 1) {
            *slot = Some(follow(&anchor, &inner, px));
        }
    }
    out.into_iter().flatten().collect()
}

fn unreachable_point() -> PlacedPoint {
    PlacedPoint {
        pixel: None,
        world: [0.0; 3],
        depth: 0.0,
        source: PointSource::Tangent,
    }
}

/// Depth along the ray `eye + s * ray` (ray need not be unit) of its point
/// closest to the line `p + t * d`; `None` when parallel or behind the eye.
fn closest_on_ray(eye: [f64; 3], ray: [f64; 3], p: [f64; 3], d: [f64; 3]) -> Option<f64> {
    let rl = norm(ray);
    let dl = norm(d);
    if rl < 1e-12 || dl < 1e-12 {
        return None;
    }
    let r = scale(ray, 1.0 / rl);
    let u = scale(d, 1.0 / dl);
    let w0 = sub(eye, p);
    let b = dot(r, u);
    let denom = 1.0 - b * b;
    if denom < 1e-9 {
        return None;
    }
    let s = (b * dot(u, w0) - dot(r, w0)) / denom;
    (s > 0.0 && s.is_finite()).then_some(s)
}

/// Feature completion: extends the placed curve at both ends along its 3D
/// tangent (turned downwards at least by `min_slope` when it rises) in steps
/// of `step_m`, until a point reaches the terrain (it is then put on it), the
/// terrain is undefined, or `max_m` is reached. Returns the completed curve
/// (completion points first and last, marked [`PointSource::Completion`]).
///
/// The extension is there to bring the curve down to the terrain; where the
/// terrain falls away faster than the tangent (a stroke ending over a
/// valley), the tangent never gets closer to it, and constraining it would
/// lift the valley under a line in mid-air. So the extension also stops,
/// without that point, as soon as it is higher above the terrain than the
/// end point it started from.
pub fn complete_feature(
    placed: &[PlacedPoint],
    proj: &dyn ViewProjection,
    step_m: f64,
    max_m: f64,
    min_slope: f64,
) -> Vec<PlacedPoint> {
    if placed.len() < 2 || step_m <= 0.0 {
        return placed.to_vec();
    }
    let ext = |end: usize, inner_dir: isize| -> Vec<PlacedPoint> {
        // Tangent from a point a few samples inside to the end.
        let k = (end as isize + inner_dir * 4).clamp(0, placed.len() as isize - 1) as usize;
        let mut t = sub(placed[end].world, placed[k].world);
        let h = (t[0] * t[0] + t[1] * t[1]).sqrt();
        if h < 1e-9 {
            return Vec::new();
        }
        if t[2] > -min_slope * h {
            t[2] = -min_slope * h;
        }
        let u = scale(t, 1.0 / norm(t));
        let mut out = Vec::new();
        let mut s = step_m;
        let start = placed[end].world;
        // Already on or below the terrain: nothing to complete.
        let mut gap0 = f64::INFINITY;
        if let Some(g) = proj.terrain_height(start[0], start[1]) {
            if start[2] <= g {
                return out;
            }
            gap0 = start[2] - g;
        }
        while s <= max_m + 1e-9 {
            let mut p = add(start, scale(u, s));
            let Some(g) = proj.terrain_height(p[0], p[1]) else {
                break;
            };
            if p[2] - g > gap0 {
                break;
            }
            let reached = p[2] <= g;
            if reached {
                p[2] = g;
            }
            let pr = proj.project(p);
            out.push(PlacedPoint {
                pixel: pr.map(|x| x.0),
                world: p,
                depth: norm(sub(p, proj.eye())),
                source: PointSource::Completion,
            });
            if reached {
                break;
            }
            s += step_m;
        }
        out
    };
    let mut head = ext(0, 1);
    head.reverse();
    let tail = ext(placed.len() - 1, -1);
    let mut out = head;
    out.extend_from_slice(placed);
    out.extend(tail);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sketch::projection::SimplePinhole;
    use std::sync::Arc;

    /// A placed curve 100 m above flat ground, heading away from the eye
    /// (+y) and rising gently.
    fn placed(proj: &SimplePinhole) -> Vec<PlacedPoint> {
        (0..5)
            .map(|k| {
                let world = [0.0, 1000.0 + 10.0 * k as f64, 100.0 + k as f64];
                let (px, depth) = proj.project(world).expect("in front of the camera");
                PlacedPoint {
                    pixel: Some(px),
                    world,
                    depth,
                    source: PointSource::Feature,
                }
            })
            .collect()
    }

    #[test]
    fn completion_comes_down_to_the_terrain() {
        let flat: crate::sketch::HeightFn = Arc::new(|_, _| Some(0.0));
        let proj =
            SimplePinhole::new([0.0, 0.0, 10.0], 0.0, 0.0, 60.0, 800, 400).with_terrain(flat);
        let done = complete_feature(&placed(&proj), &proj, 5.0, 3000.0, 0.25);
        let last = done.last().expect("points");
        assert_eq!(last.source, PointSource::Completion);
        assert!(last.world[2].abs() < 1e-9, "ends on the ground: {last:?}");
    }

    #[test]
    fn completion_stops_where_the_terrain_falls_away_faster() {
        // The ground drops at 1:1 beyond y = 1040: the tangent, turned down
        // at slope 0.25, never gets closer to it.
        let cliff: crate::sketch::HeightFn = Arc::new(|_, y| {
            Some(if y < 1040.0 {
                90.0
            } else {
                90.0 - (y - 1040.0)
            })
        });
        let proj =
            SimplePinhole::new([0.0, 0.0, 10.0], 0.0, 0.0, 60.0, 800, 400).with_terrain(cliff);
        let curve = placed(&proj);
        let done = complete_feature(&curve, &proj, 5.0, 3000.0, 0.25);
        // Nothing is added after the last placed point: no constraint in
        // mid-air over the drop.
        let tail = done.len()
            - done
                .iter()
                .rposition(|p| p.source != PointSource::Completion)
                .expect("placed points")
            - 1;
        assert!(tail <= 1, "{tail} completion points over the drop");
        assert!(done.len() < curve.len() + 40);
    }
}
