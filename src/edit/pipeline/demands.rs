//! What the matched strokes ask of the terrain: anchored points held where
//! they already lie on a silhouette, the free stretches as curve
//! constraints in the DEM's CRS (the stroke's own points apart from the
//! feature completion beyond its ends, which acts only within the
//! influence of what was drawn), the observer's ground held; and the
//! check that every stroke touches terrain.

use super::*;
use crate::edit::stretch_placement::AGREEMENT;
use crate::sketch::PlacedPoint;

/// Refuse a stroke (without `depth_m`) whose end points both lie in empty
/// sky in the view before the edit, with no terrain close under them
/// ([`TERRAIN_TOUCH_RISE`], [`TERRAIN_TOUCH_PX`]): nothing says how far
/// it is. Names the view and the stroke, and whether the terrain lies
/// beyond `--max-distance` or nowhere on the DEM.
pub(super) fn check_strokes_touch_terrain(
    v: &ViewState,
    dem: &Dem,
    max_d: Option<f64>,
    sketch: &str,
) -> Result<(), EditError> {
    let depth = &v.before.depth;
    let (w, h) = (v.camera.width, v.camera.height);
    let touches = |p: [f64; 2]| -> bool {
        let i0 = (p[0].floor() as i64).clamp(0, w as i64 - 1);
        let j0 = (p[1].floor() as i64).clamp(0, h as i64 - 1);
        let rows = touch_rows(&v.camera, p).ceil() as i64;
        (i0 - 1..=i0 + 1).any(|i| {
            (j0 - 1..=j0 + rows)
                .any(|j| i >= 0 && j >= 0 && depth.depth_at(i as usize, j as usize).is_finite())
        }) || (j0 + rows >= h as i64
            // Under the image's lower border: the stroke is cut by the frame.
            && v.before.terrain_at_or_below(p, rows as f64).is_some())
    };
    for s in &v.spec.strokes {
        if s.depth_m.is_some() {
            continue;
        }
        let (Some(&a), Some(&b)) = (s.points.first(), s.points.last()) else {
            continue;
        };
        if touches(a) || touches(b) {
            continue;
        }
        // Would the DEM go on beyond --max-distance along the end's ray?
        let beyond = max_d.is_some_and(|d| {
            [a, b].iter().any(|p| {
                let r = v.camera.ray(p[0], p[1]);
                let n = r[0].hypot(r[1]);
                if n <= 0.0 {
                    return false;
                }
                let (x, y) = v.frame.en_to_crs(r[0] / n * d, r[1] / n * d);
                dem.geotransform.crs_to_pixel(x, y).is_some_and(|(px, py)| {
                    px >= 0.0 && py >= 0.0 && px < dem.width as f64 && py < dem.height as f64
                })
            })
        });
        let problem = match (beyond, max_d) {
            (true, Some(d)) => format!(
                "the rays through its end points hit no terrain within --max-distance {d} m (the DEM goes on beyond it): raise --max-distance, or give the stroke's depth_m"
            ),
            _ => "drawn in empty sky: the rays through its end points hit no terrain of the DEM; give the stroke's depth_m (distance from the eye, metres) to place it".to_string(),
        };
        return Err(EditError::Unusable {
            sketch: sketch.to_string(),
            message: format!("view \"{}\" stroke \"{}\": {problem}", v.spec.name, s.id),
        });
    }
    Ok(())
}

