//! The passes of an edit: the first (stages 2 to 5 on the loaded views),
//! and the later ones on the terrain the earlier made, while they help and
//! a stroke is left unfitted: first those that place the passes' own near
//! misses again ([`NEAR_MISS_PASSES`], each kept only near the strokes as
//! placed and near what the passes before changed), then those a re-edit
//! of the output would make, until one changes nothing; their
//! deformations composed into the one the write stores.

use super::*;

/// The first pass ([`edit_pass`]) and, while one is kept and leaves a
/// stroke unfitted, the later ones ([`second_pass`]), up to
/// [`MAX_PASSES`].
pub(super) fn all_passes<'s>(
    edit: &Edit,
    (sketch, dem, dem_name, sketch_path): (&'s SketchFile, &Dem, &str, &Path),
    loaded: (Vec<ViewScene>, Vec<Vec<Stroke>>, Vec<String>),
    timings: &mut Timings,
) -> Result<(Vec<ViewState<'s>>, Outcome), EditError> {
    let (views, outcome, _) = edit_pass(
        edit,
        (sketch, dem, dem_name),
        loaded,
        (Vec::new(), None),
        timings,
        false,
    )?;
    let Some(outcome) = outcome else {
        return Err(EditError::Internal(
            "the first pass was dropped as a later one".into(),
        ));
    };
    // The later passes anchor a stroke's short gaps loosely only on
    // boundaries the view as drawn on showed there too
    // ([`TracedBoundaries`]): the passes' own near misses are placed again.
    let later = Edit {
        opts: edit.opts,
        sketch_name: edit.sketch_name.clone(),
        max_d: edit.max_d,
        pb: edit.pb.clone(),
        skyline: edit.skyline,
        exact_cells: edit.exact_cells,
        traced: Some(std::sync::Arc::new(
            views
                .iter()
                .map(|v| TracedBoundaries::of(&v.before))
                .collect(),
        )),
    };
    // The far rings of a long view lie beyond every pass's changes: the
    // later passes take the first's (when they serve, see `load_views`).
    let far: Vec<FarLayers> = views
        .iter()
        .map(|v| v.before.terrain.far_layers())
        .collect();
    let t = Instant::now();
    let inputs = (sketch, dem, sketch_path);
    let (outcome, pass) = near_miss_passes(&later, inputs, &views, outcome, &far)?;
    // Then passes as a re-edit of the output would make them, until one
    // changes nothing: the edit ends at its own fixed point. (They have
    // their own budget, as many as an edit without the passes above.)
    let (outcome, _) = later_passes(edit, inputs, outcome, &far, (pass, pass + MAX_PASSES - 1))?;
    timings.lowering += secs(t);
    Ok((views, outcome))
}

/// The most later passes that place again the near misses the passes
/// before left (with [`TracedBoundaries`]) in one edit; the passes as a
/// re-edit makes them follow.
pub const NEAR_MISS_PASSES: usize = 3;

/// The later passes that place again the near misses the passes before
/// left (`edit` carries the view as drawn on, [`TracedBoundaries`]), up to
/// [`NEAR_MISS_PASSES`], while one is kept and leaves a stroke unfitted.
/// Such a pass re-matches those columns and may place them farther than
/// the edit had them: a pass that changes a cell farther than the
/// influence distance from the sight lines to the strokes as the passes
/// before placed them ([`within_sight_wedge`]) is not kept, and ends them.
/// `views`: the first pass's. Returns the outcome and the number of the
/// last pass made.
fn near_miss_passes(
    edit: &Edit,
    (sketch, dem, sketch_path): (&SketchFile, &Dem, &Path),
    views: &[ViewState],
    mut outcome: Outcome,
    far: &[FarLayers],
) -> Result<(Outcome, usize), EditError> {
    let mut pass = 1;
    while pass < 1 + NEAR_MISS_PASSES && needs_second_pass(sketch, &outcome) {
        pass += 1;
        let before = outcome.without_renders();
        let (changed, seen);
        (outcome, changed, seen) = second_pass(edit, dem, sketch_path, outcome, far, pass)?;
        if !changed {
            break;
        }
        let changed = changed_cells(&before.deformation, &outcome.deformation);
        if !(within_sight_wedge(dem, views, &before, &changed)
            && near_earlier_change(views, &before, &changed))
        {
            outcome = before;
            // The next pass reads the terrain this one read.
            outcome.take_seen(seen);
            outcome.notes.push(format!(
                "a {} pass placed the strokes' near misses again, but changed terrain beyond the influence distance of the strokes as placed, or of what the passes before changed: not kept",
                ordinal(pass)
            ));
            break;
        }
    }
    Ok((outcome, pass))
}

