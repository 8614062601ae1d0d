//! A stroke drawn in the sky just over a near silhouette, narrower than one
//! DEM cell at that silhouette's depth (issue 11, item 3: the depth a
//! person means): the DEM cannot draw it there, so it is a landform behind
//! the silhouette showing over it, placed at the nearest depth where it
//! spans one cell (`edit::stretch_placement::drawable_depth_behind`).
//!
//! The stroke is the fidelity suite's tuned case "Zion 90 m new hill"
//! (dense style): a hill raised 2.05 km from the eye, traced 1.6 px over a
//! slope 0.5 km away; before, the stroke was matched to that slope, where
//! it spans 0.2 cells, and the edit changed nothing (fit 0.28).

mod common;

use common::OneStrokeCase;
use serde_json::json;

const CASE: OneStrokeCase = OneStrokeCase {
    dem: "zion_srtm90m_epsg4326.tif",
    viewpoint: [-113.14580110243843, 37.2364721722352, 1217.175],
    heading_deg: 186.2937,
    points: &[
        [348.5, 84.815],
        [351.5, 86.107],
        [354.5, 87.385],
        [357.5, 88.656],
        [360.5, 89.936],
        [363.5, 92.122],
        [366.5, 94.343],
        [369.5, 96.572],
        [372.5, 98.779],
    ],
    influence_m: None,
    extra: &[],
};

#[test]
fn a_stroke_finer_than_the_dem_over_a_near_silhouette_goes_behind_it() {
    let e = CASE.edit();
    let (r, s) = (e.report(), e.stroke());
    // (the stroke is resampled: count the points, not the input's nine)
    assert!(s["placement"]["behind"].as_u64().unwrap() >= 9, "{s}");
    assert_eq!(s["placement"]["feature"], json!(0), "{s}");
    let (lo, hi) = e.depth_m();
    // One cell (92 m) spans the stroke's 24 px at 2.1 km; the hill is at
    // 2.05 km, the slope it was matched to at 0.47-0.53 km.
    assert!(lo > 1900.0 && hi < 2400.0, "placed at {lo:.0}-{hi:.0} m");
    assert!(r["changed_cells"].as_u64().unwrap() > 0);
    let fit = e.fitted_fraction();
    assert!(fit >= 0.9, "fit {fit}");
}
