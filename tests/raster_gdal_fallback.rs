//! What the native GeoTIFF decoder does not read goes through GDAL: GDAL
//! virtual file systems (`/vsizip/`, `/vsigzip/`), LERC and LERC_DEFLATE,
//! JPEG compression, and user-defined CRSs it cannot build from GeoKeys
//! (oblique Mercator, oblique stereographic, orthographic). Each reads with
//! exactly GDAL's values. Writing back: such inputs are never rewritten in
//! place (refused in one line, nothing touched); `--out` writes a new
//! GeoTIFF through GDAL.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use demsketch::raster::Dem;

const ZION: &str = "zion_srtm_utm12n.tif";

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// The inputs: (name, path given to demsketch, read through GDAL).
fn inputs(d: &Path) -> Vec<(&'static str, PathBuf)> {
    let zion = fixture(ZION);
    let mut v = Vec::new();
    let lerc = d.join("lerc.tif");
    gdal_translate(
        &zion,
        &lerc,
        &["-co", "COMPRESS=LERC", "-co", "MAX_Z_ERROR=0"],
    );
    v.push(("LERC", lerc));
    let lerc_deflate = d.join("lerc_deflate.tif");
    gdal_translate(
        &zion,
        &lerc_deflate,
        &["-co", "COMPRESS=LERC_DEFLATE", "-co", "MAX_Z_ERROR=0"],
    );
    v.push(("LERC_DEFLATE", lerc_deflate));
    let jpeg = d.join("jpeg.tif");
    gdal_translate(
        &zion,
        &jpeg,
        &[
            "-ot",
            "Byte",
            "-scale",
            "-a_nodata",
            "none",
            "-co",
            "COMPRESS=JPEG",
        ],
    );
    v.push(("JPEG", jpeg));
    for (name, srs) in [
        (
            "omerc",
            "+proj=omerc +lat_0=37.3 +lonc=-113 +alpha=30 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m",
        ),
        (
            "stere",
            "+proj=stere +lat_0=37.3 +lon_0=-113 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m",
        ),
        (
            "ortho",
            "+proj=ortho +lat_0=37.3 +lon_0=-113 +x_0=0 +y_0=0 +datum=WGS84 +units=m",
        ),
    ] {
        let p = d.join(format!("{name}.tif"));
        run("gdalwarp", &["-q", "-t_srs", srs, &s(&zion), &s(&p)]);
        v.push((name, p));
    }
    // A zip and a gzip holding the fixture.
    let inner = d.join("zion.tif");
    std::fs::copy(&zion, &inner).expect("copy fixture");
    run(
        "/usr/bin/python3",
        &[
            "-c",
            "import sys, zipfile, gzip, shutil\n\
             with zipfile.ZipFile(sys.argv[2], 'w', zipfile.ZIP_DEFLATED) as z: z.write(sys.argv[1], 'dem/zion.tif')\n\
             with open(sys.argv[1], 'rb') as i, gzip.open(sys.argv[3], 'wb') as o: shutil.copyfileobj(i, o)",
            &s(&inner),
            &s(&d.join("dem.zip")),
            &s(&d.join("zion.tif.gz")),
        ],
    );
    std::fs::remove_file(&inner).expect("remove");
    v.push((
        "vsizip",
        PathBuf::from(format!(
            "/vsizip/{}/dem/zion.tif",
            d.join("dem.zip").display()
        )),
    ));
    v.push((
        "vsigzip",
        PathBuf::from(format!("/vsigzip/{}", d.join("zion.tif.gz").display())),
    ));
    v
}

/// Min and max of the valid values GDAL reads.
fn gdal_min_max(path: &Path) -> (f64, f64) {
    let (_, _, v, nodata) = gdal_values(path);
    v.iter()
        .filter(|x| !x.is_nan() && Some(**x) != nodata)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(*x), b.max(*x))
        })
}

