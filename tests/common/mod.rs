//! Helpers shared by the integration tests: fixtures, GDAL command-line
//! references and the `demsketch` binary.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

pub const FIXTURES: [&str; 6] = [
    "arenal_aster30m_epsg4326.tif",
    "zion_srtm90m_epsg4326.tif",
    "zion_srtm_utm12n.tif",
    "vinschgau_250m_utm32n.tif",
    "texas_srtm90m_tiled_int16.tif",
    "nz_1km_nan_nodata.tif",
];

/// Run a command and fail the test with its stderr if it fails.
pub fn run(cmd: &str, args: &[&str]) -> Output {
    let out = Command::new(cmd)
        .args(args)
        .env("GDAL_PAM_ENABLED", "NO")
        .output()
        .unwrap_or_else(|e| panic!("cannot run {cmd}: {e}"));
    assert!(
        out.status.success(),
        "{cmd} {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `gdal_translate` with extra arguments, quietly.
pub fn gdal_translate(src: &Path, dst: &Path, extra: &[&str]) {
    let mut args: Vec<&str> = vec!["-q"];
    args.extend_from_slice(extra);
    let (s, d) = (src.to_string_lossy(), dst.to_string_lossy());
    args.push(&s);
    args.push(&d);
    run("gdal_translate", &args);
}

/// `gdalinfo -json` of a file, parsed.
pub fn gdalinfo(path: &Path) -> serde_json::Value {
    let out = run("gdalinfo", &["-json", &path.to_string_lossy()]);
    serde_json::from_slice(&out.stdout).expect("gdalinfo -json output is JSON")
}

/// The demsketch binary built for these tests.
pub fn demsketch(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_demsketch"))
        .args(args)
        .env("GDAL_PAM_ENABLED", "NO")
        .output()
        .expect("run demsketch")
}

/// `edit` of `input` with `sketch` into `out` (and its report, where
/// given) as the fidelity suite runs it (`--allow-partial`, 50 km); the
/// edit must succeed.
pub fn suite_edit(input: &Path, sketch: &Path, out: &Path, report: Option<&Path>) {
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let (input, sketch, out) = (s(input), s(sketch), s(out));
    let report = report.map(s);
    let mut args = vec!["edit", &input, "--sketch", &sketch, "--out", &out];
    if let Some(r) = &report {
        args.extend(["--report", r.as_str()]);
    }
    args.extend(["--allow-partial", "--max-distance", "50000", "-q"]);
    let o = demsketch(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// What [`edit_fidelity_case`] leaves: its directory, the written DEM and
/// the report.
pub struct EditedCase {
    pub dir: tempfile::TempDir,
    pub out: PathBuf,
    pub report: serde_json::Value,
}

/// The fixture `dem` edited as the fidelity suite edits it
/// ([`suite_edit`]) with the sketch `tests/data/<sketch>` (a case the
/// suite's judge traced), into a temporary directory.
pub fn edit_fidelity_case(dem: &str, sketch: &str) -> EditedCase {
    let dir = tempfile::tempdir().expect("temporary directory");
    let sketch = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(sketch);
    let (out, report) = (dir.path().join("out.tif"), dir.path().join("report.json"));
    suite_edit(&fixture(dem), &sketch, &out, Some(&report));
    let report =
        serde_json::from_slice(&std::fs::read(&report).expect("report")).expect("report JSON");
    EditedCase { dir, out, report }
}

/// Every file under `dir` with its bytes, for "nothing changed" checks.
pub fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                v.extend(snapshot(&p));
            } else if let Ok(b) = std::fs::read(&p) {
                v.push((p, b));
            }
        }
    }
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

/// Band 1 of a raster read by GDAL as f64, row-major.
pub fn gdal_values(path: &Path) -> (usize, usize, Vec<f64>, Option<f64>) {
    let ds = gdal::Dataset::open(path).expect("GDAL opens the file");
    let band = ds.rasterband(1).expect("band 1");
    let (w, h) = band.size();
    let buf = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .expect("GDAL reads the band");
    (w, h, buf.data().to_vec(), band.no_data_value())
}

/// A sketch of one view as the fidelity suite draws it (640 x 360 px,
/// 60 degrees wide, level) from `viewpoint` (lon, lat, absolute eye
/// altitude in metres) towards `heading_deg`, with one stroke `s0` through
/// `points`, and an influence of 1,500 m.
pub fn one_stroke_sketch(
    viewpoint: [f64; 3],
    heading_deg: f64,
    points: &[[f64; 2]],
) -> serde_json::Value {
    serde_json::json!({
        "views": [{
            "name": "fidelity",
            "viewpoint": {"lon": viewpoint[0], "lat": viewpoint[1], "alt_m": viewpoint[2]},
            "camera": {"heading_deg": heading_deg, "pitch_deg": 0.0, "roll_deg": 0.0,
                       "hfov_deg": 60.0, "width": 640, "height": 360},
            "strokes": [{"id": "s0", "points": points}]
        }],
        "options": {"influence_m": 1500.0}
    })
}

/// `demsketch edit DEM --sketch SKETCH --allow-partial` plus `extra`, with
/// the output and the report in a temporary directory: asserts that it
/// succeeds and returns the report.
pub fn edit_report(dem: &Path, sketch: &serde_json::Value, extra: &[&str]) -> serde_json::Value {
    let tmp = tempfile::tempdir().expect("temporary directory");
    let sk = tmp.path().join("sketch.json");
    std::fs::write(&sk, serde_json::to_string(sketch).expect("sketch JSON")).expect("write sketch");
    let (out, rep) = (tmp.path().join("out.tif"), tmp.path().join("report.json"));
    let paths = [dem, &sk, &out, &rep].map(|p| p.to_string_lossy().into_owned());
    let mut args = vec![
        "edit",
        &paths[0],
        "--sketch",
        &paths[1],
        "--out",
        &paths[2],
        "--report",
        &paths[3],
        "--allow-partial",
    ];
    args.extend_from_slice(extra);
    let o = demsketch(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(&rep).expect("report")).expect("report JSON")
}

/// A fidelity suite case of one stroke (a sketch as [`one_stroke_sketch`]
/// draws it) edited on fixture `dem` with `extra` arguments; `influence_m`,
/// where given, in place of the sketch's 1,500 m.
pub struct OneStrokeCase {
    pub dem: &'static str,
    pub viewpoint: [f64; 3],
    pub heading_deg: f64,
    pub points: &'static [[f64; 2]],
    pub influence_m: Option<f64>,
    pub extra: &'static [&'static str],
}

