//! Landforms from silhouettes and noise regions (issue 14 item 5, Gain et
//! al. 2009 sections 3 and 4), through `demsketch correct --features F
//! --sketch S`, on a synthetic DEM written here with GDAL: a plain at 500 m
//! (gentle +-2 m waves) in UTM 32N with 10 m cells, 5 x 5 km, and a 200 m
//! cone the viewpoint stands on, 300 m from the southern edge, looking
//! north over the plain. A stroke drawn from the plain about 2 km away up
//! above the horizon and down again is placed on the vertical surface
//! through its end points' terrain points; the landform built from it is
//! rendered by the independent judge (`tools/fidelity/landform_fit.py`,
//! `judge.fit`) from the same view and must be fitted at >= 0.95. A
//! jagged stroke gives measurably rougher terrain than a smooth one (the
//! wavelet energy ratio of the report and the terrain's own detail read
//! back with GDAL). The default boundary given back as the feature's
//! Polygon (from the report, edited in map view) gives the same terrain; a
//! noise region roughens its polygon only; bad references fail with one
//! line naming the feature and write nothing; a 4 x 4 tile set gives the
//! single-file result within 1e-3 m; a stroke ending half a pixel above
//! a crest stands on it.

mod common;
mod correct_support;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{demsketch, snapshot};
use correct_support::{
    collection, report, split, to_lonlat, vrt_of_tiles, write_f32_geotiff, Raster,
};
use serde_json::{json, Value};

const N: usize = 500;
const CELL: f64 = 10.0;
const X0: f64 = 600_000.0;
const Y0: f64 = 5_105_000.0;
/// The viewpoint, metres east and south of the north-west corner.
const VIEW: [f64; 2] = [2500.0, 4700.0];

fn write_plain(path: &Path) {
    let mut data = vec![0f32; N * N];
    for r in 0..N {
        for c in 0..N {
            let (x, y) = ((c as f64 + 0.5) * CELL, (r as f64 + 0.5) * CELL);
            let cone = 200.0 * (1.0 - (x - VIEW[0]).hypot(y - VIEW[1]) / 400.0).max(0.0);
            data[r * N + c] =
                (500.0 + 2.0 * (x / 700.0).sin() + 2.0 * (y / 900.0).cos() + cone) as f32;
        }
    }
    write_f32_geotiff(path, N, N, [X0, CELL, 0.0, Y0, 0.0, -CELL], 32632, &data);
}

/// A silhouette from image column 220 to 420, on the plain (row 236, about
/// 2 km away) at both ends, peaking at row 150; `jag` px of square-wave
/// detail (period 12 px) on the way.
fn stroke(jag: f64) -> Vec<[f64; 2]> {
    (0..=100)
        .map(|k| {
            let x = 220.0 + 2.0 * k as f64;
            let t = (x - 320.0) / 100.0;
            let d = if k == 0 || k == 100 {
                0.0
            } else if (k / 3) % 2 == 1 {
                jag
            } else {
                -jag
            };
            [x, 236.0 - 86.0 * (1.0 - t * t) + d]
        })
        .collect()
}

fn sketch() -> Value {
    let ll = to_lonlat(32632, &[[X0 + VIEW[0], Y0 - VIEW[1]]])[0];
    json!({"views": [{"name": "hill",
    "viewpoint": {"lon": ll[0], "lat": ll[1], "eye_height_m": 1.7},
    "camera": {"heading_deg": 0.0, "hfov_deg": 60.0, "width": 640, "height": 360},
    "strokes": [
        {"id": "smooth", "points": stroke(0.0)},
        {"id": "jagged", "points": stroke(4.0)},
        {"id": "noise", "points": stroke(4.0)}
    ]}]})
}

fn landform(name: &str, stroke_id: &str, geometry: Value) -> Value {
    json!({"type": "Feature",
        "properties": {"kind": "landform", "name": name,
            "silhouette": {"view": "hill", "stroke": stroke_id}},
        "geometry": geometry})
}

/// A directory with the plain, the sketch and `features`.
struct Case {
    dir: tempfile::TempDir,
}

