//! Matching on real rendered views (Zion UTM, Vinschgau) through the bridge
//! of `sketch::view_input`: identity (strokes traced from a view's own
//! silhouettes match the silhouette that produced them and are placed on it,
//! within one DEM cell, checked in the DEM's CRS) and multi-view matching
//! (a joint assignment that satisfies every constraint; intersecting
//! sketches are reported).

use demsketch::features::{
    detect_ridges, extract_silhouettes, RidgeNetwork, RidgeParams, Silhouette, SilhouetteParams,
    Silhouettes,
};
use demsketch::raster::Dem;
use demsketch::render::{DepthBuffer, Scene};
use demsketch::sketch::{
    match_sketch, match_view, occludes_across_views, occludes_within_view, prepare_stroke,
    FeatureKind, FeatureSource, FoldBackPolicy, MatchError, MatchKind, PointSource, SceneView,
    SketchOptions, Stroke, ViewFeature, ViewFeatureOptions, ViewInput, ViewProjection,
};
use demsketch::view::{Camera, Viewpoint};

fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// A rendered view of a fixture with its features.
struct Rendered {
    scene: Scene,
    camera: Camera,
    sil: Silhouettes,
    ridges: RidgeNetwork,
    cell_m: f64,
}

fn render(name: &str, lon: f64, lat: f64, heading: f64) -> Rendered {
    let dem = Dem::open(&fixture(name)).expect("open fixture");
    let scene = Scene::open(
        &dem,
        &Viewpoint::above_surface(lon, lat, 1.7),
        None,
        1.0 / 7.0,
    )
    .expect("scene");
    let camera = Camera::new(800, 450, heading, 2.0, 0.0, 60.0).expect("camera");
    let db = DepthBuffer::render(&scene.terrain, &camera);
    let sil = extract_silhouettes(&scene.terrain, &db, &SilhouetteParams::default())
        .expect("silhouettes");
    let ridges = detect_ridges(&scene.window, &RidgeParams::default()).expect("ridges");
    let (gx, gy) = scene.window.geotransform.pixel_size();
    Rendered {
        scene,
        camera,
        sil,
        ridges,
        cell_m: gx.abs().max(gy.abs()),
    }
}

/// The `n` silhouettes with the widest x span (at least `min_span` px)
/// that a person would trace as distinct strokes: a curve running within
/// 2 px of an already chosen one over more than 5 % of its samples (two
/// terrain edges at different depths that project onto the same image line)
/// is skipped; touching at a junction is fine.
fn widest(sil: &Silhouettes, n: usize, min_span: f64) -> Vec<&Silhouette> {
    let span = |c: &Silhouette| c.samples.last().unwrap().pixel[0] - c.samples[0].pixel[0];
    let mut v: Vec<&Silhouette> = sil.curves.iter().filter(|c| span(c) >= min_span).collect();
    v.sort_by(|a, b| span(b).total_cmp(&span(a)).then(a.id.cmp(&b.id)));
    let mut out: Vec<&Silhouette> = Vec::new();
    for c in v {
        if out.len() == n {
            break;
        }
        let close = c
            .samples
            .iter()
            .filter(|s| {
                out.iter().any(|o| {
                    o.samples.iter().any(|t| {
                        (t.pixel[0] - s.pixel[0]).abs() < 0.6
                            && (t.pixel[1] - s.pixel[1]).abs() < 2.0
                    })
                })
            })
            .count();
        if close as f64 <= 0.05 * c.samples.len() as f64 {
            out.push(c);
        }
    }
    out
}

/// A stroke traced from a silhouette's pixel polyline, resampled every 2 px.
fn traced(id: &str, index: usize, c: &Silhouette, lift: impl Fn(f64) -> f64) -> Stroke {
    let pts: Vec<[f64; 2]> = c
        .samples
        .iter()
        .map(|s| [s.pixel[0], s.pixel[1] - lift(s.pixel[0])])
        .collect();
    prepare_stroke(id, index, &pts, 2.0, 3.0, FoldBackPolicy::Reject)
        .expect("traced stroke")
        .remove(0)
}

