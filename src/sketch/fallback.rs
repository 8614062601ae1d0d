//! Fallback 3D embedding of strokes left without a feature (section 5.2.2
//! of Tassé et al.), so that every stroke still yields a deformation
//! constraint.
//!
//! A stroke whose priority list was emptied is placed halfway (in depth,
//! column by column) between the placed strokes just in front of and just
//! behind it in the depth order. Without a stroke behind it, it goes behind
//! the one in front (depth times `ratio`); without a stroke in front, in
//! front of the one behind (depth divided by `ratio`). When the view has no
//! placed stroke at all (the terrain has no features), the nearest stroke
//! is put on the drawing plane (normal: the camera view direction) through
//! a point where it touches the terrain, the first terrain point met by the
//! rays below one of its ends (section 8 of the paper); the strokes behind
//! it are then placed relative to it as above.

use super::candidates::interp_by_x;
use super::placement::{place_with_depths, PlacedPoint, PointSource};
use super::projection::{dot, norm, sub, ViewProjection};
use super::stroke::Stroke;

/// Depth of a placed stroke at pixel column `x` (interpolated), or its mean
/// depth outside its range.
pub fn placed_depth_at(placed: &[PlacedPoint], x: f64) -> Option<f64> {
    let on: Vec<([f64; 2], f64)> = placed
        .iter()
        .filter(|p| p.source != PointSource::Completion)
        .filter_map(|p| p.pixel.map(|px| (px, p.depth)))
        .collect();
    if on.is_empty() {
        return None;
    }
    interp_by_x(&on, x, |p| p.0[0], |p| p.1)
        .or_else(|| Some(on.iter().map(|p| p.1).sum::<f64>() / on.len() as f64))
}

/// Per-point depths of a fallback stroke between its neighbours in depth.
/// `None` when it has no neighbour.
pub fn fallback_depths(
    stroke: &Stroke,
    front: Option<&[PlacedPoint]>,
    back: Option<&[PlacedPoint]>,
    ratio: f64,
) -> Option<Vec<f64>> {
    let at = |pl: Option<&[PlacedPoint]>, x: f64| pl.and_then(|p| placed_depth_at(p, x));
    let mut out = Vec::with_capacity(stroke.points.len());
    for p in &stroke.points {
        let d = match (at(front, p[0]), at(back, p[0])) {
            (Some(f), Some(b)) => 0.5 * (f + b),
            (Some(f), None) => f * ratio,
            (None, Some(b)) => b / ratio,
            (None, None) => return None,
        };
        out.push(d);
    }
    Some(out)
}

/// The first terrain point met by the pixel rays just below either end of
/// the stroke, scanning down the image column (2-pixel steps).
pub fn terrain_touching_point(
    stroke: &Stroke,
    proj: &dyn ViewProjection,
    max_distance: f64,
) -> Option<[f64; 3]> {
    let (_, h) = proj.image_size();
    let mut best: Option<(f64, [f64; 3])> = None;
    for end in [stroke.start(), stroke.end()] {
        let mut v = end[1];
        while v <= h as f64 {
            if let Some(p) = march_ray(proj, [end[0], v], max_distance) {
                let d = norm(sub(p, proj.eye()));
                if best.is_none_or(|b| d < b.0) {
                    best = Some((d, p));
                }
                break;
            }
            v += 2.0;
        }
    }
    best.map(|b| b.1)
}

/// First point of the pixel's ray at or below the terrain.
pub fn march_ray(
    proj: &dyn ViewProjection,
    pixel: [f64; 2],
    max_distance: f64,
) -> Option<[f64; 3]> {
    let mut t = 1.0;
    let mut prev: Option<(f64, f64)> = None; // (t, height above terrain)
    while t <= max_distance {
        let p = proj.unproject(pixel, t);
        if let Some(g) = proj.terrain_height(p[0], p[1]) {
            let above = p[2] - g;
            if above <= 0.0 {
                // Refine between the previous step and this one.
                let tt = match prev {
                    Some((t0, a0)) if a0 > 0.0 => t0 + (t - t0) * a0 / (a0 - above),
                    _ => t,
                };
                return Some(proj.unproject(pixel, tt));
            }
            prev = Some((t, above));
        } else {
            prev = None;
        }
        t += (0.005 * t).max(1.0);
    }
    None
}

/// Places the stroke on the drawing plane through `point`: the plane whose
/// normal is the camera view direction (section 8 of Tassé et al.: "the
/// drawing plane determined by the camera direction and a 3D point where
/// the stroke touches the terrain").
pub fn embed_on_plane(
    stroke: &Stroke,
    proj: &dyn ViewProjection,
    point: [f64; 3],
) -> Vec<PlacedPoint> {
    let eye = proj.eye();
    let (w, h) = proj.image_size();
    let n = sub(proj.unproject([w as f64 / 2.0, h as f64 / 2.0], 1.0), eye);
    let nl = norm(n);
    let fallback_depth = norm(sub(point, eye)).max(1.0);
    let depths: Vec<Option<f64>> = stroke
        .points
        .iter()
        .map(|&px| {
            if nl < 1e-9 {
                return Some(fallback_depth);
            }
            let ray = sub(proj.unproject(px, 1.0), eye);
            let denom = dot(ray, n);
            if denom <= 1e-12 {
                return Some(fallback_depth);
            }
            let s = dot(sub(point, eye), n) / denom;
            Some(if s > 0.0 {
                s * norm(ray)
            } else {
                fallback_depth
            })
        })
        .collect();
    place_with_depths(stroke, &depths, PointSource::Fallback, proj)
}

/// Embeds the unmatched strokes of one view. `order` is front to back;
/// `placed[i]` is `Some` for matched strokes and is filled for the others.
/// `default_distance` is used when the terrain gives no touching point.
pub fn embed_unmatched(
    strokes: &[Stroke],
    order: &[usize],
    placed: &mut [Option<Vec<PlacedPoint>>],
    proj: &dyn ViewProjection,
    ratio: f64,
    default_distance: f64,
) {
    let matched: Vec<bool> = placed.iter().map(|p| p.is_some()).collect();
    for (k, &s) in order.iter().enumerate() {
        if placed[s].is_some() {
            continue;
        }
        // Nearest placed stroke in front (matched or already embedded) and
        // nearest matched stroke behind.
        let front = order[..k]
            .iter()
            .rev()
            .find(|&&r| placed[r].is_some())
            .copied();
        let back = order[k + 1..].iter().find(|&&r| matched[r]).copied();
        let depths = fallback_depths(
            &strokes[s],
            front.and_then(|r| placed[r].as_deref()),
            back.and_then(|r| placed[r].as_deref()),
            ratio,
        );
        let pts = match depths {
            Some(d) => {
                let d: Vec<Option<f64>> = d.into_iter().map(Some).collect();
                place_with_depths(&strokes[s], &d, PointSource::Fallback, proj)
            }
            None => match terrain_touching_point(&strokes[s], proj, 100_000.0) {
                Some(p) => embed_on_plane(&strokes[s], proj, p),
                None => {
                    let d = vec![Some(default_distance); strokes[s].points.len()];
                    place_with_depths(&strokes[s], &d, PointSource::Fallback, proj)
                }
            },
        };
        placed[s] = Some(pts);
    }
}
