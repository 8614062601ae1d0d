//! `demsketch edit` end to end on a real fixture (Zion, SRTM in UTM 12N):
//! the bundled sketch gives a report with every DESIGN.md field, GDAL reads
//! the corrected GeoTIFF with the input's grid and nodata, nodata cells stay
//! nodata and cells away from the edit are untouched; strokes traced from
//! the DEM's own skyline are fitted and visible; failures (bad sketch,
//! viewpoint off the DEM, write error) exit 1 with one line and write
//! nothing.

mod common;

use common::{demsketch, fixture, gdal_values, gdalinfo, snapshot};
use demsketch::features::{extract_silhouettes, SilhouetteParams};
use demsketch::raster::{Dem, Destination};
use demsketch::render::{DepthBuffer, Scene};
use demsketch::view::{Camera, Viewpoint};
use serde_json::Value;
use std::path::Path;

const DEM: &str = "zion_srtm_utm12n.tif";

fn sketch_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion_dome.json")
}

fn assert_fraction(v: &Value, what: &str) -> f64 {
    let f = v
        .as_f64()
        .unwrap_or_else(|| panic!("{what} is not a number: {v}"));
    assert!((0.0..=1.0).contains(&f), "{what} = {f} outside [0, 1]");
    f
}

#[test]
fn bundled_sketch_edits_zion_with_full_report() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("corrected.tif");
    let report = tmp.path().join("report.json");
    let renders = tmp.path().join("renders");
    let dem = fixture(DEM);
    let sketch = sketch_path();
    let r = demsketch(&[
        "edit",
        dem.to_str().unwrap(),
        "--sketch",
        sketch.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
        "--renders",
        renders.to_str().unwrap(),
    ]);
    assert!(
        r.status.success(),
        "edit failed: {}",
        String::from_utf8_lossy(&r.stderr)
    );

    // Report: every field DESIGN.md names.
    let rep: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let views = rep["views"].as_array().expect("views[]");
    assert_eq!(views.len(), 1);
    let strokes = views[0]["strokes"].as_array().expect("strokes[]");
    assert_eq!(strokes.len(), 2);
    for s in strokes {
        let kind = s["match"]["kind"].as_str().expect("match.kind");
        assert!(
            ["silhouette", "ridge", "embedded"].contains(&kind),
            "match.kind {kind}"
        );
        let fitted = assert_fraction(&s["fit"]["fitted_fraction"], "fitted_fraction");
        let visible = assert_fraction(&s["visible_fraction"], "visible_fraction");
        let mean = s["fit"]["mean_px"].as_f64().expect("mean_px");
        let max = s["fit"]["max_px"].as_f64().expect("max_px");
        assert!(mean >= 0.0 && max >= mean, "mean {mean} max {max}");
        // The edited terrain follows the strokes: most columns within 1 px,
        // on average within 2 px, and the strokes are not hidden.
        assert!(fitted >= 0.6, "{}: fitted_fraction {fitted}", s["id"]);
        assert!(mean <= 2.0, "{}: mean_px {mean}", s["id"]);
        assert!(visible >= 0.8, "{}: visible_fraction {visible}", s["id"]);
    }
    assert!(views[0]["lowering_iterations"].as_u64().is_some());
    let tiles = rep["tiles_written"].as_array().expect("tiles_written[]");
    assert_eq!(tiles.len(), 1);
    let changed = rep["changed_cells"].as_u64().expect("changed_cells");
    assert!(changed > 100, "changed_cells {changed}");
    let maxd = rep["max_abs_displacement_m"].as_f64().unwrap();
    assert!(
        maxd > 20.0 && maxd < 1000.0,
        "max_abs_displacement_m {maxd}"
    );
    for stage in [
        "load",
        "features",
        "matching",
        "deformation",
        "lowering",
        "write",
    ] {
        let t = rep["timings_s"][stage]
            .as_f64()
            .unwrap_or_else(|| panic!("timings_s.{stage}"));
        assert!(t >= 0.0);
    }

    // Pictures.
    for name in [
        "kolob-south_before.png",
        "kolob-south_after.png",
        "height_change.png",
    ] {
        let bytes = std::fs::read(renders.join(name)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{name} is a PNG");
    }

    // GDAL reads the output: same grid, CRS and nodata; nodata preserved;
    // changes only where the report says, by at most its largest change.
    let a = gdalinfo(&dem);
    let b = gdalinfo(&out);
    assert_eq!(a["size"], b["size"]);
    assert_eq!(a["geoTransform"], b["geoTransform"]);
    assert_eq!(
        a["bands"][0]["noDataValue"], b["bands"][0]["noDataValue"],
        "nodata"
    );
    assert_eq!(a["bands"][0]["type"], b["bands"][0]["type"]);
    let (_, _, va, nd) = gdal_values(&dem);
    let (_, _, vb, _) = gdal_values(&out);
    let nd = nd.expect("the fixture has a nodata value");
    let mut n_changed = 0;
    for (x, y) in va.iter().zip(&vb) {
        assert_eq!(*x == nd, *y == nd, "nodata not preserved");
        if x != y {
            n_changed += 1;
            assert!((x - y).abs() <= maxd + 1.0);
        }
    }
    assert_eq!(n_changed as u64, changed);
}

