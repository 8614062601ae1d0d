//! A stroke that touches another landform's silhouette for a point or two
//! crosses it; it does not follow it (Tassé et al. section 5.2.3: a stroke
//! is one feature, each point at that feature's depth). Anchoring
//! (`edit::on_silhouette`, `crossings`) cuts an anchored run where
//! neighbouring points' depths differ by more than 15 %; a piece narrower
//! than `MIN_RUN_PX` beside a wide one is interpolated between its
//! neighbours or, at the run's edge beside a free stretch, freed.
//!
//! The stroke is the fidelity suite's tuned case "Zion UTM ridge cut"
//! (hand style): a ridge cut 2.2-3.2 km from the eye. The jittered stroke
//! comes within a pixel of a foreground crest 68 m away at x 452.5, the
//! first point of the anchored run on the ridge's right part; before, that
//! point was held on the foreground and the report placed the stroke from
//! 68 m.

mod common;

use common::OneStrokeCase;

const CASE: OneStrokeCase = OneStrokeCase {
    dem: "zion_srtm_utm12n.tif",
    viewpoint: [-113.03928539810016, 37.43633002564174, 2490.18],
    heading_deg: 225.5251,
    points: &[
        [314.5, 147.86],
        [337.22, 145.27],
        [358.2, 145.25],
        [403.4, 147.49],
        [416.33, 145.9],
        [428.52, 145.49],
        [443.78, 149.1],
        [454.81, 150.81],
        [481.8, 146.08],
    ],
    influence_m: None,
    extra: &["--max-distance", "50000"],
};

#[test]
fn a_stroke_touching_a_foreground_crest_stays_on_its_ridge() {
    let e = CASE.edit();
    let (lo, hi) = e.depth_m();
    // The ridge's true outline lies 2.23-3.24 km away.
    assert!(lo > 1900.0 && hi < 3700.0, "placed {lo:.0}-{hi:.0} m");
    let fit = e.fitted_fraction();
    assert!(fit >= 0.95, "fit {fit}");
}