/// Change under this (metres) is no change, for [`within_sight_wedge`]:
/// half a metre, above the rounding of the usual storages, so that the
/// same heights stored in metres, decimetres or feet give one answer.
const NO_CHANGE_M: f32 = 0.5;

/// True when every cell a near-miss pass changed (`changed`,
/// [`changed_cells`]) lies within the influence distance of a
/// stroke's sight line as placed: the segments from a view's eye to the
/// points `before`'s report placed the strokes at.
fn within_sight_wedge(
    dem: &Dem,
    views: &[ViewState],
    before: &Outcome,
    changed: &[(i64, i64)],
) -> bool {
    let a = &before.deformation;
    let influence = a.stats.influence_m;
    if !(influence.is_finite() && influence > 0.0) {
        return true;
    }
    // Per view: its frame and the ends of its sight segments (local east,
    // north), a few dozen per stroke.
    let wedges: Vec<(&LocalFrame, Vec<(f64, f64)>)> = views
        .iter()
        .zip(&before.views)
        .map(|(v, r)| {
            let ends = r
                .strokes
                .iter()
                .flat_map(|s| {
                    let curve = s.first_curve();
                    let step = (curve.len() / 40).max(1);
                    curve.iter().step_by(step)
                })
                .map(|p| v.frame.crs_to_en(p[0], p[1]))
                .collect();
            (&v.frame, ends)
        })
        .collect();
    let near = |x: f64, y: f64| {
        wedges.iter().any(|(frame, ends)| {
            let c = frame.crs_to_en(x, y);
            ends.iter().any(|&e| segment_distance(c, e) <= influence)
        })
    };
    changed.iter().all(|&(col, row)| {
        let (x, y) = dem
            .geotransform
            .pixel_to_crs(col as f64 + 0.5, row as f64 + 0.5);
        near(x, y)
    })
}

/// True when every cell a near-miss pass changed (`changed`,
/// [`changed_cells`]) lies within the influence distance (in
/// cells of the first view's grid, per axis) of a cell `before` changed:
/// a near-miss pass refines the terrain the passes before made, it does
/// not start a change elsewhere along a stroke's sight line (hold-out 4:
/// Zion UTM peak raised long, placed up to 8.5 km against a truth within
/// 3.3 km, changed cells at the far end the passes before had left).
fn near_earlier_change(views: &[ViewState], before: &Outcome, changed: &[(i64, i64)]) -> bool {
    let a = &before.deformation;
    let influence = a.stats.influence_m;
    let Some(v) = views.first() else {
        return true;
    };
    if !(influence.is_finite() && influence > 0.0) {
        return true;
    }
    let (hx, hy) = super::observer::cell_m(&v.frame);
    let (rx, ry) = (
        (influence / hx.max(1e-9)).ceil() as usize,
        (influence / hy.max(1e-9)).ceil() as usize,
    );
    let wa = a.window;
    let was_changed: Vec<bool> = a
        .displacement
        .iter()
        .map(|m| !m.is_nan() && m.abs() > NO_CHANGE_M)
        .collect();
    // `before`'s changed cells dilated by (rx, ry), over its window grown
    // by as much.
    let (w, h) = (wa.width + 2 * rx, wa.height + 2 * ry);
    let mut grid = vec![false; w * h];
    for r in 0..wa.height {
        for c in 0..wa.width {
            grid[(r + ry) * w + c + rx] = was_changed[r * wa.width + c];
        }
    }
    for row in grid.chunks_mut(w) {
        let d = dilated(row, rx);
        row.copy_from_slice(&d);
    }
    let mut column = vec![false; h];
    for c in 0..w {
        for r in 0..h {
            column[r] = grid[r * w + c];
        }
        for (r, v) in dilated(&column, ry).into_iter().enumerate() {
            grid[r * w + c] = v;
        }
    }
    let near = grid;
    changed.iter().all(|&(col, row)| {
        let (x, y) = (col - wa.col + rx as i64, row - wa.row + ry as i64);
        x >= 0
            && y >= 0
            && (x as usize) < w
            && (y as usize) < h
            && near[y as usize * w + x as usize]
    })
}

