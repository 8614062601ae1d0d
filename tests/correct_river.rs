//! Rivers on a real DEM: the floor of the upper Vinschgau valley (the
//! Etsch/Adige, south from the Malser Haide, then east) in `fixtures/vinschgau_250m_utm32n.tif`,
//! drawn as a 1250 m wide centreline in the DEM's CRS (legacy `crs`
//! member). Checked with GDAL: along the centreline the water surface
//! never rises downstream; across it (bilinear along the normals of the
//! straight reaches) flat within 1 cm; the line's order and `flow: "auto"`
//! on the reversed line give the same surface.

mod common;
mod correct_support;

use std::path::{Path, PathBuf};

use common::fixture;
use correct_support::{collection, correct_ok, Raster};
use serde_json::{json, Value};

const DEM: &str = "vinschgau_250m_utm32n.tif";
const WIDTH_M: f64 = 1250.0;
/// Pixel-space centreline, upstream first (the valley floor's lowest cells).
const LINE_PX: [[f64; 2]; 7] = [
    [86.5, 91.5],
    [87.5, 100.5],
    [91.5, 108.5],
    [100.5, 113.5],
    [115.5, 114.5],
    [128.5, 115.5],
    [140.5, 114.5],
];

fn run_river(tmp: &Path, name: &str, line: &[[f64; 2]], flow: &str) -> (PathBuf, Value) {
    run_river_with(tmp, name, line, json!({"flow": flow}))
}

/// As [`run_river`] with `extra` properties (the direction's).
fn run_river_with(tmp: &Path, name: &str, line: &[[f64; 2]], extra: Value) -> (PathBuf, Value) {
    let input = Raster::read(&fixture(DEM));
    let coords: Vec<[f64; 2]> = line.iter().map(|&p| input.crs(p)).collect();
    let mut props = json!({"kind": "river", "name": "etsch", "width_m": WIDTH_M});
    for (k, v) in extra.as_object().unwrap() {
        props[k] = v.clone();
    }
    let fc = collection(
        vec![json!({"type": "Feature",
            "properties": props,
            "geometry": {"type": "LineString", "coordinates": coords}})],
        Some(32632),
    );
    let features = tmp.join(format!("{name}.geojson"));
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (
        tmp.join(format!("{name}.tif")),
        tmp.join(format!("{name}.json")),
    );
    let r = correct_ok(&fixture(DEM), &features, &out, &rep);
    (out, r)
}

#[test]
fn valley_river_is_flat_across_and_never_rises_downstream() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, r) = run_river(tmp.path(), "line", &LINE_PX, "line");
    let f = &r["corrections"][0];
    assert_eq!(f["kind"], "river");
    assert_eq!(f["reversed"], false);
    let (s0, s1) = (
        f["surface_start_m"].as_f64().unwrap(),
        f["surface_end_m"].as_f64().unwrap(),
    );
    assert!(s0 >= s1, "surface {s0} -> {s1}");
    let output = Raster::read(&out);
    let cell = output.gt[1];

    // Downstream: the cell under each station, in order, never rises.
    let mut last = f64::INFINITY;
    let mut worst_rise = 0f64;
    let mut stations = 0;
    for seg in LINE_PX.windows(2) {
        for k in 0..200 {
            let t = k as f64 / 200.0;
            let p = [
                seg[0][0] + t * (seg[1][0] - seg[0][0]),
                seg[0][1] + t * (seg[1][1] - seg[0][1]),
            ];
            let v = output.at(p[0] as usize, p[1] as usize);
            worst_rise = worst_rise.max(v - last);
            last = v;
            stations += 1;
        }
    }
    println!("{stations} stations, largest rise downstream {worst_rise} m");
    assert!(
        worst_rise <= 0.0,
        "the surface rises by {worst_rise} m downstream"
    );

    // Across: bilinear along the normals of the segments (every twentieth
    // of each, ends included) and through every bend (both normals and the
    // bisector at the vertex), within half the width less 1.5 cells of the
    // centreline, at sections more than 1.5 cells from a kink of the
    // surface profile (the report's knots: the surface is linear in the arc
    // length between them, level through the bends).
    let knots: Vec<f64> = f["surface_knots_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k[0].as_f64().unwrap())
        .collect();
    assert!(knots.len() >= 2);
    let reach = (0.5 * WIDTH_M - 1.5 * cell) / cell;
    let fl = correct_support::flatness(&output, &LINE_PX, &knots, reach, 1.5 * cell);
    println!("{} knots; {fl:?}", knots.len());
    assert!(fl.normal_count >= 40 && fl.bend_count >= 9, "{fl:?}");
    assert!(fl.normal_worst <= 0.01, "not flat across: {fl:?}");
    assert!(fl.bend_worst <= 0.01, "not flat across the bends: {fl:?}");
}

