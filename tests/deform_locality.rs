//! Locality and nodata of `deform`: on 200 x 200 crops of the Zion UTM
//! fixture (Float32 with a nodata hole, split into 4 x 4 tiles; and the
//! original UInt16 as one file), every cell farther than the influence
//! distance from the curves is bit-identical to the input after
//! `Dem::write_back` (read with GDAL), tiles outside the affected set are not
//! rewritten (hard-linked or byte-identical), nodata cells keep nodata and
//! are never constrained, and `deform` is a pure function of its inputs.

mod deform_support;

use std::path::Path;

use deform_support::*;
use demsketch::deform::{
    deform, deform_bounded, deform_with_cells, plan, CellConstraint, CurveConstraint, DeformError,
    DeformOptions,
};
use demsketch::raster::{Dem, Destination, Provenance};

const SIZE: usize = 200;
const TILE: usize = 50;
/// Centre (pixel) and radius (cells) of the nodata hole punched in the crop.
const HOLE: (f64, f64, f64) = (60.0, 140.0, 8.0);
const NODATA: f64 = -9999.0;

/// A 200 x 200 Float32 crop with a round nodata hole, as one file.
fn float_crop_with_hole(dir: &Path) -> std::path::PathBuf {
    let raw = dir.join("raw.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &raw,
        &["-srcwin", "100", "150", "200", "200", "-ot", "Float32"],
    );
    let g = gdal_read(&raw);
    let mut data: Vec<f32> = g.data.iter().map(|&v| v as f32).collect();
    for r in 0..SIZE {
        for c in 0..SIZE {
            let (dx, dy) = (c as f64 + 0.5 - HOLE.0, r as f64 + 0.5 - HOLE.1);
            if dx.hypot(dy) <= HOLE.2 {
                data[r * SIZE + c] = NODATA as f32;
            }
        }
    }
    let path = dir.join("crop.tif");
    write_f32_geotiff(&path, SIZE, SIZE, g.gt, 32612, &data, Some(NODATA));
    path
}

/// A polyline given in pixel coordinates of `dem`, raised by `bump` metres
/// (sin^2 profile along it) above the DEM's own surface.
fn raised(dem: &Dem, px: &[[f64; 2]], bump: f64, samples: usize) -> CurveConstraint {
    let h = dem.read_height_map(dem.full_window()).unwrap();
    let n = px.len() - 1;
    let mut pts = Vec::new();
    for s in 0..=samples {
        let u = s as f64 / samples as f64;
        let k = ((u * n as f64).floor() as usize).min(n - 1);
        let t = u * n as f64 - k as f64;
        let p = [
            px[k][0] + t * (px[k + 1][0] - px[k][0]),
            px[k][1] + t * (px[k + 1][1] - px[k][1]),
        ];
        // Over nodata, take the surface height of the hole's rim (any z).
        let base = demsketch::deform::constraints::bilinear_valid(&h, p[0], p[1]).unwrap_or(2000.0);
        let (x, y) = dem.geotransform.pixel_to_crs(p[0], p[1]);
        pts.push([x, y, base + bump * (std::f64::consts::PI * u).sin().powi(2)]);
    }
    CurveConstraint { points: pts }
}

/// Checks bit-identity beyond the influence distance between `input` and
/// `output` (GDAL reads), returns (cells beyond, cells changed).
fn check_beyond(
    input: &Grid,
    output: &Grid,
    curve: &CurveConstraint,
    influence: f64,
) -> (usize, usize) {
    let poly: Vec<[f64; 2]> = curve.points.iter().map(|p| [p[0], p[1]]).collect();
    let (mut beyond, mut changed) = (0, 0);
    for r in 0..input.height {
        for c in 0..input.width {
            let (a, b) = (input.at(c, r), output.at(c, r));
            let d = distance_to_polyline(centre(&input.gt, c, r), &poly);
            if a.to_bits() != b.to_bits() {
                changed += 1;
                assert!(
                    d <= influence,
                    "cell ({c}, {r}) at {d:.1} m > {influence} m changed: {a} -> {b}"
                );
            }
            if d > influence {
                beyond += 1;
            }
        }
    }
    (beyond, changed)
}

