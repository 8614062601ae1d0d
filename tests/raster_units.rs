//! True heights: a DEM whose values are not plain metres (an Int32
//! decimetre DEM with band scale 0.1, a DEM in feet by its band unit, a DEM
//! in US survey feet by its compound CRS with NAVD88 height (ftUS)) gives
//! the same view and the same edit, in metres, as the original; `info`
//! shows the vertical unit, datum, scale and offset; written files keep
//! scale, offset and unit (checked with `gdalinfo -json`).

mod common;

use std::path::{Path, PathBuf};

use common::*;
use serde_json::Value;

const ZION: &str = "zion_srtm_utm12n.tif";
const US_FOOT: f64 = 1200.0 / 3937.0;

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// One variant of the Zion fixture: how it is made and what it means.
struct Variant {
    name: &'static str,
    /// Metres per stored unit (scale x unit).
    to_metre: f64,
    /// Expected `info --json` vertical fields.
    unit: &'static str,
    unit_source: &'static str,
    datum: Option<&'static str>,
    scale: f64,
}

const VARIANTS: [Variant; 3] = [
    Variant {
        name: "decimetre",
        to_metre: 0.1,
        unit: "metre",
        unit_source: "default",
        datum: None,
        scale: 0.1,
    },
    Variant {
        name: "feet",
        to_metre: 0.3048,
        unit: "ft",
        unit_source: "band",
        datum: None,
        scale: 1.0,
    },
    Variant {
        name: "usfeet_compound",
        to_metre: US_FOOT,
        unit: "US survey foot",
        unit_source: "crs",
        datum: Some("NAVD88 height (ftUS)"),
        scale: 1.0,
    },
];

/// Make the variant from the fixture in `dir` (and a DEFLATE-compressed
/// copy of it, which the write-back re-encodes rather than updates).
fn make(dir: &Path, v: &Variant) -> (PathBuf, PathBuf) {
    let zion = fixture(ZION);
    let out = dir.join(format!("{}.tif", v.name));
    let factor = format!("{}", 1.0 / v.to_metre);
    match v.name {
        "decimetre" => gdal_translate(
            &zion,
            &out,
            &[
                "-ot", "Int32", "-scale", "0", "1", "0", "10", "-a_scale", "0.1",
            ],
        ),
        // Float64: the stored feet are exact, so the heights in metres are
        // the original's to the last bit of f32.
        "feet" => {
            gdal_translate(
                &zion,
                &out,
                &["-ot", "Float64", "-scale", "0", "1", "0", &factor],
            );
            run("gdal_edit.py", &["-units", "ft", &s(&out)]);
        }
        // Float32 as real survey-foot DEMs are.
        _ => gdal_translate(
            &zion,
            &out,
            &[
                "-ot",
                "Float32",
                "-scale",
                "0",
                "1",
                "0",
                &factor,
                "-a_srs",
                "EPSG:32612+6360",
            ],
        ),
    }
    let deflate = dir.join(format!("{}_deflate.tif", v.name));
    gdal_translate(
        &out,
        &deflate,
        &["-co", "COMPRESS=DEFLATE", "-co", "TILED=YES"],
    );
    (out, deflate)
}

