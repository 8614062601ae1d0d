//! The passes' own near misses (issue 11, known change fit >= 0.95): a
//! later pass anchors a stroke's short gaps by the looser tolerance a hand
//! tracing an existing silhouette needs only on boundaries the view as
//! drawn on showed there too, so the 1-3 px near misses the passes before
//! left are placed again, not held; and the output is still its own fixed
//! point. The sketch is the fidelity suite's tuned case "Arenal peak
//! raised, hand style" (strokes traced by the judge's renderer on the truth
//! DEM, a Gaussian of +60 m on a peak 1.5 km away): the passes anchored
//! stroke s1's last near misses (1.0-1.3 px) as traced, and left it fitted
//! at 0.938.

mod common;

use common::{fixture, gdal_values, suite_edit};
use serde_json::Value;

/// `edit` of `input` with the sketch into `out` (and its report).
fn edit(input: &std::path::Path, out: &std::path::Path, report: &std::path::Path) {
    let sketch = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/tuned_arenal_peak_raised_hand.json");
    suite_edit(input, &sketch, out, Some(report));
}

#[test]
fn later_passes_fit_their_own_near_misses_and_stay_a_fixed_point() {
    let tmp = tempfile::tempdir().expect("temporary directory");
    let dem = fixture("arenal_aster30m_epsg4326.tif");
    let (first, second) = (tmp.path().join("first.tif"), tmp.path().join("second.tif"));
    let report = tmp.path().join("report.json");
    edit(&dem, &first, &report);
    let r: Value =
        serde_json::from_slice(&std::fs::read(&report).expect("report")).expect("report JSON");
    let fits: Vec<f64> = r["views"][0]["strokes"]
        .as_array()
        .expect("strokes")
        .iter()
        .map(|s| s["fit"]["fitted_fraction"].as_f64().expect("fit"))
        .collect();
    assert!(
        fits.iter().all(|&f| f >= 0.95),
        "every stroke fitted: {fits:?}"
    );
    edit(&first, &second, &tmp.path().join("report2.json"));
    let (_, _, a, nodata) = gdal_values(&first);
    let (_, _, b, _) = gdal_values(&second);
    let again = a
        .iter()
        .zip(&b)
        .filter(|(p, q)| Some(**p) != nodata && Some(**q) != nodata)
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max);
    assert!(
        again <= 0.5,
        "editing the output again moved a cell by {again} m"
    );
}
