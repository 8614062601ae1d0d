//! No stroke point is placed beyond the view distance (`--max-distance`).
//! The sketch is the fidelity suite's hold-out 4 case "NZ 1 km new hill,
//! dense style": a hill drawn 13 px over a skyline whose left pieces lie
//! 40 - 50 km away. A later pass used to place the stroke's free columns
//! on a drawing plane out to 52 km, beyond the 50 km the edit (and its
//! renders) read: the change stood where the view shows no terrain. A
//! view shows nothing beyond its distance, so what is drawn in it stands
//! within it: such points are put at the view distance on their rays and
//! the report's notes say so.

mod common;

use common::edit_fidelity_case;

#[test]
fn placed_points_stay_within_the_view_distance() {
    let case = edit_fidelity_case("nz_1km_nan_nodata.tif", "holdout4_nz_new_hill_dense.json");
    let r = &case.report;
    let s = &r["views"][0]["strokes"][0];
    let far = s["match"]["depth_m"][1].as_f64().expect("depth");
    // The suite's edit reads out to --max-distance 50000.
    assert!(far <= 50_000.0 + 1e-6, "placed out to {far:.0} m");
    let notes = r["notes"].as_array().expect("notes");
    assert!(
        notes.iter().any(|n| n
            .as_str()
            .is_some_and(|n| n.contains("beyond --max-distance"))),
        "the report says the placement was pulled back: {notes:?}"
    );
}
