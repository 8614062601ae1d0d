//! Values from the user or a file that the commands used to take silently
//! or report in two lines, each refused now with exit code 1, one line on
//! stderr naming the flag or the file and the problem, no output created
//! and the inputs untouched:
//!
//! - `--max-distance` that is not a positive finite number of metres (the
//!   library reads such a distance as "no limit": `0` read the whole DEM,
//!   and a batch could not record a NaN or infinite one), and a
//!   `--refraction` that is not finite (every ray then missed the terrain:
//!   "drawn in empty sky"), for `view`, `locate`, `edit` and `batch`;
//! - a `--lon` outside [-180, 180] for `view` and `locate`, held to the
//!   range of a sketch file's viewpoint (PROJ printed its own
//!   `utm: Invalid longitude` line before the error), and an eye height
//!   outside a sketch's (0, 10,000] m or an altitude that is not finite
//!   (a NaN was reported as "not a valid WGS84 position");
//! - a lon/lat GeoJSON position of `correct` outside [-180, 180] x
//!   [-90, 90] (the same PROJ line), and one in a CRS the `crs` member
//!   names that PROJ cannot convert: the error names the position, and
//!   PROJ's own lines appear only with `--verbose`;
//! - a batch plan file whose settings `edit` would refuse as flags;
//! - `export gltf` of an area without data (nodata throughout), which
//!   wrote a `.glb` with empty accessors and `null` bounds that glTF
//!   does not allow;
//! - the rules of one library function each, in its one wording, for
//!   every command (and the library): `--min-fit` / `min_fit`
//!   (`demsketch::view::check_min_fit`), `export --min-dz`
//!   (`change_mask::check_min_dz`), `export gltf --bounds`
//!   (`gltf_mesh::parse_bounds`: lon/lat ranges too), `locate --pixel`
//!   (`Camera::check_pixel`) and `view --target-height`
//!   (`render::check_target_height`).

mod common;

use std::path::{Path, PathBuf};

use common::{demsketch, fixture};
use serde_json::Value;

const ZION: &str = "zion_srtm_utm12n.tif";

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn sketch() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion_dome.json")
}

/// Exit code 1, exactly one line on stderr, naming every `needles`.
fn one_line_error(out: &std::process::Output, args: &[&str], needles: &[&str]) {
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: exit 1: {err}");
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "{args:?}: one line: {err}"
    );
    for n in needles {
        assert!(err.contains(n), "{args:?}: names {n}: {err}");
    }
}

/// The bytes of the inputs a test must leave untouched.
fn snapshot(paths: &[PathBuf]) -> Vec<Vec<u8>> {
    paths
        .iter()
        .map(|p| std::fs::read(p).expect("input readable"))
        .collect()
}

fn entries(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn view_distance_and_refraction_flags_are_checked_before_any_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let (d, k) = (s(&dem), s(&sketch()));
    let inputs = [dem.clone(), sketch()];
    let before = snapshot(&inputs);
    let png = s(&dir.path().join("v.png"));
    let tif = s(&dir.path().join("o.tif"));
    let jobs = dir.path().join("jobs.txt");
    std::fs::write(&jobs, format!("{k}\n")).expect("write manifest");
    let jobs = s(&jobs);
    let bout = s(&dir.path().join("b.tif"));
    let plan = s(&dir.path().join("plan.json"));
    let view = |flag: &'static str| -> Vec<String> {
        let v = [
            "view", &d, "--lon", "-112.9", "--lat", "37.4", "--out", &png, flag,
        ];
        v.iter().map(|x| x.to_string()).collect()
    };
    let locate = |flag: &'static str| -> Vec<String> {
        let v = [
            "locate", &d, "--lon", "-112.9", "--lat", "37.4", "--pixel", "800,450", flag,
        ];
        v.iter().map(|x| x.to_string()).collect()
    };
    let edit = |flag: &'static str| -> Vec<String> {
        let v = ["edit", &d, "--sketch", &k, "--out", &tif, flag];
        v.iter().map(|x| x.to_string()).collect()
    };
    let batch = |flag: &'static str| -> Vec<String> {
        let v = ["batch", &d, "--jobs", &jobs, "--out", &bout, flag];
        v.iter().map(|x| x.to_string()).collect()
    };
    let batch_plan = |flag: &'static str| -> Vec<String> {
        let v = [
            "batch", "plan", &d, "--jobs", &jobs, "--out", &bout, "--plan", &plan, flag,
        ];
        v.iter().map(|x| x.to_string()).collect()
    };
    let mut cases: Vec<(Vec<String>, &str)> = Vec::new();
    for command in [
        &view as &dyn Fn(&'static str) -> Vec<String>,
        &locate,
        &edit,
        &batch,
        &batch_plan,
    ] {
        for flag in [
            "--max-distance=0",
            "--max-distance=-5",
            "--max-distance=nan",
            "--max-distance=inf",
        ] {
            cases.push((command(flag), "--max-distance"));
        }
        for flag in ["--refraction=nan", "--refraction=inf", "--refraction=-inf"] {
            cases.push((command(flag), "--refraction"));
        }
    }
    for (args, needle) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = demsketch(&args);
        one_line_error(&out, &args, &[needle]);
        assert!(out.stdout.is_empty(), "{args:?}: nothing on stdout");
    }
    assert_eq!(
        entries(dir.path()),
        vec!["jobs.txt".to_string()],
        "nothing written"
    );
    assert_eq!(snapshot(&inputs), before, "inputs untouched");
}

