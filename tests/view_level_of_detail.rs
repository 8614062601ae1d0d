//! The level of detail of a long view (`Scene::open_wedge_lod`, issue 15):
//! the terrain exact out to the plan's reach, coarser rings of block
//! maxima beyond as far layers. Checked against the exact terrain of the
//! whole wedge (`Scene::open_wedge`) on the Zion fixture (83.5 m cells):
//! the same near pixels, the far ones within a coarse cell's relief, a
//! skyline never lower, casts and per-triangle answers on the far layers,
//! and a view within the exact reach unchanged to the bit.

mod view_support;

use demsketch::raster::Dem;
use demsketch::render::{pick, DepthBuffer, LodPlan, Scene, SKY};
use demsketch::view::{Camera, Georef, Viewpoint};
use view_support::*;

/// The fixture, a viewpoint in its south looking north across it, and a
/// camera whose pixels let the rings start at the plan's least reach.
fn setup() -> (Dem, Viewpoint, Camera) {
    let dem = Dem::open(&fixture("zion_srtm_utm12n.tif")).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(210.5, 440.5);
    let georef = Georef::for_crs(&dem.crs, "zion").unwrap();
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let vp = Viewpoint::above_surface(lon, lat, 1500.0);
    let cam = Camera::new(160, 90, 0.0, -2.0, 0.0, 90.0).unwrap();
    (dem, vp, cam)
}

/// Rings follow each other from the exact reach to the maximum distance,
/// twice as coarse each, each starting where its cells span a pixel.
#[test]
fn the_plan_doubles_the_cells_ring_by_ring() {
    let (dem, vp, cam) = setup();
    let scene = Scene::open_wedge(&dem, &vp, Some(40_000.0), 1.0 / 7.0, &cam).unwrap();
    let plan = LodPlan::new(&scene.frame, &cam, Some(40_000.0)).expect("a plan");
    assert_eq!(plan.near_m, demsketch::render::LOD_MIN_NEAR_M);
    let cell = scene.frame.p[0][0].hypot(scene.frame.p[1][0]);
    let mut at = plan.near_m;
    for &(k, inner, outer) in &plan.rings {
        assert_eq!(inner, at);
        assert!(
            k as f64 * cell * cam.focal_px <= inner * (1.0 + 1e-9),
            "ring {k} at {inner}"
        );
        assert!(outer > inner);
        at = outer;
    }
    assert_eq!(at, 40_000.0);
    let ks: Vec<usize> = plan.rings.iter().map(|r| r.0).collect();
    assert_eq!(ks, vec![2, 4]);
    assert!(LodPlan::new(&scene.frame, &cam, Some(20_000.0)).is_none());
}

/// Within the exact reach there is no level of detail: the scene is
/// `open_wedge`'s, to the bit.
#[test]
fn a_view_within_the_exact_reach_is_unchanged() {
    let (dem, vp, cam) = setup();
    let a = Scene::open_wedge(&dem, &vp, Some(15_000.0), 1.0 / 7.0, &cam).unwrap();
    let b = Scene::open_wedge_lod(&dem, &vp, Some(15_000.0), 1.0 / 7.0, &cam, None).unwrap();
    assert_same_terrain(&a, &b);
    assert!(b.terrain.far_layer_sizes().is_empty());
    let (da, db) = (
        DepthBuffer::render(&a.terrain, &cam),
        DepthBuffer::render(&b.terrain, &cam),
    );
    assert_eq!(da.triangle, db.triangle);
}