/// The cells (column, row on the DEM grid) where `after` differs from
/// `before` by more than [`NO_CHANGE_M`]: what a near-miss pass changed.
fn changed_cells(before: &Deformation, after: &Deformation) -> Vec<(i64, i64)> {
    let (wa, wb) = (before.window, after.window);
    let mut out = Vec::new();
    for r in 0..wb.height {
        for c in 0..wb.width {
            let (col, row) = (wb.col + c as i64, wb.row + r as i64);
            let (ca, ra) = (col - wa.col, row - wa.row);
            let inside =
                ca >= 0 && ra >= 0 && (ca as usize) < wa.width && (ra as usize) < wa.height;
            let was = if inside {
                before.displacement[ra as usize * wa.width + ca as usize]
            } else {
                0.0
            };
            let d = after.displacement[r * wb.width + c] - was;
            if !d.is_nan() && d.abs() > NO_CHANGE_M {
                out.push((col, row));
            }
        }
    }
    out
}

/// `line` dilated by `r`: cell `i` is set where a cell of `line` within
/// `r` of it is.
fn dilated(line: &[bool], r: usize) -> Vec<bool> {
    let n = line.len();
    let mut prefix = vec![0usize; n + 1];
    for (i, &b) in line.iter().enumerate() {
        prefix[i + 1] = prefix[i] + b as usize;
    }
    (0..n)
        .map(|i| prefix[(i + r + 1).min(n)] > prefix[i.saturating_sub(r)])
        .collect()
}

