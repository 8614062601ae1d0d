//! A large GeoTIFF whose header lies in the first bytes the open reads is
//! parsed from them and mapped only when its blocks are first read
//! (`src/raster/geotiff/file_bytes.rs`). What is read must be what GDAL
//! reads, whether the map was put off or not (a header beyond those bytes
//! is parsed from the mapped file), and a file replaced between the open
//! and the first read must fail in one line naming it, never give one
//! file's header with another's blocks.

mod common;

use common::{fixture, gdal_translate, gdal_values};
use demsketch::raster::Dem;

/// Our reading of `path`, whole, against GDAL's.
fn assert_reads_as_gdal(path: &std::path::Path) {
    let dem = Dem::open(path).expect("opens");
    let ours = dem.read_height_map(dem.full_window()).expect("reads");
    let (w, h, gdal, nodata) = gdal_values(path);
    assert_eq!((ours.width, ours.height), (w, h));
    for (i, (a, b)) in ours.data.iter().zip(&gdal).enumerate() {
        if Some(*b) == nodata || b.is_nan() {
            assert!(a.is_nan(), "cell {i}: {a} where GDAL has nodata");
        } else {
            assert_eq!(f64::from(*a), *b, "cell {i}");
        }
    }
}

#[test]
fn a_tiled_file_with_its_header_first_reads_as_gdal_does() {
    let dir = tempfile::tempdir().unwrap();
    // 64 x 64 blocks: the header (a few hundred bytes of offsets) lies in
    // the first 8 KB, the file is larger than the 64 KB read whole.
    let tif = dir.path().join("tiled.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &tif,
        &[
            "-co",
            "TILED=YES",
            "-co",
            "BLOCKXSIZE=64",
            "-co",
            "BLOCKYSIZE=64",
        ],
    );
    assert!(std::fs::metadata(&tif).unwrap().len() > 64 << 10);
    assert_reads_as_gdal(&tif);
}

#[test]
fn a_file_with_its_header_beyond_the_first_bytes_reads_as_gdal_does() {
    let dir = tempfile::tempdir().unwrap();
    // 16 x 16 blocks: thousands of offsets, past the first 8 KB.
    let tif = dir.path().join("small_blocks.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &tif,
        &[
            "-co",
            "TILED=YES",
            "-co",
            "BLOCKXSIZE=16",
            "-co",
            "BLOCKYSIZE=16",
        ],
    );
    assert_reads_as_gdal(&tif);
}

#[test]
fn a_file_replaced_after_the_open_fails_in_one_line_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("replaced.tif");
    let other = dir.path().join("other.tif");
    let extra = [
        "-co",
        "TILED=YES",
        "-co",
        "BLOCKXSIZE=64",
        "-co",
        "BLOCKYSIZE=64",
    ];
    gdal_translate(&fixture("zion_srtm_utm12n.tif"), &tif, &extra);
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &other,
        &[&extra[..], &["-scale", "0", "4000", "4000", "0"]].concat(),
    );
    let dem = Dem::open(&tif).expect("opens");
    std::fs::rename(&other, &tif).unwrap();
    let err = dem
        .read_height_map(dem.full_window())
        .expect_err("a replaced file is not read")
        .to_string();
    assert!(!err.contains('\n'), "one line: {err}");
    assert!(err.contains("replaced.tif"), "names the file: {err}");
    assert!(err.contains("changed since it was opened"), "{err}");
}
