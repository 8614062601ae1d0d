//! Overviews and sidecars after an edit, checked with GDAL: a COG with
//! AVERAGE overviews keeps AVERAGE, its overview cells away from the edit
//! stay bit-identical, the cells over it equal what `gdaladdo` computes on
//! the result, and it validates as a COG (GDAL's validation script); an
//! external `.ovr` is rebuilt the same way (in place and with `--out`);
//! stale `.aux.xml` statistics go.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use demsketch::raster::{Dem, Destination, Provenance, Window, WriteOptions};

/// Every overview level of band 1: (width, height, values).
fn levels(path: &Path) -> Vec<(usize, usize, Vec<f64>)> {
    let ds = gdal::Dataset::open(path).expect("GDAL opens the file");
    let band = ds.rasterband(1).expect("band 1");
    let n = band.overview_count().expect("overview count") as usize;
    (0..n)
        .map(|k| {
            let o = band.overview(k).expect("overview");
            let (w, h) = o.size();
            let v = o
                .read_as::<f64>((0, 0), (w, h), (w, h), None)
                .expect("read overview");
            (w, h, v.data().to_vec())
        })
        .collect()
}

fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// Is overview cell (c, r) of a `w` x `h` level of a `fw` x `fh` image
/// clear of `win` (its footprint, grown by one overview cell, misses it)?
fn clear_of(
    c: usize,
    r: usize,
    (w, h): (usize, usize),
    (fw, fh): (usize, usize),
    win: Window,
) -> bool {
    let (rx, ry) = (fw as f64 / w as f64, fh as f64 / h as f64);
    let (x0, x1) = ((c as f64 - 1.0) * rx, (c as f64 + 2.0) * rx);
    let (y0, y1) = ((r as f64 - 1.0) * ry, (r as f64 + 2.0) * ry);
    x1 <= win.col as f64
        || x0 >= win.col_end() as f64
        || y1 <= win.row as f64
        || y0 >= win.row_end() as f64
}

/// Edit `win` of `path` (+100 m) to `dest`.
fn edit(path: &Path, win: Window, dest: &Destination, opts: &WriteOptions) {
    let dem = Dem::open(path).expect("open");
    let old = dem.read_window::<f64>(win).expect("read");
    let new: Vec<f64> = old.data.iter().map(|v| v + 100.0).collect();
    let r = dem
        .write_back_with(
            win,
            &new,
            dest,
            &Provenance {
                edit_id: "overviews".into(),
            },
            opts,
        )
        .expect("write back");
    assert!(r.changed_cells > 100, "{r:?}");
}

/// Check the overviews of `after` against `before` (untouched away from
/// `win`) and against `reference` (`gdaladdo` on the result: equal over
/// `win`, and different from before there).
fn check_levels(
    before: &[(usize, usize, Vec<f64>)],
    after: &[(usize, usize, Vec<f64>)],
    reference: &[(usize, usize, Vec<f64>)],
    full: (usize, usize),
    win: Window,
) {
    assert_eq!(before.len(), after.len(), "same number of levels");
    assert_eq!(after.len(), reference.len(), "same levels as gdaladdo");
    for (k, ((b, a), g)) in before.iter().zip(after).zip(reference).enumerate() {
        assert_eq!((a.0, a.1), (b.0, b.1), "level {k} size");
        let (mut outside, mut inside, mut differ) = (0, 0, 0);
        for r in 0..a.1 {
            for c in 0..a.0 {
                let i = r * a.0 + c;
                if clear_of(c, r, (a.0, a.1), full, win) {
                    assert!(
                        same(a.2[i], b.2[i]),
                        "level {k} cell ({c}, {r}) away from the edit changed: {} -> {}",
                        b.2[i],
                        a.2[i]
                    );
                    outside += 1;
                } else {
                    assert!(
                        same(a.2[i], g.2[i]),
                        "level {k} cell ({c}, {r}) over the edit: {} but gdaladdo gives {}",
                        a.2[i],
                        g.2[i]
                    );
                    inside += 1;
                    differ += usize::from(!same(a.2[i], b.2[i]));
                }
            }
        }
        assert!(
            outside > 0 && inside > 0,
            "level {k}: {outside} outside, {inside} inside"
        );
        assert!(differ > 0, "level {k}: no cell over the edit changed");
    }
}