#[test]
fn beyond_influence_is_bit_identical_and_far_tiles_are_linked() {
    let tmp = tempfile::tempdir().unwrap();
    let crop = float_crop_with_hole(tmp.path());
    let tiles = tmp.path().join("tiles");
    split_tiles(
        &crop,
        &tiles,
        SIZE / TILE,
        TILE,
        &["-co", "COMPRESS=DEFLATE"],
    );
    let dem = Dem::open(&tiles).unwrap();
    let curve = raised(&dem, &[[15.2, 20.4], [40.7, 35.1]], 50.0, 30);
    let influence = 1000.0;
    let opts = DeformOptions {
        influence_m: Some(influence),
        ..DeformOptions::default()
    };
    // The plan is known before solving and matches the deformation.
    let p = plan(&dem, std::slice::from_ref(&curve), &opts).unwrap();
    let d = deform(&dem, std::slice::from_ref(&curve), &opts).unwrap();
    assert_eq!(p.window, d.window);
    assert_eq!(p.affected_tiles, d.affected_tiles);
    assert!(d.affected_tiles.len() < 16 / 2, "{:?}", d.affected_tiles);
    // Purity: a second call gives the same bits.
    let again = deform(&dem, std::slice::from_ref(&curve), &opts).unwrap();
    assert!(d
        .displacement
        .iter()
        .zip(&again.displacement)
        .all(|(a, b)| a.to_bits() == b.to_bits()));

    let out = tmp.path().join("out");
    let rep = dem
        .write_back(
            d.window,
            &d.write_values(),
            &Destination::Path(out.clone()),
            &Provenance {
                edit_id: "locality-test".into(),
            },
        )
        .unwrap();
    // Tiles outside the affected set: not rewritten, hard-linked or identical.
    use std::os::unix::fs::MetadataExt;
    let mut linked = 0;
    for (ti, tile) in dem.tiles.iter().enumerate() {
        let name = tile.path.file_name().unwrap();
        let written = rep
            .tiles_written
            .iter()
            .any(|p| p.file_name() == Some(name));
        if !d.affected_tiles.contains(&ti) {
            assert!(
                !written,
                "tile {} outside the affected set was rewritten",
                name.to_string_lossy()
            );
            let (a, b) = (
                std::fs::metadata(&tile.path).unwrap(),
                std::fs::metadata(out.join(name)).unwrap(),
            );
            if a.ino() == b.ino() {
                linked += 1;
            } else {
                assert_eq!(
                    std::fs::read(&tile.path).unwrap(),
                    std::fs::read(out.join(name)).unwrap()
                );
            }
        }
    }
    let input = gdal_read_mosaic(&tiles);
    let output = gdal_read_mosaic(&out);
    let (beyond, changed) = check_beyond(&input, &output, &curve, influence);
    eprintln!(
        "affected tiles {:?} of 16, written {}, hard-linked {linked}; {beyond} cells beyond \
         {influence} m all identical; {changed} cells changed; max |M| {:.1} m",
        d.affected_tiles,
        rep.tiles_written.len(),
        d.stats.max_abs_displacement_m
    );
    assert!(changed > 100);
    assert!(beyond > 30_000);
}

#[test]
fn integer_dem_beyond_influence_is_bit_identical() {
    let tmp = tempfile::tempdir().unwrap();
    let crop = tmp.path().join("crop_u16.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &crop,
        &["-srcwin", "100", "150", "200", "200"],
    );
    let dem = Dem::open(&crop).unwrap();
    let curve = raised(
        &dem,
        &[[150.3, 120.1], [120.2, 170.8], [90.0, 160.0]],
        -45.0,
        40,
    );
    // Default influence (half the curve's bbox diagonal).
    let d = deform(
        &dem,
        std::slice::from_ref(&curve),
        &DeformOptions::default(),
    )
    .unwrap();
    let influence = d.stats.influence_m;
    let out = tmp.path().join("out.tif");
    dem.write_back(
        d.window,
        &d.write_values(),
        &Destination::Path(out.clone()),
        &Provenance {
            edit_id: "locality-u16".into(),
        },
    )
    .unwrap();
    let (beyond, changed) = check_beyond(&gdal_read(&crop), &gdal_read(&out), &curve, influence);
    eprintln!(
        "UInt16: influence {influence:.0} m, {beyond} cells beyond identical, {changed} changed"
    );
    assert!(changed > 100 && beyond > 1000);
}

