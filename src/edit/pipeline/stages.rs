//! Stage 3, `matching` (`match_strokes`), and stage 4, `deformation`
//! (`deform`, the map-view corrections of the sketch, and the solves of
//! one edit, [`Solver`]).

use super::*;

/// Stage 3, `matching`: matches the strokes of all views jointly to the
/// views' features ([`match_sketch`]), notes depth-order conflicts and an
/// exhausted node budget, then places the strokes in 3D and turns them
/// into constraints in the DEM's CRS ([`place_demands`]). Also finds the
/// strokes that cannot be fitted whatever the deformation does and the
/// image regions the later re-renders need. Fails when no stroke could be
/// placed at all.
pub(super) fn match_strokes(
    edit: &Edit,
    (options, dem): (&SketchOptions, &Dem),
    (views, windows, map_only): (&[ViewState], &[HeightMap], bool),
    features: &Features,
    notes: &mut Vec<String>,
) -> Result<Placed, EditError> {
    edit.pb.set_message("matching strokes to terrain features");
    let scene_views = &features.scene_views;
    let inputs: Vec<ViewInput> = views
        .iter()
        .zip(scene_views)
        .map(|(v, sv)| sv.input(v.strokes.clone()))
        .collect();
    let mut matched = match_sketch(&inputs, options).map_err(|source| EditError::Match {
        sketch: edit.sketch_name.clone(),
        source: Box::new(source),
    })?;
    for (v, m) in views.iter().zip(&matched.views) {
        for c in &m.ordering.conflicts {
            notes.push(format!(
                "view \"{}\": depth order: {}",
                v.spec.name, c.message
            ));
        }
    }
    if matched.stopped_early {
        notes.push(format!(
            "matching: branch-and-bound stopped after its budget of {} nodes; the assignment is the best found within it (raise options.node_budget to search further)",
            matched.node_budget
        ));
    }
    if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
        trace_candidates(&matched);
    }
    let demands = place_demands(
        views,
        windows,
        scene_views,
        &mut matched.views,
        options,
        edit.traced.as_deref().map(|t| &t[..]),
    );
    notes.extend(depth_notes(views, &demands.strokes));
    let issues: Vec<Vec<Option<&'static str>>> = scene_views
        .iter()
        .zip(&matched.views)
        .map(|(sv, m)| {
            m.strokes
                .iter()
                .map(|sm| {
                    let all = sv.projection.placed_to_dem(&sm.points);
                    placement_issue(dem, &sm.points, &all, edit.max_d)
                })
                .collect()
        })
        .collect();
    // The part of each view the re-renders compute.
    let regions: Vec<StrokeRegion> = views
        .iter()
        .zip(&demands.strokes)
        .map(|(v, cs)| StrokeRegion::new(cs, v.camera.width, v.camera.height))
        .collect();
    // A sketch whose only strokes are those of its map features' landforms
    // (`map_only`: taken out of the views) edits through those alone.
    if !map_only
        && demands
            .strokes
            .iter()
            .flatten()
            .all(|c| c.depths.is_empty())
    {
        return Err(EditError::Unusable {
            sketch: edit.sketch_name.clone(),
            message: "no stroke could be placed on the terrain".into(),
        });
    }
    Ok(Placed {
        matched,
        demands,
        issues,
        regions,
    })
}

