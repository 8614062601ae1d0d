//! Shared by the write-safety tests: a small DEM cut from the tiled Texas
//! fixture (a 96 x 96 single file and a 2 x 2 tile directory of it), two
//! small sketches whose edits touch disjoint tiles (A: the bottom row, B:
//! the top row), and checks on directories.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use crate::common::*;

/// The crop of the fixture everything is cut from, written into `dir`.
pub fn crop(dir: &Path) -> PathBuf {
    let p = dir.join("crop.tif");
    gdal_translate(
        &fixture("texas_srtm90m_tiled_int16.tif"),
        &p,
        &["-srcwin", "100", "100", "96", "96"],
    );
    p
}

/// A 2 x 2 tile directory (48 x 48 tiles, DEFLATE, 16 x 16 blocks) at `dir/name`.
pub fn tile_dir(dir: &Path, name: &str) -> PathBuf {
    let src = crop(dir);
    let out = dir.join(name);
    std::fs::create_dir(&out).unwrap();
    for ty in 0..2 {
        for tx in 0..2 {
            let (x, y) = ((tx * 48).to_string(), (ty * 48).to_string());
            gdal_translate(
                &src,
                &out.join(format!("tile_{ty}_{tx}.tif")),
                &[
                    "-srcwin",
                    &x,
                    &y,
                    "48",
                    "48",
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
    std::fs::remove_file(&src).unwrap();
    out
}

fn sketch(lat: f64, heading: f64) -> String {
    format!(
        r#"{{"views":[{{"name":"v","viewpoint":{{"lon":-97.36,"lat":{lat},"eye_height_m":1.7}},
 "camera":{{"heading_deg":{heading},"pitch_deg":0.0,"roll_deg":0.0,"hfov_deg":60.0,"width":200,"height":100}},
 "strokes":[{{"id":"s","points":[[60.0,46.0],[80.0,44.5],[100.0,44.0],[120.0,45.0]]}}]}}],
 "options":{{"influence_m":300.0}}}}"#
    )
}

/// Sketch A (raises a ridge in the bottom row of tiles) and B (the top
/// row), written into `dir`.
pub fn sketches(dir: &Path) -> (PathBuf, PathBuf) {
    let (a, b) = (dir.join("a.json"), dir.join("b.json"));
    std::fs::write(&a, sketch(32.665, 0.0)).unwrap();
    std::fs::write(&b, sketch(32.732, 180.0)).unwrap();
    (a, b)
}

/// `demsketch edit DEM --sketch S --min-fit 0` plus `extra`, as a command.
pub fn edit_cmd(dem: &Path, sketch: &Path, extra: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_demsketch"));
    c.arg("edit")
        .arg(dem)
        .arg("--sketch")
        .arg(sketch)
        .args(["--min-fit", "0"])
        .args(extra)
        .env("GDAL_PAM_ENABLED", "NO");
    c
}

pub fn edit(dem: &Path, sketch: &Path, extra: &[&str]) -> Output {
    edit_cmd(dem, sketch, extra)
        .output()
        .expect("run demsketch")
}

/// Band 1 of every tile of a directory (sorted by name), as GDAL reads it.
pub fn values(dir: &Path) -> Vec<(String, Vec<f64>)> {
    let mut v: Vec<(String, Vec<f64>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "tif"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                gdal_values(&p).2,
            )
        })
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// Entries under `dir` (recursively) whose name marks a demsketch
/// temporary file or staging directory.
pub fn temporaries(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            let n = e.file_name().to_string_lossy().into_owned();
            if n.contains("demsketch") && n.ends_with(".tmp") {
                out.push(p.clone());
            }
            if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                out.extend(temporaries(&p));
            }
        }
    }
    out
}

/// stderr of a run as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}
