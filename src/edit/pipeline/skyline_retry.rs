//! Stages 3 to 5 of a pass (`match_and_fit`), and the comparison of the
//! match with the views' skylines as candidate features against the match
//! without them (see `crate::sketch::skyline`): which outcome fits the
//! strokes better, and the note that says which was kept.

use super::*;

/// Stages 3 to 5 on the rendered `views` and their `features`: matching,
/// deformation, lowering and contour rounds (with the sketch's map-view
/// corrections), and the strokes measured on the result. `later`: a pass
/// after the first, dropped when it changes no cell ([`second_pass`]): it
/// stops as soon as that is known and gives `None`, unless a stroke was
/// matched to a skyline (its outcome may then be compared with the match
/// without the skylines, see [`edit_pass`]).
pub(super) fn match_and_fit(
    edit: &Edit,
    (sketch, dem, dem_name): (&SketchFile, &Dem, &str),
    (views, windows, features): (&[ViewState], &[HeightMap], &Features),
    mut notes: Vec<String>,
    timings: &mut Timings,
    later: bool,
) -> Result<Option<Outcome>, EditError> {
    let t = Instant::now();
    let map_only = sketch.corrections.is_some() && views.iter().all(|v| v.strokes.is_empty());
    let placed = match_strokes(
        edit,
        (&sketch.options, dem),
        (views, windows, map_only),
        features,
        &mut notes,
    )?;
    timings.matching = secs(t);

    let t = Instant::now();
    let (solver, deformation) = deform(edit, dem, dem_name, &sketch.options, views, &placed)?;
    timings.deformation = secs(t);

    let t = Instant::now();
    // (map-view corrections would change the terrain after the rounds:
    // such a pass is never dropped early)
    let on_skyline = placed
        .matched
        .views
        .iter()
        .flat_map(|m| &m.strokes)
        .any(|sm| sm.feature_id.is_some_and(crate::sketch::is_skyline));
    let discard_unchanged = later && sketch.corrections.is_none() && !on_skyline;
    let Some(mut rounds) = refine(
        edit,
        views,
        &solver,
        &placed,
        deformation,
        discard_unchanged,
    )?
    else {
        return Ok(None);
    };
    if rounds.kept_unedited {
        notes.push(
            "nothing changed by the strokes: no deformation fitted them better than the terrain as it is (each stroke's fit below is on the unedited terrain)"
                .to_string(),
        );
    }
    let corrections = apply_corrections(edit, dem, sketch, views, &placed, &mut rounds)?;
    let view_reports = measure_strokes(edit, views, features, &placed, &rounds);
    timings.lowering = secs(t);

    Ok(Some(Outcome {
        views: view_reports,
        notes,
        curve_constraints: placed.demands.curves.len(),
        lowering_constraints: rounds.lowering_constraints,
        matching: MatchingReport {
            nodes: placed.matched.nodes,
            node_budget: placed.matched.node_budget,
            stopped_early: placed.matched.stopped_early,
        },
        deformation: rounds.deformation,
        corrections,
        renders: rounds.rendered,
        ridges: None,
    }))
}

/// The strokes' summed fit (the fitted fraction of each stroke).
pub(super) fn fit_score(o: &Outcome) -> f64 {
    o.views
        .iter()
        .flat_map(|v| &v.strokes)
        .map(|s| s.fit.fitted_fraction)
        .sum()
}

/// The strokes' summed fit counting only what is seen: per stroke the
/// smaller of its fitted and its visible fraction (a placed curve hidden
/// behind nearer terrain fits only where its silhouette happens to).
pub(super) fn seen_fit_score(o: &Outcome) -> f64 {
    o.views
        .iter()
        .flat_map(|v| &v.strokes)
        .map(|s| s.fit.fitted_fraction.min(s.visible_fraction))
        .sum()
}

/// True when outcome `a` fits the strokes better than `b` by the two
/// measures together: the summed fit ([`fit_score`]) plus the summed fit
/// where the placed curves are visible ([`seen_fit_score`]). A small gain
/// by one measure does not outweigh a larger loss by the other.
pub(super) fn fits_better(a: &Outcome, b: &Outcome) -> bool {
    let gain = (fit_score(a) - fit_score(b)) + (seen_fit_score(a) - seen_fit_score(b));
    gain > 1e-9
}

/// The report's note when the edit without the skylines (`plain`) is
/// kept over the skyline's (`skyline`).
pub(super) fn skyline_dropped_note(plain: &Outcome, skyline: &Outcome) -> String {
    format!(
        "a stroke matched to a view's skyline was left unfitted: matched without the skylines, the strokes' summed fit is {:.3} ({:.3} where visible) instead of {:.3} ({:.3})",
        fit_score(plain),
        seen_fit_score(plain),
        fit_score(skyline),
        seen_fit_score(skyline)
    )
}

/// True when a stroke was matched to a view's skyline feature
/// ([`crate::sketch::skyline`]) and some stroke is short of a full fit or
/// partly hidden.
pub(super) fn skyline_left_unfitted(o: &Outcome) -> bool {
    let strokes = || o.views.iter().flat_map(|v| &v.strokes);
    strokes().any(|s| s.matched.feature_id.is_some_and(crate::sketch::is_skyline))
        && strokes().any(|s| s.fit.fitted_fraction.min(s.visible_fraction) < 1.0 - 1e-9)
}