fn info_json(path: &Path) -> Value {
    let out = demsketch(&["info", "--json", &s(path)]);
    assert!(
        out.status.success(),
        "info {}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("info --json is JSON")
}

/// Values of band 1 in metres as GDAL reads them (scale, offset applied,
/// then `to_metre`), with the nodata mask.
fn metres_by_gdal(path: &Path, unit_to_metre: f64) -> (Vec<f64>, Vec<bool>) {
    let ds = gdal::Dataset::open(path).expect("GDAL opens");
    let band = ds.rasterband(1).expect("band 1");
    let (scale, offset) = (band.scale().unwrap_or(1.0), band.offset().unwrap_or(0.0));
    let (_, _, v, nodata) = gdal_values(path);
    let nodata_mask: Vec<bool> = v.iter().map(|x| Some(*x) == nodata).collect();
    let m = v
        .iter()
        .map(|x| (x * scale + offset) * unit_to_metre)
        .collect();
    (m, nodata_mask)
}

fn view_depth(dem: &Path, dir: &Path, tag: &str) -> Vec<f64> {
    let depth = dir.join(format!("depth_{tag}.tif"));
    let sketch = fixture("sketches/zion_dome.json");
    let out = demsketch(&[
        "view",
        &s(dem),
        "--sketch",
        &s(&sketch),
        "--out",
        &s(&dir.join(format!("view_{tag}.png"))),
        "--depth",
        &s(&depth),
    ]);
    assert!(
        out.status.success(),
        "view {tag}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    gdal_values(&depth).2
}

fn edit(dem: &Path, dir: &Path, tag: &str) -> (PathBuf, Value) {
    let out = dir.join(format!("edited_{tag}.tif"));
    let report = dir.join(format!("report_{tag}.json"));
    let sketch = fixture("sketches/zion_dome.json");
    let r = demsketch(&[
        "edit",
        &s(dem),
        "--sketch",
        &s(&sketch),
        "--out",
        &s(&out),
        "--report",
        &s(&report),
    ]);
    assert!(
        r.status.success(),
        "edit {tag}: {}",
        String::from_utf8_lossy(&r.stderr)
    );
    let rep = serde_json::from_slice(&std::fs::read(&report).expect("report")).expect("JSON");
    (out, rep)
}

#[test]
fn info_shows_unit_datum_scale_and_offset_and_heights_in_metres() {
    let dir = tempfile::tempdir().expect("tempdir");
    let original = info_json(&fixture(ZION));
    assert_eq!(original["vertical"]["unit"], "metre");
    assert_eq!(original["vertical"]["scale"], 1.0);
    let (lo, hi) = (
        original["min"].as_f64().expect("min"),
        original["max"].as_f64().expect("max"),
    );
    for v in &VARIANTS {
        let (path, _) = make(dir.path(), v);
        let i = info_json(&path);
        let vert = &i["vertical"];
        assert_eq!(vert["unit"], v.unit, "{}: unit", v.name);
        assert_eq!(
            vert["unit_source"], v.unit_source,
            "{}: unit source",
            v.name
        );
        assert_eq!(vert["datum"].as_str(), v.datum, "{}: datum", v.name);
        assert_eq!(vert["scale"].as_f64(), Some(v.scale), "{}: scale", v.name);
        assert_eq!(vert["offset"].as_f64(), Some(0.0), "{}: offset", v.name);
        // The horizontal CRS of the compound one is still EPSG:32612.
        assert_eq!(i["epsg"].as_u64(), Some(32612), "{}: EPSG", v.name);
        let (a, b) = (i["min"].as_f64().unwrap(), i["max"].as_f64().unwrap());
        assert!(
            (a - lo).abs() < 1e-3 && (b - hi).abs() < 1e-3,
            "{}: min/max {a} / {b} m, original {lo} / {hi} m",
            v.name
        );
        // The text form says it too.
        let text = demsketch(&["info", &s(&path)]);
        let text = String::from_utf8_lossy(&text.stdout);
        assert!(
            text.contains(&format!("unit {}", v.unit)),
            "{}: text info: {text}",
            v.name
        );
        if let Some(d) = v.datum {
            assert!(text.contains(d), "{}: datum in text info: {text}", v.name);
        }
    }
}

#[test]
fn scaled_and_feet_dems_give_the_same_view() {
    let dir = tempfile::tempdir().expect("tempdir");
    let reference = view_depth(&fixture(ZION), dir.path(), "original");
    for v in &VARIANTS {
        let (path, _) = make(dir.path(), v);
        let depth = view_depth(&path, dir.path(), v.name);
        assert_eq!(depth.len(), reference.len());
        let mut worst = 0f64;
        for (a, b) in depth.iter().zip(&reference) {
            assert_eq!(
                a.is_finite(),
                b.is_finite(),
                "{}: sky/terrain differs",
                v.name
            );
            if b.is_finite() {
                worst = worst.max((a - b).abs() / b.abs().max(1e-9));
            }
        }
        assert!(
            worst <= 1e-3,
            "{}: depth differs by {worst} relative",
            v.name
        );
    }
}

/// The passes an edit made and kept: the first and each later one its
/// report's notes name.
fn passes(report: &Value) -> usize {
    let later = report["notes"]
        .as_array()
        .map(|n| {
            n.iter()
                .filter(|t| {
                    t.as_str()
                        .is_some_and(|t| t.contains(" pass over the strokes"))
                })
                .count()
        })
        .unwrap_or(0);
    1 + later
}

#[test]
fn scaled_and_feet_dems_get_the_same_edit_in_metres_and_keep_their_units() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let zion = fixture(ZION);
    let (orig_out, orig_rep) = edit(&zion, d, "original");
    let (orig_in, _) = metres_by_gdal(&zion, 1.0);
    let (orig_edit, orig_mask) = metres_by_gdal(&orig_out, 1.0);
    let orig_dz = orig_rep["max_abs_displacement_m"].as_f64().expect("max dz");
    let orig_passes = passes(&orig_rep);
    for v in &VARIANTS {
        let (plain, deflate) = make(d, v);
        for (input, tag) in [
            (&plain, v.name.to_string()),
            (&deflate, format!("{}_deflate", v.name)),
        ] {
            let (out, rep) = edit(input, d, &tag);
            // The report's heights are metres, of the heights as written:
            // each file's own step (1 m for the original, 0.1 m for
            // decimetres) rounds them, as below.
            // An edit made in several passes stores each pass's change at
            // the file's step (a later pass reads the terrain the passes
            // before made in whole metres, the same for every storage, so
            // the passes' decisions agree): one rounding per pass.
            let step = if v.name == "decimetre" { 0.1 } else { 0.0 };
            let rounding = 0.5 * orig_passes.max(passes(&rep)) as f64 + step / 2.0 + 1e-3;
            let dz = rep["max_abs_displacement_m"].as_f64().expect("max dz");
            assert!(
                (dz - orig_dz).abs() <= rounding,
                "{tag}: max |dz| {dz} m, original {orig_dz} m"
            );
            // The written file keeps scale, offset and unit.
            let g = gdalinfo(&out);
            let band = &g["bands"][0];
            let gi = gdalinfo(input);
            let band_in = &gi["bands"][0];
            for key in ["scale", "offset", "unit", "type", "noDataValue"] {
                assert_eq!(band[key], band_in[key], "{tag}: band {key} kept");
            }
            if let Some(datum) = v.datum {
                let wkt = g["coordinateSystem"]["wkt"].as_str().unwrap_or("");
                assert!(wkt.contains(datum), "{tag}: vertical CRS kept");
                assert_eq!(band["unit"], "US survey foot", "{tag}: GDAL's unit");
            }
            // Same heights in metres as the original's edit, up to the
            // rounding of each file to its own step (1 m for the original,
            // 0.1 m for decimetres), once per pass; same changed area.
            let (edited, mask) = metres_by_gdal(&out, v.to_metre / v.scale);
            assert_eq!(mask, orig_mask, "{tag}: nodata kept");
            let mut worst = 0f64;
            for i in 0..edited.len() {
                if mask[i] {
                    continue;
                }
                worst = worst.max((edited[i] - orig_edit[i]).abs());
                let changed_orig = (orig_edit[i] - orig_in[i]).abs() > 0.5 + 1e-6;
                if changed_orig {
                    assert!(
                        (edited[i] - orig_in[i]).abs() > 1e-3,
                        "{tag}: cell {i} changed in the original's edit only"
                    );
                }
            }
            assert!(
                worst <= rounding,
                "{tag}: edited heights differ from the original's by {worst} m"
            );
        }
    }
}
