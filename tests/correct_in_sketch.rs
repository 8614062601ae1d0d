//! Map-view corrections inside a sketch file (`corrections`, a GeoJSON
//! FeatureCollection next to the views), applied by `demsketch edit` in
//! the same write: on the Zion fixture, a sketch with one stroke and a lake
//! behind the viewpoint gives the lake flat (every cell inside equal to the
//! level as the UInt16 fixture stores it, in whole metres; read back with
//! GDAL) and the stroke's report as the same
//! sketch without the lake gives it; cells away from both are untouched.
//! A bad feature fails the edit with one line naming the sketch and the
//! feature, and unknown keys are still rejected.

mod common;
mod correct_support;

use std::path::{Path, PathBuf};

use common::{demsketch, fixture, snapshot};
use correct_support::{inside, report, Raster};
use serde_json::{json, Value};

const DEM: &str = "zion_srtm_utm12n.tif";

/// The bundled sketch with its first stroke only.
fn one_stroke_sketch() -> Value {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion_dome.json"),
    )
    .unwrap();
    let mut v: Value = serde_json::from_str(&text).unwrap();
    let strokes = v["views"][0]["strokes"].as_array_mut().unwrap();
    strokes.truncate(1);
    v
}

/// A square lake, 12 cells a side, about 3 km north-east of (behind) the
/// viewpoint, in pixel space.
const LAKE_PX: [[f64; 2]; 5] = [
    [384.0, 125.0],
    [396.0, 125.0],
    [396.0, 137.0],
    [384.0, 137.0],
    [384.0, 125.0],
];

fn lake_collection(input: &Raster, kind: &str) -> Value {
    let ring: Vec<[f64; 2]> = LAKE_PX.iter().map(|&p| input.crs(p)).collect();
    json!({"type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32612"}},
        "features": [{"type": "Feature", "properties": {"kind": kind, "name": "pond"},
            "geometry": {"type": "Polygon", "coordinates": [ring]}}]})
}

fn write_sketch(tmp: &Path, name: &str, sketch: &Value) -> PathBuf {
    let sk = tmp.join(format!("{name}.json"));
    std::fs::write(&sk, serde_json::to_string_pretty(sketch).unwrap()).unwrap();
    // A copy of the DEM per run: edits of one DEM take its lock in turn.
    std::fs::copy(fixture(DEM), tmp.join(format!("{name}.dem.tif"))).unwrap();
    sk
}

fn run_edit(tmp: &Path, name: &str) -> (std::process::Output, PathBuf, PathBuf) {
    let sk = tmp.join(format!("{name}.json"));
    let (out, rep) = (
        tmp.join(format!("{name}.tif")),
        tmp.join(format!("{name}.report.json")),
    );
    let dem = tmp.join(format!("{name}.dem.tif"));
    let o = demsketch(&[
        "edit",
        dem.to_str().unwrap(),
        "--sketch",
        sk.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
    ]);
    (o, out, rep)
}

fn edit(tmp: &Path, name: &str, sketch: &Value) -> (std::process::Output, PathBuf, PathBuf) {
    write_sketch(tmp, name, sketch);
    run_edit(tmp, name)
}

