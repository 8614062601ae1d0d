//! `DeformOptions::footprint_eye`: a curve that raises the terrain changes
//! the ground in front of it (nearer the eye) only over its landform's own
//! footprint (half its length, Gain et al. 2009, section 3.1), and reaches
//! the influence distance behind it; a lowering curve is unaffected. On a
//! 200 x 200 crop of the Zion UTM fixture (84 m cells).

mod deform_support;

use deform_support::*;
use demsketch::deform::{deform, footprint_reach, CurveConstraint, DeformOptions};
use demsketch::raster::Dem;

/// A straight curve between two pixel positions of `dem`, `bump` metres
/// above (below, when negative) the surface, sin^2 along it.
fn curve(dem: &Dem, a: [f64; 2], b: [f64; 2], bump: f64) -> CurveConstraint {
    let h = dem.read_height_map(dem.full_window()).unwrap();
    let n = 40;
    let pts = (0..=n)
        .map(|s| {
            let u = s as f64 / n as f64;
            let p = [a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1])];
            let z = demsketch::deform::constraints::bilinear_valid(&h, p[0], p[1]).unwrap();
            let (x, y) = dem.geotransform.pixel_to_crs(p[0], p[1]);
            [x, y, z + bump * (std::f64::consts::PI * u).sin().powi(2)]
        })
        .collect();
    CurveConstraint { points: pts }
}

#[test]
fn a_raised_curve_changes_its_front_over_its_footprint_and_its_back_to_the_influence() {
    let tmp = tempfile::tempdir().unwrap();
    let crop = tmp.path().join("crop.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &crop,
        &["-srcwin", "100", "150", "200", "200", "-ot", "Float32"],
    );
    let dem = Dem::open(&crop).unwrap();
    let gt = dem.geotransform.0;
    let cell = gt[1];
    // An east-west curve 20 cells long, 80 m high in its middle; the eye
    // 80 cells south of it (rows grow southwards).
    let raised = curve(&dem, [90.0, 100.0], [110.0, 100.0], 80.0);
    let (ex, ey) = dem.geotransform.pixel_to_crs(100.0, 180.0);
    let influence = 2500.0;
    let plain = DeformOptions {
        influence_m: Some(influence),
        ..DeformOptions::default()
    };
    let foot = DeformOptions {
        footprint_eye: Some([ex, ey]),
        ..plain.clone()
    };
    let one = std::slice::from_ref(&raised);
    let (a, b) = (
        deform(&dem, one, &plain).unwrap(),
        deform(&dem, one, &foot).unwrap(),
    );
    assert_eq!(a.window, b.window, "the window is the influence's");
    let cs = demsketch::deform::CellSize { hx: cell, hy: cell };
    let reach = footprint_reach(20.0 * cell, 80.0, cs, influence);
    assert!(
        (reach - 10.0 * cell).abs() < 1.0,
        "half the curve's length: {reach}"
    );
    let poly: Vec<[f64; 2]> = raised.points.iter().map(|p| [p[0], p[1]]).collect();
    let w = a.window;
    let (mut front_plain, mut back_far) = (0, 0);
    for r in 0..w.height {
        for c in 0..w.width {
            let k = r * w.width + c;
            let (row, col) = (w.row as usize + r, w.col as usize + c);
            let dist = distance_to_polyline(centre(&gt, col, row), &poly);
            let front = row > 100 && (90..110).contains(&col);
            if front && dist > reach {
                assert_eq!(
                    b.displacement[k], 0.0,
                    "cell ({col}, {row}) in front, {dist:.0} m from the curve, moved"
                );
                if a.displacement[k].abs() > 0.5 {
                    front_plain += 1;
                }
            }
            if row < 100 && (90..110).contains(&col) && dist > reach && b.displacement[k] > 0.5 {
                back_far += 1;
            }
            assert!(
                b.displacement[k].abs() <= a.displacement[k].abs() + 1e-3,
                "the footprint never adds change: ({col}, {row})"
            );
        }
    }
    assert!(
        front_plain > 20,
        "without it the front moves ({front_plain} cells)"
    );
    assert!(
        back_far > 20,
        "behind, the change still reaches past the footprint ({back_far} cells)"
    );
    // A lowering curve reaches the influence all round, as without the eye.
    let lowered = curve(&dem, [90.0, 100.0], [110.0, 100.0], -40.0);
    let one = std::slice::from_ref(&lowered);
    assert_eq!(
        deform(&dem, one, &plain).unwrap().displacement,
        deform(&dem, one, &foot).unwrap().displacement
    );
}