/// Distance from point `p` to the segment from the origin to `e`.
fn segment_distance(p: (f64, f64), e: (f64, f64)) -> f64 {
    let len2 = e.0 * e.0 + e.1 * e.1;
    let t = if len2 > 0.0 {
        ((p.0 * e.0 + p.1 * e.1) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p.0 - t * e.0).hypot(p.1 - t * e.1)
}

/// Later passes ([`second_pass`]) with `edit`'s anchoring after pass
/// `pass`, while one is kept, leaves a stroke unfitted and the passes
/// stay within pass number `last`. Returns the outcome and the number of
/// the last pass made.
fn later_passes(
    edit: &Edit,
    (sketch, dem, sketch_path): (&SketchFile, &Dem, &Path),
    mut outcome: Outcome,
    far: &[FarLayers],
    (mut pass, last): (usize, usize),
) -> Result<(Outcome, usize), EditError> {
    while pass < last && needs_second_pass(sketch, &outcome) {
        pass += 1;
        let changed;
        (outcome, changed, _) = second_pass(edit, dem, sketch_path, outcome, far, pass)?;
        if !changed {
            break;
        }
    }
    Ok((outcome, pass))
}

/// Stages 2 to 5 on the loaded views: features, matching, deformation,
/// lowering and contour rounds (with the sketch's map-view corrections),
/// and the strokes measured on the result. `timings` gets their times.
/// `earlier`: per view, the pass before's last render, which the views'
/// renders take what they can from ([`render_and_extract`]; none for the
/// first pass), and the ridges a pass before detected, taken where they
/// were detected from the same windows ([`ridge_network`]). Also returns
/// this pass's ridges with its windows ([`RidgesOf`]).
/// `later`: a pass after the first, which the run drops when it changes no
/// cell ([`second_pass`]); such a pass stops as soon as that is known and
/// gives no outcome (`None`; the first pass always gives one).
/// When a stroke matched to a view's skyline is left unfitted, stages 3
/// to 5 run again without the skylines, and that outcome is kept if it
/// fits the strokes better (ties keep the skyline's).
pub(super) fn edit_pass<'s>(
    edit: &Edit,
    (sketch, dem, dem_name): (&'s SketchFile, &Dem, &str),
    (scenes, prepared, notes): (Vec<ViewScene>, Vec<Vec<Stroke>>, Vec<String>),
    earlier: (Vec<RenderedView>, Option<RidgesOf>),
    timings: &mut Timings,
    later: bool,
) -> Result<(Vec<ViewState<'s>>, Option<Outcome>, RidgesOf), EditError> {
    let t = Instant::now();
    let extracted = render_and_extract(edit, sketch, dem, scenes, prepared, earlier)?;
    let Extracted {
        views,
        windows,
        seen,
        ridges,
    } = extracted;
    let features = scene_features(&views, &ridges, &sketch.options, edit.skyline);
    timings.features = secs(t);
    let found = (&views[..], &windows[..], &features);
    let Some(outcome) = match_and_fit(
        edit,
        (sketch, dem, dem_name),
        found,
        notes.clone(),
        timings,
        later,
    )?
    else {
        drop(features);
        let ridges = RidgesOf::of(ridges, windows, seen, &views);
        return Ok((views, None, ridges));
    };
    if !(edit.skyline && skyline_left_unfitted(&outcome)) {
        drop(features);
        let ridges = RidgesOf::of(ridges, windows, seen, &views);
        return Ok((views, Some(outcome), ridges));
    }
    // A skyline match that leaves a stroke unfitted stands against the
    // match without the skyline (see `sketch::skyline`); the two are
    // compared whole (never dropped early).
    let plain = scene_features(&views, &ridges, &sketch.options, false);
    let mut scratch = Timings::default();
    let found = (&views[..], &windows[..], &plain);
    let other = match_and_fit(
        edit,
        (sketch, dem, dem_name),
        found,
        notes,
        &mut scratch,
        false,
    );
    let outcome = match other {
        Ok(Some(mut other)) if fits_better(&other, &outcome) => {
            other.notes.push(skyline_dropped_note(&other, &outcome));
            other
        }
        _ => outcome,
    };
    timings.add(&scratch);
    drop((features, plain));
    let ridges = RidgesOf::of(ridges, windows, seen, &views);
    Ok((views, Some(outcome), ridges))
}

/// A second pass is made when the first changed the terrain but left a
/// stroke short of a full fit, and the sketch has no map-view
/// corrections (which the first pass applied already).
pub(super) fn needs_second_pass(sketch: &SketchFile, first: &Outcome) -> bool {
    sketch.corrections.is_none()
        && first.deformation.stats.changed_cells > 0
        && first
            .views
            .iter()
            .flat_map(|v| &v.strokes)
            .any(|s| s.fit.fitted_fraction < 1.0 - 1e-9)
}

/// The edit again, on the terrain the first pass made (read through an
/// overlay of `dem`, nothing written): where the first pass fitted a
/// stroke, the stroke now lies on a silhouette and is kept; the columns it
/// left unfitted are matched and placed again, against the terrain as it
/// now is, as editing the output again would. Without it an edit is not
/// its own fixed point: editing its output again with the same sketch
/// would move those columns (issue 11: on the fidelity suite, 3 of 126
/// tuned and 35 of 235 hold-out cases moved by more than 0.5 m). The
/// result is the first pass's deformation plus the second's, reported with
/// the first pass's matches (the landform the strokes asked for), the
/// placement of the last pass kept (the curve the written terrain is
/// fitted to: a report's `depth_m` says where the change stands; the
/// passes' own checks keep measuring against the first placement, see
/// [`crate::edit::report::StrokeReport::first_curve`]) and the final fit; it is kept only when it fits the strokes
/// at least as well as the first pass alone and the sum of the two changes
/// has no more spikes ([`find_spikes`]) than the first alone. `pass` numbers
/// it (2 for the second; `first` is then everything the passes before
/// made). Returns the outcome and whether this pass was kept: when it was,
/// the run makes another pass ([`MAX_PASSES`] in all at most), so that
/// the edit stops only where a pass, as a re-edit of its output would,
/// changes nothing. A pass not kept leaves in the outcome what it
/// rendered of the terrain it read ([`Seen`]), which the next pass reads
/// again where the DEM is in whole units of a metre; a kept pass returns
/// it beside (the caller may yet drop the pass).
pub(super) fn second_pass(
    edit: &Edit,
    dem: &Dem,
    sketch_path: &Path,
    mut first: Outcome,
    far: &[FarLayers],
    pass: usize,
) -> Result<(Outcome, bool, Option<Seen>), EditError> {
    edit.pb
        .set_message(format!("pass {pass} over the strokes left unfitted"));
    // What the pass reads: the terrain the passes before made, in whole
    // metres where the pass places their near misses again
    // (`in_whole_metres`), else as the write would store it (as a re-edit
    // of the output reads it).
    let seen = &match edit.traced {
        Some(_) => in_whole_metres(&first.deformation),
        None => quantized(dem, &first.deformation),
    };
    // The pass before's last renders are of the terrain this pass starts
    // from, as the write would store it: its views' renders take what they
    // can from them where that is the terrain the pass reads (a DEM in
    // whole units of a metre).
    let mut earlier = std::mem::take(&mut first.renders);
    let mut earlier_ridges = first.ridges.take();
    if seen.displacement != quantized(dem, &first.deformation).displacement {
        earlier.clear();
        earlier_ridges = None;
    }
    let run_second = || -> Result<(Option<Outcome>, Seen), EditError> {
        let overlay = dem
            .reopened()?
            .with_overlay(seen.window, seen.edited().data);
        let Loaded {
            sketch,
            dem: dem2,
            notes,
            prepared,
            scenes,
        } = load_views(edit, overlay, sketch_path, far)?;
        let dem_name = dem.path.display().to_string();
        let mut scratch = Timings::default();
        let (views, second, ridges) = edit_pass(
            edit,
            (&sketch, &dem2, &dem_name),
            (scenes, prepared, notes),
            (earlier, earlier_ridges),
            &mut scratch,
            true,
        )?;
        let renders = views.into_iter().map(|v| v.before).collect();
        Ok((second, Seen { renders, ridges }))
    };
    // The first pass stands on its own: a second that cannot run (a stroke
    // end no longer on terrain, say) leaves it as it is.
    let (second, seen_by_pass) = match run_second() {
        Ok((Some(o), s)) => (o, s),
        // A pass that changes no cell is dropped (below) whatever it
        // measured: it stopped as soon as that was known.
        Ok((None, s)) => {
            first.take_seen(Some(s));
            return Ok((first, false, None));
        }
        Err(e) => {
            let mut out = first;
            out.notes.push(format!("no {} pass: {e}", ordinal(pass)));
            return Ok((out, false, None));
        }
    };
    let score = fit_score;
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        eprintln!(
            "pass {pass}: fit {:.3} -> {:.3}, its change {} cells, max |dz| {:.1} m (before: {:.1} m)",
            score(&first),
            score(&second),
            second.deformation.stats.changed_cells,
            second.deformation.stats.max_abs_displacement_m,
            first.deformation.stats.max_abs_displacement_m
        );
    }
    if score(&second) < score(&first) - 1e-9 || second.deformation.stats.changed_cells == 0 {
        first.take_seen(Some(seen_by_pass));
        return Ok((first, false, None));
    }
    // The change is added to the terrain the passes before made, as solved
    // (the write rounds the sum to the file's step once).
    let total = compose(dem, &first.deformation, &second.deformation)?;
    // Each pass's change is free of spikes, but their sum need not be
    // (issue 11, item 5): a pass that adds one is dropped.
    let (added, before) = rayon::join(
        || find_spikes(&total).len(),
        || find_spikes(&first.deformation).len(),
    );
    if added > before {
        first.take_seen(Some(seen_by_pass));
        return Ok((first, false, None));
    }
    let mut out = first;
    let (f1, f2) = (score(&out), score(&second));
    for (v1, v2) in out.views.iter_mut().zip(second.views) {
        for (s1, s2) in v1.strokes.iter_mut().zip(v2.strokes) {
            // The report states where the stroke now stands: this pass's
            // placement, on the terrain the passes before made (the
            // columns they fitted anchored on the silhouettes they made,
            // the others placed again), is the curve the written terrain
            // is fitted to.
            if !s2.placed_curve.is_empty() {
                s1.take_placement(&s2);
            }
            s1.fit = s2.fit;
            s1.visible_fraction = s2.visible_fraction;
            s1.status = s2.status;
            s1.reason = s2.reason;
        }
        v1.lowering_iterations += v2.lowering_iterations;
        v1.silhouettes_lowered += v2.silhouettes_lowered;
        v1.contour_iterations += v2.contour_iterations;
    }
    out.lowering_constraints += second.lowering_constraints;
    out.renders = second.renders;
    out.notes.push(format!(
        "a {} pass over the strokes the {} left unfitted, on the terrain it made, took their summed fit from {f1:.3} to {f2:.3}",
        ordinal(pass),
        if pass == 2 { "first" } else { "passes before" }
    ));
    out.deformation = total;
    Ok((out, true, Some(seen_by_pass)))
}

