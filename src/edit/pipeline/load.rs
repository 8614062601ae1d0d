//! Stage 1, `load`, and the first half of stage 2, `features`: the sketch
//! and the DEM read and checked, every view set up on the DEM and rendered,
//! its silhouettes extracted, the ridge network of the DEM around all
//! views, and the features each view offers the strokes.

use super::*;

/// Stage 1, `load`: reads the sketch and opens the DEM, prepares every
/// view's strokes, and sets up each view on the DEM: its viewpoint
/// resolved, its camera built, and the DEM read where the camera can see
/// within the maximum view distance ([`Scene::open_wedge_lod`]: the box of its
/// horizontal wedge, not the whole square around the eye), plus the cells
/// around the eye its fixed ground can take ([`EyeGround`]). Refuses a viewpoint
/// whose absolute altitude is not above the ground. Everything later
/// stages read comes from here; nothing is rendered yet. `far`: per view,
/// the far rings of an earlier pass, taken where they serve (the same eye,
/// no changed cell within their reach) instead of being read again.
pub(super) fn load_views(
    edit: &Edit,
    dem: Dem,
    sketch_path: &Path,
    far: &[FarLayers],
) -> Result<Loaded, EditError> {
    let sketch_name = &edit.sketch_name;
    edit.pb.set_message("loading DEM and sketch");
    let mut sketch = SketchFile::from_path(sketch_path)?;
    if sketch.corrections.is_none() && sketch.views.iter().all(|v| v.strokes.is_empty()) {
        return Err(EditError::Unusable {
            sketch: sketch_name.clone(),
            message: "the sketch has no strokes and no map_features: nothing to edit".into(),
        });
    }
    sketch.split_map_feature_strokes();
    let mut notes = Vec::new();
    let mut prepared = Vec::new();
    for v in &sketch.views {
        let (strokes, n) = v.prepared_strokes(&sketch.options, sketch_name)?;
        notes.extend(n);
        prepared.push(strokes);
    }
    check_view_sizes(edit, &dem, &sketch)?;
    let mut scenes = Vec::new();
    for (i, v) in sketch.views.iter().enumerate() {
        let vp = v.eye();
        let view_err = |source| EditError::View {
            sketch: sketch_name.clone(),
            view: v.name.clone(),
            source: Box::new(source),
        };
        let camera = v.pinhole().map_err(|e| view_err(e.into()))?;
        // (the far rings are read later, beside the ridges' detection)
        let (scene, rings) = Scene::open_wedge_lod_deferred(
            &dem,
            &vp,
            edit.max_d,
            edit.opts.refraction,
            &camera,
            far.get(i),
            edit.exact_cells,
        )
        .map_err(view_err)?;
        if let Some(problem) =
            crate::view::below_ground_problem("viewpoint alt_m", vp.height, scene.frame.ground)
        {
            return Err(EditError::Unusable {
                sketch: sketch_name.clone(),
                message: format!("view \"{}\": {problem}", v.name),
            });
        }
        let eye_ground = eye_ground(
            &dem,
            &scene,
            &vp,
            edit.max_d,
            sketch.options.observer_radius_m,
        )
        .map_err(view_err)?;
        scenes.push((scene, camera, eye_ground, rings));
    }
    Ok(Loaded {
        sketch,
        dem,
        notes,
        prepared,
        scenes,
    })
}

/// Bytes of memory an edit takes per cell of its views' windows, at most
/// (measured: 45 on a 45.8 M-cell view at 100 km): the window read, the
/// view's terrain and cast index before the edit, the terrains of the
/// rounds' renders kept (the best, the latest and the current one), the
/// ridge detection's arrays.
pub const EDIT_BYTES_PER_CELL: u64 = 48;

