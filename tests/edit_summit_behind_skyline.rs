//! A stroke that rises out of the outline under it and falls back into it
//! (issue 11, known change; `edit::tangent_rise`).
//!
//! Hold-out 1's Texas 90 m raised peak (dense): a summit 2.2 - 2.3 km away,
//! hidden before the edit behind a flat skyline 200 - 390 m away, that the
//! +50 m raise lifts 9 px over it. The stroke leaves that skyline and comes
//! back to it within the pixel at both ends; the skyline has no summit of
//! its own under the stroke's bump (it only climbs across it). Main matched
//! the near skyline (212 - 308 m, a 5 m change nobody asked for): the
//! occluder is always the cheaper match for a stroke drawn over it. The
//! stroke is now matched behind it, on the drawing plane through the hidden
//! ridge's point under its top (placed 2.28 - 2.33 km).
//!
//! Hold-out 3's NZ 1 km raised peak (dense) rises out of an outline that
//! peaks under the stroke's bump, in the same place: that outline's own
//! summit raised is the reading, and the stroke stays on it (33.8 -
//! 34.6 km; the truth 33.75 - 34.75 km).

mod common;

use common::edit_fidelity_case;

fn depths(report: &serde_json::Value) -> Vec<f64> {
    report["views"][0]["strokes"][0]["match"]["depth_m"]
        .as_array()
        .expect("depths")
        .iter()
        .filter_map(|d| d.as_f64())
        .collect()
}

fn fit(report: &serde_json::Value) -> f64 {
    report["views"][0]["strokes"][0]["fit"]["fitted_fraction"]
        .as_f64()
        .expect("fit")
}

#[test]
fn a_summit_rising_over_a_flat_near_skyline_is_placed_behind_it() {
    let case = edit_fidelity_case(
        "texas_srtm90m_tiled_int16.tif",
        "holdout1_texas_peak_raised_dense.json",
    );
    let d = depths(&case.report);
    assert!(
        d.iter().all(|&d| (1900.0..=2650.0).contains(&d)),
        "placed at {d:?} m (the summit's outline is 2.2 - 2.3 km away)"
    );
    assert!(fit(&case.report) >= 0.95, "fit {}", fit(&case.report));
}

#[test]
fn a_stroke_over_its_outlines_own_summit_stays_on_it() {
    let case = edit_fidelity_case(
        "nz_1km_nan_nodata.tif",
        "holdout3_nz_peak_raised_dense.json",
    );
    let d = depths(&case.report);
    assert!(
        d.iter()
            .all(|&d| (33750.0 * 0.85..=34750.0 * 1.15).contains(&d)),
        "placed at {d:?} m (the raised summit's outline is 33.75 - 34.75 km away)"
    );
}
