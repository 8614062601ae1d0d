//! Seams: corrections across tile corners on a 4 x 4 tile set of
//! `fixtures/vinschgau_250m_utm32n.tif` (split with `gdal_translate
//! -srcwin`) give the single-file result within 1e-3 m: a lake over the
//! corner at (126, 97), a control curve through (63, 48) and a river
//! across (189, 145). The tiled output is read back through a VRT
//! (`gdalbuildvrt`).

mod common;
mod correct_support;

use common::{demsketch, fixture};
use correct_support::{collection, split, vrt_of_tiles, Raster};
use serde_json::json;

const DEM: &str = "vinschgau_250m_utm32n.tif";

#[test]
fn corrections_across_tile_corners_equal_the_single_file_result() {
    let tmp = tempfile::tempdir().unwrap();
    let input = Raster::read(&fixture(DEM));
    let at = |p: [f64; 2]| input.crs(p);
    let lake: Vec<[f64; 2]> = [
        [122.0, 93.0],
        [131.0, 94.0],
        [130.0, 102.0],
        [121.0, 101.0],
        [122.0, 93.0],
    ]
    .iter()
    .map(|&p| at(p))
    .collect();
    let curve: Vec<[f64; 3]> = [[55.3, 43.2], [63.0, 48.0], [71.6, 54.9]]
        .iter()
        .map(|&p| {
            let c = at(p);
            [c[0], c[1], input.bilinear(p).unwrap() + 20.0]
        })
        .collect();
    let river: Vec<[f64; 2]> = [[180.5, 139.5], [189.0, 145.0], [199.5, 152.5]]
        .iter()
        .map(|&p| at(p))
        .collect();
    let fc = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "lake", "name": "corner_lake"},
                "geometry": {"type": "Polygon", "coordinates": [lake]}}),
            json!({"type": "Feature", "properties": {"kind": "control_curve", "name": "corner_curve", "influence_m": 1500.0},
                "geometry": {"type": "LineString", "coordinates": curve}}),
            json!({"type": "Feature", "properties": {"kind": "river", "name": "corner_river", "width_m": 750.0, "flow": "auto"},
                "geometry": {"type": "LineString", "coordinates": river}}),
        ],
        Some(32632),
    );
    let features = tmp.path().join("corners.geojson");
    std::fs::write(&features, fc).unwrap();
    let f = features.to_string_lossy().into_owned();

    let single = tmp.path().join("single.tif");
    let o = demsketch(&[
        "correct",
        &fixture(DEM).to_string_lossy(),
        "--features",
        &f,
        "--out",
        &single.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let tiles = tmp.path().join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    split(&fixture(DEM), &tiles, 4);
    let out = tmp.path().join("out_tiles");
    let o = demsketch(&[
        "correct",
        &tiles.to_string_lossy(),
        "--features",
        &f,
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let vrt = tmp.path().join("tiles.vrt");
    assert_eq!(vrt_of_tiles(&out, &vrt), 16);

    let (a, b) = (Raster::read(&single), Raster::read(&vrt));
    assert_eq!((a.w, a.h), (b.w, b.h));
    let mut worst = 0f64;
    let mut changed = 0;
    for i in 0..a.v.len() {
        if a.v[i].is_nan() || b.v[i].is_nan() {
            assert!(a.v[i].is_nan() && b.v[i].is_nan(), "nodata differs at {i}");
            continue;
        }
        worst = worst.max((a.v[i] - b.v[i]).abs());
        if a.v[i].to_bits() != input.v[i].to_bits() {
            changed += 1;
        }
    }
    println!("{changed} cells changed; tiled vs single file: max |diff| {worst} m");
    assert!(changed > 100);
    assert!(
        worst <= 1e-3,
        "tiled and single-file results differ by {worst} m"
    );
}