/// How many rows below the stroke end `p` terrain may lie and still touch
/// it: at least [`TERRAIN_TOUCH_PX`], and down to the row whose ray
/// climbs [`TERRAIN_TOUCH_RISE`] less per metre of distance than the
/// end's (at that row's terrain, whatever its distance, the end's ray
/// passes at most that share of the distance above it). Rows below the
/// image's lower border count too (the frame may cut a stroke off).
fn touch_rows(camera: &Camera, p: [f64; 2]) -> f64 {
    let slope = |y: f64| {
        let r = camera.ray(p[0], y);
        r[2] / r[0].hypot(r[1]).max(f64::MIN_POSITIVE)
    };
    let top = slope(p[1]);
    // The slope falls with the row; bisect for the row where it has fallen
    // by the allowed rise (searched down to 4 image heights below the end).
    let limit = p[1] + 4.0 * camera.height as f64;
    if top - slope(limit) <= TERRAIN_TOUCH_RISE {
        return (limit - p[1]).max(TERRAIN_TOUCH_PX);
    }
    let (mut lo, mut hi) = (p[1], limit);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if top - slope(mid) <= TERRAIN_TOUCH_RISE {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    (lo - p[1]).max(TERRAIN_TOUCH_PX)
}

/// Anchors the matched strokes where they already lie on a silhouette and
/// turns the rest into curve constraints in the DEM's CRS; adds the
/// observer's ground.
pub(super) fn place_demands(
    views: &[ViewState],
    windows: &[HeightMap],
    scene_views: &[SceneView],
    matched: &mut [crate::sketch::ViewMatch],
    options: &SketchOptions,
    traced: Option<&[TracedBoundaries]>,
) -> Demands {
    let mut d = Demands {
        curves: Vec::new(),
        completions: Vec::new(),
        fixed: Vec::new(),
        strokes: Vec::new(),
        on_silhouette: Vec::new(),
        placement: Vec::new(),
    };
    let mut held = Vec::new();
    for (i, (((v, w), sv), m)) in views
        .iter()
        .zip(windows)
        .zip(scene_views)
        .zip(matched.iter_mut())
        .enumerate()
    {
        let traced_here = traced.and_then(|t| t.get(i));
        let mut cs = Vec::new();
        let mut fractions = Vec::new();
        let mut placements = Vec::new();
        let crate::sketch::ViewMatch {
            strokes: stroke_matches,
            lists,
            ..
        } = m;
        for (k, (s, sm)) in v.strokes.iter().zip(stroke_matches.iter_mut()).enumerate() {
            let occluder = lists.get(k).and_then(|list| {
                match_behind_occluder(&v.before, &sv.projection, s, list, options, sm)
            });
            let matched_behind = occluder.map(|_| sm.points.clone());
            fractions.push(anchor_on_silhouettes(
                &v.before,
                &sv.projection,
                sm,
                traced_here,
            ));
            if let Some(behind) = matched_behind {
                unanchor_occluder(sm, behind);
            }
            placements.push(place_free_stretches(
                &v.before,
                &sv.projection,
                &sv.features,
                v.observer_radius(options.observer_radius_m),
                occluder,
                sm,
            ));
            if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
                for p in &sm.points {
                    if let Some(px) = p.pixel {
                        eprintln!(
                            "placed {} x {:.1} y {:.1} depth {:.0} {:?}",
                            s.id, px[0], px[1], p.depth, p.source
                        );
                    }
                }
            }
            let dem_points = sv.projection.placed_to_dem(&sm.points);
            let anchored: Vec<bool> = sm
                .points
                .iter()
                .map(|p| p.source == PointSource::Silhouette)
                .collect();
            let depths: Vec<f64> = sm.points.iter().map(|p| p.depth).collect();
            let completion: Vec<bool> = sm
                .points
                .iter()
                .map(|p| p.source == PointSource::Completion)
                .collect();
            let curves = stroke_curves(&dem_points, &depths, &anchored, &completion);
            d.curves.extend(curves.own);
            d.completions.extend(curves.completion);
            for (p, _) in dem_points.iter().zip(&anchored).filter(|(_, &a)| a) {
                held.extend(v.stencil_cells(w, p[0], p[1]));
            }
            cs.push(StrokeCurve::new(s, sm));
        }
        d.strokes.push(cs);
        d.on_silhouette.push(fractions);
        d.placement.push(placements);
    }
    // Cells under anchored points are held, except next to a free
    // stretch: on a coarse DEM one cell spans many pixels of a stroke, and
    // holding it would keep the free stretch beside it from rising. There
    // the free stretch's own curve, which starts on the anchor, decides.
    if let Some(v) = views.first() {
        let all: Vec<CurveConstraint> = d.curves.iter().chain(&d.completions).cloned().collect();
        let near = cells_near_curves(v, &all, ANCHOR_CLEARANCE_CELLS);
        d.fixed
            .extend(held.into_iter().filter(|c| !near.contains(&(c.col, c.row))));
    }
    for (v, w) in views.iter().zip(windows) {
        d.fixed
            .extend(v.observer_cells(w, options.observer_radius_m));
    }
    d
}