#[test]
fn a_viewpoint_off_the_globe_or_the_ground_is_one_line_without_proj_talking() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let before = snapshot(std::slice::from_ref(&dem));
    let d = s(&dem);
    let png = s(&dir.path().join("v.png"));
    for lon in ["1e15", "200", "nan"] {
        let lon_flag = format!("--lon={lon}");
        let cases: [Vec<&str>; 2] = [
            vec!["view", &d, &lon_flag, "--lat", "37.4", "--out", &png],
            vec![
                "locate", &d, &lon_flag, "--lat", "37.4", "--pixel", "800,450",
            ],
        ];
        for args in cases {
            let out = demsketch(&args);
            one_line_error(&out, &args, &["viewpoint lon", "[-180, 180]"]);
        }
    }
    let args = ["view", &d, "--lon", "-112.9", "--lat", "91", "--out", &png];
    one_line_error(&demsketch(&args), &args, &["viewpoint lat 91", "[-90, 90]"]);
    for (flag, needle) in [
        ("--eye-height=nan", "eye height NaN"),
        ("--eye-height=0", "eye height 0"),
        ("--eye-height=-3", "eye height -3"),
        ("--eye-height=20000", "eye height 20000"),
        ("--alt=nan", "altitude NaN"),
        ("--alt=inf", "altitude inf"),
    ] {
        let cases: [Vec<&str>; 2] = [
            vec![
                "view",
                &d,
                "--lon=-112.9",
                "--lat",
                "37.4",
                flag,
                "--out",
                &png,
            ],
            vec![
                "locate",
                &d,
                "--lon=-112.9",
                "--lat",
                "37.4",
                flag,
                "--pixel",
                "800,450",
            ],
        ];
        for args in cases {
            one_line_error(&demsketch(&args), &args, &[needle]);
        }
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
    assert_eq!(
        snapshot(std::slice::from_ref(&dem)),
        before,
        "DEM untouched"
    );
}

#[test]
fn a_geojson_position_off_the_globe_names_the_file_and_the_feature() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("vinschgau_250m_utm32n.tif");
    let features = dir.path().join("bad.geojson");
    for (i, lon) in [1e15, -1e300, 190.0].into_iter().enumerate() {
        let fc = serde_json::json!({
            "type": "FeatureCollection",
            "features": [{
                "type": "Feature",
                "properties": {"kind": "breakline", "id": "dyke"},
                "geometry": {"type": "LineString", "coordinates": [
                    [10.55, 46.70, 1500.0], [lon, 46.71, 1500.0]
                ]}
            }]
        });
        std::fs::write(&features, fc.to_string()).expect("write features");
        let inputs = [dem.clone(), features.clone()];
        let before = snapshot(&inputs);
        let out_tif = dir.path().join(format!("o{i}.tif"));
        let args = [
            "correct",
            &s(&dem),
            "--features",
            &s(&features),
            "--out",
            &s(&out_tif),
        ];
        let out = demsketch(&args);
        one_line_error(
            &out,
            &args,
            &[
                "bad.geojson",
                "\"dyke\"",
                "is not a longitude in [-180, 180]",
            ],
        );
        assert!(!out_tif.exists(), "nothing written");
        assert_eq!(snapshot(&inputs), before, "inputs untouched");
    }
    assert_eq!(entries(dir.path()), vec!["bad.geojson".to_string()]);
}