/// The size limits of the stages after the load, checked before reading
/// any height (issue 15: the deformation's window limit used to be hit only
/// at a re-solve, after seconds of work and gigabytes): the windows every
/// view reads ([`Scene::wedge_cells`]: its window and its far rings), their union (where the ridges are
/// detected: at most 2^30 cells) and the memory the edit will take over
/// them ([`EDIT_BYTES_PER_CELL`] per cell) against the memory budget
/// ([`crate::raster::geotiff::memory_budget`]).
pub(super) fn check_view_sizes(
    edit: &Edit,
    dem: &Dem,
    sketch: &SketchFile,
) -> Result<(), EditError> {
    let mut windows = Vec::new();
    let mut ring_cells = 0u64;
    for v in &sketch.views {
        let view_err = |source| EditError::View {
            sketch: edit.sketch_name.clone(),
            view: v.name.clone(),
            source: Box::new(source),
        };
        let camera = v.pinhole().map_err(|e| view_err(e.into()))?;
        let (w, rings) =
            Scene::wedge_cells(dem, &v.eye(), edit.max_d, edit.opts.refraction, &camera)
                .map_err(view_err)?;
        windows.push(w);
        ring_cells = ring_cells.saturating_add(rings);
    }
    let Some(first) = windows.first() else {
        return Ok(());
    };
    let (mut c0, mut r0, mut c1, mut r1) = (first.col, first.row, first.col_end(), first.row_end());
    for w in &windows {
        c0 = c0.min(w.col);
        r0 = r0.min(w.row);
        c1 = c1.max(w.col_end());
        r1 = r1.max(w.row_end());
    }
    let union = ((c1 - c0) as u64).saturating_mul((r1 - r0) as u64);
    // (a far ring's cell costs a terrain's, not a window's: counted as one)
    let cells: u64 = windows.iter().map(|w| w.len() as u64).sum::<u64>() + ring_cells;
    let bytes = cells.saturating_mul(EDIT_BYTES_PER_CELL);
    let budget = crate::raster::geotiff::memory_budget();
    let distance = match edit.max_d {
        Some(d) => format!("--max-distance {d} m"),
        None => "the whole DEM (no --max-distance)".to_string(),
    };
    let message = if union >= 1 << 30 {
        format!(
            "the views see {union} cells within {distance} (ridge detection handles at most 2^30): lower --max-distance"
        )
    } else if bytes > budget {
        format!(
            "the views see {cells} cells within {distance}: the edit would take about {} MB, over the memory budget of {} MB (DEMSKETCH_MEMORY_BUDGET_MB): lower --max-distance",
            bytes >> 20,
            budget >> 20
        )
    } else {
        return Ok(());
    };
    Err(EditError::Unusable {
        sketch: edit.sketch_name.clone(),
        message,
    })
}

/// Stage 2, `features` (first half): renders every view of `sketch` on its
/// scene before the edit (exact depth buffer and silhouettes) and, side by
/// side, detects one ridge network over what all views see
/// ([`ridge_network`]); a view's render takes from `earlier` (the pass
/// before's last render of it, when there is one) the silhouettes it
/// refined already ([`RenderedView::from_terrain_after`]: the same
/// render). Pairs each render with its view's window, frame,
/// camera and prepared strokes into a [`ViewState`], which every later
/// stage works on, and refuses strokes drawn in empty sky
/// ([`check_strokes_touch_terrain`]).
pub(super) fn render_and_extract<'a>(
    edit: &Edit,
    sketch: &'a SketchFile,
    dem: &Dem,
    scenes: Vec<ViewScene>,
    prepared: Vec<Vec<Stroke>>,
    (earlier, earlier_ridges): (Vec<RenderedView>, Option<RidgesOf>),
) -> Result<Extracted<'a>, EditError> {
    edit.pb
        .set_message("rendering views, silhouettes and ridges");
    // The ridges and the views' renders are independent: computed side by
    // side, each also parallel inside.
    let mut parts = Vec::new();
    let mut terrains = Vec::new();
    for (scene, camera, eye_ground, rings) in scenes {
        let Scene {
            window,
            window_offset,
            frame,
            terrain,
            ..
        } = scene;
        parts.push((window, window_offset, frame, camera, eye_ground));
        terrains.push((terrain, camera, rings));
    }
    let windows: Vec<(&HeightMap, (i64, i64))> = parts.iter().map(|p| (&p.0, p.1)).collect();
    let seen: Vec<Window> = parts
        .iter()
        .zip(&terrains)
        .map(|(p, (t, _, _))| {
            Window::new(p.1 .0 + t.col0 as i64, p.1 .1 + t.row0 as i64, t.nx, t.ny)
        })
        .collect();
    let mut earlier: Vec<Option<RenderedView>> = earlier.into_iter().map(Some).collect();
    // A view's far rings still to be read are read first on the renders'
    // side (they need the exact terrain's ids only, not its render), so
    // that their reading, not the renders alone, runs beside the ridges'
    // detection (and beside the exact terrain's cast index).
    let view_err = |k: usize, source: crate::render::RenderError| EditError::View {
        sketch: edit.sketch_name.clone(),
        view: sketch.views[k].name.clone(),
        source: Box::new(source),
    };
    let (ridges, befores) = rayon::join(
        || ridge_network(dem, &windows, &seen, earlier_ridges),
        || {
            terrains
                .into_iter()
                .enumerate()
                .map(|(k, (t, c, rings))| {
                    let t = match rings {
                        // (beside the exact terrain's cast index, which
                        // the render builds beside it otherwise: it is
                        // of the terrain's own grid, no far layer's)
                        Some(r) => {
                            let (rings, ()) = rayon::join(|| r.read(dem), || t.build_cast_index());
                            t.with_far_layers(rings.map_err(|e| view_err(k, e))?)
                        }
                        None => t,
                    };
                    let name = &sketch.views[k].name;
                    let internal =
                        |e| EditError::Internal(format!("view \"{name}\": features: {e}"));
                    match earlier.get_mut(k).and_then(Option::take) {
                        // The pass before's whole render of this surface.
                        Some(e) if e.is_whole_render_of(&t, &c) => Ok(e),
                        e => RenderedView::from_terrain_after(t, &c, e.as_ref()).map_err(internal),
                    }
                })
                .collect::<Vec<_>>()
        },
    );
    let ridges = ridges?;
    let mut views: Vec<ViewState> = Vec::new();
    let mut heights = Vec::new();
    for (((v, (window, window_offset, frame, camera, eye_ground)), strokes), before) in
        sketch.views.iter().zip(parts).zip(prepared).zip(befores)
    {
        let before = before?;
        views.push(ViewState {
            spec: v,
            window_offset,
            eye_ground,
            frame,
            camera,
            strokes,
            before,
        });
        heights.push(window);
    }
    for v in &views {
        check_strokes_touch_terrain(v, dem, edit.max_d, &edit.sketch_name)?;
    }
    Ok(Extracted {
        views,
        windows: heights,
        seen,
        ridges,
    })
}