/// Anchored cells within this many cells of a free stretch are not held.
pub const ANCHOR_CLEARANCE_CELLS: i64 = 2;

/// The DEM cells (whole-DEM grid, through `v`'s window) within `reach`
/// cells of the curves' points and of the segments between them.
pub(super) fn cells_near_curves(
    v: &ViewState,
    curves: &[CurveConstraint],
    reach: i64,
) -> std::collections::HashSet<(i64, i64)> {
    let gt = &v.eye_ground.grid;
    let mut near = std::collections::HashSet::new();
    let mut mark = |x: f64, y: f64| {
        if let Some((c, r)) = v.cell_of(x, y) {
            for dr in -reach..=reach + 1 {
                for dc in -reach..=reach + 1 {
                    near.insert((c + dc, r + dr));
                }
            }
        }
    };
    for curve in curves {
        for w in curve.points.windows(2) {
            let (a, b) = (w[0], w[1]);
            // Half-cell steps along the segment.
            let steps = gt
                .crs_to_pixel(a[0], a[1])
                .zip(gt.crs_to_pixel(b[0], b[1]))
                .map(|(p, q)| (2.0 * (q.0 - p.0).hypot(q.1 - p.1)).ceil() as usize)
                .unwrap_or(1)
                .clamp(1, 10_000);
            for k in 0..=steps {
                let t = k as f64 / steps as f64;
                mark(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
            }
        }
        if let [p] = curve.points.as_slice() {
            mark(p[0], p[1]);
        }
    }
    near
}

/// Neighbouring points of a placed stroke whose depths differ by more than
/// this fraction are not joined by a curve constraint: the stroke passes
/// from one landform to another there (a segment between them would be a
/// wall across the ground in between).
pub const DEPTH_BREAK: f64 = 0.15;

/// The curve constraints of a placed stroke (DEM CRS points, with their
/// depths): its stretches between anchored points, each with the anchored
/// point on either side where its depth continues the stretch, so that
/// the curve meets the terrain it continues; cut where the depth jumps
/// ([`DEPTH_BREAK`]). Each is split where the stroke's own points end and
/// its feature completion begins (`completion`:
/// the points [`PointSource::Completion`] added beyond the stroke's
/// ends): the stroke's own parts, which define the edit's influence, and
/// the completion parts, each starting (or ending) on the stroke's end
/// point, which act only within it (`deform_bounded`). `influence_m` is
/// the distance from what was drawn, not from the edit's extension of it.
pub(super) fn stroke_curves(
    points: &[[f64; 3]],
    depths: &[f64],
    anchored: &[bool],
    completion: &[bool],
) -> StrokeCurves {
    let mut out = StrokeCurves::default();
    for piece in stretch_pieces(points, depths, anchored) {
        let own: Vec<usize> = (0..piece.len())
            .filter(|&j| !completion[piece[j]])
            .collect();
        let (Some(&first), Some(&last)) = (own.first(), own.last()) else {
            out.completion.push(curve_of(points, &piece));
            continue;
        };
        if first > 0 {
            out.completion.push(curve_of(points, &piece[..=first]));
        }
        out.own.push(curve_of(points, &piece[first..=last]));
        if last + 1 < piece.len() {
            out.completion.push(curve_of(points, &piece[last..]));
        }
    }
    out
}

/// [`stroke_curves`]: the stroke's own curves and its completion's.
#[derive(Debug, Default)]
pub(super) struct StrokeCurves {
    pub(super) own: Vec<CurveConstraint>,
    pub(super) completion: Vec<CurveConstraint>,
}

/// The curve through `points[k]` for the indices `k` of `piece`.
fn curve_of(points: &[[f64; 3]], piece: &[usize]) -> CurveConstraint {
    CurveConstraint {
        points: piece.iter().map(|&k| points[k]).collect(),
    }
}

/// The indices of the points of each stretch of [`stroke_curves`] before
/// the split (finite points only, at least two per stretch).
fn stretch_pieces(points: &[[f64; 3]], depths: &[f64], anchored: &[bool]) -> Vec<Vec<usize>> {
    let finite = |p: &[f64; 3]| p.iter().all(|c| c.is_finite());
    let joined = |i: usize, j: usize| {
        let (a, b) = (depths[i], depths[j]);
        (a - b).abs() <= DEPTH_BREAK * a.min(b)
    };
    let mut out = Vec::new();
    let n = points.len();
    let mut a = 0;
    while a < n {
        if anchored[a] {
            a += 1;
            continue;
        }
        let mut b = a;
        while b < n && !anchored[b] {
            b += 1;
        }
        let lo = if a > 0 && joined(a - 1, a) { a - 1 } else { a };
        let hi = if b < n && joined(b - 1, b) { b } else { b - 1 };
        let mut piece: Vec<usize> = Vec::new();
        for (k, p) in points.iter().enumerate().take(hi + 1).skip(lo) {
            if k > lo && !joined(k - 1, k) {
                if piece.len() >= 2 {
                    out.push(std::mem::take(&mut piece));
                }
                piece.clear();
            }
            if finite(p) {
                piece.push(k);
            }
        }
        if piece.len() >= 2 {
            out.push(piece);
        }
        a = b;
    }
    out
}

/// A stroke matched behind the outline it rises out of and falls back
/// into ([`match_behind_occluder`]): the points anchored on that outline
/// (in front of their place on the matched feature by more than
/// [`AGREEMENT`]) are where the landform behind passes out of sight
/// (T-junctions, Tassé et al. section 5.2.2), not the landform itself:
/// they go with the stretch behind, at the matched feature's depth
/// (`behind`, the placement before anchoring), and the completions at an
/// end that is no longer anchored come back.
fn unanchor_occluder(sm: &mut crate::sketch::StrokeMatch, behind: Vec<PlacedPoint>) {
    let drawn = |p: &&PlacedPoint| p.source != PointSource::Completion;
    let anchored: Vec<PlacedPoint> = sm.points.iter().filter(drawn).copied().collect();
    if anchored.len() != behind.iter().filter(drawn).count() {
        return;
    }
    let mut it = anchored.into_iter();
    let mut out: Vec<PlacedPoint> = Vec::with_capacity(behind.len());
    for p in &behind {
        if p.source == PointSource::Completion {
            out.push(*p);
            continue;
        }
        let q = it.next().unwrap_or(*p);
        let on_occluder = q.source == PointSource::Silhouette
            && p.depth.is_finite()
            && q.depth < p.depth * (1.0 - AGREEMENT);
        out.push(if on_occluder { *p } else { q });
    }
    // Completions only at ends that are not anchored (as anchoring does).
    let first = out.iter().position(|p| p.source != PointSource::Completion);
    let last = out
        .iter()
        .rposition(|p| p.source != PointSource::Completion);
    let (Some(first), Some(last)) = (first, last) else {
        return;
    };
    let first_anchored = out[first].source == PointSource::Silhouette;
    let last_anchored = out[last].source == PointSource::Silhouette;
    let mut k = 0;
    out.retain(|p| {
        let keep = p.source != PointSource::Completion
            || !((k < first && first_anchored) || (k > last && last_anchored));
        k += 1;
        keep
    });
    sm.points = out;
}