/// Strokes traced from the DEM's own skyline and lifted a little: the edit
/// must leave them fully visible, on average within 1 px, and at least 95 %
/// of their columns within 1 px (issue 5's bar; the target-DEM cases of
/// `tests/edit_fit_cases.rs` check it together with the height error).
#[test]
fn strokes_traced_from_the_skyline_are_fitted_and_visible() {
    let dem_path = fixture(DEM);
    let dem = Dem::open(&dem_path).unwrap();
    let (lon, lat, heading) = (-112.90, 37.40, 200.0);
    let camera = Camera::new(1200, 600, heading, -1.0, 0.0, 35.0).unwrap();
    let scene = Scene::open(
        &dem,
        &Viewpoint::above_surface(lon, lat, 1.7),
        Some(50_000.0),
        1.0 / 7.0,
    )
    .unwrap();
    let depth = DepthBuffer::render(&scene.terrain, &camera);
    let sil = extract_silhouettes(&scene.terrain, &depth, &SilhouetteParams::default()).unwrap();
    // The longest skyline pieces, traced over their middle part and lifted
    // 6 px in the middle (a small, plausible change).
    let mut sky: Vec<_> = sil
        .curves
        .iter()
        .filter(|c| c.skyline && c.samples.len() > 80)
        .collect();
    sky.sort_by_key(|c| std::cmp::Reverse(c.samples.len()));
    assert!(!sky.is_empty(), "no skyline found");
    let mut strokes = Vec::new();
    for (k, c) in sky.iter().take(2).enumerate() {
        let n = c.samples.len();
        let (a, b) = (n / 4, 3 * n / 4);
        let pts: Vec<[f64; 2]> = c.samples[a..b]
            .iter()
            .step_by(4)
            .map(|s| {
                let t = (s.pixel[0] - c.samples[a].pixel[0])
                    / (c.samples[b - 1].pixel[0] - c.samples[a].pixel[0]).max(1.0);
                let lift = 6.0 * (std::f64::consts::PI * t).sin();
                [s.pixel[0], s.pixel[1] - lift]
            })
            .collect();
        strokes.push(serde_json::json!({"id": format!("sky{k}"), "points": pts}));
    }
    let sketch = serde_json::json!({
        "views": [{
            "name": "traced",
            "viewpoint": {"lon": lon, "lat": lat, "eye_height_m": 1.7},
            "camera": {"heading_deg": heading, "pitch_deg": -1.0, "roll_deg": 0.0,
                       "hfov_deg": 35.0, "width": 1200, "height": 600},
            "strokes": strokes
        }],
        "options": {"influence_m": 1500.0}
    });
    let tmp = tempfile::tempdir().unwrap();
    let sk = tmp.path().join("traced.json");
    std::fs::write(&sk, serde_json::to_string(&sketch).unwrap()).unwrap();
    let mut opts = demsketch::edit::EditOptions::new(Destination::Path(tmp.path().join("o.tif")));
    // A caller's stage bar (the browser app's) follows the edit's stages.
    let stage = indicatif::ProgressBar::hidden();
    opts.stage = Some(stage.clone());
    let rep = demsketch::edit::run(&dem_path, &sk, &opts).unwrap();
    assert_eq!(stage.message(), "writing corrected tiles");
    const FITTED_MIN: f64 = 0.95;
    for s in &rep.views[0].strokes {
        eprintln!(
            "{}: {:?}, fitted {:.3}, mean {:.2} px, max {:.2} px, visible {:.3}",
            s.id,
            s.matched.kind,
            s.fit.fitted_fraction,
            s.fit.mean_px,
            s.fit.max_px,
            s.visible_fraction
        );
        assert!(s.fit.mean_px <= 1.0, "{}: mean_px {}", s.id, s.fit.mean_px);
        assert!(
            s.fit.fitted_fraction >= FITTED_MIN,
            "{}: fitted_fraction {} (mean {} px, max {} px)",
            s.id,
            s.fit.fitted_fraction,
            s.fit.mean_px,
            s.fit.max_px
        );
        assert_eq!(s.visible_fraction, 1.0, "{}: visible_fraction", s.id);
    }
}

/// Copy the fixture into a fresh directory (the input of failure tests).
fn staged_input(tmp: &Path) -> std::path::PathBuf {
    let dir = tmp.join("in");
    std::fs::create_dir(&dir).unwrap();
    let p = dir.join(DEM);
    std::fs::copy(fixture(DEM), &p).unwrap();
    p
}

