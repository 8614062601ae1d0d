//! A short, nearly straight stroke drawn just over a near silhouette
//! (issue 11, known change). The sketch is the fidelity suite's hold-out 4
//! case "Zion 90 m new hill, hand style": stroke `s1` (eight points, 45 px
//! wide, within 0.9 px of its chord) outlines the near part of a new hill,
//! 447 to 465 m from the eye, where one DEM cell spans about 110 px. The
//! rule that sends a stroke finer than a cell behind its silhouette (the
//! DEM could not draw its shape there) moved it to 1,141 m, behind the
//! hill the other stroke raises: hidden, fit 0.00. A stroke straight
//! within the fit's tolerance is drawn by one cell's edge, however wide:
//! it stays at its feature's depth.

mod common;

use common::edit_fidelity_case;

#[test]
fn a_straight_stroke_finer_than_a_cell_stays_on_its_silhouette() {
    let case = edit_fidelity_case(
        "zion_srtm90m_epsg4326.tif",
        "holdout4_zion90m_new_hill_hand.json",
    );
    let s = &case.report["views"][0]["strokes"][1];
    assert_eq!(s["id"], "s1");
    assert_eq!(
        s["placement"]["behind"].as_u64(),
        Some(0),
        "{}",
        s["placement"]
    );
    let depths = &s["match"]["depth_m"];
    for d in [&depths[0], &depths[1]] {
        let d = d.as_f64().expect("depth");
        // the truth's silhouette lies 447 - 465 m away
        assert!((400.0..=520.0).contains(&d), "placed at {d:.0} m");
    }
    let visible = s["visible_fraction"].as_f64().expect("visible fraction");
    assert!(visible >= 0.5, "visible {visible}");
}
