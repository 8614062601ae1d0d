//! Outputs a GIS expects, and clean process behaviour, through the binary,
//! each checked with GDAL: the format follows `-of` or the extension (an
//! `.asc` is an Arc/Info grid, `.vrt` and unknown extensions are refused in
//! one line with nothing written), `-co` reaches the driver, `--dz` writes
//! the height change on the window's grid with a nodata value, provenance
//! is a history, the depth GeoTIFF has a nodata value and no infinities,
//! feature ids are unique and equal the report's; a closed pipe, `--quiet`,
//! `--verbose`, a non-UTF-8 file name and a corrupt GDAL_NODATA tag.

mod common;

use std::path::{Path, PathBuf};

use common::{demsketch, fixture, gdal_values, gdalinfo, snapshot};
use serde_json::Value;

fn sketch() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion_dome.json")
}

fn dem() -> PathBuf {
    fixture("zion_srtm_utm12n.tif")
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "failed ({:?}): {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn one_line_error(out: &std::process::Output, names: &str) {
    assert_eq!(out.status.code(), Some(1), "exit 1");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(err.contains(names), "names {names}: {err}");
    assert!(!err.contains("ERROR "), "no GDAL ERROR line: {err}");
}

#[test]
fn edit_out_format_follows_the_extension_and_flags() {
    let dir = tempfile::tempdir().expect("tempdir");
    let tif = dir.path().join("a.tif");
    let asc = dir.path().join("a.asc");
    let dat = dir.path().join("a.dat");
    let dz = dir.path().join("dz.tif");
    let report = dir.path().join("r.json");
    let (d, k) = (s(&dem()), s(&sketch()));
    ok(&demsketch(&[
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&tif),
        "--dz",
        &s(&dz),
        "--report",
        &s(&report),
    ]));
    ok(&demsketch(&[
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&asc),
        "--quiet",
    ]));
    ok(&demsketch(&[
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&dat),
        "-of",
        "GTiff",
        "-co",
        "COMPRESS=ZSTD",
        "-co",
        "TILED=YES",
    ]));
    // .asc: an Arc/Info ASCII grid with its .prj, the same heights.
    let ia = gdalinfo(&asc);
    assert_eq!(
        ia["driverShortName"], "AAIGrid",
        "{}",
        ia["driverShortName"]
    );
    assert!(dir.path().join("a.prj").is_file(), "the .prj beside it");
    let (_, _, va, _) = gdal_values(&asc);
    let (w, h, vt, _) = gdal_values(&tif);
    assert_eq!(va, vt, "same heights as the GeoTIFF output");
    // -of GTiff -co COMPRESS=ZSTD on a .dat name.
    let id = gdalinfo(&dat);
    assert_eq!(id["driverShortName"], "GTiff");
    assert_eq!(id["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"], "ZSTD");
    assert_eq!(gdal_values(&dat).2, vt);
    // --dz: Float32 on the changed window's grid, nodata -9999, new - old.
    let iz = gdalinfo(&dz);
    assert_eq!(iz["bands"][0]["type"], "Float32");
    assert_eq!(iz["bands"][0]["noDataValue"].as_f64(), Some(-9999.0));
    let rep: Value =
        serde_json::from_slice(&std::fs::read(&report).expect("report")).expect("json");
    let win = &rep["deformation"]["window"];
    let (c0, r0, ww, wh) = (
        win[0].as_i64().unwrap() as usize,
        win[1].as_i64().unwrap() as usize,
        win[2].as_i64().unwrap() as usize,
        win[3].as_i64().unwrap() as usize,
    );
    assert_eq!(iz["size"], serde_json::json!([ww, wh]), "the window's size");
    let gt_dem = gdalinfo(&dem())["geoTransform"].clone();
    let gt_dz = iz["geoTransform"].clone();
    let x0 = gt_dem[0].as_f64().unwrap() + c0 as f64 * gt_dem[1].as_f64().unwrap();
    let y0 = gt_dem[3].as_f64().unwrap() + r0 as f64 * gt_dem[5].as_f64().unwrap();
    assert!((gt_dz[0].as_f64().unwrap() - x0).abs() < 1e-6);
    assert!((gt_dz[3].as_f64().unwrap() - y0).abs() < 1e-6);
    let (_, _, vin, _) = gdal_values(&dem());
    let (_, _, vz, _) = gdal_values(&dz);
    let mut seen = 0;
    for r in 0..wh {
        for c in 0..ww {
            let z = vz[r * ww + c];
            let i = (r0 + r) * w + c0 + c;
            let change = vt[i] - vin[i];
            if z != -9999.0 && change != 0.0 {
                // UInt16 heights: the stored change is dz rounded.
                assert!(
                    (change - z).abs() <= 0.5 + 1e-3,
                    "({c}, {r}): dz {z}, stored change {change}"
                );
                seen += 1;
            }
        }
    }
    assert!(seen > 0 && h > 0, "dz matches the stored change");
    // Provenance names the input, the sketch's digest and the parameters.
    let md = &gdalinfo(&tif)["metadata"][""];
    let p1 = md["DEMSKETCH_PROVENANCE_1"]
        .as_str()
        .expect("history entry 1");
    assert!(
        p1.contains("input=")
            && p1.contains("sketch_sha256=")
            && p1.contains("parameters=--max-distance"),
        "{p1}"
    );
}

