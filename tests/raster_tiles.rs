//! The tile layer over a directory of tiles, and write-back of an edit that
//! crosses tile corners: checked against the original file and against what
//! GDAL reads from the written tiles.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use demsketch::raster::{Dem, Destination, LayerKind, Provenance, Window, PROVENANCE_KEY};

/// Split `src` into a `n` x `n` grid of tiles with `gdal_translate -srcwin`.
fn split(src: &Path, dir: &Path, n: usize, extra: &[&str]) -> Vec<PathBuf> {
    let (w, h, _, _) = gdal_values(src);
    let mut out = Vec::new();
    for ty in 0..n {
        for tx in 0..n {
            let (x0, x1) = (w * tx / n, w * (tx + 1) / n);
            let (y0, y1) = (h * ty / n, h * (ty + 1) / n);
            let dst = dir.join(format!("tile_{ty}_{tx}.tif"));
            let win = [x0, y0, x1 - x0, y1 - y0].map(|v| v.to_string());
            let mut args: Vec<&str> = vec!["-srcwin", &win[0], &win[1], &win[2], &win[3]];
            args.extend_from_slice(extra);
            gdal_translate(src, &dst, &args);
            out.push(dst);
        }
    }
    out
}

#[test]
fn three_by_three_tiles_read_back_identical() {
    for name in [
        "zion_srtm_utm12n.tif",
        "nz_1km_nan_nodata.tif",
        "arenal_aster30m_epsg4326.tif",
    ] {
        let src = fixture(name);
        let dir = tempfile::tempdir().expect("tempdir");
        split(
            &src,
            dir.path(),
            3,
            &[
                "-co",
                "TILED=YES",
                "-co",
                "BLOCKXSIZE=32",
                "-co",
                "BLOCKYSIZE=32",
                "-co",
                "COMPRESS=DEFLATE",
            ],
        );
        let whole = Dem::open(&src).expect("open original");
        let tiled = Dem::open(dir.path()).expect("open tile directory");
        assert_eq!(tiled.kind, LayerKind::TileDirectory);
        assert_eq!(tiled.tiles.len(), 9);
        assert_eq!((tiled.width, tiled.height), (whole.width, whole.height));
        assert_eq!(tiled.geotransform, whole.geotransform);
        let (w, h) = (whole.width as i64, whole.height as i64);
        // Windows across tile corners, an edge, the whole raster, and one
        // hanging off the DEM (outside reads as nodata).
        let windows = [
            Window::new(w / 3 - 17, h / 3 - 13, 40, 30),
            Window::new(2 * w / 3 - 5, 2 * h / 3 - 7, 11, 19),
            Window::new(w / 3 - 1, 0, 2, h as usize),
            Window::new(0, 0, w as usize, h as usize),
            Window::new(-5, -5, 30, 30),
        ];
        for win in windows {
            let a = whole.read_window::<f64>(win).expect("read original");
            let b = tiled.read_window::<f64>(win).expect("read tiles");
            assert_eq!(a.valid, b.valid, "{name} {win:?}: masks differ");
            for i in 0..a.data.len() {
                if a.valid[i] {
                    assert_eq!(
                        a.data[i].to_bits(),
                        b.data[i].to_bits(),
                        "{name} {win:?} cell {i}"
                    );
                }
            }
        }
    }
}

