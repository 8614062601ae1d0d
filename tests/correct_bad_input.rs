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
    expect_failure_with(bad, Vec::new(), needle)
}

/// A good lake first, then `bad` as feature 1, then `extra`.
fn expect_failure_with(bad: Value, extra: Vec<Value>, needle: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("dem.tif");
    std::fs::copy(fixture(DEM), &dem).unwrap();
    let good = json!({"type": "Feature", "properties": {"kind": "lake", "name": "ok"},
        "geometry": {"type": "Polygon", "coordinates": [lake_square([73.0, 33.0])]}});
    let features = tmp.path().join("bad.geojson");
    let mut all = vec![good, bad];
    all.extend(extra);
    std::fs::write(&features, collection(all, Some(32632))).unwrap();
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

fn section(a: [f64; 2], b: [f64; 2], curve: &str) -> Value {
    let (a, b) = (utm(a), utm(b));
    json!({"type": "Feature", "properties": {"kind": "cross_section", "name": "bad", "control_curve": curve},
        "geometry": {"type": "LineString", "coordinates": [[a[0], a[1], 1000.0], [b[0], b[1], 990.0]]}})
}

fn curve(name: &str) -> Value {
    let (a, b) = (utm([100.0, 100.0]), utm([110.0, 100.0]));
    json!({"type": "Feature", "properties": {"kind": "control_curve", "name": name},
        "geometry": {"type": "LineString", "coordinates": [[a[0], a[1], 1000.0], [b[0], b[1], 1000.0]]}})
}

#[test]
fn cross_section_that_does_not_cross_its_curve() {
    expect_failure_with(
        section([104.0, 102.0], [104.0, 106.0], "dike"),
        vec![curve("dike")],
        "the cross-section does not cross its control curve \"dike\"",
    );
}

#[test]
fn cross_section_of_a_missing_or_wrong_feature() {
    expect_failure_with(
        section([104.0, 98.0], [104.0, 102.0], "road"),
        vec![curve("dike")],
        "no feature \"road\" to attach the cross-section to",
    );
    expect_failure(
        section([104.0, 98.0], [104.0, 102.0], "ok"),
        "feature \"ok\" is a lake, not a control curve",
    );
}

#[test]
fn cross_section_without_heights_or_curve() {
    let (a, b) = (utm([104.0, 98.0]), utm([104.0, 102.0]));
    expect_failure_with(
        json!({"type": "Feature", "properties": {"kind": "cross_section", "name": "bad", "control_curve": "dike"},
            "geometry": {"type": "LineString", "coordinates": [a, b]}}),
        vec![curve("dike")],
        "position 0 has no height",
    );
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "cross_section", "name": "bad"},
            "geometry": {"type": "LineString", "coordinates": [[a[0], a[1], 1.0], [b[0], b[1], 1.0]]}}),
        "needs a control_curve property",
    );
}

fn breakline(coords: Vec<Vec<f64>>, extra: Value) -> Value {
    let mut props = json!({"kind": "breakline", "name": "bad"});
    for (k, v) in extra.as_object().unwrap() {
        props[k] = v.clone();
    }
    json!({"type": "Feature", "properties": props,
        "geometry": {"type": "LineString", "coordinates": coords}})
}

fn utm_z(p: [f64; 2], z: Option<f64>) -> Vec<f64> {
    let q = utm(p);
    match z {
        Some(z) => vec![q[0], q[1], z],
        None => vec![q[0], q[1]],
    }
}

#[test]
fn breakline_without_heights() {
    expect_failure(
        breakline(
            vec![
                utm_z([150.0, 60.0], Some(2000.0)),
                utm_z([160.0, 62.0], None),
            ],
            json!({}),
        ),
        "position 1 has no height",
    );
}

#[test]
fn breakline_with_fewer_than_two_positions() {
    expect_failure(
        breakline(vec![utm_z([150.0, 60.0], Some(2000.0))], json!({})),
        "at least two distinct positions",
    );
    // Two positions, the same one twice.
    expect_failure(
        breakline(
            vec![
                utm_z([150.0, 60.0], Some(2000.0)),
                utm_z([150.0, 60.0], Some(2000.0)),
            ],
            json!({}),
        ),
        "at least two distinct positions",
    );
}

#[test]
fn self_intersecting_breakline() {
    let bow = [[150.0, 60.0], [160.0, 70.0], [160.0, 60.0], [150.0, 70.0]];
    expect_failure(
        breakline(
            bow.iter().map(|&p| utm_z(p, Some(2000.0))).collect(),
            json!({}),
        ),
        "the breakline crosses itself",
    );
    // Folding straight back over itself is crossing too.
    let fold = [[150.0, 60.0], [160.0, 60.0], [155.0, 60.0]];
    expect_failure(
        breakline(
            fold.iter().map(|&p| utm_z(p, Some(2000.0))).collect(),
            json!({}),
        ),
        "the breakline crosses itself",
    );
}

#[test]
fn breakline_with_a_bad_hard_property() {
    expect_failure(
        breakline(
            vec![
                utm_z([150.0, 60.0], Some(2000.0)),
                utm_z([160.0, 62.0], Some(2000.0)),
            ],
            json!({"hard": "yes"}),
        ),
        "property hard must be true or false",
    );
}