#[test]
fn unwritable_formats_are_refused_before_any_work() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (d, k) = (s(&dem()), s(&sketch()));
    for (name, extra) in [
        ("o.vrt", vec![]),
        ("o.qqq", vec![]),
        ("o.tif", vec!["-of", "NoSuchFormat"]),
    ] {
        let out = dir.path().join(name);
        let mut args = vec!["edit", &d, "--sketch", &k];
        let o = s(&out);
        args.extend(["--out", &o]);
        args.extend(extra.iter().copied());
        let before = snapshot(dir.path());
        let r = demsketch(&args);
        one_line_error(&r, name);
        assert_eq!(snapshot(dir.path()), before, "nothing written");
    }
    let r = demsketch(&[
        "view",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&dir.path().join("v.png")),
        "--features",
        &s(&dir.path().join("f.shp")),
    ]);
    one_line_error(&r, "f.shp");
    // A creation option GDAL rejects: GDAL's own error, in our one line,
    // naming the output (not a temporary file), nothing left behind. This
    // edit runs up to the write, so it edits a private copy of the DEM (the
    // fixtures' directory lock is shared with the other tests running now,
    // and waiting for it would say so on stderr).
    let own = tempfile::tempdir().expect("tempdir");
    let own_dem = own.path().join("zion.tif");
    std::fs::copy(dem(), &own_dem).expect("copy the DEM");
    let d = s(&own_dem);
    let out = dir.path().join("bad_co.tif");
    let before = snapshot(dir.path());
    let r = demsketch(&[
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&out),
        "-co",
        "TILED=YES",
        "-co",
        "BLOCKXSIZE=7",
    ]);
    one_line_error(&r, "bad_co.tif");
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(!err.contains(".demsketch-"), "names the target: {err}");
    assert_eq!(snapshot(dir.path()), before, "nothing written");
}

#[test]
fn provenance_is_a_history() {
    use demsketch::raster::{Dem, Destination, Provenance, Window, WriteOptions};
    let dir = tempfile::tempdir().expect("tempdir");
    let copy = dir.path().join("dem.tif");
    std::fs::copy(dem(), &copy).expect("copy");
    for (k, col) in [(1, 100), (2, 200)] {
        let dem = Dem::open(&copy).expect("open");
        let win = Window::new(col, 100, 10, 10);
        let old = dem.read_window::<f64>(win).expect("read");
        let new: Vec<f64> = old.data.iter().map(|v| v + 3.0).collect();
        let opts = WriteOptions {
            record: demsketch::raster::ProvenanceRecord {
                input: Some(format!("edit {k}")),
                ..Default::default()
            },
            ..Default::default()
        };
        dem.write_back_with(
            win,
            &new,
            &Destination::InPlace,
            &Provenance {
                edit_id: format!("e{k}"),
            },
            &opts,
        )
        .expect("write");
    }
    let md = gdalinfo(&copy)["metadata"][""].clone();
    let e1 = md["DEMSKETCH_PROVENANCE_1"]
        .as_str()
        .expect("entry 1")
        .to_string();
    let e2 = md["DEMSKETCH_PROVENANCE_2"]
        .as_str()
        .expect("entry 2")
        .to_string();
    assert!(md["DEMSKETCH_PROVENANCE_3"].is_null());
    assert_eq!(
        md["DEMSKETCH_PROVENANCE"].as_str(),
        Some(e2.as_str()),
        "latest repeated"
    );
    assert!(
        e1.contains("edit=e1") && e1.contains("input=edit 1"),
        "{e1}"
    );
    assert!(
        e2.contains("edit=e2") && e2.contains("input=edit 2"),
        "{e2}"
    );
    for e in [&e1, &e2] {
        assert!(e.contains("tool=demsketch") && e.contains("time="), "{e}");
    }
}

