//! Strokes drawn on silhouettes the DEM already shows change nothing
//! (issue 11): traced from `demsketch view --features` on real fixtures, in
//! a dense, a hand-like (few points, jitter within a pixel) and a
//! right-to-left style, the edit writes a DEM with no changed cell and
//! reports every stroke on a silhouette; editing that output again changes
//! nothing either. (The independent check, with a second renderer and
//! many more cases, is `tools/fidelity/`; this one guards the mechanism in
//! `cargo test`.)

mod common;

use common::{demsketch, fixture};
use serde_json::{json, Value};
use std::path::Path;

/// A sketch view: viewpoint and camera of the cases.
fn view(lon: f64, lat: f64, heading: f64) -> Value {
    json!({
        "name": "identity",
        "viewpoint": {"lon": lon, "lat": lat, "eye_height_m": 1.7},
        "camera": {"heading_deg": heading, "pitch_deg": 0.0, "roll_deg": 0.0,
                   "hfov_deg": 60.0, "width": 800, "height": 450},
        "strokes": []
    })
}

/// The longest skyline silhouettes `demsketch view` finds, as pixel lists.
fn skylines(dem: &Path, sketch: &Path, dir: &Path) -> Vec<Vec<[f64; 2]>> {
    let feats = dir.join("features.geojson");
    let r = demsketch(&[
        "view",
        dem.to_str().unwrap(),
        "--sketch",
        sketch.to_str().unwrap(),
        "--out",
        dir.join("view.png").to_str().unwrap(),
        "--features",
        feats.to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let fc: Value = serde_json::from_slice(&std::fs::read(&feats).unwrap()).unwrap();
    let mut out: Vec<Vec<[f64; 2]>> = fc["features"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["properties"]["kind"] == "silhouette")
        .filter(|f| f["properties"]["skyline"] == true)
        .map(|f| {
            f["properties"]["pixels"]
                .as_array()
                .unwrap()
                .iter()
                .map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()])
                .collect::<Vec<_>>()
        })
        .filter(|p: &Vec<[f64; 2]>| p.len() >= 40)
        .collect();
    out.sort_by_key(|p| std::cmp::Reverse(p.len()));
    out.truncate(3);
    assert!(!out.is_empty(), "no long skyline silhouette");
    out
}

/// The three drawing styles of a traced silhouette.
fn styles(px: &[[f64; 2]]) -> Vec<(&'static str, Vec<[f64; 2]>)> {
    let dense: Vec<[f64; 2]> = px.iter().step_by(3).copied().collect();
    // Hand-like: 12 points, jitter of up to 0.7 px (deterministic).
    let n = 12.min(px.len());
    let hand: Vec<[f64; 2]> = (0..n)
        .map(|k| {
            let p = px[k * (px.len() - 1) / (n - 1)];
            let jitter = 0.7 * ((k as f64 * 2.399).sin());
            [p[0], p[1] + jitter]
        })
        .collect();
    let mut rtl = dense.clone();
    rtl.reverse();
    vec![("dense", dense), ("hand", hand), ("rtl", rtl)]
}

fn edit(dem: &Path, sketch: &Path, out: &Path, report: &Path) -> Value {
    let r = demsketch(&[
        "edit",
        dem.to_str().unwrap(),
        "--sketch",
        sketch.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--report",
        report.to_str().unwrap(),
    ]);
    assert!(
        r.status.success(),
        "edit failed: {}",
        String::from_utf8_lossy(&r.stderr)
    );
    serde_json::from_slice(&std::fs::read(report).unwrap()).unwrap()
}

fn identity_case(dem_name: &str, lon: f64, lat: f64, heading: f64) {
    let dir = tempfile::tempdir().unwrap();
    let dem = fixture(dem_name);
    let base = json!({"views": [view(lon, lat, heading)], "options": {}});
    let sketch0 = dir.path().join("view.json");
    std::fs::write(&sketch0, base.to_string()).unwrap();
    let traced = skylines(&dem, &sketch0, dir.path());
    for (style, _) in styles(&traced[0]) {
        let mut s = base.clone();
        s["views"][0]["strokes"] = traced
            .iter()
            .enumerate()
            .map(|(k, px)| {
                let pts = styles(px).into_iter().find(|(n, _)| *n == style).unwrap().1;
                json!({"id": format!("s{k}"), "points": pts})
            })
            .collect();
        let sketch = dir.path().join(format!("{style}.json"));
        std::fs::write(&sketch, s.to_string()).unwrap();
        let out = dir.path().join(format!("{style}.tif"));
        let rep = edit(&dem, &sketch, &out, &dir.path().join("r.json"));
        assert_eq!(
            rep["changed_cells"], 0,
            "{dem_name} {style}: strokes on silhouettes changed the DEM: {rep}"
        );
        for st in rep["views"][0]["strokes"].as_array().unwrap() {
            let on = st["on_silhouette"].as_f64().unwrap();
            assert!(on >= 0.95, "{dem_name} {style}: on_silhouette {on}: {st}");
        }
        // Editing the output again with the same sketch changes nothing.
        let again = edit(
            &out,
            &sketch,
            &dir.path().join(format!("{style}2.tif")),
            &dir.path().join("r2.json"),
        );
        assert_eq!(again["changed_cells"], 0, "{dem_name} {style}: re-edit");
    }
}

#[test]
fn strokes_on_the_zion_skyline_change_nothing() {
    identity_case("zion_srtm_utm12n.tif", -112.90, 37.40, 200.0);
}

#[test]
fn strokes_on_the_vinschgau_skyline_change_nothing() {
    identity_case("vinschgau_250m_utm32n.tif", 10.75, 46.63, 90.0);
}
