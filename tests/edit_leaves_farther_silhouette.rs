//! A stroke that goes on from an existing silhouette into the sky, over a
//! nearer feature that does not run along that silhouette, outlines the
//! landform it leaves (`edit::stretch_placement`,
//! `leaves_farther_silhouette`). Before, the free stretch was kept on the
//! nearer feature because that feature lay near it in the image (it needs
//! the least lift there), and the stroke's own anchor was ignored.
//!
//! The stroke is the fidelity suite's tuned case "NZ 1 km peak raised"
//! (dense style): a peak raised 29.5-34.5 km from the eye. Its right end
//! lies on the 29.5-30 km ridge's silhouette; its free left part, 2 to 6 px
//! over a ridge 21-23 km away, was placed on that ridge (21.1-22.6 km; the
//! judge's depth ratio 0.64, fit 0.76, and the rounds then raised a valley
//! behind that ridge by 925 m). Now it goes on the drawing plane through
//! the anchor, at 29.5 km.

mod common;

use common::OneStrokeCase;

const CASE: OneStrokeCase = OneStrokeCase {
    dem: "nz_1km_nan_nodata.tif",
    viewpoint: [172.3790191741533, -41.850561994491294, 667.795],
    heading_deg: 119.5159,
    points: &[
        [412.50, 153.44],
        [415.50, 152.40],
        [418.50, 151.36],
        [421.50, 150.30],
        [424.50, 149.68],
        [427.50, 150.07],
        [430.50, 150.52],
        [433.50, 150.90],
        [436.50, 151.35],
        [439.50, 151.80],
        [442.50, 152.24],
        [445.50, 152.69],
        [448.50, 153.15],
        [451.50, 154.21],
        [454.50, 155.52],
        [457.50, 156.72],
        [460.50, 156.31],
        [463.50, 156.06],
        [466.50, 155.82],
        [469.50, 155.62],
        [472.50, 155.35],
        [474.50, 155.48],
    ],
    // The suite's influence on the 1 km DEM: six cells.
    influence_m: Some(6000.0),
    extra: &["--max-distance", "50000"],
};

#[test]
fn a_stroke_leaving_a_farther_silhouette_into_the_sky_stays_on_its_landform() {
    let e = CASE.edit();
    let s = e.stroke();
    // The free stretch goes on the drawing plane through the anchor, not
    // on the nearer ridge.
    let placement = &s["placement"];
    assert_eq!(placement["feature"].as_u64(), Some(0), "{s}");
    assert!(placement["drawing_plane"].as_u64().unwrap() >= 20, "{s}");
    let (_, hi) = e.depth_m();
    assert!(hi > 29000.0 && hi < 35000.0, "placed up to {hi:.0} m");
    let fit = e.fitted_fraction();
    assert!(fit >= 0.9, "fit {fit}");
}