/// A copy of `path` (and nothing else) with its overviews rebuilt by
/// gdaladdo with `-r resampling` (`external`: as `-ro` makes them).
fn gdaladdo_reference(
    path: &Path,
    dir: &Path,
    resampling: &str,
    factors: &[&str],
    external: bool,
) -> PathBuf {
    let copy = dir.join(format!(
        "reference_{}.tif",
        if external { "ext" } else { "int" }
    ));
    if external {
        gdal_translate(path, &copy, &["-co", "TILED=YES"]);
    } else {
        std::fs::copy(path, &copy).expect("copy");
    }
    let c = copy.to_string_lossy().into_owned();
    let mut args = vec!["-q", "-r", resampling];
    if external {
        args.push("-ro");
    }
    args.push(&c);
    args.extend_from_slice(factors);
    run("gdaladdo", &args);
    copy
}

fn validate_cog(path: &Path) -> (bool, String) {
    let script = [
        "/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_cloud_optimized_geotiff.py",
        "/usr/share/doc/python3-gdal/examples/validate_cloud_optimized_geotiff.py",
    ]
    .into_iter()
    .find(|p| Path::new(p).is_file())
    .expect("GDAL's validate_cloud_optimized_geotiff.py is installed");
    let out = std::process::Command::new("/usr/bin/python3")
        .args([script, &path.to_string_lossy()])
        .output()
        .expect("run the COG validator");
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

#[test]
fn cog_with_average_overviews_keeps_average_and_stays_a_cog() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cog = dir.path().join("cog.tif");
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
            "-co",
            "RESAMPLING=AVERAGE",
        ],
    );
    assert!(validate_cog(&cog).0, "the input is a COG");
    let before = levels(&cog);
    let (w, h, _, _) = gdal_values(&cog);
    let win = Window::new(600, 700, 60, 40);
    edit(&cog, win, &Destination::InPlace, &WriteOptions::default());
    let (ok, msg) = validate_cog(&cog);
    assert!(ok, "the edited COG validates: {msg}");
    assert_eq!(
        gdalinfo(&cog)["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"],
        "COG",
        "LAYOUT=COG"
    );
    let after = levels(&cog);
    let factors: Vec<String> = before
        .iter()
        .map(|l| ((w as f64 / l.0 as f64).round() as usize).to_string())
        .collect();
    let f: Vec<&str> = factors.iter().map(String::as_str).collect();
    let reference = levels(&gdaladdo_reference(&cog, dir.path(), "average", &f, false));
    check_levels(&before, &after, &reference, (w, h), win);
    // The resampling is recorded on the overviews, as newer GDAL reads it.
    let ds = gdal::Dataset::open(&cog).expect("open");
    assert_eq!(
        demsketch::raster::overviews::recorded_resampling(&ds),
        Some("AVERAGE")
    );
}

#[test]
fn internal_overviews_of_an_evenly_divided_image_are_refreshed_in_a_window() {
    // 1024 x 1024 with levels 2, 4, 8: the windowed path, with the user's
    // choice (--overview-resampling) of NEAREST, and of AVERAGE.
    for (r, upper) in [("nearest", "NEAREST"), ("average", "AVERAGE")] {
        let dir = tempfile::tempdir().expect("tempdir");
        let src = dir.path().join("even.tif");
        gdal_translate(
            &fixture("nz_1km_nan_nodata.tif"),
            &src,
            &[
                "-srcwin",
                "0",
                "0",
                "1024",
                "1024",
                "-co",
                "TILED=YES",
                "-co",
                "COMPRESS=LZW",
            ],
        );
        run(
            "gdaladdo",
            &["-q", "-r", r, &src.to_string_lossy(), "2", "4", "8"],
        );
        let before = levels(&src);
        let win = Window::new(600, 700, 70, 33);
        let opts = WriteOptions {
            overview_resampling: Some(upper.into()),
            ..Default::default()
        };
        edit(&src, win, &Destination::InPlace, &opts);
        let after = levels(&src);
        let reference = levels(&gdaladdo_reference(
            &src,
            dir.path(),
            r,
            &["2", "4", "8"],
            false,
        ));
        check_levels(&before, &after, &reference, (1024, 1024), win);
    }
}