#[test]
fn a_plan_file_with_settings_edit_refuses_is_one_line_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let jobs = dir.path().join("jobs.txt");
    std::fs::write(&jobs, format!("{}\n", s(&sketch()))).expect("write manifest");
    let out = dir.path().join("b.tif");
    let plan = dir.path().join("plan.json");
    let made = demsketch(&[
        "batch",
        "plan",
        &s(&dem),
        "--jobs",
        &s(&jobs),
        "--out",
        &s(&out),
        "--plan",
        &s(&plan),
        "-q",
    ]);
    assert!(
        made.status.success(),
        "batch plan: {}",
        String::from_utf8_lossy(&made.stderr)
    );
    // (`batch plan` copies the DEM to OUT and keeps the plan beside it)
    let planned = entries(dir.path());
    let state = dir.path().join(".b.tif.demsketch_batch");
    let kept = entries(&state);
    let stored = state.join("plan.json");
    let good: Value = serde_json::from_slice(&std::fs::read(&plan).expect("plan")).expect("json");
    // (JSON has no NaN or infinity: any refraction a file holds is finite.)
    let cases: [(&str, Value, &str); 4] = [
        ("max_distance_m", Value::from(0.0), "max_distance_m 0"),
        (
            "max_distance_m",
            Value::from(-1000.0),
            "max_distance_m -1000",
        ),
        ("min_fit", Value::from(-0.5), "min_fit -0.5"),
        ("pyramid_resampling", Value::from("sharpest"), "sharpest"),
    ];
    for (key, value, needle) in cases {
        let mut bad = good.clone();
        bad["settings"][key] = value;
        std::fs::write(&plan, serde_json::to_string_pretty(&bad).expect("json"))
            .expect("write plan");
        let inputs = [dem.clone(), plan.clone(), out.clone(), stored.clone()];
        let before = snapshot(&inputs);
        for args in [
            vec!["batch", "run", "--plan", &s(&plan), "--index", "0"],
            vec!["batch", "finish", "--plan", &s(&plan)],
        ] {
            let o = demsketch(&args);
            one_line_error(&o, &args, &["plan.json", "settings", needle]);
        }
        assert_eq!(
            entries(dir.path()),
            planned,
            "nothing written beside the plan"
        );
        assert_eq!(
            entries(&state),
            kept,
            "nothing written into the batch's state"
        );
        assert_eq!(snapshot(&inputs), before, "DEM, plan and OUT untouched");
    }
}

#[test]
fn proj_speaks_only_with_verbose() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("vinschgau_250m_utm32n.tif");
    let features = dir.path().join("etrs.geojson");
    // ETRS89 (EPSG:4258) positions, a longitude PROJ refuses for UTM.
    let fc = serde_json::json!({
        "type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::4258"}},
        "features": [{
            "type": "Feature",
            "properties": {"kind": "breakline", "id": "dyke"},
            "geometry": {"type": "LineString", "coordinates": [
                [1e15, 46.70, 1500.0], [10.56, 46.71, 1500.0]
            ]}
        }]
    });
    std::fs::write(&features, fc.to_string()).expect("write features");
    let out_tif = dir.path().join("o.tif");
    let (d, f, o) = (s(&dem), s(&features), s(&out_tif));
    let args = ["correct", &d, "--features", &f, "--out", &o];
    let out = demsketch(&args);
    one_line_error(
        &out,
        &args,
        &["etrs.geojson", "\"dyke\"", "(1000000000000000, 46.7)"],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("Invalid longitude"), "PROJ quiet: {err}");
    let args = ["-v", "correct", &d, "--features", &f, "--out", &o];
    let out = demsketch(&args);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.lines().any(|l| l.starts_with("demsketch: PROJ: ")),
        "--verbose shows PROJ's lines: {err}"
    );
    assert!(!out_tif.exists(), "nothing written");
}

#[test]
fn the_library_refuses_the_same_edit_options() {
    use demsketch::edit::{EditError, EditOptions};
    use demsketch::raster::Destination;
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("o.tif");
    type Set = fn(&mut EditOptions);
    let cases: [(Set, &str); 6] = [
        (|o| o.max_distance_m = Some(0.0), "max_distance_m 0"),
        (|o| o.max_distance_m = Some(f64::NAN), "max_distance_m NaN"),
        (
            |o| o.max_distance_m = Some(f64::INFINITY),
            "max_distance_m inf",
        ),
        (|o| o.refraction = f64::NAN, "refraction NaN"),
        (|o| o.min_fit = -1.0, "min_fit -1"),
        (|o| o.min_fit = f64::NAN, "min_fit NaN"),
    ];
    for (set, needle) in cases {
        let mut o = EditOptions::new(Destination::Path(out.clone()));
        o.progress = false;
        set(&mut o);
        match demsketch::edit::run(&fixture(ZION), &sketch(), &o) {
            Err(e @ EditError::Options(_)) => {
                assert!(e.is_user_error(), "{e}");
                let m = e.to_string();
                assert!(m.contains(needle) && !m.contains('\n'), "{m}");
            }
            other => panic!("{needle}: {:?}", other.map(|_| ())),
        }
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
}

#[test]
fn a_mesh_of_an_area_without_data_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    // A part of the Zion fixture, every cell set to the nodata value 0.
    let dem = dir.path().join("nodata.tif");
    common::gdal_translate(
        &fixture(ZION),
        &dem,
        &[
            "-srcwin",
            "150",
            "50",
            "40",
            "30",
            "-scale",
            "0",
            "100000",
            "0",
            "0",
            "-a_nodata",
            "0",
        ],
    );
    let before = snapshot(std::slice::from_ref(&dem));
    let glb = dir.path().join("m.glb");
    let args = ["export", "gltf", &s(&dem), "--out", &s(&glb)];
    let out = demsketch(&args);
    one_line_error(
        &out,
        &args,
        &["nodata.tif", "no 2 x 2 block of cells with data"],
    );
    assert!(!glb.exists(), "nothing written");
    assert_eq!(entries(dir.path()), vec!["nodata.tif".to_string()]);
    assert_eq!(
        snapshot(std::slice::from_ref(&dem)),
        before,
        "DEM untouched"
    );
}

