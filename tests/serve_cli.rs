//! `demsketch serve` from the command line: the help names the options,
//! and bad input (a missing DEM, an --out naming the DEM, a bad --out
//! format, a bad --max-distance, an --underlay that is missing, not a
//! raster or without a georeference) is one line naming the file and the
//! problem, exit code 1, before anything listens or is written. The app
//! itself is tested through Chromium by `tests/browser/run.py` (run by
//! `tools/test.sh`).

mod common;

use common::{demsketch, fixture};

fn stderr_line(out: &std::process::Output) -> String {
    let s = String::from_utf8_lossy(&out.stderr).trim_end().to_string();
    assert_eq!(s.lines().count(), 1, "expected one line, got: {s}");
    s
}

#[test]
fn help_lists_the_options() {
    let out = demsketch(&["serve", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for opt in [
        "--out",
        "--port",
        "--bind",
        "--open",
        "--max-distance",
        "--min-fit",
        "--underlay",
    ] {
        assert!(help.contains(opt), "{opt} missing from: {help}");
    }
}

#[test]
fn missing_dem_is_one_line_exit_1() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = dir.path().join("nope.tif");
    let out_path = dir.path().join("out.tif");
    let out = demsketch(&[
        "serve",
        dem.to_str().expect("utf-8"),
        "--out",
        out_path.to_str().expect("utf-8"),
        "--port",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(line.contains("nope.tif"), "{line}");
    assert!(!out_path.exists());
}

#[test]
fn out_naming_the_dem_is_refused() {
    let dem = fixture("zion_srtm_utm12n.tif");
    let d = dem.to_str().expect("utf-8");
    let out = demsketch(&["serve", d, "--out", d, "--port", "0"]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(line.contains("--out"), "{line}");
}

#[test]
fn bad_out_format_and_distance_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("zion_srtm_utm12n.tif");
    let bad = dir.path().join("out.unknownext");
    let out = demsketch(&[
        "serve",
        dem.to_str().expect("utf-8"),
        "--out",
        bad.to_str().expect("utf-8"),
        "--port",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(line.contains("out.unknownext"), "{line}");
    let out = demsketch(&[
        "serve",
        dem.to_str().expect("utf-8"),
        "--max-distance",
        "-5",
        "--port",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    stderr_line(&out);
}

#[test]
fn bad_underlay_is_one_line_naming_it_exit_1() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("zion_srtm_utm12n.tif");
    let out_path = dir.path().join("out.tif");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not a raster\n").expect("write");
    let missing = dir.path().join("missing.tif");
    for (bad, why) in [(&missing, "no such file"), (&text, "not a raster")] {
        let out = demsketch(&[
            "serve",
            dem.to_str().expect("utf-8"),
            "--out",
            out_path.to_str().expect("utf-8"),
            "--port",
            "0",
            "--underlay",
            bad.to_str().expect("utf-8"),
        ]);
        assert_eq!(out.status.code(), Some(1));
        let line = stderr_line(&out);
        assert!(
            line.contains(bad.to_str().expect("utf-8")) && line.contains(why),
            "{line}"
        );
        assert!(!String::from_utf8_lossy(&out.stdout).contains("http://"));
        assert!(!out_path.exists());
    }
}