#[test]
fn write_back_rewrites_only_the_four_touched_tiles() {
    let src = fixture("zion_srtm_utm12n.tif");
    let input = tempfile::tempdir().expect("tempdir");
    let tiles = split(
        &src,
        input.path(),
        3,
        &[
            "-co",
            "TILED=YES",
            "-co",
            "BLOCKXSIZE=64",
            "-co",
            "BLOCKYSIZE=32",
            "-co",
            "COMPRESS=DEFLATE",
            "-co",
            "PREDICTOR=2",
        ],
    );
    let before = snapshot(input.path());
    let dem = Dem::open(input.path()).expect("open tiles");
    // A window around the corner shared by tiles (0,0), (0,1), (1,0), (1,1).
    let (cx, cy) = (dem.width as i64 / 3, dem.height as i64 / 3);
    let win = Window::new(cx - 20, cy - 25, 40, 50);
    let old = dem.read_window::<f64>(win).expect("read");
    let new: Vec<f64> = old
        .data
        .iter()
        .enumerate()
        .map(|(i, v)| {
            if old.valid[i] {
                v + 100.4 + (i % 7) as f64 * 0.25
            } else {
                f64::NAN
            }
        })
        .collect();
    let out_parent = tempfile::tempdir().expect("tempdir");
    let out = out_parent.path().join("edited");
    let report = dem
        .write_back(
            win,
            &new,
            &Destination::Path(out.clone()),
            &Provenance {
                edit_id: "test-edit".into(),
            },
        )
        .expect("write back");
    assert_eq!(report.tiles_written.len(), 4, "{report:?}");
    assert_eq!(report.tiles_unchanged.len(), 5);
    // The input is untouched.
    assert_eq!(before, snapshot(input.path()));
    // The 5 untouched tiles are byte-identical.
    for t in &tiles {
        let name = t.file_name().expect("name");
        let written = report
            .tiles_written
            .iter()
            .any(|w| w.file_name() == Some(name));
        let a = std::fs::read(t).expect("read input tile");
        let b = std::fs::read(out.join(name)).expect("read output tile");
        assert_eq!(
            a == b,
            !written,
            "{}: byte-identical iff untouched",
            name.to_string_lossy()
        );
    }
    // GDAL sees the same layout, encoding, CRS, nodata, and the new values.
    for w in &report.tiles_written {
        let orig = input.path().join(w.file_name().expect("name"));
        let (gi, go) = (gdalinfo(w), gdalinfo(&orig));
        assert_eq!(
            gi["bands"][0]["block"], go["bands"][0]["block"],
            "block size"
        );
        assert_eq!(
            gi["bands"][0]["type"], go["bands"][0]["type"],
            "sample type"
        );
        assert_eq!(
            gi["bands"][0]["noDataValue"], go["bands"][0]["noDataValue"],
            "nodata"
        );
        assert_eq!(gi["metadata"]["IMAGE_STRUCTURE"]["COMPRESSION"], "DEFLATE");
        assert_eq!(gi["metadata"]["IMAGE_STRUCTURE"]["PREDICTOR"], "2");
        assert_eq!(
            gi["coordinateSystem"]["wkt"], go["coordinateSystem"]["wkt"],
            "CRS"
        );
        assert_eq!(gi["geoTransform"], go["geoTransform"], "geotransform");
        let prov = gi["metadata"][""][PROVENANCE_KEY]
            .as_str()
            .expect("provenance item shows in gdalinfo");
        assert!(
            prov.contains("edit=test-edit") && prov.contains("tool=demsketch"),
            "{prov}"
        );
    }
    // Values: rounded to the UInt16 grid, through GDAL.
    let edited = Dem::open(&out).expect("open output");
    let got = edited.read_window::<f64>(win).expect("read output");
    assert_eq!(got.data.len(), new.len());
    for (i, &n) in new.iter().enumerate() {
        assert_eq!(got.valid[i], old.valid[i]);
        if old.valid[i] {
            assert_eq!(got.data[i], n.round().clamp(0.0, 65535.0), "cell {i}");
        }
    }
    // Outside the window nothing changed.
    let all_in = Dem::open(input.path())
        .expect("open")
        .read_window::<f64>(dem.full_window())
        .expect("read");
    let all_out = edited.read_window::<f64>(dem.full_window()).expect("read");
    for r in 0..dem.height as i64 {
        for c in 0..dem.width as i64 {
            let inside = c >= win.col && c < win.col_end() && r >= win.row && r < win.row_end();
            let i = r as usize * dem.width + c as usize;
            if !inside && all_in.valid[i] {
                assert_eq!(all_in.data[i], all_out.data[i]);
            }
        }
    }
}

#[test]
fn write_back_in_place_and_single_file_with_overviews() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cog = dir.path().join("dem_cog.tif");
    gdal_translate(
        &fixture("nz_1km_nan_nodata.tif"),
        &cog,
        &[
            "-of",
            "COG",
            "-co",
            "BLOCKSIZE=256",
            "-co",
            "COMPRESS=DEFLATE",
            "-co",
            "PREDICTOR=YES",
        ],
    );
    let striped = dir.path().join("dem_striped.tif");
    gdal_translate(
        &fixture("vinschgau_250m_utm32n.tif"),
        &striped,
        &["-co", "COMPRESS=LZW", "-co", "BLOCKYSIZE=8"],
    );
    run("gdaladdo", &["-q", &striped.to_string_lossy(), "2", "4"]);
    for (path, win) in [
        (&cog, Window::new(600, 700, 60, 40)),
        (&striped, Window::new(100, 100, 50, 40)),
    ] {
        let dem = Dem::open(path).expect("open");
        let old = dem.read_window::<f64>(win).expect("read");
        let new: Vec<f64> = old.data.iter().map(|v| v + 250.0).collect();
        let info_before = gdalinfo(path);
        let report = dem
            .write_back(
                win,
                &new,
                &Destination::InPlace,
                &Provenance {
                    edit_id: "in-place".into(),
                },
            )
            .expect("write back in place");
        assert_eq!(report.tiles_written.len(), 1);
        assert!(report.changed_cells > 100, "{report:?}");
        let info = gdalinfo(path);
        assert_eq!(info["bands"][0]["block"], info_before["bands"][0]["block"]);
        assert_eq!(
            info["bands"][0]["overviews"].as_array().map(|a| a.len()),
            info_before["bands"][0]["overviews"]
                .as_array()
                .map(|a| a.len()),
            "overviews rebuilt"
        );
        assert_eq!(
            info["metadata"]["IMAGE_STRUCTURE"],
            info_before["metadata"]["IMAGE_STRUCTURE"]
        );
        let again = Dem::open(path).expect("reopen");
        let got = again.read_window::<f64>(win).expect("read");
        assert_eq!(got.data.len(), new.len());
        for (i, &n) in new.iter().enumerate() {
            assert_eq!(got.valid[i], old.valid[i], "nodata stays nodata");
            if old.valid[i] {
                assert_eq!(got.data[i], (n as f32) as f64);
            }
        }
        // No temporary files left behind.
        let names: Vec<String> = std::fs::read_dir(dir.path())
            .expect("list")
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| !n.ends_with(".tmp")), "{names:?}");
    }
}