/// A property the kind does not have (a misspelling, or one from another
/// kind) is refused by name, with the properties the kind takes.
#[test]
fn unknown_property_of_each_kind() {
    let line = |props: Value| {
        let (a, b) = (utm([100.0, 100.0]), utm([110.0, 100.0]));
        json!({"type": "Feature", "properties": props,
            "geometry": {"type": "LineString", "coordinates": [[a[0], a[1], 1000.0], [b[0], b[1], 1000.0]]}})
    };
    let area = |props: Value| {
        json!({"type": "Feature", "properties": props,
            "geometry": {"type": "Polygon", "coordinates": [lake_square([100.0, 100.0])]}})
    };
    let stroke = json!({"view": "v", "stroke": "s"});
    let cases = [
        (
            area(json!({"kind": "lake", "name": "bad", "levle_m": 1000.0})),
            "unknown property \"levle_m\" for a lake (expected one of: level_m, blend_m, id, name, kind, fid)",
        ),
        (
            line(json!({"kind": "river", "name": "bad", "width_m": 30.0, "downstrem": true})),
            "unknown property \"downstrem\" for a river (expected one of: width_m, downstream, flow, blend_m,",
        ),
        (
            line(json!({"kind": "river", "name": "bad", "width_m": 30.0, "downstream": "north"})),
            "downstream \"north\" must be \"end\" or true",
        ),
        (
            line(json!({"kind": "river", "name": "bad", "width_m": 30.0, "downstream": "end", "flow": "auto"})),
            "a river's direction is given once: downstream or flow, not both",
        ),
        (
            area(json!({"kind": "river", "name": "bad", "width_m": 30.0})),
            "unknown property \"width_m\" for a river (expected one of: blend_m, id,",
        ),
        (
            line(json!({"kind": "control_curve", "name": "bad", "slope_dg": 10.0})),
            "unknown property \"slope_dg\" for a control_curve (expected one of: heights_m, influence_m, slope_deg,",
        ),
        (
            line(json!({"kind": "control_curve", "name": "bad", "slope_deg": 95.0})),
            "slope_deg 95.0 must be a number of degrees in (-90, 90) or two of them [left, right]",
        ),
        (
            line(json!({"kind": "cross_section", "name": "bad", "control_curv": "c1"})),
            "unknown property \"control_curv\" for a cross_section (expected one of: control_curve, control, heights_m,",
        ),
        (
            line(json!({"kind": "cross_section", "name": "bad", "control": "c1", "control_curve": "c1"})),
            "a cross-section names its control curve once: control or control_curve, not both",
        ),
        (
            line(json!({"kind": "breakline", "name": "bad", "hieght_m": 1000.0})),
            "unknown property \"hieght_m\" for a breakline (expected one of: heights_m, height_m, hard, influence_m,",
        ),
        (
            json!({"type": "Feature", "properties": {"kind": "landform", "name": "bad",
                "silhouette": stroke, "shade": [[0.0, 0.0], [1.0, 1.0]]}, "geometry": null}),
            "unknown property \"shade\" for a landform (expected one of: silhouette, shadow,",
        ),
        (
            area(json!({"kind": "noise_region", "name": "bad", "noise_stroke": stroke, "amplitude": 5.0})),
            "unknown property \"amplitude\" for a noise_region (expected one of: noise_stroke, amplitude_m,",
        ),
    ];
    for (bad, needle) in cases {
        expect_failure(bad, needle);
    }
}

#[test]
fn fid_that_is_not_an_integer() {
    expect_failure(
        json!({"type": "Feature", "properties": {"kind": "lake", "name": "bad", "fid": "seven"},
            "geometry": {"type": "Polygon", "coordinates": [lake_square([100.0, 100.0])]}}),
        "property fid must be an integer",
    );
}

/// QGIS writes an integer `fid` on every feature saved from a GeoPackage
/// layer: accepted on every kind, and it changes nothing.
#[test]
fn qgis_fid_is_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (utm([100.0, 100.0]), utm([110.0, 100.0]));
    let features = |fid: bool| {
        let mut lake = json!({"kind": "lake", "name": "pond", "blend_m": 300.0});
        let mut road = json!({"kind": "control_curve", "name": "road", "influence_m": 2000.0});
        let mut sec = json!({"kind": "cross_section", "name": "s1", "control_curve": "road"});
        if fid {
            lake["fid"] = json!(1);
            road["fid"] = json!(2);
            sec["fid"] = json!(3);
        }
        let (c, d) = (utm([105.0, 97.0]), utm([105.0, 103.0]));
        collection(
            vec![
                json!({"type": "Feature", "properties": lake,
                    "geometry": {"type": "Polygon", "coordinates": [lake_square([73.0, 33.0])]}}),
                json!({"type": "Feature", "properties": road,
                    "geometry": {"type": "LineString", "coordinates": [[a[0], a[1], 1500.0], [b[0], b[1], 1500.0]]}}),
                json!({"type": "Feature", "properties": sec,
                    "geometry": {"type": "LineString", "coordinates": [[c[0], c[1], 1510.0], [d[0], d[1], 1490.0]]}}),
            ],
            Some(32632),
        )
    };
    let mut outs = Vec::new();
    // A copy of the DEM: the shared fixture's edit lock, held by these
    // corrections, would make the other tests' one-line errors wait.
    let dem = tmp.path().join("dem.tif");
    std::fs::copy(fixture(DEM), &dem).unwrap();
    for fid in [false, true] {
        let f = tmp.path().join(format!("f{fid}.geojson"));
        std::fs::write(&f, features(fid)).unwrap();
        let out = tmp.path().join(format!("o{fid}.tif"));
        correct_support::correct_succeeds(&dem, &f, &out, &[]);
        outs.push(Raster::read(&out));
    }
    let bits = |r: &Raster| r.v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&outs[0]), bits(&outs[1]), "fid changed the result");
}
