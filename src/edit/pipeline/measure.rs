//! Stage 5's measure: each stroke's fit and visibility on the edited
//! terrain, its placed curve, and the notes on its placement and depth
//! for the report.

use super::*;

/// Stage 5, `lowering` (last step): measures on the final terrain of the
/// refinement rounds how well each view shows each of its strokes (fit and
/// visibility, [`measure`]), decides each stroke's status against
/// `--min-fit` ([`stroke_outcome`]), and assembles the per-view reports
/// with the matching, the placement and the rounds' counts. The write
/// stage gates on these statuses.
pub(super) fn measure_strokes(
    edit: &Edit,
    views: &[ViewState],
    features: &Features,
    placed: &Placed,
    rounds: &Rounds,
) -> Vec<ViewReport> {
    let demands = &placed.demands;
    let mut view_reports = Vec::new();
    for (((k, v), m), after) in views
        .iter()
        .enumerate()
        .zip(&placed.matched.views)
        .zip(&rounds.rendered)
    {
        let strokes = demands.strokes[k]
            .par_iter()
            .zip(&m.strokes)
            .zip(&placed.issues[k])
            .enumerate()
            .map(|(j, ((c, sm), issue))| {
                let (fit, visible) = measure(c, after);
                let cells = free_cells_across(c, after);
                let (status, reason) =
                    stroke_outcome(&fit, visible, *issue, cells, edit.opts.min_fit);
                let (lo, hi) = c.depths.iter().fold((f64::INFINITY, 0.0f64), |(a, b), d| {
                    (a.min(d.1), b.max(d.1))
                });
                StrokeReport {
                    id: c.id.clone(),
                    source_id: c.source_id.clone(),
                    matched: MatchReport {
                        kind: sm.kind,
                        feature_id: sm.feature_id,
                        cost: sm.costs.map(|c| c.total),
                        depth_rank: sm.depth_rank,
                        depth_m: [if lo.is_finite() { lo } else { 0.0 }, hi],
                    },
                    fit,
                    visible_fraction: visible,
                    status,
                    reason,
                    on_silhouette: demands.on_silhouette[k][j],
                    placement: demands.placement[k][j],
                    placed_curve: placed_curve(&features.scene_views[k], sm),
                    first_placed: None,
                }
            })
            .collect();
        view_reports.push(ViewReport {
            name: v.spec.name.clone(),
            eye_alt_m: v.frame.eye_alt,
            strokes,
            lowering_iterations: rounds.lowering_iterations[k],
            silhouettes_lowered: rounds.silhouettes_lowered[k],
            contour_iterations: rounds.contour_iterations[k],
            features: features.counts[k],
            matching_stopped_early: placed.matched.stopped_early,
        });
    }
    view_reports
}

/// A placed stroke's points in the DEM's CRS (absolute heights), for the
/// report: the finite ones, rounded to about a millimetre on the ground
/// ([`millimetre_decimals`]: in degrees on a geographic CRS, not to a
/// thousandth of a degree).
pub(super) fn placed_curve(sv: &SceneView, sm: &crate::sketch::StrokeMatch) -> Vec<[f64; 3]> {
    let points = sv.projection.placed_to_dem(&sm.points);
    let xy = millimetre_decimals(&sv.projection, sm.points.first().map(|p| p.world));
    let round = |v: f64, decimals: i32| {
        let f = 10f64.powi(decimals);
        (v * f).round() / f
    };
    points
        .into_iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .map(|p| [round(p[0], xy), round(p[1], xy), round(p[2], 3)])
        .collect()
}

/// Decimals of the DEM's CRS units that resolve a millimetre on the ground
/// near `at` (a world-frame point; 3 for metres, 8 for degrees), from the
/// CRS distance of a metre east and north of it.
fn millimetre_decimals(projection: &SceneProjection, at: Option<[f64; 3]>) -> i32 {
    let Some(p) = at else { return 3 };
    let o = projection.local_to_dem(p);
    let e = projection.local_to_dem([p[0] + 1.0, p[1], p[2]]);
    let n = projection.local_to_dem([p[0], p[1] + 1.0, p[2]]);
    let per_m = (e[0] - o[0])
        .hypot(e[1] - o[1])
        .min((n[0] - o[0]).hypot(n[1] - o[1]));
    if !(per_m.is_finite() && per_m > 0.0) {
        return 3;
    }
    (-(per_m * 1e-3).log10()).ceil().clamp(3.0, 12.0) as i32
}