#[test]
fn nodata_keeps_nodata_and_is_never_constrained() {
    let tmp = tempfile::tempdir().unwrap();
    let crop = float_crop_with_hole(tmp.path());
    let dem = Dem::open(&crop).unwrap();
    // Straight across the hole.
    let curve = raised(&dem, &[[35.0, 141.3], [86.0, 139.1]], 70.0, 50);
    let d = deform(
        &dem,
        std::slice::from_ref(&curve),
        &DeformOptions::default(),
    )
    .unwrap();
    let w = d.window;
    let mut hole = 0;
    let mut constrained_near_hole = 0;
    for r in 0..w.height {
        for c in 0..w.width {
            let k = r * w.width + c;
            let (gc, gr) = (w.col as usize + c, w.row as usize + r);
            let dist = (gc as f64 + 0.5 - HOLE.0).hypot(gr as f64 + 0.5 - HOLE.1);
            if dist <= HOLE.2 {
                hole += 1;
                assert!(d.base.data[k].is_nan());
                assert!(!d.constrained[k], "nodata cell ({gc}, {gr}) constrained");
                assert!(d.displacement[k].is_nan());
                assert!(d.edited().data[k].is_nan());
                assert!(d.write_values()[k].is_nan());
            } else if dist <= HOLE.2 + 2.0 && d.constrained[k] {
                constrained_near_hole += 1;
            }
        }
    }
    assert!(hole > 150);
    assert!(constrained_near_hole > 0);
    let out = tmp.path().join("out.tif");
    dem.write_back(
        d.window,
        &d.write_values(),
        &Destination::Path(out.clone()),
        &Provenance {
            edit_id: "nodata".into(),
        },
    )
    .unwrap();
    let (a, b) = (gdal_read(&crop), gdal_read(&out));
    let mut nodata_cells = 0;
    for (x, y) in a.data.iter().zip(&b.data) {
        assert_eq!(a.is_nodata(*x), b.is_nodata(*y));
        if a.is_nodata(*x) {
            nodata_cells += 1;
            assert_eq!(x.to_bits(), y.to_bits());
        }
    }
    eprintln!(
        "hole of {hole} cells kept nodata ({nodata_cells} nodata cells in the output); \
         {constrained_near_hole} constrained cells on the hole's rim; max |M| {:.1} m",
        d.stats.max_abs_displacement_m
    );
    assert_eq!(nodata_cells, hole);

    // An integer DEM whose nodata (65535) is along its left edge: a curve
    // starting over it leaves every nodata cell's stored value as it was.
    let u16 = tmp.path().join("edge_u16.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &u16,
        &["-srcwin", "0", "50", "120", "120"],
    );
    let edge = Dem::open(&u16).unwrap();
    let c = raised(&edge, &[[0.4, 30.2], [40.5, 70.3]], 60.0, 40);
    let d = deform(&edge, &[c], &DeformOptions::default()).unwrap();
    let out = tmp.path().join("edge_out.tif");
    edge.write_back(
        d.window,
        &d.write_values(),
        &Destination::Path(out.clone()),
        &Provenance {
            edit_id: "nodata-u16".into(),
        },
    )
    .unwrap();
    let (a, b) = (gdal_read(&u16), gdal_read(&out));
    assert_eq!(a.nodata, Some(65535.0));
    let mut kept = 0;
    let mut changed = 0;
    for (x, y) in a.data.iter().zip(&b.data) {
        if *x == 65535.0 {
            assert_eq!(*y, 65535.0, "a UInt16 nodata cell was overwritten");
            kept += 1;
        } else if x != y {
            changed += 1;
        }
    }
    eprintln!("UInt16: {kept} nodata cells kept, {changed} cells changed");
    assert!(kept >= 120 && changed > 100);

    // A curve entirely over nodata constrains nothing: an error, not a no-op.
    let inside = raised(&dem, &[[57.0, 139.0], [63.0, 141.0]], 10.0, 4);
    let err = deform(&dem, &[inside], &DeformOptions::default()).unwrap_err();
    assert!(
        matches!(err, DeformError::NothingConstrained { .. }),
        "{err}"
    );
    // Off the DEM.
    let off = CurveConstraint {
        points: vec![[0.0, 0.0, 1000.0], [10.0, 10.0, 1000.0]],
    };
    let err = deform(&dem, &[off], &DeformOptions::default()).unwrap_err();
    assert!(matches!(err, DeformError::OffDem { .. }), "{err}");
    assert!(!err.to_string().contains('\n'));
}

