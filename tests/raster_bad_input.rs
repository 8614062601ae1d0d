//! Bad input: every kind of broken or unsupported DEM gives exit code 1 and
//! one line naming the file and the problem, and nothing is created or
//! modified.

mod common;

use std::path::{Path, PathBuf};

use common::*;

/// Run `demsketch ARGS` and check the failure contract. Returns stderr.
fn expect_user_error(dir: &Path, args: &[&str], expect_in_message: &[&str]) -> String {
    let before = snapshot(dir);
    let out = demsketch(args);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(1),
        "{args:?}: exit code; stderr: {stderr}"
    );
    assert_eq!(
        stderr.trim_end().lines().count(),
        1,
        "{args:?}: one line, got: {stderr}"
    );
    for needle in expect_in_message {
        assert!(
            stderr.contains(needle),
            "{args:?}: '{needle}' not in: {stderr}"
        );
    }
    assert_eq!(
        before,
        snapshot(dir),
        "{args:?}: nothing may be created or modified"
    );
    stderr
}

/// A minimal little-endian TIFF whose header claims `w` x `h` Float32 pixels
/// in one strip, with a georeference.
fn huge_header_tiff(path: &Path, w: u32, h: u32) {
    let mut entries: Vec<(u16, u16, u32, u32)> = vec![
        (256, 4, 1, w),  // ImageWidth
        (257, 4, 1, h),  // ImageLength
        (258, 3, 1, 32), // BitsPerSample
        (259, 3, 1, 1),  // Compression none
        (262, 3, 1, 1),  // Photometric
        (273, 4, 1, 8),  // StripOffsets
        (277, 3, 1, 1),  // SamplesPerPixel
        (278, 4, 1, h),  // RowsPerStrip
        (279, 4, 1, 16), // StripByteCounts
        (339, 3, 1, 3),  // SampleFormat float
    ];
    entries.sort();
    let mut b: Vec<u8> = b"II*\0".to_vec();
    let ifd_offset = 8u32 + 16;
    b.extend_from_slice(&ifd_offset.to_le_bytes());
    b.extend_from_slice(&[0u8; 16]);
    // Scale + tiepoint doubles go after the IFD.
    let n = entries.len() as u16 + 2;
    let data_offset = ifd_offset + 2 + 12 * n as u32 + 4;
    b.extend_from_slice(&n.to_le_bytes());
    for (tag, typ, count, value) in &entries {
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&typ.to_le_bytes());
        b.extend_from_slice(&count.to_le_bytes());
        b.extend_from_slice(&value.to_le_bytes());
    }
    for (tag, count, off) in [(33550u16, 3u32, data_offset), (33922, 6, data_offset + 24)] {
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&12u16.to_le_bytes());
        b.extend_from_slice(&count.to_le_bytes());
        b.extend_from_slice(&off.to_le_bytes());
    }
    b.extend_from_slice(&0u32.to_le_bytes());
    for v in [1.0f64, 1.0, 0.0, 0.0, 0.0, 0.0, 500000.0, 4000000.0, 0.0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, b).expect("write test TIFF");
}

/// A copy of a little-endian classic TIFF with the Compression tag of its
/// first IFD set to `code`.
fn patch_compression(bytes: &[u8], code: u16) -> Vec<u8> {
    let mut b = bytes.to_vec();
    let ifd = u32::from_le_bytes(b[4..8].try_into().expect("4 bytes")) as usize;
    let n = u16::from_le_bytes([b[ifd], b[ifd + 1]]) as usize;
    for i in 0..n {
        let e = ifd + 2 + 12 * i;
        if u16::from_le_bytes([b[e], b[e + 1]]) == 259 {
            b[e + 8..e + 10].copy_from_slice(&code.to_le_bytes());
            return b;
        }
    }
    panic!("no Compression tag");
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

#[test]
fn broken_files_fail_cleanly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let zion = fixture("zion_srtm_utm12n.tif");

    // Truncated: the second half of the file is gone.
    let truncated = d.join("truncated.tif");
    let bytes = std::fs::read(&zion).expect("read fixture");
    std::fs::write(&truncated, &bytes[..bytes.len() / 2]).expect("write");
    expect_user_error(
        d,
        &["info", &s(&truncated)],
        &["truncated.tif", "truncated"],
    );

    // Corrupt: the IFD offset points nowhere.
    let corrupt = d.join("corrupt.tif");
    let mut c = bytes.clone();
    c[4..8].copy_from_slice(&0x7fff_fff0u32.to_le_bytes());
    std::fs::write(&corrupt, &c).expect("write");
    expect_user_error(d, &["info", &s(&corrupt)], &["corrupt.tif"]);

    // Not a TIFF at all.
    let text = d.join("notes.tif");
    std::fs::write(&text, "elevation,lon,lat\n1,2,3\n").expect("write");
    expect_user_error(d, &["info", &s(&text)], &["notes.tif", "not a TIFF"]);

    // Empty file.
    let empty = d.join("empty.tif");
    std::fs::write(&empty, "").expect("write");
    expect_user_error(d, &["info", &s(&empty)], &["empty.tif", "not a TIFF"]);

    // Missing file.
    expect_user_error(d, &["info", &s(&d.join("missing.tif"))], &["missing.tif"]);

    // A header claiming 1,000,000 x 1,000,000 pixels.
    let huge = d.join("huge.tif");
    huge_header_tiff(&huge, 1_000_000, 1_000_000);
    expect_user_error(d, &["info", &s(&huge)], &["huge.tif", "memory budget"]);
}