/// A 200 x 200 Float32 DEM of 50 m cells (UTM 12N), north up, whose height
/// is `f(col, row)`.
fn synthetic(path: &std::path::Path, f: impl Fn(f64, f64) -> f64) -> Dem {
    let (w, h) = (200usize, 200usize);
    let data: Vec<f32> = (0..w * h)
        .map(|i| f((i % w) as f64 + 0.5, (i / w) as f64 + 0.5) as f32)
        .collect();
    let gt = [500_000.0, 50.0, 0.0, 4_200_000.0, 0.0, -50.0];
    write_f32_geotiff(path, w, h, gt, 32612, &data, None);
    Dem::open(path).unwrap()
}

/// The footprint holds a raised curve's front only where the curve is a
/// summit of the terrain it is placed on (the ground behind it, along the
/// sight lines, stays below it): on an east-west ridge the front beyond
/// the footprint does not move; on a slope that goes on rising behind the
/// curve (a tangent: the landform's top lies behind its outline) the
/// change is the plain diffusion's, cell for cell.
#[test]
fn the_front_is_held_to_the_footprint_only_on_a_summit() {
    let tmp = tempfile::tempdir().unwrap();
    let ridge = synthetic(&tmp.path().join("ridge.tif"), |_, r| {
        1000.0 + 150.0 * (-((r - 100.0) * 50.0 / 400.0).powi(2) / 2.0).exp()
    });
    // rising northwards (rows decrease), away from an eye in the south
    let slope = synthetic(&tmp.path().join("slope.tif"), |_, r| {
        1000.0 + 0.3 * 50.0 * (200.0 - r)
    });
    let influence = 2500.0;
    let plain = DeformOptions {
        influence_m: Some(influence),
        ..DeformOptions::default()
    };
    for (dem, summit) in [(&ridge, true), (&slope, false)] {
        let raised = curve(dem, [90.0, 100.0], [110.0, 100.0], 80.0);
        let (ex, ey) = dem.geotransform.pixel_to_crs(100.0, 180.0);
        let foot = DeformOptions {
            footprint_eye: Some([ex, ey]),
            ..plain.clone()
        };
        let one = std::slice::from_ref(&raised);
        let (a, b) = (
            deform(dem, one, &plain).unwrap(),
            deform(dem, one, &foot).unwrap(),
        );
        if !summit {
            assert_eq!(
                a.displacement, b.displacement,
                "a tangent on rising ground keeps the diffusion"
            );
            continue;
        }
        let gt = dem.geotransform.0;
        let cs = demsketch::deform::CellSize { hx: 50.0, hy: 50.0 };
        let reach = footprint_reach(20.0 * 50.0, 80.0, cs, influence);
        let poly: Vec<[f64; 2]> = raised.points.iter().map(|p| [p[0], p[1]]).collect();
        let w = a.window;
        let mut front_plain = 0;
        for r in 0..w.height {
            for c in 0..w.width {
                let k = r * w.width + c;
                let (row, col) = (w.row as usize + r, w.col as usize + c);
                let dist = distance_to_polyline(centre(&gt, col, row), &poly);
                if row > 100 && (90..110).contains(&col) && dist > reach {
                    assert_eq!(b.displacement[k], 0.0, "({col}, {row}) in front moved");
                    front_plain += (a.displacement[k].abs() > 0.5) as usize;
                }
            }
        }
        assert!(
            front_plain > 20,
            "without it the front moves ({front_plain})"
        );
    }
}
