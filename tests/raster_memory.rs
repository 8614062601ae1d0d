//! Bounded memory: crafted files made here from a fixture by patching bytes
//! (a tag count set to 0xFFFFFFFF; a ~1 KB tiled file whose header claims
//! 32768 x 32768 tiles, in every compression the native decoder reads) and
//! a camera too large for memory fail with exit code 1 and one line, in
//! under a second of CPU time and 500 MB of peak memory (`/usr/bin/time`),
//! and never abort under an address-space limit (`prlimit --as`).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;

const ZION: &str = "zion_srtm_utm12n.tif";

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

/// The byte offset of the IFD entry of `tag` in the first IFD of a
/// little-endian classic TIFF.
fn entry(b: &[u8], tag: u16) -> usize {
    assert_eq!(&b[..4], b"II*\0", "little-endian classic TIFF");
    let ifd = u32::from_le_bytes(b[4..8].try_into().expect("4 bytes")) as usize;
    let n = u16::from_le_bytes([b[ifd], b[ifd + 1]]) as usize;
    (0..n)
        .map(|i| ifd + 2 + 12 * i)
        .find(|&e| u16::from_le_bytes([b[e], b[e + 1]]) == tag)
        .unwrap_or_else(|| panic!("no tag {tag}"))
}

/// Set the count of `tag`.
fn set_count(b: &mut [u8], tag: u16, count: u32) {
    let e = entry(b, tag);
    b[e + 4..e + 8].copy_from_slice(&count.to_le_bytes());
}

/// Set the value of a SHORT `tag` with one value.
fn set_short(b: &mut [u8], tag: u16, v: u16) {
    let e = entry(b, tag);
    assert_eq!(
        u16::from_le_bytes([b[e + 2], b[e + 3]]),
        3,
        "tag {tag} is SHORT"
    );
    b[e + 8..e + 10].copy_from_slice(&v.to_le_bytes());
}

fn have(tool: &str) -> bool {
    Path::new(tool).exists()
}

/// What a run cost: exit code, stderr, peak RSS (kB) and CPU seconds.
struct Cost {
    code: Option<i32>,
    stderr: String,
    max_rss_kb: u64,
    cpu_s: f64,
}