#[test]
fn missing_georeference_and_unsupported_encodings_fail_cleanly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let zion = fixture("zion_srtm_utm12n.tif");
    let plain = d.join("plain.tif");
    gdal_translate(&zion, &plain, &["-co", "PROFILE=BASELINE"]);
    expect_user_error(d, &["info", &s(&plain)], &["plain.tif", "no georeference"]);

    // A compression neither the native decoder nor GDAL knows (JPEG, LERC
    // and the like are read through GDAL: tests/raster_gdal_fallback.rs).
    let unknown = d.join("unknown_compression.tif");
    std::fs::write(
        &unknown,
        patch_compression(&std::fs::read(&zion).expect("read"), 0x7777),
    )
    .expect("write");
    expect_user_error(
        d,
        &["info", &s(&unknown)],
        &["unknown_compression.tif", "unsupported", "compression"],
    );

    let rgb = d.join("rgb.tif");
    gdal_translate(&zion, &rgb, &["-b", "1", "-b", "1", "-b", "1"]);
    expect_user_error(
        d,
        &["info", &s(&rgb)],
        &["rgb.tif", "unsupported", "3 samples"],
    );
}

fn tile_dir_with(d: &Path, name: &str, second: impl FnOnce(&Path)) -> PathBuf {
    let tiles = d.join(name);
    std::fs::create_dir(&tiles).expect("mkdir");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &tiles.join("a.tif"),
        &["-srcwin", "0", "0", "200", "200"],
    );
    second(&tiles.join("b.tif"));
    tiles
}

#[test]
fn mismatched_tiles_fail_cleanly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let zion = fixture("zion_srtm_utm12n.tif");
    let crs = tile_dir_with(d, "crs", |b| {
        gdal_translate(
            &zion,
            b,
            &["-srcwin", "200", "0", "200", "200", "-a_srs", "EPSG:32613"],
        )
    });
    expect_user_error(d, &["info", &s(&crs)], &["b.tif", "different CRS"]);

    let size = tile_dir_with(d, "pixel_size", |b| {
        gdal_translate(
            &zion,
            b,
            &[
                "-srcwin", "200", "0", "200", "200", "-outsize", "50%", "50%",
            ],
        )
    });
    expect_user_error(d, &["info", &s(&size)], &["b.tif", "pixel size"]);

    let gt = gdalinfo(&zion)["geoTransform"].clone();
    let x0 = gt[0].as_f64().expect("gt") + 200.5 * gt[1].as_f64().expect("gt");
    let y0 = gt[3].as_f64().expect("gt");
    let dx = gt[1].as_f64().expect("gt");
    let ullr = [x0, y0, x0 + 200.0 * dx, y0 - 200.0 * dx].map(|v| v.to_string());
    let misaligned = tile_dir_with(d, "misaligned", |b| {
        gdal_translate(
            &zion,
            b,
            &[
                "-srcwin", "200", "0", "200", "200", "-a_ullr", &ullr[0], &ullr[1], &ullr[2],
                &ullr[3],
            ],
        )
    });
    expect_user_error(d, &["info", &s(&misaligned)], &["b.tif", "not aligned"]);

    // Overlapping tiles: the error names the first tile (in name order)
    // that overlaps an earlier one, and the first earlier one it overlaps
    // (the open checks overlaps with a sweep, then names them so).
    let overlap = tile_dir_with(d, "overlap", |b| {
        gdal_translate(&zion, b, &["-srcwin", "200", "0", "200", "200"])
    });
    gdal_translate(
        &zion,
        &overlap.join("c.tif"),
        &["-srcwin", "300", "100", "200", "200"],
    );
    gdal_translate(
        &zion,
        &overlap.join("d.tif"),
        &["-srcwin", "0", "150", "200", "200"],
    );
    let msg = expect_user_error(d, &["info", &s(&overlap)], &["overlaps tile"]);
    assert!(
        msg.contains("c.tif") && msg.contains("overlaps tile") && msg.contains("b.tif"),
        "{msg}"
    );
    assert!(
        msg.find("c.tif") < msg.find("overlaps tile"),
        "names c.tif as the overlapping tile: {msg}"
    );

    let empty = d.join("no_tiles");
    std::fs::create_dir(&empty).expect("mkdir");
    expect_user_error(d, &["info", &s(&empty)], &["no_tiles", "no GeoTIFF tiles"]);
}

/// Bad flags are user errors: exit 1 (clap's own default would be 2, which
/// demsketch keeps for internal errors), a message naming the flag.
#[test]
fn bad_flags_exit_with_one() {
    let zion = s(&fixture("zion_srtm_utm12n.tif"));
    for args in [
        vec![
            "view",
            zion.as_str(),
            "--lon",
            "-112.9",
            "--lat",
            "37.4",
            "--size",
            "12y9",
            "--out",
            "x.png",
        ],
        vec!["info", zion.as_str(), "--no-such-flag"],
        vec!["no-such-command"],
    ] {
        let out = demsketch(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        assert!(!out.stderr.is_empty(), "{args:?}");
    }
    assert_eq!(demsketch(&["--help"]).status.code(), Some(0));
}