#[test]
fn screening_tightens_the_falloff_and_options_are_checked() {
    let tmp = tempfile::tempdir().unwrap();
    let crop = tmp.path().join("crop_u16.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &crop,
        &["-srcwin", "100", "150", "120", "120"],
    );
    let dem = Dem::open(&crop).unwrap();
    let curve = raised(&dem, &[[30.2, 60.3], [90.4, 62.1]], 80.0, 30);
    let cs = std::slice::from_ref(&curve);
    let laplace = deform(&dem, cs, &DeformOptions::default()).unwrap();
    let screened = deform(
        &dem,
        cs,
        &DeformOptions {
            screening: 1.0 / (250.0f64 * 250.0),
            ..DeformOptions::default()
        },
    )
    .unwrap();
    assert_eq!(laplace.window, screened.window);
    // Same constraints; away from the curve the screened field is smaller.
    let (mut sum_l, mut sum_s) = (0.0, 0.0);
    for k in 0..laplace.displacement.len() {
        assert_eq!(laplace.constrained[k], screened.constrained[k]);
        if laplace.constrained[k] {
            assert_eq!(laplace.displacement[k], screened.displacement[k]);
        } else if !laplace.displacement[k].is_nan() {
            sum_l += laplace.displacement[k].abs() as f64;
            sum_s += screened.displacement[k].abs() as f64;
        }
    }
    eprintln!("mean-free |M|: Laplace {sum_l:.0}, screened {sum_s:.0} (sums over free cells)");
    assert!(sum_s < 0.7 * sum_l);

    let bad = |o: DeformOptions| deform(&dem, cs, &o).unwrap_err();
    assert!(matches!(
        bad(DeformOptions {
            influence_m: Some(-1.0),
            ..DeformOptions::default()
        }),
        DeformError::BadOption(_)
    ));
    assert!(matches!(
        bad(DeformOptions {
            max_window_cells: 100,
            ..DeformOptions::default()
        }),
        DeformError::WindowTooLarge { .. }
    ));
    assert!(matches!(
        deform(&dem, &[], &DeformOptions::default()).unwrap_err(),
        DeformError::NoCurves
    ));
    let nan = CurveConstraint {
        points: vec![[f64::NAN, 0.0, 0.0]],
    };
    assert!(matches!(
        deform(&dem, &[nan], &DeformOptions::default()).unwrap_err(),
        DeformError::NonFinite { curve: 0, point: 0 }
    ));
}