#[test]
fn view_outputs_depth_nodata_formats_and_feature_ids() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (d, k) = (s(&dem()), s(&sketch()));
    let depth = dir.path().join("depth.tif");
    let vis = dir.path().join("vis.asc");
    let feats = dir.path().join("f.geojson");
    let report = dir.path().join("r.json");
    ok(&demsketch(&[
        "view",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&dir.path().join("v.tif")),
        "--depth",
        &s(&depth),
        "--viewshed",
        &s(&vis),
        "--features",
        &s(&feats),
        "-co",
        "COMPRESS=LZW",
    ]));
    let i = gdalinfo(&depth);
    assert_eq!(i["bands"][0]["noDataValue"].as_f64(), Some(-9999.0));
    let (_, _, v, _) = gdal_values(&depth);
    assert!(v.iter().all(|x| x.is_finite()), "no bare inf");
    assert!(v.contains(&-9999.0), "sky is nodata");
    assert_eq!(gdalinfo(&vis)["driverShortName"], "AAIGrid");
    assert_eq!(
        gdalinfo(&dir.path().join("v.tif"))["bands"]
            .as_array()
            .map(|b| b.len()),
        Some(3)
    );
    // Feature ids: unique, and the report's feature_id of an edit with the
    // same sketch names features of the file.
    let fc: Value = serde_json::from_slice(&std::fs::read(&feats).expect("geojson")).expect("json");
    let ids: Vec<u64> = fc["features"]
        .as_array()
        .expect("features")
        .iter()
        .map(|f| {
            assert_eq!(f["id"], f["properties"]["id"]);
            assert_eq!(f["id"], f["properties"]["feature_id"]);
            f["id"].as_u64().expect("numeric id")
        })
        .collect();
    let mut uniq = ids.clone();
    uniq.sort_unstable();
    uniq.dedup();
    assert_eq!(uniq.len(), ids.len(), "unique ids");
    ok(&demsketch(&[
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &s(&dir.path().join("o.tif")),
        "--report",
        &s(&report),
        "--dry-run",
        "--allow-partial",
    ]));
    let rep: Value =
        serde_json::from_slice(&std::fs::read(&report).expect("report")).expect("json");
    let mut matched = 0;
    for st in rep["views"][0]["strokes"].as_array().expect("strokes") {
        if let Some(fid) = st["match"]["feature_id"].as_u64() {
            assert!(ids.contains(&fid), "report feature_id {fid} in the GeoJSON");
            matched += 1;
        }
    }
    assert!(matched > 0, "some stroke matched a feature");
    // ogr2ogr to a GeoPackage, which needs unique ids.
    let gpkg = dir.path().join("f.gpkg");
    let r = std::process::Command::new("ogr2ogr")
        .args(["-f", "GPKG", &s(&gpkg), &s(&feats)])
        .output()
        .expect("ogr2ogr");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

#[test]
fn broken_pipe_quiet_and_verbose() {
    let (d, k) = (s(&dem()), s(&sketch()));
    let dir = tempfile::tempdir().expect("tempdir");
    let bin = env!("CARGO_BIN_EXE_demsketch");
    let out = s(&dir.path().join("o.tif"));
    let cmd = format!("'{bin}' edit '{d}' --sketch '{k}' --out '{out}' --json | true; echo \"${{PIPESTATUS[0]}}\"");
    let r = std::process::Command::new("bash")
        .args(["-c", &cmd])
        .output()
        .expect("bash");
    let code = String::from_utf8_lossy(&r.stdout).trim().to_string();
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(code == "0" || code == "141", "exit {code}: {err}");
    assert!(!err.contains("internal error"), "{err}");
    let cmd = format!("'{bin}' info --json '{d}' | true; echo \"${{PIPESTATUS[0]}}\"");
    let r = std::process::Command::new("bash")
        .args(["-c", &cmd])
        .output()
        .expect("bash");
    let code = String::from_utf8_lossy(&r.stdout).trim().to_string();
    assert!(code == "0" || code == "141", "info exit {code}");
    // --quiet: nothing on stderr; --verbose: stage timings.
    let q = demsketch(&[
        "--quiet",
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &out,
        "--dry-run",
    ]);
    ok(&q);
    assert!(
        q.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&q.stderr)
    );
    let v = demsketch(&[
        "edit",
        &d,
        "--sketch",
        &k,
        "--out",
        &out,
        "--dry-run",
        "--verbose",
    ]);
    ok(&v);
    let e = String::from_utf8_lossy(&v.stderr);
    assert!(
        e.contains("demsketch: total:") && e.contains("demsketch: matching:"),
        "{e}"
    );
}