#[test]
fn what_the_native_decoder_lacks_reads_through_gdal_with_gdals_values() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (name, path) in inputs(dir.path()) {
        let out = demsketch(&["info", "--json", &s(&path)]);
        assert!(
            out.status.success(),
            "{name}: info failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let info: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
        assert_eq!(info["read_by_gdal"], true, "{name}: read through GDAL");
        let (lo, hi) = gdal_min_max(&path);
        assert_eq!(info["min"].as_f64(), Some(lo), "{name}: min");
        assert_eq!(info["max"].as_f64(), Some(hi), "{name}: max");

        // Every value, bit for bit, and nodata where GDAL has it.
        let (w, h, gv, nodata) = gdal_values(&path);
        let dem = Dem::open(&path).expect("open");
        assert_eq!((dem.width, dem.height), (w, h), "{name}: size");
        let ours = dem.read_window::<f64>(dem.full_window()).expect("read");
        let bad = (0..w * h)
            .filter(|&i| {
                let gdal_nodata = gv[i].is_nan() || Some(gv[i]) == nodata;
                if gdal_nodata {
                    ours.valid[i]
                } else {
                    !ours.valid[i] || ours.data[i].to_bits() != gv[i].to_bits()
                }
            })
            .count();
        assert_eq!(bad, 0, "{name}: {bad} values differ from GDAL's");

        // The user-defined CRSs are GDAL's, and usable (lon/lat bounds).
        if ["omerc", "stere", "ortho"].contains(&name) {
            let proj = info["proj"].as_str().unwrap_or("");
            assert!(
                proj.contains(&format!("+proj={name}")),
                "{name}: CRS {proj}"
            );
            assert!(info["bounds_lonlat"].is_array(), "{name}: lon/lat bounds");
        }
    }
}

fn expect_refused(dir: &Path, args: &[&str], needles: &[&str]) {
    let before = snapshot(dir);
    let out = demsketch(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{args:?}: exit code; {stderr}");
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "{args:?}: one line: {stderr}"
    );
    for n in needles {
        assert!(stderr.contains(n), "{args:?}: '{n}' not in {stderr}");
    }
    assert_eq!(before, snapshot(dir), "{args:?}: nothing touched");
}

#[test]
fn inputs_read_through_gdal_are_never_rewritten_in_place_and_out_works() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let sketch = fixture("sketches/zion_dome.json");
    let all = inputs(d);
    let get = |n: &str| all.iter().find(|(k, _)| *k == n).expect("input").1.clone();

    for name in ["vsizip", "LERC_DEFLATE"] {
        let p = get(name);
        expect_refused(
            d,
            &["edit", &s(&p), "--sketch", &s(&sketch), "--in-place"],
            &["in-place", "--out"],
        );
    }

    // --out to a plain GeoTIFF: the same edit as of the fixture itself.
    let reference = d.join("reference_out.tif");
    let r = demsketch(&[
        "edit",
        &s(&fixture(ZION)),
        "--sketch",
        &s(&sketch),
        "--out",
        &s(&reference),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    for name in ["vsizip", "LERC_DEFLATE"] {
        let out = d.join(format!("{name}_out.tif"));
        let r = demsketch(&[
            "edit",
            &s(&get(name)),
            "--sketch",
            &s(&sketch),
            "--out",
            &s(&out),
        ]);
        assert!(
            r.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&r.stderr)
        );
        let g = gdalinfo(&out);
        assert_eq!(g["driverShortName"], "GTiff", "{name}: a GeoTIFF");
        assert_eq!(
            gdal_values(&out).2,
            gdal_values(&reference).2,
            "{name}: same heights as the fixture's edit"
        );
    }
}

#[test]
fn an_unknown_epsg_code_is_not_hidden_by_the_fallback() {
    // GDAL opens such a file with a local CRS made from the citation; the
    // native error (one line, exit 1) stands.
    let dir = tempfile::tempdir().expect("tempdir");
    let mut b = std::fs::read(fixture(ZION)).expect("fixture");
    let key: Vec<u8> = [3072u16, 0, 1, 32612]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let at = b
        .windows(8)
        .position(|w| w == key.as_slice())
        .expect("ProjectedCSTypeGeoKey");
    b[at + 6..at + 8].copy_from_slice(&1234u16.to_le_bytes());
    let p = dir.path().join("unknown_epsg.tif");
    std::fs::write(&p, &b).expect("write");
    expect_refused(
        dir.path(),
        &["info", &s(&p)],
        &["unknown_epsg.tif", "EPSG:1234"],
    );
}