/// The level-of-detail view against the exact one: the near pixels show
/// the same cells at the same depth; the far ones show terrain where the
/// exact view does, about as far; no column's skyline is lower; a pick on
/// a far pixel answers from the far layer.
#[test]
fn the_rings_draw_the_far_terrain_of_the_exact_view() {
    let (dem, vp, cam) = setup();
    let max_d = Some(40_000.0);
    let exact = Scene::open_wedge(&dem, &vp, max_d, 1.0 / 7.0, &cam).unwrap();
    let lod = Scene::open_wedge_lod(&dem, &vp, max_d, 1.0 / 7.0, &cam, None).unwrap();
    let sizes = lod.terrain.far_layer_sizes();
    assert_eq!(sizes.iter().map(|s| s.0).collect::<Vec<_>>(), vec![2, 4]);
    assert!(lod.window.width * lod.window.height < exact.window.width * exact.window.height);
    let (de, dl) = (
        DepthBuffer::render(&exact.terrain, &cam),
        DepthBuffer::render(&lod.terrain, &cam),
    );
    let (mut near, mut far, mut far_agree, mut far_close) = (0, 0, 0, 0);
    for k in 0..de.depth.len() {
        let (a, b) = (de.depth[k], dl.depth[k]);
        if a.is_finite() && a < 18_000.0 {
            near += 1;
            // the same cell, at the same depth (to rounding: the terrain's
            // origin differs, so ties between triangles may go the other way)
            let ca = exact.terrain.triangle_cell(de.triangle[k]);
            let cb = lod.terrain.triangle_cell(dl.triangle[k]);
            let off = (
                lod.window_offset.0 - exact.window_offset.0,
                lod.window_offset.1 - exact.window_offset.1,
            );
            assert_eq!(
                (ca.0 as i64, ca.1 as i64),
                (cb.0 as i64 + off.0, cb.1 as i64 + off.1),
                "pixel {k}: cell"
            );
            assert!((a - b).abs() <= 1e-4 * a, "pixel {k}: {a} against {b}");
        } else if a.is_finite() && a > 22_000.0 {
            far += 1;
            if b.is_finite() {
                far_agree += 1;
                if (a - b).abs() <= 0.05 * a {
                    far_close += 1;
                }
            }
        }
    }
    assert!(near > 1000 && far > 200, "near {near}, far {far}");
    assert!(
        far_agree as f64 >= 0.99 * far as f64,
        "far terrain {far_agree} of {far}"
    );
    assert!(
        far_close as f64 >= 0.9 * far as f64,
        "far depths {far_close} of {far}"
    );
    // The skyline: the block maxima never lower it (by more than the
    // patch tolerance's pixel).
    for x in 0..cam.width {
        let top = |d: &DepthBuffer| (0..cam.height).find(|&y| d.triangle[y * cam.width + x] != SKY);
        if let (Some(e), Some(l)) = (top(&de), top(&dl)) {
            assert!(l <= e + 1, "column {x}: skyline at row {l}, exact {e}");
        }
    }
    // A far pixel: a pick answers from a far layer, with its triangle.
    let k = (0..dl.depth.len())
        .find(|&k| dl.depth[k].is_finite() && dl.depth[k] > 30_000.0)
        .expect("a far pixel");
    let (x, y) = ((k % cam.width) as f64 + 0.5, (k / cam.width) as f64 + 0.5);
    let hit = pick(&lod.terrain, &cam, x, y).expect("a hit");
    assert!(lod.terrain.is_far_triangle(hit.triangle));
    assert!(lod.terrain.triangle_vertices(hit.triangle).is_some());
    assert!((hit.distance - dl.depth[k] as f64).abs() < 0.02 * hit.distance);
    let (c, r, _) = lod.terrain.triangle_cell(hit.triangle);
    let (c, r) = (
        c as i64 + lod.window_offset.0,
        r as i64 + lod.window_offset.1,
    );
    assert!(c >= 0 && r >= 0 && (c as usize) < dem.width && (r as usize) < dem.height);
}

/// A second scene of the same eye takes the first's far layers: the same
/// render.
#[test]
fn far_layers_are_shared_by_a_second_scene() {
    let (dem, vp, cam) = setup();
    let max_d = Some(40_000.0);
    let first = Scene::open_wedge_lod(&dem, &vp, max_d, 1.0 / 7.0, &cam, None).unwrap();
    let layers = first.terrain.far_layers();
    let second = Scene::open_wedge_lod(&dem, &vp, max_d, 1.0 / 7.0, &cam, Some(&layers)).unwrap();
    assert_same_render(&first, &second, &cam);
}

/// `a` and `b` read the same window into the same terrain, to the bit.
fn assert_same_terrain(a: &Scene, b: &Scene) {
    assert_eq!(a.window_offset, b.window_offset);
    assert_eq!((a.terrain.nx, a.terrain.ny), (b.terrain.nx, b.terrain.ny));
    assert!(a
        .terrain
        .z
        .iter()
        .zip(&b.terrain.z)
        .all(|(p, q)| p.to_bits() == q.to_bits()));
}