/// Under `DEMSKETCH_DEBUG`: the best candidates of every stroke, with
/// their depths and costs, on stderr (six, or `DEMSKETCH_DEBUG_CANDIDATES`).
pub(super) fn trace_candidates(matched: &SketchMatch) {
    let shown = std::env::var("DEMSKETCH_DEBUG_CANDIDATES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(6);
    for m in &matched.views {
        for (k, l) in m.lists.iter().enumerate() {
            for c in l.candidates.iter().take(shown) {
                let d: Vec<f64> = c.points.iter().map(|p| p.depth).collect();
                eprintln!(
                    "stroke {k}: feature {} {:?} depth {:.0}..{:.0} cost {:.2} = dis {:.2} def {:.2} sam {:.2} ext {:.2} cov {:.2}",
                    c.feature_id % (1 << 40),
                    c.kind,
                    d.iter().cloned().fold(f64::INFINITY, f64::min),
                    d.iter().cloned().fold(0.0, f64::max),
                    c.costs.total,
                    c.costs.dissimilarity,
                    c.costs.deformation,
                    c.costs.sampling,
                    c.costs.extension,
                    c.coverage
                );
            }
        }
    }
}

/// Stage 4, `deformation`: the initial solve. Sets up the [`Solver`] every
/// later solve goes through (the DEM, the sketch's influence radius, the
/// cells held fixed) and deforms the DEM through the placed strokes'
/// curve constraints alone; the refinement rounds
/// ([`crate::edit::rounds::refine`]) start from this terrain.
pub(super) fn deform<'a>(
    edit: &Edit,
    dem: &'a Dem,
    dem_name: &'a str,
    options: &SketchOptions,
    views: &[ViewState],
    placed: &'a Placed,
) -> Result<(Solver<'a>, Deformation), EditError> {
    edit.pb.set_message("deforming the DEM (multigrid)");
    let solver = Solver {
        dem,
        dem_name,
        opts: DeformOptions {
            influence_m: options.influence_m,
            ..DeformOptions::default()
        },
        fixed: &placed.demands.fixed,
        bounded: &placed.demands.completions,
        idle: views[0].eye_cell(),
    };
    let deformation = solver.solve(&placed.demands.curves, &[])?;
    Ok((solver, deformation))
}

/// After the refinement rounds, the sketch's map-view corrections (its
/// `corrections` member) on the terrain they gave
/// ([`crate::correct::in_sketch`]: in turn, not in one solve, and why);
/// the views are rendered again on the result, so the strokes are measured
/// on the terrain that is written.
pub(super) fn apply_corrections(
    edit: &Edit,
    dem: &Dem,
    sketch: &SketchFile,
    views: &[ViewState],
    placed: &Placed,
    rounds: &mut Rounds,
) -> Result<Vec<crate::correct::FeatureReport>, EditError> {
    let Some(collection) = &sketch.corrections else {
        return Ok(Vec::new());
    };
    edit.pb.set_message("map-view corrections");
    let name = format!("{}: map_features", edit.sketch_name);
    // Landforms place their strokes on the views as the file gives them.
    let full = SketchFile {
        views: sketch
            .map_feature_views
            .clone()
            .unwrap_or_else(|| sketch.views.clone()),
        options: sketch.options.clone(),
        corrections: None,
        map_feature_views: None,
    };
    let (deformation, reports) = crate::correct::in_sketch::apply_after_edit(
        dem,
        collection,
        &name,
        (&full, &edit.sketch_name),
        &rounds.deformation,
        crate::correct::MAX_WINDOW_CELLS,
    )
    .map_err(|e| match e {
        crate::correct::CorrectError::Raster(r) => EditError::Raster(r),
        crate::correct::CorrectError::Internal(m) => EditError::Internal(m),
        crate::correct::CorrectError::Input(message) => EditError::Unusable {
            sketch: edit.sketch_name.clone(),
            message: message
                .strip_prefix(&format!("{}: ", edit.sketch_name))
                .unwrap_or(&message)
                .to_string(),
        },
    })?;
    rounds.rendered = views
        .iter()
        .zip(&placed.regions)
        .map(|(v, r)| render_edited(v, &deformation, Some(r)))
        .collect::<Result<_, _>>()?;
    rounds.deformation = deformation;
    Ok(reports)
}

impl Solver<'_> {
    /// `d` as the write will store it ([`quantized`]) when the DEM's
    /// sample type is an integer one; `None` on a floating-point DEM,
    /// which stores the heights as solved.
    pub(in crate::edit) fn as_written(&self, d: &Deformation) -> Option<Deformation> {
        self.dem
            .sample_type
            .is_integer()
            .then(|| quantized(self.dem, d))
    }

    /// Deform the DEM through `curves` with the cells `cells` (then the
    /// fixed ones) held, and the bounded curves within their influence;
    /// no curve: no deformation at all.
    pub(in crate::edit) fn solve(
        &self,
        curves: &[CurveConstraint],
        cells: &[CellConstraint],
    ) -> Result<Deformation, EditError> {
        let err = |e: DeformError| match e {
            DeformError::Raster(r) => EditError::Raster(r),
            source => EditError::Deform {
                dem: self.dem_name.to_string(),
                source,
            },
        };
        if curves.is_empty() {
            return Deformation::none(self.dem, self.idle).map_err(err);
        }
        let all: Vec<CellConstraint> = cells.iter().chain(self.fixed).copied().collect();
        deform_bounded(self.dem, curves, self.bounded, &all, &self.opts).map_err(err)
    }
}
