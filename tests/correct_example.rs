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