#[test]
fn a_sketch_with_a_stroke_and_a_lake_flattens_the_lake_and_fits_the_stroke_as_before() {
    let tmp = tempfile::tempdir().unwrap();
    let input = Raster::read(&fixture(DEM));
    let plain = one_stroke_sketch();
    let mut with_lake = plain.clone();
    with_lake["map_features"] = lake_collection(&input, "lake");

    let (o, out_a, rep_a) = edit(tmp.path(), "plain", &plain);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (o, out_b, rep_b) = edit(tmp.path(), "lake", &with_lake);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (a, b) = (report(&rep_a), report(&rep_b));

    // The stroke's report as before.
    let (sa, sb) = (&a["views"][0]["strokes"][0], &b["views"][0]["strokes"][0]);
    for key in ["match", "fit", "visible_fraction", "status", "placed_curve"] {
        assert_eq!(sa[key], sb[key], "stroke {key} differs");
    }
    assert!(a.get("corrections").is_none());

    // The lake: reported, and flat to its level in the written DEM.
    let f = &b["corrections"][0];
    assert_eq!(f["kind"], "lake");
    assert_eq!(f["id"], "pond");
    let level = f["level_m"].as_f64().unwrap();
    let (ra, rb) = (Raster::read(&out_a), Raster::read(&out_b));
    // The fixture stores whole metres (UInt16): the level is written
    // rounded, the same value in every lake cell.
    let (c0, r0) = (LAKE_PX[0][0] as usize, LAKE_PX[0][1] as usize);
    let stored = rb.at(c0, r0);
    assert!(
        (stored - level).abs() <= 0.51,
        "level {level} stored as {stored}"
    );
    let mut lake_cells = 0;
    for r in 0..input.h {
        for c in 0..input.w {
            let p = [c as f64 + 0.5, r as f64 + 0.5];
            if inside(&LAKE_PX, p) {
                lake_cells += 1;
                let v = rb.at(c, r);
                assert!(
                    (v - stored).abs() <= 0.01,
                    "lake cell ({c}, {r}) = {v}, level {level} stored as {stored}"
                );
            }
        }
    }
    assert!(lake_cells >= 100, "{lake_cells} lake cells");
    assert!(f["cells_changed"].as_u64().unwrap() > 0);

    // Away from the lake (beyond its blend width), the two outputs agree
    // bit for bit: the stroke's edit is unchanged.
    let blend_cells = f["blend_m"].as_f64().unwrap() / input.gt[1] + 1.5;
    let mut compared = 0;
    for r in 0..input.h {
        for c in 0..input.w {
            let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
            let dx = (384.0 - x).max(x - 396.0).max(0.0);
            let dy = (125.0 - y).max(y - 137.0).max(0.0);
            if dx.hypot(dy) > blend_cells {
                compared += 1;
                let (u, v) = (ra.at(c, r), rb.at(c, r));
                assert!(
                    u.to_bits() == v.to_bits() || (u.is_nan() && v.is_nan()),
                    "({c}, {r}) differs away from the lake: {u} vs {v}"
                );
            }
        }
    }
    assert!(compared > input.w * input.h / 2);
    assert!(
        b["changed_cells"].as_u64().unwrap() > a["changed_cells"].as_u64().unwrap(),
        "the lake's cells are counted"
    );
}

#[test]
fn a_bad_correction_in_a_sketch_fails_the_edit_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let input = Raster::read(&fixture(DEM));
    let mut sketch = one_stroke_sketch();
    sketch["map_features"] = lake_collection(&input, "glacier");
    write_sketch(tmp.path(), "bad", &sketch);
    let before = snapshot(tmp.path());
    let (o, out, rep) = run_edit(tmp.path(), "bad");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    assert!(err.contains("bad.json"), "names the sketch: {err}");
    assert!(
        err.contains("map_features: feature 0 (\"pond\")"),
        "names the feature: {err}"
    );
    assert!(err.contains("unknown kind \"glacier\""), "{err}");
    assert!(!out.exists() && !rep.exists());
    assert!(snapshot(tmp.path()) == before, "something was written");
}

#[test]
fn unknown_keys_next_to_the_corrections_are_still_rejected() {
    let tmp = tempfile::tempdir().unwrap();
    let input = Raster::read(&fixture(DEM));
    let mut sketch = one_stroke_sketch();
    sketch["correction"] = lake_collection(&input, "lake");
    let (o, _, _) = edit(tmp.path(), "typo", &sketch);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("unknown field `correction`"), "{err}");

    // `corrections`, the member's older name, is still read as `map_features`.
    let mut sketch = one_stroke_sketch();
    sketch["corrections"] = json!({"type": "Feature"});
    let (o, _, _) = edit(tmp.path(), "notfc", &sketch);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("map_features: must be a GeoJSON FeatureCollection"),
        "{err}"
    );

    // Both names at once: one member too many.
    let mut sketch = one_stroke_sketch();
    sketch["map_features"] = lake_collection(&input, "lake");
    sketch["corrections"] = lake_collection(&input, "lake");
    let (o, _, _) = edit(tmp.path(), "both", &sketch);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
}
