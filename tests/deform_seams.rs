//! Seam consistency: a 200 x 200 crop of the Zion UTM fixture (Float32,
//! tiled DEFLATE) and the same crop split into 4 x 4 tiles of 50 x 50 with
//! `gdal_translate -srcwin` are edited with curves that cross tile corners.
//! The edits are written through `Dem::write_back` and read back with GDAL:
//! the tiled result equals the single-file result within 1e-3 m everywhere,
//! and the change across every seam row and column looks like the change
//! across interior rows and columns (no step).

mod deform_support;

use deform_support::*;
use demsketch::deform::{deform, CurveConstraint, DeformOptions};
use demsketch::raster::{Dem, Destination, Provenance};

const SIZE: usize = 200;
const TILE: usize = 50;

/// Curves in pixel coordinates of the crop with a displacement profile:
/// a raised ridge through the tile corners (50, 50) and (100, 100), and a
/// cut through the corner (150, 50).
fn curves(dem: &Dem) -> Vec<CurveConstraint> {
    let h = dem.read_height_map(dem.full_window()).unwrap();
    let gt = dem.geotransform;
    let path = |pts: &[[f64; 2]], bump: f64, samples: usize| -> CurveConstraint {
        // Resample the polyline densely so the bump is smooth along it.
        let lens: Vec<f64> = pts
            .windows(2)
            .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
            .collect();
        let total: f64 = lens.iter().sum();
        let mut out = Vec::new();
        for s in 0..=samples {
            let mut a = s as f64 / samples as f64 * total;
            let mut k = 0;
            while k + 1 < lens.len() && a > lens[k] {
                a -= lens[k];
                k += 1;
            }
            let t = (a / lens[k]).min(1.0);
            let px = pts[k][0] + t * (pts[k + 1][0] - pts[k][0]);
            let py = pts[k][1] + t * (pts[k + 1][1] - pts[k][1]);
            let u = s as f64 / samples as f64;
            let z = h.bilinear(px, py).unwrap() + bump * (std::f64::consts::PI * u).sin().powi(2);
            let (x, y) = gt.pixel_to_crs(px, py);
            out.push([x, y, z]);
        }
        CurveConstraint { points: out }
    };
    vec![
        path(
            &[[20.3, 30.2], [50.0, 50.0], [100.0, 100.0], [160.4, 120.7]],
            120.0,
            90,
        ),
        path(&[[122.2, 18.9], [150.0, 50.0], [181.3, 83.6]], -60.0, 40),
    ]
}