/// The most passes of one edit: the first and the later ones over the
/// strokes the passes before left unfitted ([`second_pass`]). Most edits
/// stop after one to three (the first pass that changes nothing, or does
/// no better, ends them); four left a stroke placed where the DEM cannot
/// draw it still moving on a re-edit (hold-out 4: Zion 90 m new hill,
/// hand, 3 m; with eight, nothing), at the cost of more passes only where
/// each one still helps.
pub const MAX_PASSES: usize = 8;

/// "second", "third", ...: the name of pass `n` in the report's notes.
pub(super) fn ordinal(n: usize) -> String {
    match n {
        1 => "first".to_string(),
        2 => "second".to_string(),
        3 => "third".to_string(),
        4 => "fourth".to_string(),
        n => format!("{n}th"),
    }
}

/// `d` with each changed cell's displacement made what the write stores:
/// the edited height quantized to `dem`'s sample type (an integer DEM
/// stores whole units), so that a second pass sees the terrain exactly as
/// editing the written output again would.
pub(super) fn quantized(dem: &Dem, d: &Deformation) -> Deformation {
    let mut q = d.clone();
    let (st, v) = (dem.sample_type, &dem.vertical);
    for (m, &h) in q.displacement.iter_mut().zip(&d.base.data) {
        if *m != 0.0 && !m.is_nan() && !h.is_nan() {
            let stored = v.to_metres(st.quantize(v.to_raw(h as f64 + *m as f64)));
            *m = (stored - h as f64) as f32;
        }
    }
    q.stats.recount(&q.displacement);
    q
}

