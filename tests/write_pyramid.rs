//! Tile pyramids as `gdal_retile.py -levels` makes them (issue 15, item 5):
//! after an in-place correction of the base tiles, every level equals what
//! `gdal_retile.py` makes from the corrected DEM (the same correction
//! applied to the single GeoTIFF the pyramid was cut from, then retiled),
//! and the level tiles away from the change keep their bytes. Bad input
//! (an unknown resampling) exits 1 with one line and touches nothing.

mod common;

use common::*;
use std::path::{Path, PathBuf};

/// A lake of about 60 x 54 cells at the middle of the 400 x 400 cut.
const LAKE: &str = r#"{"type":"FeatureCollection",
 "crs":{"type":"name","properties":{"name":"urn:ogc:def:crs:EPSG::32612"}},
 "features":[{"type":"Feature","properties":{"kind":"lake","name":"pond"},
 "geometry":{"type":"Polygon","coordinates":[[[315500,4135000],[320500,4135000],
 [320500,4139500],[315500,4139500],[315500,4135000]]]}}]}"#;

/// `gdal_retile.py -levels 2 -ps 128 128 -r R -targetDir dir src`.
fn retile(src: &Path, dir: &Path, resampling: &str) {
    std::fs::create_dir_all(dir).unwrap();
    run(
        "gdal_retile.py",
        &[
            "-q",
            "-levels",
            "2",
            "-ps",
            "128",
            "128",
            "-r",
            resampling,
            "-targetDir",
            &dir.to_string_lossy(),
            &src.to_string_lossy(),
        ],
    );
}

/// The level tiles (`1/*.tif`, `2/*.tif`) of a pyramid, relative names.
fn level_tiles(dir: &Path) -> Vec<PathBuf> {
    let mut v = Vec::new();
    for k in ["1", "2"] {
        for e in std::fs::read_dir(dir.join(k)).unwrap().flatten() {
            v.push(Path::new(k).join(e.file_name()));
        }
    }
    v.sort();
    v
}

/// A `size` x `size` cut of the Zion fixture (`src.tif`), its pyramid
/// (`pyr/`, resampling `r`) and the lake's GeoJSON, under `dir`.
fn pyramid_case(dir: &Path, size: &str, r: &str) -> (PathBuf, PathBuf, PathBuf) {
    let src = dir.join("src.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &src,
        &["-srcwin", "0", "0", size, size],
    );
    let pyr = dir.join("pyr");
    retile(&src, &pyr, r);
    let lake = dir.join("lake.geojson");
    std::fs::write(&lake, LAKE).unwrap();
    (src, pyr, lake)
}

#[test]
fn every_level_equals_gdal_retile_of_the_corrected_dem_and_the_rest_keeps_its_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let (src, pyr, lake) = pyramid_case(tmp.path(), "400", "bilinear");
    let before: Vec<Vec<u8>> = level_tiles(&pyr)
        .iter()
        .map(|t| std::fs::read(pyr.join(t)).unwrap())
        .collect();

    let o = demsketch(&[
        "correct",
        &pyr.to_string_lossy(),
        "--features",
        &lake.to_string_lossy(),
        "--in-place",
        "--pyramid-resampling",
        "bilinear",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // The reference: the same correction of the single GeoTIFF, retiled
    // (under the same name: gdal_retile.py names the tiles after it).
    std::fs::create_dir(tmp.path().join("fixed")).unwrap();
    let fixed = tmp.path().join("fixed").join("src.tif");
    let o = demsketch(&[
        "correct",
        &src.to_string_lossy(),
        "--features",
        &lake.to_string_lossy(),
        "--out",
        &fixed.to_string_lossy(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let want = tmp.path().join("want");
    retile(&fixed, &want, "bilinear");

    let tiles = level_tiles(&pyr);
    assert_eq!(tiles, level_tiles(&want));
    let mut changed = 0;
    for (t, old) in tiles.iter().zip(&before) {
        let (got, exp) = (gdal_values(&pyr.join(t)), gdal_values(&want.join(t)));
        assert_eq!((got.0, got.1), (exp.0, exp.1), "{}: size", t.display());
        let off = got.2.iter().zip(&exp.2).filter(|(a, b)| a != b).count();
        assert_eq!(
            off,
            0,
            "{}: {off} cells differ from gdal_retile.py",
            t.display()
        );
        let bytes = std::fs::read(pyr.join(t)).unwrap();
        if &bytes != old {
            changed += 1;
            // A rewritten level tile differs from the old one in value too.
            assert_ne!(gdal_values(&pyr.join(t)).2, {
                let d = tmp.path().join("old.tif");
                std::fs::write(&d, old).unwrap();
                gdal_values(&d).2
            });
        }
    }
    // The lake lies under level 1's first tile and level 2's only one; the
    // other three level 1 tiles keep their bytes.
    assert_eq!(changed, 2, "level tiles rewritten");
}

#[test]
fn an_unknown_pyramid_resampling_is_one_line_and_touches_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, pyr, lake) = pyramid_case(tmp.path(), "200", "near");
    let before = snapshot(tmp.path());
    let o = demsketch(&[
        "correct",
        &pyr.to_string_lossy(),
        "--features",
        &lake.to_string_lossy(),
        "--in-place",
        "--pyramid-resampling",
        "bicubic",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("unknown pyramid resampling 'bicubic'"),
        "{err}"
    );
    assert!(snapshot(tmp.path()) == before, "something was written");
}