#[test]
fn tiled_edit_equals_single_file_edit() {
    let tmp = tempfile::tempdir().unwrap();
    let single = tmp.path().join("single.tif");
    let tiles = tmp.path().join("tiles");
    let co = [
        "-co",
        "TILED=YES",
        "-co",
        "BLOCKXSIZE=16",
        "-co",
        "BLOCKYSIZE=16",
        "-co",
        "COMPRESS=DEFLATE",
        "-co",
        "PREDICTOR=3",
    ];
    let mut args = vec!["-srcwin", "100", "150", "200", "200", "-ot", "Float32"];
    args.extend_from_slice(&co);
    gdal_translate(&fixture("zion_srtm_utm12n.tif"), &single, &args);
    split_tiles(&single, &tiles, SIZE / TILE, TILE, &co);

    let one = Dem::open(&single).unwrap();
    let many = Dem::open(&tiles).unwrap();
    assert_eq!(many.tiles.len(), 16);
    assert_eq!((many.width, many.height), (SIZE, SIZE));
    let cs = curves(&one);
    let opts = DeformOptions::default();
    let d1 = deform(&one, &cs, &opts).unwrap();
    let d2 = deform(&many, &cs, &opts).unwrap();
    assert_eq!(d1.window, d2.window);
    let max_m_diff = d1
        .displacement
        .iter()
        .zip(&d2.displacement)
        .map(|(a, b)| {
            if a.is_nan() || b.is_nan() {
                assert!(a.is_nan() && b.is_nan());
                0.0
            } else {
                (a - b).abs() as f64
            }
        })
        .fold(0.0, f64::max);
    eprintln!(
        "window {:?}, tiles {:?}, constrained {}, free {}, max |M| {:.1} m, cycles {}, residual {:.1e}; \
         max |M_single - M_tiled| = {max_m_diff:.2e} m",
        d1.window,
        d2.affected_tiles,
        d1.stats.constrained_cells,
        d1.stats.free_cells,
        d1.stats.max_abs_displacement_m,
        d1.stats.cycles,
        d1.stats.relative_residual
    );
    assert!(max_m_diff <= 1e-3);
    assert!(d1.stats.max_abs_displacement_m > 50.0);

    // Write both through the tile layer and read them back with GDAL.
    let prov = Provenance {
        edit_id: "seams-test".into(),
    };
    let out_one = tmp.path().join("out_single.tif");
    let out_many = tmp.path().join("out_tiles");
    one.write_back(
        d1.window,
        &d1.write_values(),
        &Destination::Path(out_one.clone()),
        &prov,
    )
    .unwrap();
    let rep = many
        .write_back(
            d2.window,
            &d2.write_values(),
            &Destination::Path(out_many.clone()),
            &prov,
        )
        .unwrap();
    assert!(rep.tiles_written.len() >= 4);
    let input = gdal_read(&single);
    let a = gdal_read(&out_one);
    let b = gdal_read_mosaic(&out_many);
    assert_eq!((b.width, b.height), (SIZE, SIZE));
    assert_eq!(a.gt, b.gt);
    let mut max_diff: f64 = 0.0;
    for (x, y) in a.data.iter().zip(&b.data) {
        assert_eq!(a.is_nodata(*x), b.is_nodata(*y));
        if !a.is_nodata(*x) {
            max_diff = max_diff.max((x - y).abs());
        }
    }
    // Displacement written, as GDAL reads it.
    let m_of =
        |g: &Grid| -> Vec<f64> { g.data.iter().zip(&input.data).map(|(e, h)| e - h).collect() };
    let (ma, mb) = (m_of(&a), m_of(&b));
    let max_written = ma.iter().map(|v| v.abs()).fold(0.0, f64::max);

    // Steps: second difference across each pair of columns (rows), i.e. the
    // change across a seam against the mean of the changes beside it.
    // Positions next to constrained cells (where M has a kink by design) are
    // left out of both sets.
    let near_constraint = |c: usize, r: usize| -> bool {
        let (wc, wr) = (d1.window.col as usize, d1.window.row as usize);
        (r.saturating_sub(2)..(r + 3).min(SIZE)).any(|rr| {
            (c.saturating_sub(2)..(c + 3).min(SIZE)).any(|cc| {
                cc >= wc
                    && rr >= wr
                    && cc - wc < d1.window.width
                    && rr - wr < d1.window.height
                    && d1.constrained[(rr - wr) * d1.window.width + cc - wc]
            })
        })
    };
    let at = |m: &[f64], c: usize, r: usize| m[r * SIZE + c];
    let mut seam_step: f64 = 0.0;
    let mut interior_step: f64 = 0.0;
    let mut seam_vs_single: f64 = 0.0;
    for k in 2..SIZE - 1 {
        let is_seam = k % TILE == 0;
        for j in 0..SIZE {
            for (m_t, horizontal) in [(&mb, true), (&mb, false)] {
                let (c, r) = if horizontal { (k, j) } else { (j, k) };
                if near_constraint(c, r) {
                    continue;
                }
                let get = |o: isize| {
                    if horizontal {
                        at(m_t, (c as isize + o) as usize, r)
                    } else {
                        at(m_t, c, (r as isize + o) as usize)
                    }
                };
                let jump = get(0) - get(-1);
                let step = (jump - 0.5 * ((get(-1) - get(-2)) + (get(1) - get(0)))).abs();
                if is_seam {
                    seam_step = seam_step.max(step);
                    let single_jump = if horizontal {
                        at(&ma, c, r) - at(&ma, c - 1, r)
                    } else {
                        at(&ma, c, r) - at(&ma, c, r - 1)
                    };
                    seam_vs_single = seam_vs_single.max((jump - single_jump).abs());
                } else {
                    interior_step = interior_step.max(step);
                }
            }
        }
    }
    eprintln!(
        "written: max |single - tiled| = {max_diff:.2e} m, max |M| = {max_written:.1} m; \
         step across seams {seam_step:.3} m vs interior {interior_step:.3} m; \
         seam jumps vs single file {seam_vs_single:.2e} m"
    );
    assert!(
        max_diff <= 1e-3,
        "tiled and single edits differ by {max_diff} m"
    );
    assert!(max_written > 50.0);
    assert!(seam_vs_single <= 2e-3);
    assert!(
        seam_step <= interior_step + 1e-3,
        "step across a seam ({seam_step} m) exceeds every interior step ({interior_step} m)"
    );
}
