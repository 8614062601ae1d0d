//! A stroke drawn over a gap in the nearer landform (issue 11, the depth a
//! person means). The sketch is the fidelity suite's tuned case "Vinschgau
//! new hill, long style": one stroke traced by the judge's renderer along
//! the whole skyline of the truth DEM, where a hill of +174 m was added on
//! a ridge 7.4-7.9 km away. Over the hill the unedited skyline is that
//! ridge, except where two gaps in it show a range 27 km away. The stroke
//! runs in the sky over both; the stretch was kept at the matched
//! skyline's depth column by column, so its points over the gaps went to
//! 27 km, and what the edit kept of it (the plain match, placed between
//! the stretch's anchors at up to 8.5 km) raised the valley behind the
//! ridge by up to 712 m. Now the points over the gaps take the depth of
//! the nearer landform on both sides of them (`bridge_farther_gaps`).

mod common;

use common::edit_fidelity_case;

#[test]
fn a_stroke_over_a_gap_in_a_nearer_ridge_raises_that_ridge() {
    let case = edit_fidelity_case(
        "vinschgau_250m_utm32n.tif",
        "tuned_vinschgau_new_hill_long.json",
    );
    let r = &case.report;
    let s = &r["views"][0]["strokes"][0];
    let fit = s["fit"]["fitted_fraction"].as_f64().expect("fit");
    assert!(fit >= 0.95, "fit {fit}");
    // The truth's silhouette lies 5.3-8.3 km away along the stroke.
    let far = s["match"]["depth_m"][1].as_f64().expect("depth");
    assert!(far < 9_000.0, "placed up to {far:.0} m");
    // The hill is +174 m; the wall in the valley behind the ridge was
    // +712 m.
    let dz = r["max_abs_displacement_m"].as_f64().expect("displacement");
    assert!(dz < 450.0, "largest change {dz:.0} m");
}