/// Stage 2, `features` (second half): each view's silhouettes and the
/// ridges it sees, as the features its strokes are matched against
/// ([`SceneView`]); multi-view sketches in one world frame, the first
/// view's. Features are cut where they come within the observer's fixed
/// ground: no deformation may move it, so no free stroke part may be
/// placed there. Also counts them per view for the report.
pub(super) fn scene_features<'v>(
    views: &'v [ViewState],
    ridges: &RidgeNetwork,
    options: &SketchOptions,
    skyline: bool,
) -> Features<'v> {
    // Multi-view sketches are matched in one world frame: the first view's.
    let world = (views.len() > 1).then(|| views[0].frame);
    let scene_views: Vec<SceneView> = views
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let mut p = SceneProjection::new(v.camera, &v.before.terrain);
            if let Some(w) = world {
                p = p.in_world_frame(w);
            }
            SceneView::build(
                &v.spec.name,
                k,
                p,
                &v.before.silhouettes,
                ridges,
                &ViewFeatureOptions {
                    min_depth_m: v.observer_radius(options.observer_radius_m),
                    skyline,
                    ..ViewFeatureOptions::default()
                },
            )
        })
        .collect();
    let counts: Vec<FeatureCounts> = scene_views
        .iter()
        .map(|sv| {
            let sil = sv
                .features
                .iter()
                .filter(|f| f.kind == crate::sketch::FeatureKind::Silhouette)
                .count();
            FeatureCounts {
                silhouettes: sil,
                ridges: sv.features.len() - sil,
            }
        })
        .collect();
    Features {
        scene_views,
        counts,
    }
}

/// Ridge network of the DEM over the union of what the views see (their
/// terrains' extents, given as windows in the DEM grid) within the windows
/// read for them (with their offsets in the DEM grid): one network, so that
/// a ridge seen from two views is one feature; ridges beyond every view's
/// field of view could match no stroke. `earlier`: the network a pass
/// before detected, taken as it is where it was detected from the same
/// windows and extents ([`RidgesOf::detected_from`]).
pub(super) fn ridge_network(
    dem: &Dem,
    windows: &[(&HeightMap, (i64, i64))],
    seen: &[Window],
    earlier: Option<RidgesOf>,
) -> Result<RidgeNetwork, EditError> {
    if let Some(e) = earlier.filter(|e| e.detected_from(windows, seen)) {
        return Ok(e.ridges);
    }
    let Some(first) = seen.first() else {
        return Ok(RidgeNetwork::default());
    };
    let (mut c0, mut r0, mut c1, mut r1) = (first.col, first.row, first.col_end(), first.row_end());
    for w in seen {
        c0 = c0.min(w.col);
        r0 = r0.min(w.row);
        c1 = c1.max(w.col_end());
        r1 = r1.max(w.row_end());
    }
    let union = Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize);
    // Within one window read already (always, for one view): cropped from
    // it; else read from the DEM.
    let inside = windows.iter().find(|(map, off)| {
        Window::new(off.0, off.1, map.width, map.height).intersect(&union) == Some(union)
    });
    // The whole of one window (one view whose terrain is all of its wedge's
    // box): the window itself, no copy.
    let map = match inside {
        Some((map, off))
            if (off.0, off.1, map.width, map.height)
                == (union.col, union.row, union.width, union.height) =>
        {
            std::borrow::Cow::Borrowed(*map)
        }
        Some((map, off)) => std::borrow::Cow::Owned(map.crop(
            (union.col - off.0) as usize,
            (union.row - off.1) as usize,
            union.width,
            union.height,
        )),
        None => std::borrow::Cow::Owned(dem.read_height_map(union)?),
    };
    detect_ridges(&map, &RidgeParams::default())
        .map_err(|e| EditError::Internal(format!("ridges: {e}")))
}
