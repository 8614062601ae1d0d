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
use std::path::{Path, PathBuf};

/// Our reading of `path`, whole, against GDAL's.
fn assert_reads_as_gdal(path: &Path) {
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

/// The Zion fixture copied to `dir/name` by GDAL, tiled in blocks of
/// `block` cells (uncompressed: larger than the 64 KB read whole), with
/// `extra` arguments.
fn tiled_copy(dir: &Path, name: &str, block: usize, extra: &[&str]) -> PathBuf {
    let out = dir.join(name);
    let (bx, by) = (format!("BLOCKXSIZE={block}"), format!("BLOCKYSIZE={block}"));
    let mut args = vec!["-co", "TILED=YES", "-co", &bx, "-co", &by];
    args.extend_from_slice(extra);
    gdal_translate(&fixture("zion_srtm_utm12n.tif"), &out, &args);
    assert!(std::fs::metadata(&out).unwrap().len() > 64 << 10);
    out
}

#[test]
fn a_tiled_file_with_its_header_first_reads_as_gdal_does() {
    // 64 x 64 blocks: the header (a few hundred bytes of offsets) lies in
    // the first 8 KB.
    let dir = tempfile::tempdir().unwrap();
    assert_reads_as_gdal(&tiled_copy(dir.path(), "tiled.tif", 64, &[]));
}

#[test]
fn a_file_with_its_header_beyond_the_first_bytes_reads_as_gdal_does() {
    // 16 x 16 blocks: thousands of offsets, past the first 8 KB.
    let dir = tempfile::tempdir().unwrap();
    assert_reads_as_gdal(&tiled_copy(dir.path(), "small_blocks.tif", 16, &[]));
}

#[test]
fn a_file_replaced_after_the_open_fails_in_one_line_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let tif = tiled_copy(dir.path(), "replaced.tif", 64, &[]);
    let other = tiled_copy(
        dir.path(),
        "other.tif",
        64,
        &["-scale", "0", "4000", "4000", "0"],
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