impl Case {
    fn new() -> Case {
        let dir = tempfile::tempdir().unwrap();
        write_plain(&dir.path().join("plain.tif"));
        std::fs::write(
            dir.path().join("sketch.json"),
            serde_json::to_string_pretty(&sketch()).unwrap(),
        )
        .unwrap();
        Case { dir }
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    /// Runs `correct` on `dem` with `features`; returns the output.
    fn correct(&self, dem: &Path, name: &str, features: Vec<Value>) -> std::process::Output {
        let f = self.path(&format!("{name}.geojson"));
        std::fs::write(&f, collection(features, Some(32632))).unwrap();
        demsketch(&[
            "correct",
            &dem.to_string_lossy(),
            "--features",
            &f.to_string_lossy(),
            "--sketch",
            &self.path("sketch.json").to_string_lossy(),
            "--out",
            &self.path(&format!("{name}.tif")).to_string_lossy(),
            "--report",
            &self.path(&format!("{name}.json")).to_string_lossy(),
        ])
    }

    /// As [`Case::correct`] on the plain, asserting success; the report.
    fn ok(&self, name: &str, features: Vec<Value>) -> Value {
        let o = self.correct(&self.path("plain.tif"), name, features);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        report(&self.path(&format!("{name}.json")))
    }

    /// The judge's fit of `stroke` on the output `name`.
    fn judge(&self, name: &str, stroke: &str) -> Value {
        self.judge_on("plain.tif", name, stroke)
    }

    /// The judge's fit of `stroke` on the output `name` of the DEM `input`.
    fn judge_on(&self, input: &str, name: &str, stroke: &str) -> Value {
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/fidelity/landform_fit.py");
        let o = Command::new("/usr/bin/python3")
            .arg(script)
            .arg(self.path(input))
            .arg(self.path(&format!("{name}.tif")))
            .arg(self.path("sketch.json"))
            .args(["hill", stroke])
            .output()
            .expect("run the judge");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).expect("the judge prints JSON")
    }
}

/// Root mean square of the terrain's own detail (height minus its 3 x 3
/// mean) over the cells `name` changed, read back with GDAL.
fn detail_rms(input: &Raster, out: &Raster) -> f64 {
    let (mut s2, mut n) = (0.0, 0usize);
    for r in 1..out.h - 1 {
        for c in 1..out.w - 1 {
            if out.at(c, r) == input.at(c, r) {
                continue;
            }
            let mut m = 0.0;
            for dr in 0..3 {
                for dc in 0..3 {
                    m += out.at(c + dc - 1, r + dr - 1);
                }
            }
            let d = out.at(c, r) - m / 9.0;
            s2 += d * d;
            n += 1;
        }
    }
    (s2 / n.max(1) as f64).sqrt()
}

fn corrections(rep: &Value) -> &Value {
    &rep["corrections"][0]
}