/// A synthetic tight bend: a plane falling 2 cm/m east and 3 cm/m south
/// (10 m cells), a 200 m wide river east then, with a right angle, south,
/// then turning 45 degrees south-west. Before the bends were level, the
/// inner bank of the right angle took heights from cross-sections 200 m
/// apart (a 5 m spread across).
#[test]
fn tight_bend_is_flat_across_and_never_rises() {
    let tmp = tempfile::tempdir().unwrap();
    let (w, h) = (200usize, 200usize);
    let gt = [600000.0, 10.0, 0.0, 5200000.0, 0.0, -10.0];
    let data: Vec<f32> = (0..w * h)
        .map(|i| {
            let (c, r) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
            (1000.0 - 0.2 * c - 0.3 * r) as f32
        })
        .collect();
    let dem = tmp.path().join("plane.tif");
    correct_support::write_f32_geotiff(&dem, w, h, gt, 32632, &data);
    let line: [[f64; 2]; 4] = [[20.5, 40.5], [120.5, 40.5], [120.5, 120.5], [70.5, 170.5]];
    let input = Raster::read(&dem);
    let coords: Vec<[f64; 2]> = line.iter().map(|&p| input.crs(p)).collect();
    let fc = collection(
        vec![json!({"type": "Feature",
            "properties": {"kind": "river", "name": "bend", "width_m": 200.0},
            "geometry": {"type": "LineString", "coordinates": coords}})],
        Some(32632),
    );
    let features = tmp.path().join("bend.geojson");
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (tmp.path().join("bend.tif"), tmp.path().join("bend.json"));
    let r = correct_ok(&dem, &features, &out, &rep);
    let f = &r["corrections"][0];
    let knots: Vec<[f64; 2]> = f["surface_knots_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| [k[0].as_f64().unwrap(), k[1].as_f64().unwrap()])
        .collect();
    let output = Raster::read(&out);
    // Never rises: along the knots and along the centreline, cell by cell.
    assert!(knots.windows(2).all(|k| k[1][1] <= k[0][1]), "{knots:?}");
    let mut last = f64::INFINITY;
    for seg in line.windows(2) {
        for k in 0..400 {
            let t = k as f64 / 400.0;
            let p = [
                seg[0][0] + t * (seg[1][0] - seg[0][0]),
                seg[0][1] + t * (seg[1][1] - seg[0][1]),
            ];
            let v = output.at(p[0] as usize, p[1] as usize);
            assert!(v <= last, "rises downstream at {p:?}: {last} -> {v}");
            last = v;
        }
    }
    let s: Vec<f64> = knots.iter().map(|k| k[0]).collect();
    let fl = correct_support::flatness(&output, &line, &s, (100.0 - 15.0) / 10.0, 15.0);
    println!("tight bend: {} knots; {fl:?}", knots.len());
    assert!(fl.normal_count >= 30 && fl.bend_count >= 6, "{fl:?}");
    assert!(fl.normal_worst <= 0.01, "not flat across: {fl:?}");
    assert!(fl.bend_worst <= 0.01, "not flat across the bends: {fl:?}");
    // The water still falls: the outlet is lower than the source by most
    // of the plane's fall along the line.
    let drop = f["surface_start_m"].as_f64().unwrap() - f["surface_end_m"].as_f64().unwrap();
    assert!(drop > 20.0, "drop {drop} m");
}

#[test]
fn flow_auto_finds_the_outlet_of_a_reversed_line() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = run_river(tmp.path(), "line", &LINE_PX, "line");
    let mut rev = LINE_PX.to_vec();
    rev.reverse();
    let (b, r) = run_river(tmp.path(), "auto", &rev, "auto");
    assert_eq!(r["corrections"][0]["reversed"], true);
    let (a, b) = (Raster::read(&a), Raster::read(&b));
    let differ =
        a.v.iter()
            .zip(&b.v)
            .filter(|(x, y)| (*x - *y).abs() > 1e-3)
            .count();
    assert_eq!(
        differ, 0,
        "{differ} cells differ between line order and flow auto"
    );
}