/// Run `edit` expecting a user error: exit 1, one line on stderr, and no
/// file created or changed anywhere under `tmp`.
fn expect_clean_failure(tmp: &Path, args: &[&str], what: &str) -> String {
    let before = snapshot(tmp);
    let r = demsketch(args);
    assert_eq!(r.status.code(), Some(1), "{what}: exit code");
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: one line: {err}");
    assert_eq!(snapshot(tmp), before, "{what}: files changed");
    err
}

#[test]
fn failures_write_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let input = staged_input(tmp.path());
    let good: Value = serde_json::from_slice(&std::fs::read(sketch_path()).unwrap()).unwrap();
    let out = tmp.path().join("out.tif");
    let report = tmp.path().join("report.json");
    let renders = tmp.path().join("renders");
    let run_with = |sketch: &Value, out: &Path, what: &str| -> String {
        let sk = tmp.path().join("sketch.json");
        std::fs::write(&sk, serde_json::to_string(sketch).unwrap()).unwrap();
        let e = expect_clean_failure(
            tmp.path(),
            &[
                "edit",
                input.to_str().unwrap(),
                "--sketch",
                sk.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
                "--report",
                report.to_str().unwrap(),
                "--renders",
                renders.to_str().unwrap(),
            ],
            what,
        );
        std::fs::remove_file(&sk).unwrap();
        e
    };

    // Bad sketch: a point outside the image.
    let mut bad = good.clone();
    bad["views"][0]["strokes"][0]["points"][0] = serde_json::json!([5000.0, 10.0]);
    let e = run_with(&bad, &out, "bad sketch");
    assert!(e.contains("sketch.json") && e.contains("dome"), "{e}");

    // Viewpoint off the DEM.
    let mut off = good.clone();
    off["views"][0]["viewpoint"]["lon"] = serde_json::json!(-100.0);
    let e = run_with(&off, &out, "viewpoint off the DEM");
    assert!(e.contains("outside"), "{e}");

    // Write error found before any work: the output's directory does not exist.
    let missing = tmp.path().join("no/such/dir/out.tif");
    let e = run_with(&good, &missing, "missing output directory");
    assert!(e.contains("out.tif"), "{e}");

    // Write error found at write time, after the whole edit was computed and
    // the report and pictures staged: the output is a directory. The staged
    // files must be gone.
    let dir_out = tmp.path().join("taken.tif");
    std::fs::create_dir(&dir_out).unwrap();
    let e = run_with(&good, &dir_out, "output is a directory");
    assert!(e.contains("taken.tif"), "{e}");

    // In place with a bad sketch leaves the input unchanged (covered by the
    // snapshot of the whole directory).
    let sk = tmp.path().join("bad.json");
    std::fs::write(&sk, "{ not json").unwrap();
    let e = expect_clean_failure(
        tmp.path(),
        &[
            "edit",
            input.to_str().unwrap(),
            "--sketch",
            sk.to_str().unwrap(),
            "--in-place",
        ],
        "in place, unreadable sketch",
    );
    assert!(e.contains("bad.json"), "{e}");
}

/// Ten strokes, each a long silhouette of a 1200 x 600 view raised by a
/// 6 px bump (the sketch `tools/bench_serve.py` builds, kept in
/// `fixtures/sketches/zion512_bumps.json`), on the Zion fixture resampled
/// to 512 x 512 by `gdalwarp` as that benchmark does. It once placed a
/// stroke drawn far under a 23 km skyline at the skyline's depth, 2 km
/// under the ground, and the edit failed on the UInt16 range. Now it
/// succeeds and no cell moves by more than the 6 px bumps ask (at most
/// some 100 m on the farthest silhouettes).
#[test]
fn many_bumped_silhouettes_on_a_resampled_dem_stay_in_range() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("zion512.tif");
    let st = std::process::Command::new("gdalwarp")
        .args(["-q", "-overwrite", "-ts", "512", "512", "-r", "cubicspline"])
        .args(["-co", "TILED=YES", "-co", "COMPRESS=DEFLATE"])
        .arg(fixture(DEM))
        .arg(&dem)
        .status()
        .expect("gdalwarp runs");
    assert!(st.success(), "gdalwarp");
    let sketch = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion512_bumps.json");
    let out = tmp.path().join("out.tif");
    let r = demsketch(&[
        "edit",
        dem.to_str().unwrap(),
        "--sketch",
        sketch.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--allow-partial",
    ]);
    assert_eq!(
        r.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let info = gdalinfo(&out);
    assert_eq!(info["bands"][0]["type"], "UInt16", "{info}");
    let (_, _, before, _) = gdal_values(&dem);
    let (_, _, after, _) = gdal_values(&out);
    let max = before
        .iter()
        .zip(&after)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f64, f64::max);
    assert!(max < 150.0, "max |dz| {max} m");
}