#[test]
fn a_silhouette_stroke_gives_a_landform_the_judge_fits_and_a_jagged_one_is_rougher() {
    let case = Case::new();
    let rep = case.ok(
        "smooth",
        vec![landform("hill_smooth", "smooth", Value::Null)],
    );
    let f = corrections(&rep);
    println!(
        "smooth: {}",
        serde_json::to_string(&f["noise"]).unwrap_or_default()
    );
    assert_eq!(f["kind"], "landform");
    assert_eq!(f["landform"]["both_ends_on_terrain"], true);
    assert_eq!(f["landform"]["default_boundary"], true);
    assert_eq!(f["landform"]["boundary"]["type"], "Polygon");
    assert_eq!(f["landform"]["shadow"]["type"], "LineString");
    let fit = case.judge("smooth", "smooth");
    println!("judge, smooth stroke: {fit}");
    assert!(fit["fit_before"].as_f64().unwrap() < 0.2, "{fit}");
    assert!(
        fit["fit_after"].as_f64().unwrap() >= 0.95,
        "the judge fits the landform's silhouette at {fit}"
    );
    // The landform rises about 300 m over the plain, within its boundary.
    let peak = f["landform"]["peak_m"].as_f64().unwrap();
    assert!((780.0..840.0).contains(&peak), "peak {peak}");
    let input = Raster::read(&case.path("plain.tif"));
    let smooth = Raster::read(&case.path("smooth.tif"));
    let ring: Vec<[f64; 2]> =
        serde_json::from_value(f["landform"]["boundary"]["coordinates"][0].clone()).unwrap();
    let ring_px: Vec<[f64; 2]> = ring.iter().map(|p| input.pixel(p[0], p[1])).collect();
    let mut changed = 0;
    for r in 0..input.h {
        for c in 0..input.w {
            let p = [c as f64 + 0.5, r as f64 + 0.5];
            if smooth.at(c, r).to_bits() != input.at(c, r).to_bits() {
                changed += 1;
                assert!(
                    correct_support::inside(&ring_px, p),
                    "cell ({c}, {r}) outside the boundary changed"
                );
            }
        }
    }
    assert!(changed > 1000, "{changed} cells changed");

    let rep_j = case.ok(
        "jagged",
        vec![landform("hill_jagged", "jagged", Value::Null)],
    );
    let j = corrections(&rep_j);
    let jagged = Raster::read(&case.path("jagged.tif"));
    let (es, ej) = (
        f["noise"]["detail_energy_ratio"].as_f64().unwrap(),
        j["noise"]["detail_energy_ratio"].as_f64().unwrap(),
    );
    let (rs, rj) = (detail_rms(&input, &smooth), detail_rms(&input, &jagged));
    let (ns, nj) = (
        f["noise"]["noise_rms_m"].as_f64().unwrap(),
        j["noise"]["noise_rms_m"].as_f64().unwrap(),
    );
    println!(
        "wavelet energy ratio of the stroke: smooth {es:.3e}, jagged {ej:.3e} ({:.0}x); \
         noise added (rms): {ns:.2} m, {nj:.2} m; terrain detail (rms, GDAL): {rs:.2} m, {rj:.2} m ({:.1}x)",
        ej / es,
        rj / rs
    );
    assert!(ej > 10.0 * es, "energy ratios {es} {ej}");
    assert!(nj > 3.0 * ns, "noise {ns} {nj}");
    assert!(rj > 1.5 * rs, "terrain detail {rs} {rj}");
    println!("judge, jagged stroke: {}", case.judge("jagged", "jagged"));
}

#[test]
fn the_default_boundary_given_back_as_the_polygon_gives_the_same_landform() {
    let case = Case::new();
    let rep = case.ok("first", vec![landform("hill", "smooth", Value::Null)]);
    let boundary = corrections(&rep)["landform"]["boundary"].clone();
    let rep2 = case.ok("again", vec![landform("hill", "smooth", boundary)]);
    assert_eq!(corrections(&rep2)["landform"]["default_boundary"], false);
    let (a, b) = (
        Raster::read(&case.path("first.tif")),
        Raster::read(&case.path("again.tif")),
    );
    let worst =
        a.v.iter()
            .zip(&b.v)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
    assert!(worst < 1e-3, "max |diff| {worst} m");

    // A smaller boundary (a square of 40 cells around the peak's foot)
    // keeps every cell outside it.
    let input = Raster::read(&case.path("plain.tif"));
    let sq: Vec<[f64; 2]> = [
        [226.0, 252.0],
        [266.0, 252.0],
        [266.0, 292.0],
        [226.0, 292.0],
        [226.0, 252.0],
    ]
    .iter()
    .map(|&p| input.crs(p))
    .collect();
    let o = case.correct(
        &case.path("plain.tif"),
        "small",
        vec![landform(
            "hill",
            "smooth",
            json!({"type": "Polygon", "coordinates": [sq]}),
        )],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    // The silhouette's ground track runs beyond that square: refused.
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("ground track leaves the boundary"), "{err}");
}