fn seg_dist(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let ap = [p[0] - a[0], p[1] - a[1], p[2] - a[2]];
    let l2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
    let t = if l2 > 0.0 {
        ((ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let q = [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]];
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

/// Distance from `p` to the polyline through the silhouette's terrain
/// points in the DEM's CRS.
fn dist_to_curve_crs(p: [f64; 3], c: &Silhouette) -> f64 {
    c.samples
        .windows(2)
        .map(|w| seg_dist(p, w[0].world, w[1].world))
        .fold(f64::INFINITY, f64::min)
}

fn no_completion() -> SketchOptions {
    SketchOptions {
        feature_completion: false,
        ..SketchOptions::default()
    }
}

fn identity(name: &str, lon: f64, lat: f64, heading: f64) {
    let r = render(name, lon, lat, heading);
    let view = SceneView::new(
        "v",
        0,
        &r.scene,
        r.camera,
        &r.sil,
        &r.ridges,
        &ViewFeatureOptions::default(),
    );
    let curves = widest(&r.sil, 6, 60.0);
    assert!(
        curves.len() >= 3,
        "{name}: only {} silhouettes",
        curves.len()
    );
    let strokes: Vec<Stroke> = curves
        .iter()
        .enumerate()
        .map(|(k, c)| traced(&format!("s{k}"), k, c, |_| 0.0))
        .collect();
    let input = view.input(strokes);
    let t = std::time::Instant::now();
    let m = match_view(&input, &no_completion()).expect("match");
    eprintln!(
        "{name}: {} strokes, {} features ({} silhouettes, {} ridge pieces), matched in {:.1} ms",
        curves.len(),
        view.features.len(),
        r.sil.curves.len(),
        view.features.len() - r.sil.curves.len(),
        t.elapsed().as_secs_f64() * 1e3
    );
    // The depth order agrees with the terrain: where two traced strokes
    // share pixel columns, the upper one is the farther silhouette (along a
    // column, visible depth grows upwards) and must be ordered behind.
    let mut pairs = 0;
    for a in 0..curves.len() {
        for b in 0..curves.len() {
            let (sa, sb) = (&input.strokes[a], &input.strokes[b]);
            let (lo, hi) = (
                sa.x_range().0.max(sb.x_range().0),
                sa.x_range().1.min(sb.x_range().1),
            );
            if hi - lo < 10.0 {
                continue;
            }
            let x = 0.5 * (lo + hi);
            let (ya, yb) = (sa.y_at(x).unwrap(), sb.y_at(x).unwrap());
            if ya < yb - 2.0 {
                // a above b: a behind b.
                assert!(
                    m.ordering.rank[a] > m.ordering.rank[b],
                    "{name}: stroke {a} is above stroke {b} at x {x:.0} but ordered in front: {:?}",
                    m.ordering.order
                );
                pairs += 1;
            }
        }
    }
    eprintln!("{name}: depth order agrees with the terrain on {pairs} overlapping pairs");
    let mut worst = 0.0_f64;
    for (k, (s, c)) in m.strokes.iter().zip(&curves).enumerate() {
        let want = FeatureSource::Silhouette {
            view: 0,
            curve: c.id,
        }
        .id();
        assert_eq!(
            s.feature_id,
            Some(want),
            "{name} stroke {k} (silhouette {}) matched {:?}",
            c.id,
            s.feature_id.map(FeatureSource::of_id)
        );
        assert_eq!(s.kind, MatchKind::Silhouette, "{name} stroke {k}");
        assert!(!s.points.is_empty());
        for p in &s.points {
            assert_ne!(p.source, PointSource::Fallback);
            // The placed point in the DEM's CRS (x, y metres, absolute z).
            let crs = view.projection.local_to_dem(p.world);
            let d = dist_to_curve_crs(crs, c);
            worst = worst.max(d);
            assert!(
                d <= r.cell_m,
                "{name} stroke {k}: placed point {crs:?} is {d:.1} m from its silhouette (cell {} m)",
                r.cell_m
            );
            // And back.
            let back = view.projection.dem_to_local(crs);
            for (b, w) in back.iter().zip(&p.world) {
                assert!((b - w).abs() < 1e-6);
            }
        }
    }
    eprintln!(
        "{name}: worst placement distance {worst:.2} m (cell {} m)",
        r.cell_m
    );
}

#[test]
fn identity_on_zion_utm() {
    identity("zion_srtm_utm12n.tif", -113.0463, 37.3225, 30.0);
}

#[test]
fn identity_on_vinschgau() {
    identity("vinschgau_250m_utm32n.tif", 10.6959, 46.6597, 200.0);
}

#[test]
fn scene_projection_agrees_with_the_renderer() {
    let r = render("zion_srtm_utm12n.tif", -113.0463, 37.3225, 30.0);
    let view = SceneView::new(
        "v",
        0,
        &r.scene,
        r.camera,
        &r.sil,
        &r.ridges,
        &ViewFeatureOptions::default(),
    );
    let proj = &view.projection;
    // Silhouette samples project to their pixel and depth, and lie on the
    // terrain surface the projection reports.
    let mut n = 0;
    for c in &r.sil.curves {
        for s in &c.samples {
            let (px, d) = proj.project(s.local).unwrap();
            // (pixel rows are stored to about 1e-4 px)
            assert!((px[0] - s.pixel[0]).abs() < 1e-3 && (px[1] - s.pixel[1]).abs() < 1e-3);
            assert!((d - s.depth).abs() < 1e-6 * s.depth.max(1.0));
            let u = proj.unproject(s.pixel, s.depth);
            for (a, b) in u.iter().zip(&s.local) {
                assert!((a - b).abs() < 1e-5 * s.depth.max(1.0));
            }
            // The projection's height is the cells' two triangles; the
            // view draws the bilinear patch, up to a quarter of the cells'
            // twist away.
            let g = proj.terrain_height(s.local[0], s.local[1]).unwrap();
            let t = &r.scene.terrain;
            let (vx, vy) = t.en_to_v(s.local[0], s.local[1]);
            let cell =
                (vy.floor().max(0.0) as usize * t.cells_x() + vx.floor().max(0.0) as usize) as u32;
            let slack = 0.25 * t.twist_around(2 * cell);
            assert!(
                (g - s.local[2]).abs() < 0.05 + slack,
                "{g} vs {}",
                s.local[2]
            );
            n += 1;
        }
    }
    assert!(n > 100);
    // Ridge features: x-monotone, samples consistent with the projection.
    let ridges: Vec<_> = view
        .features
        .iter()
        .filter(|f| f.kind == FeatureKind::Ridge)
        .collect();
    assert!(!ridges.is_empty());
    for f in ridges {
        assert!(f.samples.windows(2).all(|w| w[0].pixel[0] <= w[1].pixel[0]));
        for s in &f.samples {
            let (px, _) = proj.project(s.world).unwrap();
            assert!((px[0] - s.pixel[0]).abs() < 1e-6);
        }
    }
}

/// Checks every constraint of a joint assignment (sections 5.2.2 and 7).
fn check_constraints(inputs: &[ViewInput], m: &demsketch::sketch::SketchMatch) {
    // A feature is used at most once in the whole sketch.
    let mut used = std::collections::HashSet::new();
    for v in &m.views {
        for s in &v.strokes {
            if let Some(f) = s.feature_id {
                assert!(used.insert(f), "feature {f} used twice");
            }
        }
    }
    // Within a view: a feature assigned to a nearer stroke is not hidden by
    // one assigned to a farther stroke.
    let mut within = 0;
    for (t, v) in m.views.iter().enumerate() {
        for a in 0..v.strokes.len() {
            for b in 0..v.strokes.len() {
                let (sa, sb) = (&v.strokes[a], &v.strokes[b]);
                let (Some(ca), Some(cb)) = (sa.candidate, sb.candidate) else {
                    continue;
                };
                if sa.depth_rank >= sb.depth_rank {
                    continue;
                }
                let front = &v.lists[a].candidates[ca];
                let back = &v.lists[b].candidates[cb];
                assert!(
                    !occludes_within_view(
                        &inputs[t].strokes[a],
                        front,
                        &inputs[t].strokes[b],
                        back
                    ),
                    "view {t}: stroke {} hides stroke {}",
                    sb.id,
                    sa.id
                );
                within += 1;
            }
        }
    }
    // Across views: no feature assigned in one view lies between another
    // view's camera and the feature assigned there.
    let mut across = 0;
    for (t, v) in m.views.iter().enumerate() {
        for (u, w) in m.views.iter().enumerate() {
            if t == u {
                continue;
            }
            for (a, sa) in v.strokes.iter().enumerate() {
                let Some(ca) = sa.candidate else { continue };
                let cand = &v.lists[a].candidates[ca];
                for (b, sb) in w.strokes.iter().enumerate() {
                    let Some(cb) = sb.candidate else { continue };
                    // Both views work in the same world frame.
                    let other: Vec<[f64; 3]> = w.lists[b].candidates[cb]
                        .points
                        .iter()
                        .map(|p| p.deformed)
                        .collect();
                    assert!(
                        !occludes_across_views(
                            &inputs[t].strokes[a],
                            cand,
                            inputs[t].projection,
                            &other
                        ),
                        "feature of {}/{} hides the feature of {}/{}",
                        w.name,
                        sb.id,
                        v.name,
                        sa.id
                    );
                    across += 1;
                }
            }
        }
    }
    eprintln!(
        "checked {} assignments, {within} within-view and {across} cross-view pairs",
        used.len()
    );
}

fn two_zion_views() -> (Rendered, Rendered) {
    (
        render("zion_srtm_utm12n.tif", -113.0463, 37.3225, 30.0),
        render("zion_srtm_utm12n.tif", -113.0613, 37.2975, 30.0),
    )
}

#[test]
fn multi_view_joint_assignment_satisfies_every_constraint() {
    let (a, b) = two_zion_views();
    let fo = ViewFeatureOptions::default();
    let world = a.scene.frame;
    let va = SceneView::in_world_frame("a", 0, &a.scene, a.camera, &a.sil, &a.ridges, &fo, world);
    let vb = SceneView::in_world_frame("b", 1, &b.scene, b.camera, &b.sil, &b.ridges, &fo, world);
    let sa: Vec<Stroke> = widest(&a.sil, 4, 60.0)
        .iter()
        .enumerate()
        .map(|(k, c)| traced(&format!("a{k}"), k, c, |_| 0.0))
        .collect();
    let sb: Vec<Stroke> = widest(&b.sil, 4, 60.0)
        .iter()
        .enumerate()
        .map(|(k, c)| traced(&format!("b{k}"), k, c, |_| 0.0))
        .collect();
    let inputs = vec![va.input(sa), vb.input(sb)];
    let m = match_sketch(&inputs, &no_completion()).expect("non-intersecting sketches match");
    for v in &m.views {
        for s in &v.strokes {
            assert_ne!(s.kind, MatchKind::Embedded, "{}/{}", v.name, s.id);
        }
    }
    check_constraints(&inputs, &m);
}

#[test]
fn intersecting_multi_view_sketches_are_reported() {
    let (a, b) = two_zion_views();
    let fo = ViewFeatureOptions::default();
    let world = a.scene.frame;
    let va = SceneView::in_world_frame("a", 0, &a.scene, a.camera, &a.sil, &a.ridges, &fo, world);
    let vb = SceneView::in_world_frame("b", 1, &b.scene, b.camera, &b.sil, &b.ridges, &fo, world);
    // View a traces its farthest wide silhouette.
    let ca = widest(&a.sil, 12, 60.0)
        .into_iter()
        .max_by(|p, q| p.samples[0].depth.total_cmp(&q.samples[0].depth))
        .unwrap();
    let sa = traced("far", 0, ca, |_| 0.0);
    // A curve C in front of it as seen from a, at 60 % of its depth, that
    // crosses it on screen (from 30 px below to 30 px above). View b (behind
    // a) draws C, and C is the only feature b offers: drawn alone, b's
    // stroke is C, which crosses a's stroke in front of it.
    let (x0, x1) = sa.x_range();
    let (m0, m1) = (x0 + (x1 - x0) / 4.0, x0 + 3.0 * (x1 - x0) / 4.0);
    let depth_a = |x: f64| {
        ca.samples
            .iter()
            .min_by(|p, q| (p.pixel[0] - x).abs().total_cmp(&(q.pixel[0] - x).abs()))
            .unwrap()
            .depth
    };
    let c_world: Vec<[f64; 3]> = (0..=60)
        .map(|i| {
            let x = m0 + (m1 - m0) * i as f64 / 60.0;
            let y = sa.y_at(x).unwrap() + 30.0 - 60.0 * i as f64 / 60.0;
            va.projection.unproject([x, y], 0.6 * depth_a(x))
        })
        .collect();
    let fb = vec![ViewFeature::from_world(
        999_999,
        FeatureKind::Ridge,
        &c_world,
        &vb.projection,
    )];
    assert!(fb[0].samples.len() > 30, "C is not in view b");
    let pb: Vec<[f64; 2]> = fb[0].samples.iter().map(|s| s.pixel).collect();
    let sb = prepare_stroke("c", 0, &pb, 2.0, 3.0, FoldBackPolicy::Reject)
        .unwrap()
        .remove(0);
    let inputs = vec![
        va.input(vec![sa]),
        ViewInput {
            name: "b".into(),
            strokes: vec![sb],
            features: &fb,
            projection: &vb.projection,
        },
    ];
    let err = match_sketch(&inputs, &no_completion()).expect_err("intersecting sketches");
    let msg = err.to_string();
    eprintln!("{msg}");
    assert!(matches!(err, MatchError::IntersectingSketches { .. }));
    assert!(msg.contains("\"a\"") && msg.contains("\"b\"") && msg.contains("intersect"));
    assert!(!msg.contains('\n'));
    // Each sketch on its own is fine.
    assert!(match_sketch(&inputs[..1], &no_completion()).is_ok());
    assert!(match_sketch(&inputs[1..], &no_completion()).is_ok());
}