impl OneStrokeCase {
    /// The case's sketch.
    pub fn sketch(&self) -> serde_json::Value {
        let mut s = one_stroke_sketch(self.viewpoint, self.heading_deg, self.points);
        if let Some(m) = self.influence_m {
            s["options"]["influence_m"] = m.into();
        }
        s
    }

    /// The report of the case's edit (see [`edit_report`]).
    pub fn edit(&self) -> EditedStroke {
        EditedStroke(edit_report(&fixture(self.dem), &self.sketch(), self.extra))
    }
}

/// The report of a [`OneStrokeCase`]'s edit.
pub struct EditedStroke(pub serde_json::Value);

impl EditedStroke {
    /// The whole report.
    pub fn report(&self) -> &serde_json::Value {
        &self.0
    }

    /// The report on the stroke.
    pub fn stroke(&self) -> &serde_json::Value {
        &self.0["views"][0]["strokes"][0]
    }

    /// The nearest and farthest depth at which the stroke was placed, m.
    pub fn depth_m(&self) -> (f64, f64) {
        let depth = &self.stroke()["match"]["depth_m"];
        let at = |i: usize| depth[i].as_f64().expect("a depth in metres");
        (at(0), at(1))
    }

    /// The fraction of the stroke the edited DEM fits.
    pub fn fitted_fraction(&self) -> f64 {
        self.stroke()["fit"]["fitted_fraction"]
            .as_f64()
            .expect("a fitted fraction")
    }
}
