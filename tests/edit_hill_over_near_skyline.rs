//! A hill drawn over a plain's skyline (issue 11, known change). The
//! sketch is the fidelity suite's hold-out 1 case "Texas 90 m new hill,
//! hand style": one stroke of nine points traced by the judge's renderer
//! on the truth DEM, where a hill 2.6 km away rises 14 px over the
//! skyline. From an eye 1.7 m over the plain that skyline is the ground
//! 110 to 125 m away. The stroke matches no feature and both its ends stop
//! on that skyline (T-junctions); it used to stay at the occluder's depth
//! (95 m), where it spans a third of a cell: the edit changed nothing and
//! fitted 0.04. Now it goes behind, to the nearest depth where the DEM's
//! cells can draw its shape (`stretch_placement::behind_occluder`).

mod common;

use common::edit_fidelity_case;

#[test]
fn a_hill_drawn_over_a_near_skyline_goes_behind_it() {
    let case = edit_fidelity_case(
        "texas_srtm90m_tiled_int16.tif",
        "holdout1_texas_new_hill_hand.json",
    );
    let r = &case.report;
    let s = &r["views"][0]["strokes"][0];
    let fit = s["fit"]["fitted_fraction"].as_f64().expect("fit");
    assert!(fit >= 0.95, "fit {fit}");
    let behind = s["placement"]["behind"].as_u64().expect("placement");
    assert!(behind > 0, "{}", s["placement"]);
    // Behind the skyline it stops on, at a depth where it spans cells.
    let depth = s["match"]["depth_m"][0].as_f64().expect("depth");
    assert!(depth > 1000.0, "placed at {depth:.0} m");
    let changed = r["changed_cells"].as_u64().expect("changed cells");
    assert!(changed > 100, "{changed} cells changed");
    let dz = r["max_abs_displacement_m"].as_f64().expect("displacement");
    assert!(dz <= 150.0, "largest change {dz:.0} m");
}