#[test]
fn a_bent_shadow_bends_the_landform_and_the_judge_still_fits_it() {
    let case = Case::new();
    let rep = case.ok("straight", vec![landform("hill", "smooth", Value::Null)]);
    let shadow: Vec<[f64; 2]> =
        serde_json::from_value(corrections(&rep)["landform"]["shadow"]["coordinates"].clone())
            .unwrap();
    // The middle of the shadow moved up to 150 m north (away from the eye).
    let n = shadow.len() as f64 - 1.0;
    let bent: Vec<[f64; 2]> = shadow
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let t = k as f64 / n;
            [p[0], p[1] + 150.0 * (std::f64::consts::PI * t).sin()]
        })
        .collect();
    let mut f = landform("bent", "smooth", Value::Null);
    f["properties"]["shadow"] = json!({"type": "LineString", "coordinates": bent});
    let rep = case.ok("bent", vec![f]);
    let lf = &corrections(&rep)["landform"];
    assert!(lf.get("both_ends_on_terrain").is_none(), "{lf}");
    let placed: Vec<[f64; 2]> =
        serde_json::from_value(lf["shadow"]["coordinates"].clone()).unwrap();
    let mid = placed[placed.len() / 2];
    let old = shadow[shadow.len() / 2];
    println!("shadow middle moved {:.1} m north", mid[1] - old[1]);
    assert!((mid[1] - old[1] - 150.0).abs() < 15.0, "{mid:?} {old:?}");
    let fit = case.judge("bent", "smooth");
    println!("judge, bent shadow: {fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.95, "{fit}");
}