/// DESIGN.md's `downstream`: `"end"`/`true` keep the line's order,
/// `"start"`/`false` reverse it, and without it (nor `flow`) the heights
/// decide; all four give the line-order surface on the line drawn the
/// matching way.
#[test]
fn downstream_names_the_outlet_and_without_it_the_heights_decide() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = run_river(tmp.path(), "line", &LINE_PX, "line");
    let a = Raster::read(&a);
    let mut rev = LINE_PX.to_vec();
    rev.reverse();
    let cases = [
        ("end", &LINE_PX[..], json!({"downstream": "end"}), false),
        ("true", &LINE_PX[..], json!({"downstream": true}), false),
        ("start", &rev[..], json!({"downstream": "start"}), true),
        ("false", &rev[..], json!({"downstream": false}), true),
        ("absent", &rev[..], json!({}), true),
    ];
    for (name, line, props, reversed) in cases {
        let (b, r) = run_river_with(tmp.path(), name, line, props);
        assert_eq!(r["corrections"][0]["reversed"], reversed, "{name}");
        let b = Raster::read(&b);
        let differ =
            a.v.iter()
                .zip(&b.v)
                .filter(|(x, y)| (*x - *y).abs() > 1e-3)
                .count();
        assert_eq!(differ, 0, "downstream {name}: {differ} cells differ");
    }
    // The line drawn upstream with downstream "end" is taken at its word:
    // the surface differs (it never rises toward the line's end).
    let (c, r) = run_river_with(tmp.path(), "wrong", &rev, json!({"downstream": "end"}));
    assert_eq!(r["corrections"][0]["reversed"], false);
    let c = Raster::read(&c);
    assert!(a.v.iter().zip(&c.v).any(|(x, y)| (x - y).abs() > 1.0));
}

#[test]
fn river_polygon_reach_is_flat_across_its_axis_and_monotonic() {
    // A straight east-west reach of the valley floor as a rectangle (its
    // principal axis is the row direction), lon/lat as QGIS writes it.
    let tmp = tempfile::tempdir().unwrap();
    let input = Raster::read(&fixture(DEM));
    let px = [
        [102.0, 110.5],
        [126.0, 110.5],
        [126.0, 115.5],
        [102.0, 115.5],
        [102.0, 110.5],
    ];
    let utm: Vec<[f64; 2]> = px.iter().map(|&p| input.crs(p)).collect();
    let ll = correct_support::to_lonlat(32632, &utm);
    let fc = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "river", "name": "reach"},
            "geometry": {"type": "Polygon", "coordinates": [ll]}}),
        ],
        None,
    );
    let features = tmp.path().join("reach.geojson");
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (tmp.path().join("reach.tif"), tmp.path().join("reach.json"));
    let r = correct_ok(&fixture(DEM), &features, &out, &rep);
    let f = &r["corrections"][0];
    assert_eq!(f["kind"], "river");
    let reversed = f["reversed"].as_bool().unwrap();
    let output = Raster::read(&out);
    // Cells inside: columns 102..126, rows 111..115 (centres inside).
    let mut columns = Vec::new();
    let mut worst_across = 0f64;
    for c in 102..126 {
        let v: Vec<f64> = (111..115).map(|r| output.at(c, r)).collect();
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        worst_across = worst_across.max(hi - lo);
        columns.push(v[0]);
    }
    if reversed {
        columns.reverse();
    }
    let rise = columns
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::NEG_INFINITY, f64::max);
    println!("polygon reach: spread across {worst_across} m, largest rise downstream {rise} m, reversed {reversed}");
    assert!(worst_across <= 0.01, "not flat across: {worst_across} m");
    assert!(rise <= 0.0, "rises downstream by {rise} m");
    assert!(f["surface_start_m"].as_f64() >= f["surface_end_m"].as_f64());
}
