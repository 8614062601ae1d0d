//! A new hill whose stroke ends on far ground (issue 11, known change).
//! The sketch is the fidelity suite's hold-out 4 case "Vinschgau 250 m new
//! hill, long style": one stroke over a hill of +175 m 2.6 - 3.6 km away.
//! Its left end stops on a silhouette 3.4 km away (a T-junction, a lower
//! bound on the depth); its right end on the valley floor 13.9 km away,
//! seen past where the hill will be. The stretch used to go on the drawing
//! plane through that ground (Gain et al.'s end rule, through the farther
//! of the two ends), 4.5 - 5.4 times the true depth, and the edit built
//! 2,878 m of terrain. A new landform's end on far ground only says it
//! stands in front of that ground (an upper bound): the stretch keeps its
//! matched feature between the two bounds
//! (`stretch_placement::stands_on_background`), and the later passes do not
//! carry its last points back onto the far ground
//! (`stretch_placement::hold_background_ends`).

mod common;

use common::edit_fidelity_case;

#[test]
fn a_new_hill_ending_on_far_ground_is_no_wall() {
    let case = edit_fidelity_case(
        "vinschgau_250m_utm32n.tif",
        "holdout4_vinschgau_new_hill_long.json",
    );
    let r = &case.report;
    let dz = r["max_abs_displacement_m"].as_f64().expect("displacement");
    assert!(dz <= 400.0, "largest change {dz:.0} m");
    let s = &r["views"][0]["strokes"][0];
    let depths: Vec<f64> = s["match"]["depth_m"]
        .as_array()
        .expect("depths")
        .iter()
        .filter_map(|d| d.as_f64())
        .collect();
    assert!(
        depths.iter().all(|&d| d < 5000.0),
        "placed at {depths:?} m (the hill is 2.6 - 3.6 km away)"
    );
}
