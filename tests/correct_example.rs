//! The worked example of the user guide (section 9):
//! `fixtures/corrections/vinschgau_example.geojson` on the Vinschgau DEM.
//! The output is a GeoTIFF GDAL reads with the input's grid and a
//! provenance entry; `--dry-run` reports the same and writes no DEM;
//! `--in-place` on a copy changes the same cells.

mod common;
mod correct_support;

use common::{demsketch, fixture, gdalinfo};
use correct_support::{report, Raster};

fn args<'a>(dem: &'a str, features: &'a str, rest: &[&'a str]) -> Vec<&'a str> {
    let mut v = vec!["correct", dem, "--features", features];
    v.extend_from_slice(rest);
    v
}

#[test]
fn worked_example_writes_report_and_dem() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("vinschgau_250m_utm32n.tif")
        .to_string_lossy()
        .into_owned();
    let features = fixture("corrections/vinschgau_example.geojson")
        .to_string_lossy()
        .into_owned();
    let out = tmp.path().join("corrected.tif");
    let rep = tmp.path().join("correct.json");
    let (o_s, r_s) = (
        out.to_string_lossy().into_owned(),
        rep.to_string_lossy().into_owned(),
    );
    let o = demsketch(&args(&dem, &features, &["--out", &o_s, "--report", &r_s]));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = report(&rep);
    let kinds: Vec<&str> = r["corrections"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| f["kind"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["lake", "river", "control_curve"]);
    assert!(r["corrections"][2]["max_curve_error_m"].as_f64().unwrap() <= 0.05);
    let river = &r["corrections"][1];
    assert!(river["surface_start_m"].as_f64() >= river["surface_end_m"].as_f64());
    let info = gdalinfo(&out);
    let src = gdalinfo(&fixture("vinschgau_250m_utm32n.tif"));
    assert_eq!(info["size"], src["size"]);
    assert_eq!(info["geoTransform"], src["geoTransform"]);
    assert!(info
        .to_string()
        .contains("correct vinschgau_example.geojson"));
    let (a, b) = (
        Raster::read(&fixture("vinschgau_250m_utm32n.tif")),
        Raster::read(&out),
    );
    let changed =
        a.v.iter()
            .zip(&b.v)
            .filter(|(x, y)| x.to_bits() != y.to_bits())
            .count();
    assert_eq!(changed as u64, r["changed_cells"].as_u64().unwrap());

    // Dry run: the same count, no DEM.
    let dry = tmp.path().join("dry.tif");
    let rep2 = tmp.path().join("dry.json");
    let (d_s, r2_s) = (
        dry.to_string_lossy().into_owned(),
        rep2.to_string_lossy().into_owned(),
    );
    let o = demsketch(&args(
        &dem,
        &features,
        &["--out", &d_s, "--report", &r2_s, "--dry-run"],
    ));
    assert!(o.status.success());
    assert!(!dry.exists());
    let r2 = report(&rep2);
    assert_eq!(r2["written"], false);
    assert_eq!(r2["changed_cells"], r["changed_cells"]);

    // In place on a copy: the same heights.
    let copy = tmp.path().join("copy.tif");
    std::fs::copy(fixture("vinschgau_250m_utm32n.tif"), &copy).unwrap();
    let c_s = copy.to_string_lossy().into_owned();
    let o = demsketch(&args(&c_s, &features, &["--in-place"]));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let c = Raster::read(&copy);
    assert!(c
        .v
        .iter()
        .zip(&b.v)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn water_mask_marks_the_water_cells() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("vinschgau_250m_utm32n.tif")
        .to_string_lossy()
        .into_owned();
    let features = fixture("corrections/vinschgau_example.geojson")
        .to_string_lossy()
        .into_owned();
    let mask = tmp.path().join("water.tif");
    let rep = tmp.path().join("r.json");
    let out = tmp.path().join("out.tif");
    let (m_s, r_s, o_s) = (
        mask.to_string_lossy().into_owned(),
        rep.to_string_lossy().into_owned(),
        out.to_string_lossy().into_owned(),
    );
    let o = demsketch(&args(
        &dem,
        &features,
        &["--out", &o_s, "--report", &r_s, "--water-mask", &m_s],
    ));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = report(&rep);
    let water: u64 = r["corrections"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|f| f["water_cells"].as_u64())
        .sum();
    let info = gdalinfo(&mask);
    assert_eq!(info["bands"][0]["type"], "Byte");
    let m = Raster::read(&mask);
    let ones = m.v.iter().filter(|&&v| v == 1.0).count() as u64;
    assert_eq!(ones, water);
    // On the DEM's grid: the mask's origin is a DEM cell corner.
    let d = Raster::read(&fixture("vinschgau_250m_utm32n.tif"));
    let w = r["window"].as_array().unwrap();
    let (c0, r0) = (w[0].as_f64().unwrap(), w[1].as_f64().unwrap());
    assert_eq!(m.gt[0], d.gt[0] + c0 * d.gt[1]);
    assert_eq!(m.gt[3], d.gt[3] + r0 * d.gt[5]);
    // Every water cell of the mask holds the corrected DEM's water surface
    // (lake cells at the lake's level).
    let level = r["corrections"][0]["level_m"].as_f64().unwrap();
    let o = Raster::read(&out);
    let at_level = (0..m.h)
        .flat_map(|rr| (0..m.w).map(move |cc| (cc, rr)))
        .filter(|&(cc, rr)| m.at(cc, rr) == 1.0)
        .filter(|&(cc, rr)| (o.at(cc + c0 as usize, rr + r0 as usize) - level).abs() < 0.01)
        .count() as u64;
    assert_eq!(
        at_level,
        r["corrections"][0]["water_cells"].as_u64().unwrap()
    );
}