/// Why a placed stroke cannot be fitted whatever the deformation does, if
/// anything: `points` its placed points, `dem_points` the same in the DEM's
/// CRS (absolute heights).
pub(super) fn placement_issue(
    dem: &Dem,
    points: &[crate::sketch::PlacedPoint],
    dem_points: &[[f64; 3]],
    max_d: Option<f64>,
) -> Option<&'static str> {
    use crate::sketch::PointSource;
    let on_stroke = |p: &&crate::sketch::PlacedPoint| p.source != PointSource::Completion;
    if points.iter().filter(on_stroke).count() == 0 {
        return Some("could not be placed on the terrain");
    }
    if points
        .iter()
        .filter(on_stroke)
        .any(|p| p.pixel.is_none() || !(p.depth > 0.0))
    {
        return Some("behind the eye");
    }
    let outside = points.iter().zip(dem_points).any(|(p, q)| {
        on_stroke(&p)
            && match dem.geotransform.crs_to_pixel(q[0], q[1]) {
                Some((px, py)) if q.iter().all(|c| c.is_finite()) => {
                    !(px >= 0.0 && py >= 0.0 && px < dem.width as f64 && py < dem.height as f64)
                }
                _ => true,
            }
    });
    if outside {
        return Some("outside the DEM");
    }
    if let Some(d) = max_d {
        if points.iter().filter(on_stroke).any(|p| p.depth > d) {
            return Some("beyond --max-distance");
        }
    }
    None
}

/// Notes for the strokes whose `depth_m` (the author's distance) the
/// placement did not follow: placement does not use `depth_m` yet, it only
/// lifts the refusal of strokes drawn in empty sky
/// ([`check_strokes_touch_terrain`]); the report says where they went.
pub(super) fn depth_notes(views: &[ViewState], curves: &[Vec<StrokeCurve>]) -> Vec<String> {
    let mut out = Vec::new();
    for (v, cs) in views.iter().zip(curves) {
        for c in cs {
            let Some(spec) = v.spec.strokes.get(c.stroke.source_index) else {
                continue;
            };
            let Some(d) = spec.depth_m else { continue };
            let [near, far] = d.range();
            let (lo, hi) = c.depths.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
                (a.min(p.1), b.max(p.1))
            });
            // Within 10 % of the range given counts as followed.
            if lo.is_finite() && lo >= 0.9 * near && hi <= 1.1 * far {
                continue;
            }
            out.push(format!(
                "view \"{}\" stroke \"{}\": placed at {:.0} to {:.0} m, not at its depth_m {near}..{far} m (placement does not use depth_m yet)",
                v.spec.name, c.id, if lo.is_finite() { lo } else { 0.0 }, hi
            ));
        }
    }
    out
}

/// Under this many DEM cells across, a stroke's free stretch is finer
/// than the DEM can draw at the depth it was placed: a bilinear cell shows
/// at most one bend of a silhouette.
pub(super) const SUB_CELL_STRETCH_CELLS: f64 = 2.0;

/// How many DEM cells the free (not anchored) stretch of `c` spans at the
/// median depth it was placed, in `view`: `(cells, depth)`; `None` when
/// the stroke has no free stretch.
pub(super) fn free_cells_across(c: &StrokeCurve, view: &RenderedView) -> Option<(f64, f64)> {
    let free: Vec<(f64, f64)> = c
        .depths
        .iter()
        .zip(&c.anchored)
        .filter(|(_, &a)| !a)
        .map(|(&d, _)| d)
        .filter(|d| d.0.is_finite() && d.1.is_finite() && d.1 > 0.0)
        .collect();
    let (first, last) = (free.first()?, free.last()?);
    let mut depths: Vec<f64> = free.iter().map(|d| d.1).collect();
    depths.sort_by(f64::total_cmp);
    let depth = depths[depths.len() / 2];
    let px = view.cell_px(depth);
    (px.is_finite() && px > 0.0).then(|| ((last.0 - first.0).abs() / px, depth))
}

/// A stroke's status and, when it is not fitted, why. `cells`: how many
/// DEM cells its free stretch spans at the depth it was placed
/// ([`free_cells_across`]).
pub(super) fn stroke_outcome(
    fit: &crate::edit::fit::StrokeFit,
    visible: f64,
    issue: Option<&'static str>,
    cells: Option<(f64, f64)>,
    min_fit: f64,
) -> (StrokeStatus, Option<String>) {
    let f = fit.fitted_fraction;
    if f >= min_fit {
        return (StrokeStatus::Fitted, None);
    }
    let status = if f > 0.0 {
        StrokeStatus::Partial
    } else {
        StrokeStatus::Unfitted
    };
    let below = format!("fit {f:.2} below --min-fit {min_fit}");
    let reason = match issue {
        Some(i) => format!("{i}; {below}"),
        None if visible < min_fit.min(1.0) => {
            format!("hidden by nearer terrain (visible {visible:.2}); {below}")
        }
        None => match cells {
            Some((n, depth)) if n < SUB_CELL_STRETCH_CELLS => format!(
                "its free stretch spans {n:.1} DEM cells at the depth it was placed ({depth:.0} m): \
                 finer than the DEM can draw there; {below}"
            ),
            _ => below,
        },
    };
    (status, Some(reason))
}