/// `d` with each changed cell's edited height rounded to whole metres:
/// the terrain a later pass that places the passes' near misses again
/// reads ([`second_pass`]). Such a pass re-places
/// the columns the passes before left unfitted, and where it anchors a
/// stroke point can turn on a few centimetres; reading the terrain as each
/// file stores it (`quantized`: 1 m in integer metres, 0.1 m in
/// decimetres, unrounded in floating point) made the same DEM stored in
/// metres, decimetres or feet get edits up to 11.7 m apart (the bundled
/// demo, `tests/raster_units.rs`). Whole metres are the coarsest step of
/// the common storages, so a DEM in integer metres reads exactly what it
/// stores, and every storage of the same heights reads the same terrain;
/// the pass's change is then added to the terrain as the file stores it.
pub(super) fn in_whole_metres(d: &Deformation) -> Deformation {
    let mut q = d.clone();
    for (m, &h) in q.displacement.iter_mut().zip(&d.base.data) {
        if *m != 0.0 && !m.is_nan() && !h.is_nan() {
            *m = ((h as f64 + *m as f64).round() - h as f64) as f32;
        }
    }
    q.stats.recount(&q.displacement);
    q
}

/// The deformation `a` followed by `b` (computed on the terrain `a` made)
/// as one deformation of `dem`: the union of their windows, the sum of
/// their displacements, either's constrained cells.
pub(super) fn compose(
    dem: &Dem,
    a: &Deformation,
    b: &Deformation,
) -> Result<Deformation, EditError> {
    let (wa, wb) = (a.window, b.window);
    let (c0, r0) = (wa.col.min(wb.col), wa.row.min(wb.row));
    let (c1, r1) = (
        wa.col_end().max(wb.col_end()),
        wa.row_end().max(wb.row_end()),
    );
    let window = Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize);
    let base = dem.read_height_map(window)?;
    let mut displacement = vec![0.0f32; window.len()];
    let mut constrained = vec![false; window.len()];
    for d in [a, b] {
        let w = d.window;
        for r in 0..w.height {
            for c in 0..w.width {
                let k = r * w.width + c;
                let j = ((w.row - r0) as usize + r) * window.width + (w.col - c0) as usize + c;
                displacement[j] += d.displacement[k];
                constrained[j] |= d.constrained[k];
            }
        }
    }
    for (m, h) in displacement.iter_mut().zip(&base.data) {
        if h.is_nan() {
            *m = f32::NAN;
        }
    }
    let mut stats = a.stats.clone();
    stats.recount(&displacement);
    stats.constrained_cells = constrained.iter().filter(|c| **c).count();
    stats.max_abs_constraint_m = a
        .stats
        .max_abs_constraint_m
        .max(b.stats.max_abs_constraint_m);
    stats.cycles += b.stats.cycles;
    stats.solve_s += b.stats.solve_s;
    Ok(Deformation {
        window,
        displacement,
        base,
        affected_tiles: dem.tiles_touching(&window),
        constrained,
        stats,
    })
}

#[cfg(test)]
mod tests {
    use super::dilated;

    #[test]
    fn a_line_dilated_by_r_sets_the_cells_within_r_of_a_set_one() {
        let line = [false, false, true, false, false, false, false, true];
        assert_eq!(
            dilated(&line, 1),
            vec![false, true, true, true, false, false, true, true]
        );
        assert_eq!(dilated(&line, 0), line.to_vec());
        assert!(dilated(&line, 5).iter().all(|&b| b));
        assert!(dilated(&[false; 4], 3).iter().all(|&b| !b));
    }
}