/// The zion_dome sketch with `from` replaced by `to`, written into `dir`.
fn sketch_with(dir: &Path, name: &str, from: &str, to: &str) -> PathBuf {
    let text = std::fs::read_to_string(sketch()).expect("read sketch");
    assert!(text.contains(from), "{from} in the sketch");
    let p = dir.join(name);
    std::fs::write(&p, text.replacen(from, to, 1)).expect("write sketch");
    p
}

/// An absolute eye at or below the ground at the viewpoint (the surface
/// the renderer draws there), which `edit` refuses, is refused by `view`
/// and `locate` too, in the edit's words, naming `--alt` or the sketch
/// view's `alt_m`; an altitude outside a sketch's [-11,000, 20,000] m is
/// refused before the DEM is read, printed compactly.
#[test]
fn an_eye_below_the_ground_is_refused_by_view_and_locate_as_by_edit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let work = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let below = sketch_with(
        work.path(),
        "below.json",
        "\"eye_height_m\": 1.7",
        "\"alt_m\": 10.0",
    );
    let inputs = [dem.clone(), below.clone()];
    let before = snapshot(&inputs);
    let (d, b) = (s(&dem), s(&below));
    let png = s(&dir.path().join("v.png"));
    let tif = s(&dir.path().join("o.tif"));
    let flags = ["--lon=-112.9", "--lat=37.4", "--alt=10"];
    let view: Vec<&str> = ["view", &d]
        .into_iter()
        .chain(flags)
        .chain(["--out", &png])
        .collect();
    let locate: Vec<&str> = ["locate", &d]
        .into_iter()
        .chain(flags)
        .chain(["--pixel", "800,450"])
        .collect();
    for args in [&view, &locate] {
        one_line_error(
            &demsketch(args),
            args,
            &[
                "viewpoint --alt 10 is not above the ground (",
                "m) at the viewpoint",
            ],
        );
    }
    let from_sketch = ["view", &d, "--sketch", &b, "--out", &png];
    let edit = ["edit", &d, "--sketch", &b, "--out", &tif];
    for args in [&from_sketch[..], &edit[..]] {
        one_line_error(
            &demsketch(args),
            args,
            &[
                "below.json",
                "view \"kolob-south\": viewpoint alt_m 10 is not above the ground (",
                "m) at the viewpoint",
            ],
        );
    }
    for (alt, needle) in [
        (
            "--alt=1e308",
            "viewpoint altitude 1e308 is not in [-11000, 20000] metres",
        ),
        ("--alt=-20000", "viewpoint altitude -20000 is not in"),
    ] {
        let args = ["view", &d, "--lon=-112.9", "--lat=37.4", alt, "--out", &png];
        one_line_error(&demsketch(&args), &args, &[needle]);
    }
    for (flag, needle) in [
        ("--lon=1e308", "viewpoint lon 1e308 is not in [-180, 180]"),
        ("--max-distance=-1e308", "--max-distance -1e308 must be"),
    ] {
        let args = [
            "locate",
            &d,
            "--lon=-112.9",
            "--lat=37.4",
            flag,
            "--pixel=8,8",
        ];
        let args: Vec<&str> = if flag.starts_with("--lon") {
            args.into_iter().filter(|a| *a != "--lon=-112.9").collect()
        } else {
            args.to_vec()
        };
        one_line_error(&demsketch(&args), &args, &[needle]);
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
    assert_eq!(snapshot(&inputs), before, "inputs untouched");
}