#[test]
fn held_and_lowered_cells_never_widen_the_influence() {
    // Issue 11 item 4: the cells the edit holds (the observer's ground,
    // anchored stretches) or lowers act only within the curves' influence
    // distance; beyond it every cell stays exactly as it is, even where a
    // held or lowered cell lies in the deformation's window.
    let tmp = tempfile::tempdir().unwrap();
    let crop = float_crop_with_hole(tmp.path());
    let dem = Dem::open(&crop).unwrap();
    let curve = raised(&dem, &[[60.2, 70.4], [90.7, 85.1]], 50.0, 30);
    let influence = 900.0;
    let opts = DeformOptions {
        influence_m: Some(influence),
        ..DeformOptions::default()
    };
    let d0 = deform(&dem, std::slice::from_ref(&curve), &opts).unwrap();
    let w = d0.window;
    let h = dem.read_height_map(w).unwrap();
    let poly: Vec<[f64; 2]> = curve.points.iter().map(|p| [p[0], p[1]]).collect();
    let gt = dem.geotransform.0;
    let dist = |c: usize, r: usize| {
        distance_to_polyline(centre(&gt, w.col as usize + c, w.row as usize + r), &poly)
    };
    // In the window's corners (farther than the influence from the curve):
    // a block of held cells and a cell lowered by 30 m.
    let mut cells = Vec::new();
    for (c, r) in [(0, 0), (1, 0), (0, 1), (1, 1), (w.width - 1, w.height - 1)] {
        assert!(
            dist(c, r) > influence,
            "the corner lies within the influence"
        );
        let height = h.data[r * w.width + c] as f64 - if c > 1 { 30.0 } else { 0.0 };
        cells.push(CellConstraint {
            col: w.col + c as i64,
            row: w.row + r as i64,
            height,
        });
    }
    let d = deform_with_cells(&dem, std::slice::from_ref(&curve), &cells, &opts).unwrap();
    assert_eq!(d.window, w);
    for r in 0..w.height {
        for c in 0..w.width {
            let m = d.displacement[r * w.width + c];
            if dist(c, r) > influence + 1e-6 {
                assert!(
                    m == 0.0 || m.is_nan(),
                    "cell ({c}, {r}) beyond the influence moved {m}"
                );
            }
        }
    }
    // Within the influence the held cells change nothing here: the same
    // field as the curve alone.
    assert!(d
        .displacement
        .iter()
        .zip(&d0.displacement)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
}

#[test]
fn a_bounded_curve_beyond_the_influence_changes_nothing_there() {
    // Issue 11: the edit's feature completion carries a stroke's end on
    // for up to kilometres beyond what was drawn. Given as a bounded curve
    // (`deform_bounded`), it acts only within the influence distance of
    // the stroke's own curve: beyond it every cell stays exactly as it is,
    // while within it the completion still raises the terrain.
    let tmp = tempfile::tempdir().unwrap();
    let crop = float_crop_with_hole(tmp.path());
    let dem = Dem::open(&crop).unwrap();
    let stroke = raised(&dem, &[[60.2, 70.4], [90.7, 85.1]], 50.0, 30);
    // From the stroke's end on, 3 km, raised up to 300 m in its middle.
    let completion = raised(&dem, &[[90.7, 85.1], [116.0, 111.0]], 300.0, 60);
    let influence = 900.0;
    let opts = DeformOptions {
        influence_m: Some(influence),
        ..DeformOptions::default()
    };
    let own = std::slice::from_ref(&stroke);
    let bounded = std::slice::from_ref(&completion);
    let d = deform_bounded(&dem, own, bounded, &[], &opts).unwrap();
    let w = d.window;
    assert_eq!(
        w,
        plan(&dem, own, &opts).unwrap().window,
        "the stroke's window"
    );
    let poly: Vec<[f64; 2]> = stroke.points.iter().map(|p| [p[0], p[1]]).collect();
    let gt = dem.geotransform.0;
    let dist = |c: usize, r: usize| {
        distance_to_polyline(centre(&gt, w.col as usize + c, w.row as usize + r), &poly)
    };
    let mut moved_by_completion = 0;
    let alone = deform(&dem, own, &opts).unwrap();
    for r in 0..w.height {
        for c in 0..w.width {
            let k = r * w.width + c;
            let m = d.displacement[k];
            if dist(c, r) > influence + 1e-6 {
                assert!(
                    m == 0.0 || m.is_nan(),
                    "cell ({c}, {r}) beyond the influence moved {m}"
                );
            } else if (m - alone.displacement[k]).abs() > 1.0 {
                moved_by_completion += 1;
            }
        }
    }
    assert!(
        moved_by_completion > 20,
        "the completion acts within the influence ({moved_by_completion} cells)"
    );
    // Where the completion leaves the influence it is still far above the
    // terrain; it is let go before the edge, so the edge is no wall: no
    // step between neighbouring cells as high as the completion there.
    let step = |m: &[f32]| {
        let mut top = 0f32;
        for r in 0..w.height {
            for c in 0..w.width {
                let k = r * w.width + c;
                for j in [
                    (c + 1 < w.width).then(|| k + 1),
                    (r + 1 < w.height).then(|| k + w.width),
                ]
                .into_iter()
                .flatten()
                {
                    if !m[k].is_nan() && !m[j].is_nan() {
                        top = top.max((m[k] - m[j]).abs());
                    }
                }
            }
        }
        top
    };
    let cell_m = gt[1].abs().min(gt[5].abs());
    let top = step(&d.displacement) as f64;
    assert!(
        top <= cell_m,
        "a step of {top:.1} m between neighbours ({cell_m:.1} m cells)"
    );
    // As an ordinary curve the completion reaches far beyond the stroke;
    // cut off at the edge without letting it go, it would leave a wall.
    let both = [stroke.clone(), completion.clone()];
    let wide = deform(&dem, &both, &opts).unwrap();
    assert!(wide.stats.changed_cells > d.stats.changed_cells * 3 / 2);
    // With no bounded curve: exactly `deform_with_cells`.
    let none = deform_bounded(&dem, own, &[], &[], &opts).unwrap();
    assert!(none
        .displacement
        .iter()
        .zip(&alone.displacement)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
}