/// Run demsketch under `/usr/bin/time`, optionally under `prlimit --as`.
fn measure(args: &[&str], address_space: Option<u64>, dir: &Path) -> Cost {
    let report = dir.join("time.txt");
    let mut cmd = Command::new("/usr/bin/time");
    cmd.args(["-f", "%M %U %S", "-o", &s(&report)]);
    if let Some(limit) = address_space {
        cmd.arg("prlimit").arg(format!("--as={limit}"));
    }
    let out = cmd
        .arg(env!("CARGO_BIN_EXE_demsketch"))
        .args(args)
        .env("GDAL_PAM_ENABLED", "NO")
        .output()
        .expect("run /usr/bin/time");
    let t = std::fs::read_to_string(&report).expect("time report");
    let last = t.lines().last().unwrap_or("");
    let f: Vec<f64> = last
        .split_whitespace()
        .filter_map(|x| x.parse().ok())
        .collect();
    assert_eq!(f.len(), 3, "time report: {t}");
    Cost {
        code: out.status.code(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        max_rss_kb: f[0] as u64,
        cpu_s: f[1] + f[2],
    }
}

/// The failure contract for a crafted input: exit 1, one line naming the
/// file, under 1 s CPU and 500 MB peak; and exit 1 (not an abort) under a
/// 1 GB address-space limit.
fn expect_bounded_failure(args: &[&str], name: &str, dir: &Path) {
    if !have("/usr/bin/time") {
        eprintln!("/usr/bin/time not installed: checking exit code and message only");
        let out = demsketch(args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        return;
    }
    let c = measure(args, None, dir);
    assert_eq!(c.code, Some(1), "{args:?}: exit code; {}", c.stderr);
    assert_eq!(
        c.stderr.trim_end().lines().count(),
        1,
        "{args:?}: one line: {}",
        c.stderr
    );
    assert!(
        c.stderr.contains(name),
        "{args:?}: names {name}: {}",
        c.stderr
    );
    assert!(
        c.max_rss_kb < 500 * 1024,
        "{args:?}: peak memory {} MB",
        c.max_rss_kb / 1024
    );
    assert!(c.cpu_s < 1.0, "{args:?}: {} s CPU", c.cpu_s);
    if have("/usr/bin/prlimit") {
        let c = measure(args, Some(1 << 30), dir);
        assert_eq!(
            c.code,
            Some(1),
            "{args:?} under a 1 GB address-space limit: {}",
            c.stderr
        );
        assert_eq!(c.stderr.trim_end().lines().count(), 1, "{}", c.stderr);
    }
}

#[test]
fn tag_counts_of_0xffffffff_fail_in_one_line_with_little_memory() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = std::fs::read(fixture(ZION)).expect("fixture");
    // StripOffsets, StripByteCounts, ModelPixelScale, ModelTiepoint,
    // GeoKeyDirectory, GeoAsciiParams, GDAL_NODATA.
    for tag in [273u16, 279, 33550, 33922, 34735, 34737, 42113] {
        let mut b = bytes.clone();
        set_count(&mut b, tag, u32::MAX);
        let name = format!("count_{tag}.tif");
        let p = dir.path().join(&name);
        std::fs::write(&p, &b).expect("write");
        expect_bounded_failure(&["info", &s(&p)], &name, dir.path());
    }
}

/// A 16 x 16 crop of the fixture as one 16 x 16 tile in `compression`,
/// with width, height and tile size patched to `claim`.
fn bomb(dir: &Path, compression: &str, claim: u16) -> PathBuf {
    let small = dir.join(format!("small_{compression}.tif"));
    gdal_translate(
        &fixture(ZION),
        &small,
        &[
            "-srcwin",
            "0",
            "0",
            "16",
            "16",
            "-co",
            "TILED=YES",
            "-co",
            "BLOCKXSIZE=16",
            "-co",
            "BLOCKYSIZE=16",
            "-co",
            &format!("COMPRESS={compression}"),
        ],
    );
    let mut b = std::fs::read(&small).expect("read");
    assert!(b.len() < 2048, "{compression}: {} bytes", b.len());
    for tag in [256u16, 257, 322, 323] {
        set_short(&mut b, tag, claim);
    }
    let p = dir.join(format!("bomb_{compression}_{claim}.tif"));
    std::fs::write(&p, &b).expect("write");
    p
}

#[test]
fn one_kilobyte_tiled_bombs_fail_in_one_line_with_little_memory() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    for compression in ["DEFLATE", "LZW", "ZSTD", "PACKBITS", "NONE"] {
        for claim in [32768u16, 65520] {
            let p = bomb(d, compression, claim);
            let name = p.file_name().expect("name").to_string_lossy().into_owned();
            // `info` scans every block; `view` reads a window.
            expect_bounded_failure(&["info", &s(&p)], &name, d);
            expect_bounded_failure(
                &[
                    "view",
                    &s(&p),
                    "--lon",
                    "-113.0463",
                    "--lat",
                    "37.3225",
                    "--out",
                    &s(&d.join("v.png")),
                ],
                &name,
                d,
            );
            assert!(!d.join("v.png").exists(), "nothing written");
        }
    }
}

#[test]
fn a_camera_too_large_for_memory_fails_in_one_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let zion = fixture(ZION);
    for size in ["65535x65535", "200000x200000"] {
        expect_bounded_failure(
            &[
                "view",
                &s(&zion),
                "--lon",
                "-113.0463",
                "--lat",
                "37.3225",
                "--size",
                size,
                "--out",
                &s(&dir.path().join("v.png")),
            ],
            "image size",
            dir.path(),
        );
    }
}