/// Every number of the sketch format is held to its documented range at
/// parse time; the message names the file, the view and the field's path
/// (`views[0].camera.heading_deg`), and prints an absurd value compactly.
#[test]
fn every_sketch_number_is_held_to_its_range() {
    use demsketch::sketch::SketchFile;
    let text = std::fs::read_to_string(sketch()).expect("read sketch");
    assert!(SketchFile::from_json_str(&text, "s.json").is_ok());
    let opt = "\"influence_m\": 1500.0";
    let dome = "\"id\": \"dome\",";
    let cases: [(&str, &str, &str); 23] = [
        (
            "\"heading_deg\": 200.0",
            "\"heading_deg\": 1e300",
            "views[0].camera.heading_deg 1e300 is not in [-360, 360] degrees",
        ),
        (
            "\"heading_deg\": 200.0",
            "\"heading_deg\": -361",
            "views[0].camera.heading_deg -361",
        ),
        (
            "\"pitch_deg\": -1.0",
            "\"pitch_deg\": 91",
            "views[0].camera.pitch_deg 91 is not in [-90, 90]",
        ),
        (
            "\"roll_deg\": 0.0",
            "\"roll_deg\": 1e12",
            "views[0].camera.roll_deg 1e12 is not in [-180, 180]",
        ),
        (
            "\"hfov_deg\": 35.0",
            "\"hfov_deg\": 180",
            "views[0].camera.hfov_deg 180 is not in (0, 180)",
        ),
        (
            "\"width\": 1200",
            "\"width\": 70000",
            "views[0].camera.width 70000 is not in [1, 65535]",
        ),
        (
            "\"height\": 600",
            "\"height\": 0",
            "views[0].camera.height 0 is not in [1, 65535]",
        ),
        (
            "\"eye_height_m\": 1.7",
            "\"eye_height_m\": 1e300",
            "views[0].viewpoint.eye_height_m 1e300 is not in (0, 10000]",
        ),
        (
            "\"eye_height_m\": 1.7",
            "\"alt_m\": 1e300",
            "views[0].viewpoint.alt_m 1e300 is not in [-11000, 20000] metres",
        ),
        (
            "\"lon\": -112.90",
            "\"lon\": 1e308",
            "views[0].viewpoint.lon 1e308 is not in [-180, 180]",
        ),
        (
            "\"lat\": 37.40",
            "\"lat\": -91",
            "views[0].viewpoint.lat -91",
        ),
        (
            "[930.0, 257.0]",
            "[1e300, 257.0]",
            "(1e300, 257) lies outside the 1200x600 image",
        ),
        (
            dome,
            "\"id\": \"dome\", \"depth_m\": 1e12,",
            "views[0].strokes[0].depth_m 1e12..1e12 is not a distance in (0, 1000000] metres",
        ),
        (
            dome,
            "\"id\": \"dome\", \"depth_m\": [3000, 2000],",
            "views[0].strokes[0].depth_m 3000..2000",
        ),
        (
            opt,
            "\"influence_m\": 1e300",
            "options.influence_m 1e300 is not in (0, 50000] metres",
        ),
        (
            opt,
            "\"observer_radius_m\": 1e300",
            "options.observer_radius_m 1e300",
        ),
        (
            opt,
            "\"weights\": {\"sampling\": 1e300}",
            "options.weights.sampling 1e300 is not in [0, 1000000]",
        ),
        (
            opt,
            "\"resample_px\": 1e-300",
            "options.resample_px 1e-300 is not in [0.1, 65535] pixels",
        ),
        (
            opt,
            "\"t_junction_px\": 1e300",
            "options.t_junction_px 1e300",
        ),
        (
            opt,
            "\"completion_step_m\": 1e-300",
            "options.completion_step_m 1e-300 is not in [0.1, 100000] metres",
        ),
        (
            opt,
            "\"fallback_depth_ratio\": 1e300",
            "options.fallback_depth_ratio 1e300 is not in (1, 100]",
        ),
        (
            opt,
            "\"max_candidates\": 1001",
            "options.max_candidates 1001 is not in [1, 1000]",
        ),
        (
            opt,
            "\"node_budget\": 1000000000000",
            "options.node_budget 1000000000000 is not in [1, 10000000]",
        ),
    ];
    for (from, to, needle) in cases {
        assert!(text.contains(from), "{from}");
        let bad = text.replacen(from, to, 1);
        let m = match SketchFile::from_json_str(&bad, "s.json") {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{to}: accepted"),
        };
        assert!(m.starts_with("s.json: "), "{m}");
        assert!(m.contains(needle), "{to}: names {needle}: {m}");
        assert!(m.len() < 250 && !m.contains('\n'), "{to}: compact: {m}");
    }
    for more in [
        "\"completion_max_m\": 1e300",
        "\"fold_back_tolerance_px\": -1",
        "\"min_coverage\": 0",
        "\"max_candidates\": 0",
        "\"node_budget\": 0",
        "\"max_candidates\": 1001",
        "\"node_budget\": 1000000000000",
    ] {
        let field = more.split('"').nth(1).expect("field");
        let bad = text.replacen(opt, more, 1);
        let m = SketchFile::from_json_str(&bad, "s.json")
            .expect_err(more)
            .to_string();
        assert!(m.contains(&format!("options.{field}")), "{m}");
    }
}

