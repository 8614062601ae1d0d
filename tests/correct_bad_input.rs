//! Bad corrections: each gives exit code 1, one line on stderr naming the
//! file and the feature (index and id or name), and writes nothing (no
//! output, no report, the input untouched).

mod common;
mod correct_support;

use common::{demsketch, fixture, snapshot};
use correct_support::{collection, Raster};
use serde_json::{json, Value};

const DEM: &str = "vinschgau_250m_utm32n.tif";

fn utm(p: [f64; 2]) -> [f64; 2] {
    Raster::read(&fixture(DEM)).crs(p)
}

fn lake_square(c: [f64; 2]) -> Vec<[f64; 2]> {
    [
        [-2.0, -2.0],
        [2.0, -2.0],
        [2.0, 2.0],
        [-2.0, 2.0],
        [-2.0, -2.0],
    ]
    .iter()
    .map(|d| utm([c[0] + d[0], c[1] + d[1]]))
    .collect()
}

/// A good lake first, then `bad` as feature 1.
fn expect_failure(bad: Value, needle: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("dem.tif");
    std::fs::copy(fixture(DEM), &dem).unwrap();
    let good = json!({"type": "Feature", "properties": {"kind": "lake", "name": "ok"},
        "geometry": {"type": "Polygon", "coordinates": [lake_square([73.0, 33.0])]}});
    let features = tmp.path().join("bad.geojson");
    std::fs::write(&features, collection(vec![good, bad], Some(32632))).unwrap();
    let before = snapshot(tmp.path());
    let (out, rep) = (tmp.path().join("out.tif"), tmp.path().join("r.json"));
    let o = demsketch(&[
        "correct",
        &dem.to_string_lossy(),
        "--features",
        &features.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--report",
        &rep.to_string_lossy(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
    assert!(err.contains("bad.geojson"), "names the file: {err}");
    assert!(
        err.contains("feature 1 (\"bad\")"),
        "names the feature: {err}"
    );
    assert!(err.contains(needle), "says '{needle}': {err}");
    assert!(!out.exists() && !rep.exists());
    assert_eq!(snapshot(tmp.path()), before, "something was written");
}

#[test]
fn self_intersecting_lake() {
    let bow: Vec<[f64; 2]> = [
        [70.0, 30.0],
        [76.0, 36.0],
        [76.0, 30.0],
        [70.0, 36.0],
        [70.0, 30.0],
    ]
    .iter()
    .map(|&p| utm(p))
    .collect();
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "lake", "name": "bad"},
            "geometry": {"type": "Polygon", "coordinates": [bow]}}),
        "invalid polygon",
    );
}

#[test]
fn control_curve_without_heights() {
    expect_failure(
        json!({"type": "Feature", "id": "bad", "properties": {"kind": "control_curve"},
            "geometry": {"type": "LineString", "coordinates": [utm([100.0, 100.0]), utm([110.0, 100.0])]}}),
        "has no height",
    );
}

#[test]
fn heights_m_of_the_wrong_length() {
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "control_curve", "name": "bad", "heights_m": [1000.0]},
            "geometry": {"type": "LineString", "coordinates": [utm([100.0, 100.0]), utm([110.0, 100.0])]}}),
        "heights_m has 1 values for 2 positions",
    );
}

#[test]
fn unknown_kind() {
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "glacier", "name": "bad"},
            "geometry": {"type": "Polygon", "coordinates": [lake_square([100.0, 100.0])]}}),
        "unknown kind \"glacier\"",
    );
}

#[test]
fn feature_outside_the_dem() {
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "lake", "name": "bad"},
            "geometry": {"type": "Polygon", "coordinates": [lake_square([300.0, 100.0])]}}),
        "outside the DEM",
    );
}

#[test]
fn river_without_width() {
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "river", "name": "bad"},
            "geometry": {"type": "LineString", "coordinates": [utm([100.0, 100.0]), utm([110.0, 100.0])]}}),
        "needs width_m",
    );
}

#[test]
fn not_geojson() {
    let tmp = tempfile::tempdir().unwrap();
    let features = tmp.path().join("broken.geojson");
    std::fs::write(
        &features,
        "{\"type\": \"FeatureCollection\", \"features\": [",
    )
    .unwrap();
    let out = tmp.path().join("out.tif");
    let o = demsketch(&[
        "correct",
        &fixture(DEM).to_string_lossy(),
        "--features",
        &features.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("broken.geojson") && err.contains("not GeoJSON"),
        "{err}"
    );
    assert!(!out.exists());
}
