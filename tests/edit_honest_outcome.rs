//! Honest outcomes of `demsketch edit` (issue 11, items 6 and 7): every
//! bad input gives exit 1 with one line naming the file and the problem and
//! writes nothing (no output, no report, no pictures, the input's bytes
//! unchanged); a fit below `--min-fit` gives exit 3, no DEM, but the report
//! (each stroke's status and reason) and the pictures; `--dry-run` writes
//! the report and pictures only and exits as a real run would;
//! `--allow-partial` writes anyway.

mod common;

use common::{demsketch, fixture, gdal_translate, gdal_values, snapshot};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

const DEM: &str = "zion_srtm_utm12n.tif";

fn bundled_sketch() -> Value {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion_dome.json");
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

/// A fresh directory with a copy of the fixture DEM (`in/`), where a
/// sketch, the output, the report and the pictures go.
struct Case {
    tmp: tempfile::TempDir,
    input: PathBuf,
}

impl Case {
    fn new() -> Case {
        Case::with_input(&fixture(DEM))
    }

    fn with_input(dem: &Path) -> Case {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("in");
        std::fs::create_dir(&dir).unwrap();
        let input = dir.join(dem.file_name().unwrap());
        std::fs::copy(dem, &input).unwrap();
        Case { tmp, input }
    }

    fn path(&self, name: &str) -> PathBuf {
        self.tmp.path().join(name)
    }

    /// `edit` with `sketch` (written into the case directory first), the
    /// output, report and pictures in the case directory, and `extra` flags.
    fn edit(&self, sketch: &Value, extra: &[&str]) -> std::process::Output {
        let sk = self.path("sketch.json");
        std::fs::write(&sk, serde_json::to_string(sketch).unwrap()).unwrap();
        let (out, rep, ren) = (
            self.path("out.tif"),
            self.path("report.json"),
            self.path("renders"),
        );
        let mut args = vec![
            "edit".to_string(),
            self.input.display().to_string(),
            "--sketch".into(),
            sk.display().to_string(),
            "--out".into(),
            out.display().to_string(),
            "--report".into(),
            rep.display().to_string(),
            "--renders".into(),
            ren.display().to_string(),
        ];
        args.extend(extra.iter().map(|s| s.to_string()));
        let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        demsketch(&args)
    }

    fn report(&self) -> Value {
        serde_json::from_slice(&std::fs::read(self.path("report.json")).unwrap()).unwrap()
    }
}

/// Exit 1, exactly one line on stderr, and nothing created or changed in
/// the case directory (the input's bytes included).
fn expect_refused(sketch: &Value, extra: &[&str], what: &str) -> String {
    let case = Case::new();
    expect_refused_in(&case, sketch, extra, what)
}

fn expect_refused_in(case: &Case, sketch: &Value, extra: &[&str], what: &str) -> String {
    // The sketch file is part of the snapshot: write it first.
    std::fs::write(
        case.path("sketch.json"),
        serde_json::to_string(sketch).unwrap(),
    )
    .unwrap();
    let before = snapshot(case.tmp.path());
    let r = case.edit(sketch, extra);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert_eq!(r.status.code(), Some(1), "{what}: exit code; stderr: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: one line: {err}");
    assert_eq!(snapshot(case.tmp.path()), before, "{what}: files changed");
    assert!(!case.path("out.tif").exists(), "{what}: output written");
    err
}

#[test]
fn eye_height_negative_or_absurd_is_refused() {
    for h in [-100.0, 0.0, 1e6] {
        let mut s = bundled_sketch();
        s["views"][0]["viewpoint"]["eye_height_m"] = json!(h);
        let e = expect_refused(&s, &[], &format!("eye_height_m {h}"));
        assert!(
            e.contains("sketch.json") && e.contains("eye_height_m"),
            "{e}"
        );
    }
}

#[test]
fn alt_below_the_ground_is_refused() {
    let mut s = bundled_sketch();
    let vp = &mut s["views"][0]["viewpoint"];
    vp.as_object_mut().unwrap().remove("eye_height_m");
    vp["alt_m"] = json!(100.0);
    let e = expect_refused(&s, &[], "alt_m below the ground");
    assert!(
        e.contains("sketch.json") && e.contains("alt_m") && e.contains("ground"),
        "{e}"
    );
}

#[test]
fn influence_absurd_is_refused() {
    for r in [1e7, -5.0, 0.0] {
        let mut s = bundled_sketch();
        s["options"]["influence_m"] = json!(r);
        let e = expect_refused(&s, &[], &format!("influence_m {r}"));
        assert!(
            e.contains("sketch.json") && e.contains("influence_m"),
            "{e}"
        );
    }
}

#[test]
fn unknown_option_key_is_refused() {
    let mut s = bundled_sketch();
    s["options"] = json!({"influnce_m": 1500.0});
    let e = expect_refused(&s, &[], "options typo");
    assert!(e.contains("sketch.json") && e.contains("influnce_m"), "{e}");
    // The keys DESIGN.md names are accepted (observer_radius_m).
    let mut ok = bundled_sketch();
    ok["options"]["observer_radius_m"] = json!(60.0);
    let case = Case::new();
    let r = case.edit(&ok, &["--dry-run", "--allow-partial"]);
    assert_eq!(
        r.status.code(),
        Some(0),
        "observer_radius_m: {}",
        String::from_utf8_lossy(&r.stderr)
    );
}

#[test]
fn sketch_without_strokes_is_refused() {
    let mut s = bundled_sketch();
    s["views"][0]["strokes"] = json!([]);
    let e = expect_refused(&s, &[], "no strokes");
    assert!(
        e.contains("sketch.json") && e.contains("no strokes") && e.contains("nothing to edit"),
        "{e}"
    );
}

#[test]
fn stroke_in_empty_sky_without_depth_is_refused() {
    let mut s = bundled_sketch();
    s["views"][0]["strokes"] = json!([
        {"id": "cloud", "points": [[500.0, 20.0], [600.0, 10.0], [700.0, 20.0]]}
    ]);
    let e = expect_refused(&s, &[], "stroke in empty sky");
    assert!(
        e.contains("sketch.json") && e.contains("cloud") && e.contains("depth_m"),
        "{e}"
    );
    // With its depth, it is not refused for want of terrain (whatever
    // becomes of its fit).
    s["views"][0]["strokes"][0]["depth_m"] = json!(2000.0);
    let case = Case::new();
    let r = case.edit(&s, &["--dry-run", "--allow-partial"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!err.contains("empty sky"), "with depth_m: {err}");
}

/// A stroke drawn above a skyline, as a person draws the top of a peak
/// that should stand higher, has terrain under it within the allowed rise
/// (its ends pass 3 % of the distance above the peak): it is placed and
/// fitted, not refused as drawn in empty sky (the old rule, 5 % of the
/// image height, refused it at 60 px on this 600 px view).
#[test]
fn stroke_drawn_above_a_skyline_is_placed() {
    let mut s = bundled_sketch();
    let mut peak = s["views"][0]["strokes"][1].clone();
    assert_eq!(peak["id"], json!("peak"));
    for p in peak["points"].as_array_mut().unwrap() {
        p[1] = json!(p[1].as_f64().unwrap() - 60.0);
    }
    s["views"][0]["strokes"] = json!([peak]);
    let case = Case::new();
    let r = case.edit(&s, &["--dry-run"]);
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{err}");
    let rep = case.report();
    let stroke = &rep["views"][0]["strokes"][0];
    assert_eq!(stroke["status"], json!("fitted"), "{stroke}");
}

#[test]
fn strokes_beyond_max_distance_are_refused() {
    let s = bundled_sketch();
    let e = expect_refused(&s, &["--max-distance", "1000"], "beyond --max-distance");
    assert!(
        e.contains("sketch.json") && e.contains("--max-distance"),
        "{e}"
    );
}

/// A height that lands on the nodata value is an error at write-back (it
/// would turn a valid cell into a hole): the input is the fixture with its
/// nodata value set to the height most cells of the edit land on.
#[test]
fn heights_landing_on_nodata_are_refused() {
    let case = Case::new();
    let r = case.edit(&bundled_sketch(), &[]);
    assert_eq!(
        r.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    let (_, _, a, _) = gdal_values(&case.input);
    let (_, _, b, _) = gdal_values(&case.path("out.tif"));
    let mut counts = std::collections::BTreeMap::new();
    for (x, y) in a.iter().zip(&b) {
        if x != y {
            *counts.entry(*y as i64).or_insert(0usize) += 1;
        }
    }
    let (&v, _) = counts
        .iter()
        .max_by_key(|(_, &n)| n)
        .expect("the edit changed cells");
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("zion_nodata.tif");
    gdal_translate(&case.input, &dem, &["-a_nodata", &v.to_string()]);
    let bad = Case::with_input(&dem);
    let e = expect_refused_in(&bad, &bundled_sketch(), &[], "height on nodata");
    assert!(e.contains("zion_nodata.tif") && e.contains("nodata"), "{e}");
    // A dry run finds it too.
    let e = expect_refused_in(&bad, &bundled_sketch(), &["--dry-run"], "dry run, nodata");
    assert!(e.contains("nodata"), "{e}");
}

#[test]
fn fit_below_min_fit_exits_3_with_report_and_pictures() {
    let case = Case::new();
    let input_bytes = std::fs::read(&case.input).unwrap();
    let r = case.edit(&bundled_sketch(), &["--min-fit", "1.01"]);
    let err = String::from_utf8_lossy(&r.stderr).to_string();
    assert_eq!(r.status.code(), Some(3), "exit code; stderr: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(
        err.contains("sketch.json") && err.contains("--min-fit") && err.contains("stroke"),
        "{err}"
    );
    assert!(!case.path("out.tif").exists(), "DEM written");
    assert_eq!(std::fs::read(&case.input).unwrap(), input_bytes);
    let rep = case.report();
    assert_eq!(rep["written"], json!(false));
    assert_eq!(rep["tiles_written"], json!([]));
    for s in rep["views"][0]["strokes"].as_array().unwrap() {
        let status = s["status"].as_str().unwrap();
        assert!(["partial", "unfitted"].contains(&status), "{status}");
        let reason = s["reason"].as_str().expect("reason");
        assert!(reason.contains("below --min-fit 1.01"), "{reason}");
    }
    for name in [
        "kolob-south_before.png",
        "kolob-south_after.png",
        "height_change.png",
    ] {
        assert!(case.path("renders").join(name).is_file(), "{name}");
    }
    // With --allow-partial the same edit is written, the strokes still
    // marked.
    let case = Case::new();
    let r = case.edit(&bundled_sketch(), &["--min-fit", "1.01", "--allow-partial"]);
    assert_eq!(
        r.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert!(case.path("out.tif").is_file());
    let rep = case.report();
    assert_eq!(rep["written"], json!(true));
    assert_eq!(rep["views"][0]["strokes"][0]["status"], json!("partial"));
}

#[test]
fn dry_run_writes_report_and_pictures_only() {
    let case = Case::new();
    let input_bytes = std::fs::read(&case.input).unwrap();
    let r = case.edit(&bundled_sketch(), &["--dry-run"]);
    assert_eq!(
        r.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&r.stderr)
    );
    assert!(!case.path("out.tif").exists(), "DEM written by a dry run");
    assert_eq!(std::fs::read(&case.input).unwrap(), input_bytes);
    let rep = case.report();
    assert_eq!(rep["written"], json!(false));
    assert_eq!(rep["dry_run"], json!(true));
    assert!(rep["changed_cells"].as_u64().unwrap() > 100);
    for s in rep["views"][0]["strokes"].as_array().unwrap() {
        assert_eq!(s["status"], json!("fitted"));
        assert!(s.get("reason").is_none());
    }
    assert!(case.path("renders").join("height_change.png").is_file());
    // A dry run says what a real run would do: exit 3 below --min-fit.
    let case = Case::new();
    let r = case.edit(&bundled_sketch(), &["--dry-run", "--min-fit", "1.01"]);
    assert_eq!(r.status.code(), Some(3));
    assert!(!case.path("out.tif").exists());
    assert!(case.path("report.json").is_file());
}

/// Heights the sample type cannot hold are an error at write-back, never
/// clamped: nothing is written (a Byte copy of the fixture, heights 0 to
/// 255, written 300 and -5; a UInt16 one written 70,000).
#[test]
fn heights_outside_the_sample_type_are_refused_at_write_back() {
    use demsketch::raster::{Dem, Destination, Provenance, Window};
    let tmp = tempfile::tempdir().unwrap();
    let byte = tmp.path().join("byte.tif");
    gdal_translate(
        &fixture(DEM),
        &byte,
        &[
            "-ot",
            "Byte",
            "-scale",
            "1000",
            "3000",
            "1",
            "254",
            "-a_nodata",
            "0",
        ],
    );
    let cases: [(&Path, f64, &str); 3] = [
        (&byte, 300.0, "Byte"),
        (&byte, -5.0, "Byte"),
        (&fixture(DEM), 70_000.0, "UInt16"),
    ];
    for (input, value, type_name) in cases {
        let dem = Dem::open(input).unwrap();
        let win = Window::new(100, 100, 8, 8);
        let old = dem.read_window::<f64>(win).unwrap();
        let mut new = old.data.clone();
        let k = (0..new.len())
            .find(|&i| old.valid[i])
            .expect("a valid cell");
        new[k] = value;
        let out = tmp.path().join("out.tif");
        let bytes = std::fs::read(input).unwrap();
        let e = dem
            .write_back(
                win,
                &new,
                &Destination::Path(out.clone()),
                &Provenance {
                    edit_id: "t".into(),
                },
            )
            .expect_err("out of range");
        let msg = e.to_string();
        assert!(
            msg.contains("outside the") && msg.contains(type_name) && !msg.contains('\n'),
            "{value}: {msg}"
        );
        assert!(!out.exists(), "{value}: output written");
        assert_eq!(
            std::fs::read(input).unwrap(),
            bytes,
            "{value}: input changed"
        );
        assert!(dem.check_write_back(win, &new).is_err());
        // A value in range is fine.
        new[k] = if type_name == "Byte" { 200.0 } else { 2000.0 };
        assert!(dem.check_write_back(win, &new).is_ok());
    }
}