#[test]
fn external_ovr_is_rebuilt_and_stale_statistics_removed() {
    for in_place in [true, false] {
        let dir = tempfile::tempdir().expect("tempdir");
        let src = dir.path().join("dem.tif");
        gdal_translate(
            &fixture("vinschgau_250m_utm32n.tif"),
            &src,
            &[
                "-co",
                "TILED=YES",
                "-co",
                "BLOCKXSIZE=64",
                "-co",
                "BLOCKYSIZE=64",
                "-co",
                "COMPRESS=DEFLATE",
            ],
        );
        run(
            "gdaladdo",
            &[
                "-q",
                "-ro",
                "-r",
                "average",
                &src.to_string_lossy(),
                "2",
                "4",
            ],
        );
        // Statistics in a PAM sidecar, as `gdalinfo -stats` leaves them,
        // beside a user's own item.
        let aux = dir.path().join("dem.tif.aux.xml");
        std::fs::write(
            &aux,
            "<PAMDataset>\n  <PAMRasterBand band=\"1\">\n    <Metadata>\n      <MDI key=\"STATISTICS_MAXIMUM\">3863</MDI>\n      <MDI key=\"STATISTICS_MINIMUM\">388</MDI>\n      <MDI key=\"SURVEY\">2019</MDI>\n    </Metadata>\n  </PAMRasterBand>\n</PAMDataset>\n",
        )
        .expect("write aux.xml");
        let ovr = dir.path().join("dem.tif.ovr");
        let before = levels(&src);
        assert_eq!(before.len(), 2, "external overviews seen");
        let (w, h, _, _) = gdal_values(&src);
        let win = Window::new(100, 120, 45, 30);
        let (dest, out) = if in_place {
            (Destination::InPlace, src.clone())
        } else {
            let o = dir.path().join("out.tif");
            (Destination::Path(o.clone()), o)
        };
        let ovr_before = std::fs::read(&ovr).expect("read ovr");
        edit(&src, win, &dest, &WriteOptions::default());
        let out_ovr = PathBuf::from(format!("{}.ovr", out.display()));
        assert!(out_ovr.is_file(), "{} written", out_ovr.display());
        if !in_place {
            assert_eq!(
                std::fs::read(&ovr).expect("read ovr"),
                ovr_before,
                "the input's .ovr untouched"
            );
        }
        let after = levels(&out);
        let reference = levels(&gdaladdo_reference(
            &out,
            dir.path(),
            "average",
            &["2", "4"],
            true,
        ));
        check_levels(&before, &after, &reference, (w, h), win);
        // No stale statistics beside the output, nor in it.
        let out_aux = PathBuf::from(format!("{}.aux.xml", out.display()));
        let t = std::fs::read_to_string(&out_aux).expect("the sidecar follows the output");
        assert!(
            !t.contains("STATISTICS_"),
            "stale statistics in {}: {t}",
            out_aux.display()
        );
        assert!(t.contains("SURVEY"), "the user's item kept: {t}");
        let md = gdalinfo(&out)["bands"][0]["metadata"].clone();
        assert!(!md.to_string().contains("STATISTICS_MAXIMUM"), "{md}");
        let names: Vec<String> = std::fs::read_dir(dir.path())
            .expect("list")
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            names
                .iter()
                .all(|n| !n.contains(".tmp") && !n.contains("demsketch-")),
            "{names:?}"
        );
    }
}
