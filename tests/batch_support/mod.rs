//! Shared by the batch tests: a 4 x 4 tile set (48 x 48 tiles) cut from the
//! tiled Texas fixture with `gdal_translate -srcwin`, sketches whose edits
//! raise a ridge in front of a viewpoint (the strokes of the write-safety
//! tests, which the edit fits on this flat DEM), placed near the tile
//! set's corners so that the plan has independent groups and, with two
//! edits at some corners, groups of overlapping edits; the reference of
//! applying them one by one with `demsketch edit OUT --in-place`; and
//! byte snapshots of the tiles.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::*;

/// The flags every edit of these tests runs with.
pub const FLAGS: [&str; 4] = ["--max-distance", "1000", "--min-fit", "0"];

/// The provenance time of every edit (SOURCE_DATE_EPOCH).
pub const EPOCH: &str = "1764547200";

/// Columns and rows of a tile, and tiles per side.
pub const TILE: usize = 48;
pub const SIDE: usize = 4;

/// The tile set (`SIDE` x `SIDE` tiles of `TILE` cells, DEFLATE, 16 x 16
/// blocks) cut from the Texas fixture at column/row 64, written at `dir/name`.
pub fn tile_set(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(name);
    std::fs::create_dir(&out).unwrap();
    for ty in 0..SIDE {
        for tx in 0..SIDE {
            let (x, y) = ((64 + tx * TILE).to_string(), (64 + ty * TILE).to_string());
            let t = TILE.to_string();
            gdal_translate(
                &fixture("texas_srtm90m_tiled_int16.tif"),
                &out.join(format!("tile_{ty}_{tx}.tif")),
                &[
                    "-srcwin",
                    &x,
                    &y,
                    &t,
                    &t,
                    "-co",
                    "TILED=YES",
                    "-co",
                    "BLOCKXSIZE=16",
                    "-co",
                    "BLOCKYSIZE=16",
                    "-co",
                    "COMPRESS=DEFLATE",
                ],
            );
        }
    }
    out
}

/// Lon/lat of the centre of cell (col, row) of the tile set.
pub fn lonlat(col: f64, row: f64) -> (f64, f64) {
    let (x0, y0, d) = (-97.485, 32.821_666_666_666_67, 0.000_833_333_333_333);
    (x0 + (64.0 + col + 0.5) * d, y0 - (64.0 + row + 0.5) * d)
}

/// A sketch raising a ridge in front of the viewpoint at cell (col, row),
/// looking `heading` degrees; `drop` px lowers the stroke (towards the
/// horizon, row 50).
pub fn sketch(col: f64, row: f64, heading: f64, drop: f64) -> String {
    let (lon, lat) = lonlat(col, row);
    let y = |v: f64| v + drop;
    format!(
        r#"{{"views":[{{"name":"v","viewpoint":{{"lon":{lon},"lat":{lat},"eye_height_m":1.7}},
 "camera":{{"heading_deg":{heading},"pitch_deg":0.0,"roll_deg":0.0,"hfov_deg":60.0,"width":200,"height":100}},
 "strokes":[{{"id":"s","points":[[60.0,{}],[80.0,{}],[100.0,{}],[120.0,{}]]}}]}}],
 "options":{{"influence_m":200.0}}}}"#,
        y(46.0),
        y(44.5),
        y(44.0),
        y(45.0)
    )
}

/// Where the edits stand (cell of the tile set, heading, drop): two at the
/// top-left corner and two at the bottom-left one (each pair one group),
/// one at each other corner.
pub fn placements(n: usize) -> Vec<(f64, f64, f64, f64)> {
    let base = [
        (20.0, 20.0, 0.0, 1.5),
        (172.0, 20.0, 180.0, 1.5),
        (20.0, 172.0, 90.0, 0.0),
        (24.0, 18.0, 90.0, 1.5),
        (172.0, 172.0, 270.0, 1.5),
        (18.0, 168.0, 0.0, 1.5),
    ];
    base.iter().copied().cycle().take(n).collect()
}

/// Write `n` sketches and a JSON manifest of them into `dir`; returns the
/// manifest and the sketch paths in order.
pub fn manifest(dir: &Path, n: usize) -> (PathBuf, Vec<PathBuf>) {
    let sk = dir.join("sketches");
    std::fs::create_dir_all(&sk).unwrap();
    let mut paths = Vec::new();
    let mut entries = Vec::new();
    for (k, (c, r, h, l)) in placements(n).into_iter().enumerate() {
        let p = sk.join(format!("e{k:02}.json"));
        std::fs::write(&p, sketch(c, r, h, l)).unwrap();
        entries.push(format!(
            r#"{{"id":"e{k:02}","sketch":"sketches/e{k:02}.json"}}"#
        ));
        paths.push(p);
    }
    let m = dir.join("manifest.json");
    std::fs::write(&m, format!(r#"{{"edits":[{}]}}"#, entries.join(","))).unwrap();
    (m, paths)
}

/// The demsketch binary with the batch tests' environment.
pub fn cmd() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_demsketch"));
    c.env("GDAL_PAM_ENABLED", "NO")
        .env("SOURCE_DATE_EPOCH", EPOCH)
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("JOB_COMPLETION_INDEX");
    c
}

pub fn out_of(c: &mut Command) -> Output {
    c.output().expect("run demsketch")
}

/// The tiles (`*.tif`) of a directory with their bytes, by name.
pub fn tiles(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

/// The reference: `dem` copied to `out`, then every sketch applied in
/// order with `demsketch edit OUT --sketch S --in-place` (FLAGS). Returns
/// the tiles' bytes and the changed cells of each edit; `out` is removed
/// afterwards so that the batch under test can be written at the same path
/// (the provenance records the path).
pub fn reference(
    dem: &Path,
    sketches: &[PathBuf],
    out: &Path,
) -> (Vec<(String, Vec<u8>)>, Vec<u64>) {
    std::fs::create_dir(out).unwrap();
    for (name, bytes) in tiles(dem) {
        std::fs::write(out.join(name), bytes).unwrap();
    }
    let mut changed = Vec::new();
    for s in sketches {
        let r = out_of(
            cmd()
                .arg("edit")
                .arg(out)
                .arg("--sketch")
                .arg(s)
                .arg("--in-place")
                .args(FLAGS)
                .arg("--json")
                .arg("--quiet"),
        );
        assert!(
            r.status.success(),
            "reference edit {} failed: {}",
            s.display(),
            String::from_utf8_lossy(&r.stderr)
        );
        let rep: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        changed.push(rep["changed_cells"].as_u64().unwrap());
    }
    let t = tiles(out);
    std::fs::remove_dir_all(out).unwrap();
    (t, changed)
}

/// Tiles that differ between two snapshots (names).
pub fn differing(a: &[(String, Vec<u8>)], b: &[(String, Vec<u8>)]) -> Vec<String> {
    assert_eq!(a.len(), b.len(), "different tile counts");
    a.iter()
        .zip(b)
        .filter(|(x, y)| x != y)
        .map(|(x, _)| x.0.clone())
        .collect()
}

/// `gdalinfo -checksum` of every tile (GDAL reads them all).
pub fn gdal_checksums(dir: &Path) -> Vec<i64> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .collect();
    names.sort();
    names
        .iter()
        .map(|p| {
            let o = run("gdalinfo", &["-json", "-checksum", &p.to_string_lossy()]);
            let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
            v["bands"][0]["checksum"].as_i64().unwrap()
        })
        .collect()
}
