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

use common::{demsketch, fixture};
use correct_support::{collection, report, Raster};
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
    let input = Raster::read(&fixture(DEM));
    let coords: Vec<[f64; 2]> = line.iter().map(|&p| input.crs(p)).collect();
    let fc = collection(
        vec![json!({"type": "Feature",
            "properties": {"kind": "river", "name": "etsch", "width_m": WIDTH_M, "flow": flow},
            "geometry": {"type": "LineString", "coordinates": coords}})],
        Some(32632),
    );
    let features = tmp.join(format!("{name}.geojson"));
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (
        tmp.join(format!("{name}.tif")),
        tmp.join(format!("{name}.json")),
    );
    let o = demsketch(&[
        "correct",
        &fixture(DEM).to_string_lossy(),
        "--features",
        &features.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--report",
        &rep.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (out, report(&rep))
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

    // Across: bilinear along the normal of each straight reach, within
    // half the width less 1.5 cells of the centreline, at cross-sections
    // more than 1.5 cells from a bend of the surface profile (the report's
    // knots; the surface is linear in the arc length between them).
    let knots: Vec<f64> = f["surface_knots_m"]
        .as_array()
        .unwrap()
        .iter()
        .map(|k| k[0].as_f64().unwrap())
        .collect();
    assert!(knots.len() >= 2);
    let reach = 0.5 * WIDTH_M - 1.5 * cell;
    let (mut worst_across, mut worst_near_knots, mut sections) = (0f64, 0f64, 0);
    let mut s0 = 0.0;
    for seg in LINE_PX.windows(2) {
        let (dx, dy) = (seg[1][0] - seg[0][0], seg[1][1] - seg[0][1]);
        let len = dx.hypot(dy);
        let (nx, ny) = (-dy / len, dx / len);
        for k in 5..=15 {
            let t = k as f64 / 20.0;
            let c = [seg[0][0] + t * dx, seg[0][1] + t * dy];
            let vals: Vec<f64> = (-10..=10)
                .filter_map(|j| {
                    let d = j as f64 / 10.0 * reach / cell;
                    output.bilinear([c[0] + nx * d, c[1] + ny * d])
                })
                .collect();
            let (lo, hi) = vals
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                    (a.min(v), b.max(v))
                });
            let s = s0 + t * len * cell;
            if knots.iter().all(|k| (k - s).abs() > 1.5 * cell) {
                worst_across = worst_across.max(hi - lo);
                sections += 1;
            } else {
                worst_near_knots = worst_near_knots.max(hi - lo);
            }
        }
        s0 += len * cell;
    }
    println!(
        "{} knots; largest spread across {worst_across} m over {sections} sections; {worst_near_knots} m near knots",
        knots.len()
    );
    assert!(sections >= 20);
    assert!(worst_across <= 0.01, "not flat across: {worst_across} m");
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
    let o = demsketch(&[
        "correct",
        &fixture(DEM).to_string_lossy(),
        "--features",
        &features.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--report",
        &rep.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = report(&rep);
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