/// `edit` refuses an absurd sketch number in one line naming the field,
/// writing nothing (the number printed compactly, not in 301 digits).
#[test]
fn edit_names_the_field_of_an_absurd_sketch_number() {
    let dir = tempfile::tempdir().expect("tempdir");
    let work = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let bad = sketch_with(
        work.path(),
        "far.json",
        "\"heading_deg\": 200.0",
        "\"heading_deg\": 1e300",
    );
    let inputs = [dem.clone(), bad.clone()];
    let before = snapshot(&inputs);
    let tif = s(&dir.path().join("o.tif"));
    let (d, b) = (s(&dem), s(&bad));
    let args = ["edit", &d, "--sketch", &b, "--out", &tif];
    let out = demsketch(&args);
    one_line_error(
        &out,
        &args,
        &[
            "far.json",
            "views[0].camera.heading_deg 1e300 is not in [-360, 360]",
        ],
    );
    assert!(String::from_utf8_lossy(&out.stderr).len() < 300);
    assert!(entries(dir.path()).is_empty(), "nothing written");
    assert_eq!(snapshot(&inputs), before, "inputs untouched");
}

/// `view --sketch` holds the sketch's camera to the same ranges as `edit`
/// (it reads the sketch through the same parser): exit 1, one line naming
/// the file and the field's path, nothing written.
#[test]
fn view_holds_a_sketch_camera_to_the_edit_ranges() {
    let dir = tempfile::tempdir().expect("tempdir");
    let work = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let d = s(&dem);
    let png = s(&dir.path().join("v.png"));
    for (name, from, to, needle) in [
        (
            "heading.json",
            "\"heading_deg\": 200.0",
            "\"heading_deg\": 1e300",
            "views[0].camera.heading_deg 1e300 is not in [-360, 360] degrees",
        ),
        (
            "roll.json",
            "\"roll_deg\": 0.0",
            "\"roll_deg\": 1e12",
            "views[0].camera.roll_deg 1e12 is not in [-180, 180]",
        ),
        (
            "width.json",
            "\"width\": 1200",
            "\"width\": 70000",
            "views[0].camera.width 70000 is not in [1, 65535]",
        ),
    ] {
        let bad = sketch_with(work.path(), name, from, to);
        let before = snapshot(std::slice::from_ref(&bad));
        let b = s(&bad);
        let args = ["view", &d, "--sketch", &b, "--out", &png];
        one_line_error(&demsketch(&args), &args, &[name, needle]);
        assert_eq!(snapshot(&[bad]), before, "sketch untouched");
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
}

/// `view --sketch` reads the sketch as `edit` does (`SketchFile`): a
/// sketch `edit` refuses anywhere (another view's viewpoint, a stroke, the
/// options, a view without a camera) is refused by `view` in the same one
/// line, and the sketch `edit` reads is drawn.
#[test]
fn view_reads_the_sketch_as_edit_does() {
    use demsketch::sketch::SketchFile;
    let dir = tempfile::tempdir().expect("tempdir");
    let work = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let d = s(&dem);
    let png = dir.path().join("v.png");
    for (name, from, to) in [
        ("lon.json", "\"lon\": -112.90", "\"lon\": 1e308"),
        ("point.json", "[930.0, 257.0]", "[1e300, 257.0]"),
        (
            "options.json",
            "\"influence_m\": 1500.0",
            "\"resample_px\": 1e-300",
        ),
        ("camera.json", "\"camera\":", "\"lens\":"),
    ] {
        let bad = sketch_with(work.path(), name, from, to);
        let edit_says = SketchFile::from_path(&bad).expect_err(name).to_string();
        let b = s(&bad);
        let args = ["view", &d, "--sketch", &b, "--out", &s(&png)];
        let out = demsketch(&args);
        one_line_error(&out, &args, &[name]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains(&edit_says),
            "{name}: as edit: {edit_says}: {err}"
        );
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
    let k = s(&sketch());
    let args = ["view", &d, "--sketch", &k, "--out", &s(&png), "-q"];
    let out = demsketch(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(png.exists());
}

/// `--min-fit` is one rule (`demsketch::view::check_min_fit`) in one
/// wording for `edit`, `batch`, `batch plan` and `serve`, a plan file's
/// `min_fit` and the library's `EditOptions::min_fit`: a number >= 0
/// (above 1: never written, a documented use).
#[test]
fn min_fit_is_one_rule_in_one_wording() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let (d, k) = (s(&dem), s(&sketch()));
    let inputs = [dem.clone(), sketch()];
    let before = snapshot(&inputs);
    let jobs = dir.path().join("jobs.txt");
    std::fs::write(&jobs, format!("{k}\n")).expect("write manifest");
    let jobs = s(&jobs);
    let (tif, bout, plan) = (
        s(&dir.path().join("o.tif")),
        s(&dir.path().join("b.tif")),
        s(&dir.path().join("plan.json")),
    );
    for (flag, value) in [
        ("--min-fit=-1", "-1"),
        ("--min-fit=nan", "NaN"),
        ("--min-fit=-inf", "-inf"),
    ] {
        let wording = format!(
            "--min-fit {value} must be a number >= 0 (a share of a stroke's columns; above 1: never written)"
        );
        for args in [
            vec!["edit", &d, "--sketch", &k, "--out", &tif, flag],
            vec!["batch", &d, "--jobs", &jobs, "--out", &bout, flag],
            vec![
                "batch", "plan", &d, "--jobs", &jobs, "--out", &bout, "--plan", &plan, flag,
            ],
            vec!["serve", &d, "--port", "0", flag],
        ] {
            let out = demsketch(&args);
            one_line_error(&out, &args, &[&format!("demsketch: {wording}")]);
            assert!(out.stdout.is_empty(), "{args:?}: nothing on stdout");
        }
    }
    // `--min-fit -1` (a space, not `=`) is the flag's value too.
    let args = ["edit", &d, "--sketch", &k, "--out", &tif, "--min-fit", "-1"];
    one_line_error(
        &demsketch(&args),
        &args,
        &["--min-fit -1 must be a number >= 0"],
    );
    assert_eq!(
        entries(dir.path()),
        vec!["jobs.txt".to_string()],
        "nothing written"
    );
    assert_eq!(snapshot(&inputs), before, "inputs untouched");
    // The library's options, in the same words with the field's name.
    let mut o = demsketch::edit::EditOptions::new(demsketch::raster::Destination::Path(
        dir.path().join("o.tif"),
    ));
    o.progress = false;
    o.min_fit = -0.5;
    let e = demsketch::edit::run(&dem, &sketch(), &o).expect_err("min_fit -0.5 refused");
    assert_eq!(
        e.to_string(),
        "edit options: min_fit -0.5 must be a number >= 0 (a share of a stroke's columns; above 1: never written)"
    );
    assert_eq!(
        entries(dir.path()),
        vec!["jobs.txt".to_string()],
        "nothing written"
    );
}

/// `export tiles|geojson --min-dz` is the library's rule
/// (`change_mask::check_min_dz`, which `change_mask::read` and `from_dz`
/// apply), checked before anything is read.
#[test]
fn export_min_dz_is_the_library_rule() {
    use demsketch::export::{change_mask, ExportError};
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let d = s(&dem);
    let before = snapshot(std::slice::from_ref(&dem));
    // (a report that does not exist: the flag is refused before it is read)
    let report = s(&dir.path().join("missing-report.json"));
    let (tiles, gj) = (
        s(&dir.path().join("tiles")),
        s(&dir.path().join("e.geojson")),
    );
    for (flag, value) in [
        ("--min-dz=-1", "-1"),
        ("--min-dz=nan", "NaN"),
        ("--min-dz=inf", "inf"),
    ] {
        let wording = format!("--min-dz {value} must be a number of metres >= 0");
        for args in [
            vec![
                "export",
                "tiles",
                &d,
                "--encoding",
                "terrarium",
                "--zoom",
                "8",
                "--out",
                &tiles,
                flag,
            ],
            vec![
                "export",
                "tiles",
                &d,
                "--encoding",
                "terrarium",
                "--zoom",
                "8",
                "--out",
                &tiles,
                "--changed",
                &d,
                flag,
            ],
            vec![
                "export", "geojson", &d, "--report", &report, "--out", &gj, flag,
            ],
        ] {
            let out = demsketch(&args);
            one_line_error(&out, &args, &[&format!("demsketch: {wording}")]);
        }
    }
    let args = [
        "export", "geojson", &d, "--report", &report, "--out", &gj, "--min-dz", "-0.5",
    ];
    one_line_error(&demsketch(&args), &args, &["--min-dz -0.5 must be"]);
    assert!(entries(dir.path()).is_empty(), "nothing written");
    assert_eq!(
        snapshot(std::slice::from_ref(&dem)),
        before,
        "DEM untouched"
    );
    // The library checks it itself, before reading the raster.
    let missing = dir.path().join("missing-dz.tif");
    for f in [
        change_mask::from_dz(&missing, -1.0).map(|_| ()),
        change_mask::check_min_dz(f64::NAN).map_err(ExportError::from),
    ] {
        match f {
            Err(e @ ExportError::MinDz(_)) => {
                assert!(e.is_user_error());
                assert!(e.to_string().starts_with("--min-dz "), "{e}");
            }
            other => panic!("{other:?}"),
        }
    }
    assert!(change_mask::check_min_dz(0.0).is_ok() && change_mask::check_min_dz(2.5).is_ok());
}

/// `export gltf --bounds` is the library's rule
/// (`gltf_mesh::parse_bounds` / `check_bounds`, which `export_gltf`
/// applies): four numbers, west < east, south < north, longitudes in
/// [-180, 180], latitudes in [-90, 90] (degrees, as documented); one line
/// naming the flag, nothing written.
#[test]
fn export_bounds_are_the_library_rule_with_lon_lat_ranges() {
    use demsketch::export::{gltf_mesh, ExportError};
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let d = s(&dem);
    let before = snapshot(std::slice::from_ref(&dem));
    let glb = s(&dir.path().join("m.glb"));
    let range = "need west < east and south < north, longitudes in [-180, 180] and latitudes in [-90, 90] degrees";
    let cases: [(&str, String); 9] = [
        (
            "1,2,3",
            "--bounds '1,2,3' must be four numbers WEST,SOUTH,EAST,NORTH (degrees)".into(),
        ),
        (
            "1,2,3,4,5",
            "--bounds '1,2,3,4,5' must be four numbers".into(),
        ),
        ("a,2,3,4", "--bounds 'a,2,3,4' must be four numbers".into()),
        (
            "-113,37.2,-112.9,nan",
            format!("--bounds -113,37.2,-112.9,NaN: {range}"),
        ),
        (
            "-112.9,37.2,-113.1,37.4",
            format!("--bounds -112.9,37.2,-113.1,37.4: {range}"),
        ),
        (
            "-113.1,37.4,-112.9,37.2",
            format!("--bounds -113.1,37.4,-112.9,37.2: {range}"),
        ),
        (
            "-190,37.2,-112.9,37.4",
            format!("--bounds -190,37.2,-112.9,37.4: {range}"),
        ),
        ("170,0,190,1", format!("--bounds 170,0,190,1: {range}")),
        (
            "-113.1,-95,-112.9,37.4",
            format!("--bounds -113.1,-95,-112.9,37.4: {range}"),
        ),
    ];
    for (b, wording) in &cases {
        for args in [
            vec!["export", "gltf", &d, "--bounds", b, "--out", &glb],
            vec![
                "export",
                "gltf",
                &d,
                &format!("--bounds={b}"),
                "--out",
                &glb,
            ],
        ] {
            let out = demsketch(&args);
            one_line_error(&out, &args, &[&format!("demsketch: {wording}")]);
        }
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
    assert_eq!(
        snapshot(std::slice::from_ref(&dem)),
        before,
        "DEM untouched"
    );
    // The library: the whole globe is an area; export_gltf refuses a bad
    // one before it opens the DEM (a DEM that does not exist here).
    assert!(gltf_mesh::check_bounds([-180.0, -90.0, 180.0, 90.0]).is_ok());
    let opts = gltf_mesh::MeshOptions {
        bounds_lonlat: Some([10.0, 0.0, 5.0, 1.0]),
        step: 1,
        max_vertices: 1000,
    };
    match gltf_mesh::export_gltf(&dir.path().join("no.tif"), Path::new("m.glb"), &opts) {
        Err(e @ ExportError::Bounds(_)) => {
            assert!(e.is_user_error() && e.to_string().contains(range))
        }
        other => panic!("{:?}", other.map(|_| ())),
    }
}

/// `locate --pixel` outside the image is refused by the library's rule
/// (`Camera::check_pixel`, which `render::locate` applies too) before
/// the DEM is read; `view --target-height` that is not finite by the
/// viewshed's (`render::check_target_height`, which
/// `viewshed_from_file` applies too).
#[test]
fn locate_pixel_and_view_target_height_are_the_library_rules() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(ZION);
    let d = s(&dem);
    let before = snapshot(std::slice::from_ref(&dem));
    for (pixel, shown) in [
        ("1e300,5", "1e300,5"),
        ("-1,450", "-1,450"),
        ("800,900.5", "800,900.5"),
        ("nan,5", "NaN,5"),
    ] {
        let args = [
            "locate", &d, "--lon", "-112.9", "--lat", "37.4", "--size", "1600x900", "--pixel",
            pixel,
        ];
        let out = demsketch(&args);
        one_line_error(
            &out,
            &args,
            &[&format!(
                "demsketch: pixel {shown} lies outside the 1600x900 image"
            )],
        );
        assert!(out.stdout.is_empty(), "{args:?}: nothing on stdout");
    }
    let (png, vs) = (s(&dir.path().join("v.png")), s(&dir.path().join("vs.tif")));
    for (flag, value) in [
        ("--target-height=nan", "NaN"),
        ("--target-height=inf", "inf"),
        ("--target-height=-inf", "-inf"),
    ] {
        let args = [
            "view",
            &d,
            "--lon",
            "-112.9",
            "--lat",
            "37.4",
            "--out",
            &png,
            "--viewshed",
            &vs,
            flag,
        ];
        one_line_error(
            &demsketch(&args),
            &args,
            &[&format!(
                "demsketch: --target-height {value} must be a finite number of metres"
            )],
        );
    }
    assert!(entries(dir.path()).is_empty(), "nothing written");
    assert_eq!(
        snapshot(std::slice::from_ref(&dem)),
        before,
        "DEM untouched"
    );
    assert!(demsketch::render::check_target_height(-2.0).is_ok());
    assert!(demsketch::render::check_target_height(f64::NAN).is_err());
}