#[test]
fn a_landform_on_a_lon_lat_dem_is_fitted_too() {
    let case = Case::new();
    // The plain warped to EPSG:4326 (cells about 13 x 10 m).
    let ll = case.path("plain_ll.tif");
    common::run(
        "gdalwarp",
        &[
            "-q",
            "-t_srs",
            "EPSG:4326",
            "-r",
            "bilinear",
            "-tr",
            "0.00012",
            "0.00009",
            &case.path("plain.tif").to_string_lossy(),
            &ll.to_string_lossy(),
        ],
    );
    let o = case.correct(&ll, "ll", vec![landform("hill", "smooth", Value::Null)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let fit = case.judge_on("plain_ll.tif", "ll", "smooth");
    println!("judge, lon/lat DEM: {fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.95, "{fit}");
}

#[test]
fn a_noise_region_roughens_its_polygon_only() {
    let case = Case::new();
    let input = Raster::read(&case.path("plain.tif"));
    let sq: Vec<[f64; 2]> = [
        [100.0, 100.0],
        [200.0, 100.0],
        [200.0, 200.0],
        [100.0, 200.0],
        [100.0, 100.0],
    ]
    .iter()
    .map(|&p| input.crs(p))
    .collect();
    let region = |amp: Option<f64>| {
        let mut props = json!({"kind": "noise_region", "name": "rough",
            "noise_stroke": {"view": "hill", "stroke": "noise"}});
        if let Some(a) = amp {
            props["amplitude_m"] = json!(a);
        }
        json!({"type": "Feature", "properties": props,
            "geometry": {"type": "Polygon", "coordinates": [sq.clone()]}})
    };
    let rep = case.ok("region", vec![region(None)]);
    let f = corrections(&rep);
    assert_eq!(f["kind"], "noise_region");
    let out = Raster::read(&case.path("region.tif"));
    let mut changed = 0;
    for r in 0..input.h {
        for c in 0..input.w {
            if out.at(c, r).to_bits() != input.at(c, r).to_bits() {
                changed += 1;
                assert!(
                    (100..200).contains(&c) && (100..200).contains(&r),
                    "({c}, {r})"
                );
            }
        }
    }
    assert!(changed > 5000, "{changed}");
    let before = detail_rms(&input, &out);
    let rms = f["noise"]["noise_rms_m"].as_f64().unwrap();
    println!("noise region: {changed} cells, noise rms {rms:.2} m, terrain detail {before:.2} m");
    assert!(rms > 1.0);
    // amplitude_m sets the field's deviation.
    let rep = case.ok("region5", vec![region(Some(5.0))]);
    let s = corrections(&rep)["noise"]["noise_sigma_m"]
        .as_f64()
        .unwrap();
    assert!((s - 5.0).abs() < 1e-6, "sigma {s}");
}

/// Exit code 1, one line naming the features file and the feature and
/// saying `needle`, nothing written.
fn expect_failure(case: &Case, args_sketch: bool, feature: Value, needle: &str) {
    let before = snapshot(case.dir.path());
    let f = case.path("bad.geojson");
    std::fs::write(&f, collection(vec![feature], Some(32632))).unwrap();
    let (plain, out, rep, sk) = (
        case.path("plain.tif"),
        case.path("bad.tif"),
        case.path("bad.json"),
        case.path("sketch.json"),
    );
    let (plain, fs, out_s, rep_s, sk_s) = (
        plain.to_string_lossy(),
        f.to_string_lossy(),
        out.to_string_lossy(),
        rep.to_string_lossy(),
        sk.to_string_lossy(),
    );
    let mut args = vec![
        "correct",
        &plain,
        "--features",
        &fs,
        "--out",
        &out_s,
        "--report",
        &rep_s,
    ];
    if args_sketch {
        args.extend(["--sketch", &sk_s]);
    }
    let o = demsketch(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    assert!(
        err.contains("bad.geojson") && err.contains("feature 0 (\"bad\")"),
        "{err}"
    );
    assert!(err.contains(needle), "says '{needle}': {err}");
    assert!(!out.exists() && !rep.exists());
    let mut after = snapshot(case.dir.path());
    after.retain(|(p, _)| p != &f);
    let mut before = before;
    before.retain(|(p, _)| p != &f);
    assert_eq!(after, before, "something was written");
}

#[test]
fn bad_landforms_fail_with_one_line_naming_the_feature() {
    let case = Case::new();
    expect_failure(
        &case,
        true,
        landform("bad", "no_such", Value::Null),
        "has no stroke \"no_such\"",
    );
    let mut missing_view = landform("bad", "smooth", Value::Null);
    missing_view["properties"]["silhouette"]["view"] = json!("elsewhere");
    expect_failure(&case, true, missing_view, "has no view \"elsewhere\"");
    expect_failure(
        &case,
        false,
        landform("bad", "smooth", Value::Null),
        "--sketch",
    );
    let mut no_ref = landform("bad", "smooth", Value::Null);
    no_ref["properties"]
        .as_object_mut()
        .unwrap()
        .remove("silhouette");
    expect_failure(&case, true, no_ref, "needs a silhouette property");
    let mut bad_ref = landform("bad", "smooth", Value::Null);
    bad_ref["properties"]["silhouette"] = json!("smooth");
    expect_failure(&case, true, bad_ref, "property silhouette must be");
    // A stroke in the sky at both ends has no terrain to stand on.
    let mut sk = sketch();
    sk["views"][0]["strokes"]
        .as_array_mut()
        .unwrap()
        .push(json!({"id": "sky", "points": [[100.0, 40.0], [200.0, 30.0], [300.0, 40.0]]}));
    std::fs::write(case.path("sketch.json"), sk.to_string()).unwrap();
    expect_failure(
        &case,
        true,
        landform("bad", "sky", Value::Null),
        "neither end stands on terrain",
    );
    let region = json!({"type": "Feature",
        "properties": {"kind": "noise_region", "name": "bad",
            "noise_stroke": {"view": "hill", "stroke": "nope"}},
        "geometry": {"type": "Polygon", "coordinates": [[[X0 + 100.0, Y0 - 100.0], [X0 + 900.0, Y0 - 100.0], [X0 + 900.0, Y0 - 900.0], [X0 + 100.0, Y0 - 100.0]]]}});
    expect_failure(&case, true, region, "has no stroke \"nope\"");
}

#[test]
fn a_landform_across_tile_corners_equals_the_single_file_result() {
    let case = Case::new();
    // The footprint covers the corner at (250, 250) of the 125-cell tiles.
    let features = vec![landform("corner_hill", "jagged", Value::Null)];
    let rep = case.ok("single", features.clone());
    let w = &rep["window"];
    let (c0, r0) = (w[0].as_i64().unwrap(), w[1].as_i64().unwrap());
    let (c1, r1) = (c0 + w[2].as_i64().unwrap(), r0 + w[3].as_i64().unwrap());
    assert!(c0 < 250 && c1 > 250 && r0 < 250 && r1 > 250, "window {w}");
    let tiles = case.path("tiles");
    std::fs::create_dir(&tiles).unwrap();
    split(&case.path("plain.tif"), &tiles, 4);
    let f = case.path("tiled.geojson");
    std::fs::write(&f, collection(features, Some(32632))).unwrap();
    let out = case.path("out_tiles");
    let o = demsketch(&[
        "correct",
        &tiles.to_string_lossy(),
        "--features",
        &f.to_string_lossy(),
        "--sketch",
        &case.path("sketch.json").to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let vrt = case.path("tiles.vrt");
    assert_eq!(vrt_of_tiles(&out, &vrt), 16);
    let input = Raster::read(&case.path("plain.tif"));
    let (a, b) = (Raster::read(&case.path("single.tif")), Raster::read(&vrt));
    let (mut worst, mut changed) = (0f64, 0);
    for i in 0..a.v.len() {
        worst = worst.max((a.v[i] - b.v[i]).abs());
        if a.v[i].to_bits() != input.v[i].to_bits() {
            changed += 1;
        }
    }
    println!("landform: {changed} cells changed; tiled vs single file: max |diff| {worst} m");
    assert!(changed > 1000);
    assert!(
        worst <= 1e-3,
        "tiled and single-file results differ by {worst} m"
    );
}

/// A landform in a sketch's `map_features` (issue 14 item 2), with a
/// control curve beside it: `demsketch edit` places the landform's stroke
/// on the sketch's own view (the stroke is not matched as a first-person
/// stroke) and applies both in the same edit. Checked on the written file
/// (GDAL): the landform's cells equal `correct --features --sketch`'s
/// within 1e-3 m, the judge fits its silhouette at >= 0.95, the control
/// curve is met within 0.05 m, and the report lists both features.
#[test]
fn a_landform_in_a_sketch_s_map_features_is_applied_in_the_edit() {
    let case = Case::new();
    let input = Raster::read(&case.path("plain.tif"));
    let curve_px = [[60.5, 60.5], [140.5, 70.5]];
    let curve: Vec<[f64; 3]> = curve_px
        .iter()
        .map(|&p| {
            let c = input.crs(p);
            [c[0], c[1], input.bilinear(p).unwrap() + 20.0]
        })
        .collect();
    let embankment = json!({"type": "Feature",
        "properties": {"kind": "control_curve", "name": "embankment", "influence_m": 300.0},
        "geometry": {"type": "LineString", "coordinates": curve}});
    let mut sk = sketch();
    // Only the landform's stroke in the view.
    sk["views"][0]["strokes"] = json!([{"id": "smooth", "points": stroke(0.0)}]);
    let features: Value = serde_json::from_str(&collection(
        vec![
            landform("inside", "smooth", Value::Null),
            embankment.clone(),
        ],
        Some(32632),
    ))
    .unwrap();
    sk["map_features"] = features;
    let path = case.path("sketch.json");
    std::fs::write(&path, sk.to_string()).unwrap();
    let out = case.path("edited.tif");
    let rep = case.path("edited.json");
    let o = demsketch(&[
        "edit",
        &case.path("plain.tif").to_string_lossy(),
        "--sketch",
        &path.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--report",
        &rep.to_string_lossy(),
        "-q",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let info = common::gdalinfo(&out);
    assert_eq!(info["size"], json!([N, N]), "{info}");
    let r = report(&rep);
    let feats = r["map_features"]
        .as_array()
        .or_else(|| r["corrections"].as_array())
        .unwrap_or_else(|| panic!("no map_features in the report: {r}"));
    let kinds: Vec<&str> = feats.iter().filter_map(|f| f["kind"].as_str()).collect();
    assert_eq!(kinds, ["landform", "control_curve"], "{r}");
    // The same landform from `correct --features F --sketch S`.
    let alone = case.ok("alone", vec![landform("inside", "smooth", Value::Null)]);
    let ring: Vec<[f64; 2]> = serde_json::from_value(
        corrections(&alone)["landform"]["boundary"]["coordinates"][0].clone(),
    )
    .unwrap();
    let ring_px: Vec<[f64; 2]> = ring.iter().map(|p| input.pixel(p[0], p[1])).collect();
    let (edited, alone) = (Raster::read(&out), Raster::read(&case.path("alone.tif")));
    let mut worst = 0f64;
    for r in 0..input.h {
        for c in 0..input.w {
            if correct_support::inside(&ring_px, [c as f64 + 0.5, r as f64 + 0.5]) {
                worst = worst.max((edited.at(c, r) - alone.at(c, r)).abs());
            }
        }
    }
    println!("landform in map_features vs correct --sketch: max |diff| {worst} m");
    assert!(worst <= 1e-3, "{worst}");
    let fit = case.judge("edited", "smooth");
    println!("judge, landform in map_features: {fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.95, "{fit}");
    let mut on_curve = 0f64;
    for i in 0..=100 {
        let t = i as f64 / 100.0;
        let p = [
            curve_px[0][0] + t * (curve_px[1][0] - curve_px[0][0]),
            curve_px[0][1] + t * (curve_px[1][1] - curve_px[0][1]),
        ];
        let z = curve[0][2] + t * (curve[1][2] - curve[0][2]);
        on_curve = on_curve.max((edited.bilinear(p).unwrap() - z).abs());
    }
    assert!(on_curve <= 0.05, "control curve missed by {on_curve} m");
}

/// The judge's fit (`tools/fidelity/landform_fit.py`) of the landform
/// `demsketch correct` builds on the real fixture `dem` from stroke
/// `stroke` of view `view` of the sketch fixture `sketch`.
fn real_landform_fit(dem: &str, sketch: &str, view: &str, stroke: &str) -> Value {
    let tmp = tempfile::tempdir().unwrap();
    let dem = common::fixture(dem);
    let sketch = common::fixture(sketch);
    let f = tmp.path().join("lf.geojson");
    std::fs::write(
        &f,
        collection(
            vec![json!({"type": "Feature",
                "properties": {"kind": "landform", "name": "lf",
                    "silhouette": {"view": view, "stroke": stroke}},
                "geometry": null})],
            None,
        ),
    )
    .unwrap();
    let out = tmp.path().join("out.tif");
    let o = demsketch(&[
        "correct",
        &dem.to_string_lossy(),
        "--features",
        &f.to_string_lossy(),
        "--sketch",
        &sketch.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/fidelity/landform_fit.py");
    let o = Command::new("/usr/bin/python3")
        .arg(script)
        .arg(&dem)
        .arg(&out)
        .arg(&sketch)
        .args([view, stroke])
        .output()
        .expect("run the judge");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// On a real DEM held out of the tuning (`fixtures/zion_srtm90m_epsg4326.tif`,
/// SRTM 3", about 74 x 93 m cells): the long ridge stroke of
/// `fixtures/sketches/zion90_landform_ridge.json` (view "west", 300 px
/// wide, its ends on the ground the judge sees about 3 km away, from
/// `tools/fidelity/landform_real.py`). The judge fits the landform's
/// silhouette at 0.944 (0.83 before the cells were held below the sight
/// line through the silhouette); asserted >= 0.94. 7% of its columns lie
/// over terrain less than 5% farther than the ridge's ends, where the judge
/// sees no boundary (landform_real.py's silhouette share, 0.93).
#[test]
fn a_landform_on_a_real_dem_is_fitted_by_the_judge() {
    let fit = real_landform_fit(
        "zion_srtm90m_epsg4326.tif",
        "sketches/zion90_landform_ridge.json",
        "west",
        "ridge",
    );
    println!("judge, Zion 90 m ridge at 3 km: {fit}");
    assert!(fit["fit_before"].as_f64().unwrap() < 0.2, "{fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.94, "{fit}");
}

/// On a real DEM held out of the tuning (`fixtures/arenal_aster30m_epsg4326.tif`,
/// ASTER 1", about 30 m cells): the dome stroke of
/// `fixtures/sketches/arenal_landform_dome.json` (160 px wide, its ends on
/// the ground about 1 km away, 10 cells across). The judge fits the
/// landform's silhouette at 0.957; asserted >= 0.95.
#[test]
fn a_dome_landform_on_a_held_out_real_dem_is_fitted_at_0_95() {
    let fit = real_landform_fit(
        "arenal_aster30m_epsg4326.tif",
        "sketches/arenal_landform_dome.json",
        "southeast",
        "dome",
    );
    println!("judge, Arenal 30 m dome at 1 km: {fit}");
    assert!(fit["fit_before"].as_f64().unwrap() < 0.2, "{fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.95, "{fit}");
}

/// The same dome stroke on the held-out Zion 90 m fixture at 3 km
/// (`fixtures/sketches/zion90_landform_dome.json`, 13 cells across): the
/// judge fits 0.944 (0.925 before the cells beyond the stroke's ends were
/// held); asserted >= 0.94.
#[test]
fn a_dome_landform_on_zion_90m_is_fitted_by_the_judge() {
    let fit = real_landform_fit(
        "zion_srtm90m_epsg4326.tif",
        "sketches/zion90_landform_dome.json",
        "west",
        "dome",
    );
    println!("judge, Zion 90 m dome at 3 km: {fit}");
    assert!(fit["fit_before"].as_f64().unwrap() < 0.2, "{fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.94, "{fit}");
}

/// The smooth bump of `tools/fidelity/landform_real.py` at 1 km on the
/// held-out Arenal fixture (`fixtures/sketches/arenal_landform_smooth_refused_end.json`):
/// both its ends are drawn on ground the judge sees, but each lies within
/// 3 px of a depth step demsketch's silhouettes count (0.5%), so the
/// edit's end test refused both and `correct` failed ("neither end stands
/// on terrain"). An end pixel that shows terrain is now the landform's
/// foot: the landform is built and the judge fits it at 0.876 (12 of its
/// 15 missed columns lie under nearer terrain); asserted >= 0.85.
#[test]
fn a_landform_whose_ends_lie_near_weak_depth_steps_is_placed_on_the_ground_its_ends_show() {
    let fit = real_landform_fit(
        "arenal_aster30m_epsg4326.tif",
        "sketches/arenal_landform_smooth_refused_end.json",
        "southeast",
        "smooth",
    );
    println!("judge, Arenal 30 m smooth bump at 1 km: {fit}");
    assert!(fit["fit_before"].as_f64().unwrap() < 0.2, "{fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.85, "{fit}");
}

/// An arc from image column 220.5 to 420.5, its ends on rows `y0` and
/// `y1`, rising 60 px between them.
fn arc(y0: f64, y1: f64) -> Vec<[f64; 2]> {
    (0..=100)
        .map(|k| {
            let x = 220.5 + 2.0 * k as f64;
            let t = (x - 320.5) / 100.0;
            [x, y0 + (y1 - y0) * k as f64 / 100.0 - 60.0 * (1.0 - t * t)]
        })
        .collect()
}

/// A stroke ending half a pixel above a crest (here the plain's far edge,
/// the horizon at rows 203-204 about 4.7 km away) stands on the terrain
/// just below its end pixels, which show sky (`END_SNAP_PX`; the edit's
/// end test refuses both ends, next to a boundary), and the judge fits its
/// landform; one ending 3.5 px above the crest is still refused. Found on
/// the real fixtures: strokes drawn on a crest's top rows were refused
/// although the judge sees ground under their ends (docs/landform_real.md).
#[test]
fn a_stroke_ending_just_above_a_crest_stands_on_it() {
    let case = Case::new();
    let mut sk = sketch();
    let strokes = sk["views"][0]["strokes"].as_array_mut().unwrap();
    strokes.push(json!({"id": "crest", "points": arc(202.5, 203.5)}));
    strokes.push(json!({"id": "above", "points": arc(199.5, 200.5)}));
    std::fs::write(case.path("sketch.json"), sk.to_string()).unwrap();
    case.ok("crest", vec![landform("crest", "crest", Value::Null)]);
    let fit = case.judge("crest", "crest");
    eprintln!("judge, stroke ending 0.5 px above the horizon: {fit}");
    assert!(fit["fit_after"].as_f64().unwrap() >= 0.95, "{fit}");
    expect_failure(
        &case,
        true,
        landform("bad", "above", Value::Null),
        "neither end stands on terrain",
    );
}