/// `a` and `b` render the same depths and triangles from `cam`, to the bit.
fn assert_same_render(a: &Scene, b: &Scene, cam: &Camera) {
    let (da, db) = (
        DepthBuffer::render(&a.terrain, cam),
        DepthBuffer::render(&b.terrain, cam),
    );
    assert!(da
        .depth
        .iter()
        .zip(&db.depth)
        .all(|(p, q)| p.to_bits() == q.to_bits()));
    assert_eq!(da.triangle, db.triangle);
}

/// Rings read from the tiles' overviews, where those hold the maxima of
/// the cells they cover (as `tools/make_edit_scale_tiles.py --overviews`
/// writes them), are the rings of block maxima read at full resolution:
/// the same render, to the bit.
#[test]
fn rings_from_overviews_of_maxima_are_the_block_maxima() {
    if !have_tool("python3") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let (plain, with_ov) = (dir.path().join("plain.tif"), dir.path().join("ov.tif"));
    let script = r#"
import sys
import numpy as np
from osgeo import gdal
gdal.UseExceptions()
src = gdal.Open(sys.argv[1])
a = src.GetRasterBand(1).ReadAsArray().astype(np.float32)
a[a == 65535] = np.nan
drv = gdal.GetDriverByName("GTiff")
for path, ov in ((sys.argv[2], False), (sys.argv[3], True)):
    ds = drv.Create(path, a.shape[1], a.shape[0], 1, gdal.GDT_Float32,
                    ["TILED=YES", "COMPRESS=DEFLATE", "PREDICTOR=3"])
    ds.SetGeoTransform(src.GetGeoTransform())
    ds.SetProjection(src.GetProjection())
    ds.GetRasterBand(1).SetNoDataValue(float("nan"))
    ds.GetRasterBand(1).WriteArray(a)
    if ov:
        ds.BuildOverviews("NEAREST", [2, 4])
        for i, f in enumerate([2, 4]):
            h, w = -(-a.shape[0] // f), -(-a.shape[1] // f)
            p = np.full((h * f, w * f), np.nan, np.float32)
            p[: a.shape[0], : a.shape[1]] = a
            with np.errstate(all="ignore"):
                import warnings
                warnings.simplefilter("ignore")
                m = np.nanmax(p.reshape(h, f, w, f), axis=(1, 3))
            ds.GetRasterBand(1).GetOverview(i).WriteArray(m)
    ds = None
"#;
    let out = std::process::Command::new("/usr/bin/python3")
        .args(["-c", script])
        .arg(fixture("zion_srtm_utm12n.tif"))
        .arg(&plain)
        .arg(&with_ov)
        .output()
        .unwrap();
    if !out.status.success() {
        eprintln!("skipped: {}", String::from_utf8_lossy(&out.stderr));
        return;
    }
    let (_, vp, cam) = setup();
    let max_d = Some(40_000.0);
    let a = Dem::open(&plain).unwrap();
    let b = Dem::open(&with_ov).unwrap();
    let all = b.full_window();
    assert!(a.overview_layer(2, all).is_none());
    assert!(b.overview_layer(2, all).is_some() && b.overview_layer(4, all).is_some());
    let sa = Scene::open_wedge_lod(&a, &vp, max_d, 1.0 / 7.0, &cam, None).unwrap();
    let sb = Scene::open_wedge_lod(&b, &vp, max_d, 1.0 / 7.0, &cam, None).unwrap();
    assert_eq!(sa.terrain.far_layer_sizes(), sb.terrain.far_layer_sizes());
    assert_same_render(&sa, &sb, &cam);
}

/// `demsketch view`'s scene (`Scene::open_view_lod`): without a maximum
/// distance the rings reach the farthest cell of the wedge; the near pixels
/// show the exact view's cells at its depths, no column's skyline is lower;
/// a camera whose exact reach takes in the whole wedge gets the exact
/// scene, to the bit.
#[test]
fn a_view_without_a_distance_reads_the_far_wedge_coarser() {
    let (dem, vp, cam) = setup();
    let exact = Scene::open_wedge(&dem, &vp, None, 1.0 / 7.0, &cam).unwrap();
    let lod = Scene::open_view_lod(&dem, &vp, None, 1.0 / 7.0, &cam).unwrap();
    assert!(!lod.terrain.far_layer_sizes().is_empty());
    assert!(lod.window.width * lod.window.height < exact.window.width * exact.window.height);
    let (de, dl) = (
        DepthBuffer::render(&exact.terrain, &cam),
        DepthBuffer::render(&lod.terrain, &cam),
    );
    let off = (
        lod.window_offset.0 - exact.window_offset.0,
        lod.window_offset.1 - exact.window_offset.1,
    );
    let mut near = 0;
    for k in 0..de.depth.len() {
        let a = de.depth[k];
        if a.is_finite() && a < 18_000.0 {
            near += 1;
            let ca = exact.terrain.triangle_cell(de.triangle[k]);
            let cb = lod.terrain.triangle_cell(dl.triangle[k]);
            assert_eq!(
                (ca.0 as i64, ca.1 as i64),
                (cb.0 as i64 + off.0, cb.1 as i64 + off.1),
                "pixel {k}: cell"
            );
            assert!((a - dl.depth[k]).abs() <= 1e-4 * a, "pixel {k}");
        }
    }
    assert!(near > 1000, "near {near}");
    for x in 0..cam.width {
        let top = |d: &DepthBuffer| (0..cam.height).find(|&y| d.triangle[y * cam.width + x] != SKY);
        if let (Some(e), Some(l)) = (top(&de), top(&dl)) {
            assert!(l <= e + 1, "column {x}: skyline at row {l}, exact {e}");
        }
    }
    // Pixels narrow enough that 2 cells span one only beyond the DEM: no
    // ring, the exact scene.
    let wide = Camera::new(1600, 900, 0.0, -2.0, 0.0, 60.0).unwrap();
    let a = Scene::open_wedge(&dem, &vp, None, 1.0 / 7.0, &wide).unwrap();
    let b = Scene::open_view_lod(&dem, &vp, None, 1.0 / 7.0, &wide).unwrap();
    assert!(b.terrain.far_layer_sizes().is_empty());
    assert_same_terrain(&a, &b);
}

/// An edit's cut of the exact terrain (`LodPlan::new_within`): a ring of
/// the DEM's own cells from the cut to the plan's exact reach (here the
/// view's distance, within it), the same surface as the exact terrain's:
/// every pixel shows terrain or sky as the exact view does, at the same
/// depth to rounding. No cut where the exact reach is within 1.25 times
/// the cut.
#[test]
fn a_cut_exact_terrain_draws_the_exact_view() {
    let (dem, vp, cam) = setup();
    let max_d = Some(15_000.0);
    let exact = Scene::open_wedge(&dem, &vp, max_d, 1.0 / 7.0, &cam).unwrap();
    let p = exact.frame.p;
    let cell = p[0][0].hypot(p[1][0]).max(p[0][1].hypot(p[1][1]));
    let plan = LodPlan::new_within(&exact.frame, &cam, max_d, Some(100.0)).expect("a plan");
    assert!((plan.near_m - 100.0 * cell).abs() < 1e-6);
    assert_eq!(plan.rings, vec![(1, plan.near_m, 15_000.0)]);
    assert!(LodPlan::new_within(&exact.frame, &cam, max_d, Some(15_000.0 / cell)).is_none());
    let cut =
        Scene::open_wedge_lod_within(&dem, &vp, max_d, 1.0 / 7.0, &cam, None, Some(100.0)).unwrap();
    assert_eq!(cut.terrain.far_layer_sizes()[0].0, 1);
    assert!(cut.window.width * cut.window.height < exact.window.width * exact.window.height);
    let (de, dc) = (
        DepthBuffer::render(&exact.terrain, &cam),
        DepthBuffer::render(&cut.terrain, &cam),
    );
    let mut beyond = 0;
    for k in 0..de.depth.len() {
        let (a, b) = (de.depth[k], dc.depth[k]);
        assert_eq!(de.triangle[k] == SKY, dc.triangle[k] == SKY, "pixel {k}");
        if a.is_finite() {
            assert!((a - b).abs() <= 1e-4 * a, "pixel {k}: {a} against {b}");
            beyond += usize::from(cut.terrain.is_far_triangle(dc.triangle[k]));
        }
    }
    assert!(beyond > 0, "no pixel on the ring");
}