#[test]
fn non_utf8_name_and_corrupt_nodata() {
    use std::os::unix::ffi::OsStrExt;
    let dir = tempfile::tempdir().expect("tempdir");
    let odd = dir
        .path()
        .join(std::ffi::OsStr::from_bytes(b"dem_\xff.tif"));
    std::fs::copy(dem(), &odd).expect("copy");
    for json in [false, true] {
        let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_demsketch"));
        c.arg("info").arg(&odd);
        if json {
            c.arg("--json");
        }
        let r = c.output().expect("run");
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    // A GDAL_NODATA tag whose text is not UTF-8 (nor a number).
    let nd = dir.path().join("nd.tif");
    common::gdal_translate(
        &fixture("vinschgau_250m_utm32n.tif"),
        &nd,
        &["-a_nodata", "-9999"],
    );
    let mut b = std::fs::read(&nd).expect("read");
    let i = b
        .windows(6)
        .position(|w| w == b"-9999\0")
        .expect("the GDAL_NODATA text");
    b[i..i + 6].copy_from_slice(b"\xff\xfe999\0");
    let bad = dir.path().join("bad_nodata.tif");
    std::fs::write(&bad, &b).expect("write");
    let r = demsketch(&["info", "--no-stats", &s(&bad)]);
    one_line_error(&r, "bad_nodata.tif");
    assert!(String::from_utf8_lossy(&r.stderr).contains("GDAL_NODATA"));
}

#[test]
fn cog_edited_in_place_by_the_binary_stays_a_valid_cog() {
    // Through the binary (its allocator is not GDAL's): the COG is patched
    // in GDAL's memory file system, which GDAL must own.
    let dir = tempfile::tempdir().expect("tempdir");
    let cog = dir.path().join("cog.tif");
    common::gdal_translate(
        &dem(),
        &cog,
        &[
            "-of",
            "COG",
            "-co",
            "RESAMPLING=AVERAGE",
            "-co",
            "BLOCKSIZE=128",
            "-co",
            "COMPRESS=DEFLATE",
        ],
    );
    let before = std::fs::read(&cog).expect("read");
    let r = demsketch(&[
        "edit",
        &s(&cog),
        "--sketch",
        &s(&sketch()),
        "--in-place",
        "--allow-partial",
        "-q",
    ]);
    ok(&r);
    assert_ne!(std::fs::read(&cog).expect("read"), before, "edited");
    let script = [
        "/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_cloud_optimized_geotiff.py",
        "/usr/share/doc/python3-gdal/examples/validate_cloud_optimized_geotiff.py",
    ]
    .into_iter()
    .find(|p| Path::new(p).is_file())
    .expect("GDAL's COG validator");
    let v = std::process::Command::new("/usr/bin/python3")
        .args([script, &s(&cog)])
        .output()
        .expect("validate");
    assert!(v.status.success(), "{}", String::from_utf8_lossy(&v.stdout));
    assert_eq!(
        gdalinfo(&cog)["metadata"][""]["DEMSKETCH_OVERVIEW_RESAMPLING"],
        "AVERAGE"
    );
}

#[test]
fn an_edit_that_changes_nothing_still_writes_the_format_asked_for() {
    use demsketch::raster::{Dem, Destination, Provenance, Window};
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("same.asc");
    let dem = Dem::open(&dem()).expect("open");
    let win = Window::new(10, 10, 5, 5);
    let old = dem.read_window::<f64>(win).expect("read");
    let r = dem
        .write_back(
            win,
            &old.data,
            &Destination::Path(out.clone()),
            &Provenance {
                edit_id: "none".into(),
            },
        )
        .expect("write");
    assert_eq!(r.changed_cells, 0);
    assert_eq!(gdalinfo(&out)["driverShortName"], "AAIGrid");
    assert_eq!(
        gdal_values(&out).2,
        gdal_values(&fixture("zion_srtm_utm12n.tif")).2
    );
}

/// The size limits are checked before any height is read: an edit whose
/// views would take more memory than the budget stops at once, in one line
/// that says to lower --max-distance, with nothing written.
#[test]
fn an_edit_over_the_memory_budget_stops_before_reading() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("o.tif");
    // The bundled sketch with its images a tenth of the size (the camera's
    // own memory check comes first): the views' windows alone are over 1 MB.
    let text = std::fs::read_to_string(sketch()).expect("sketch");
    let mut v: Value = serde_json::from_str(&text).expect("json");
    for view in v["views"].as_array_mut().expect("views") {
        for k in ["width", "height"] {
            let n = view["camera"][k].as_u64().expect("size");
            view["camera"][k] = Value::from(n / 10);
        }
        for st in view["strokes"].as_array_mut().expect("strokes") {
            for p in st["points"].as_array_mut().expect("points") {
                for c in p.as_array_mut().expect("point") {
                    *c = Value::from(c.as_f64().expect("coordinate") / 10.0);
                }
            }
        }
    }
    let small = dir.path().join("small.json");
    std::fs::write(&small, v.to_string()).expect("write");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_demsketch"))
        .args([
            "edit",
            &s(&dem()),
            "--sketch",
            &s(&small),
            "--out",
            &s(&out),
        ])
        .env("DEMSKETCH_MEMORY_BUDGET_MB", "1")
        .output()
        .expect("demsketch");
    assert_eq!(r.status.code(), Some(1));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(
        err.contains("over the memory budget") && err.contains("lower --max-distance"),
        "{err}"
    );
    assert!(!out.exists());
}
