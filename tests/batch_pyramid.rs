//! `demsketch batch` on a tile directory with pyramid levels as
//! `gdal_retile.py -levels 2` makes them (issue 15, item 5): four edits in
//! two groups on a 4 x 4 tile set (levels: 2 x 2 tiles, then one).
//!
//! - The base tiles are byte-identical to applying the edits one by one
//!   with `demsketch edit OUT --in-place` (which refreshes the levels after
//!   every edit); every level tile holds the cells the one-by-one path
//!   gives, which are those `gdal_retile.py` makes from the edited base
//!   (retiled from a VRT of it); the level tiles away from every change
//!   keep their bytes. (The bytes of a rewritten level tile are not those
//!   of the one-by-one path: the batch refreshes it once, with one
//!   provenance entry, where edits one by one rewrite it once per edit.)
//! - A batch killed at every commit in turn (each run SIGKILLed after its
//!   first journal, before its renames: edits and level tiles alike) and
//!   resumed ends with the same bytes, levels included.
//! - The array-job steps (plan, the indices in a shuffled order in
//!   separate processes, finish) give the same bytes; the levels are
//!   refreshed by the finish step.
//! - Internal and external (.ovr) overviews of the tiles: the batch's
//!   files (tiles and .ovr) are byte-identical to edits one by one.
//! - An unknown --pyramid-resampling exits 1 and writes nothing.

mod batch_support;
mod common;

use batch_support::{cmd, out_of, sketch, FLAGS};
use common::*;
use std::path::{Path, PathBuf};

const RESAMPLING: &str = "bilinear";

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// The tile set: a 192 x 192 cut of the Texas fixture at column/row 64
/// (the cells `batch_support::lonlat` names), retiled with
/// `gdal_retile.py -levels 2 -ps 48 48 -r bilinear` into `dir/pyr`.
fn pyramid(dir: &Path) -> PathBuf {
    let src = dir.join("src").join("src.tif");
    std::fs::create_dir_all(src.parent().unwrap()).unwrap();
    gdal_translate(
        &fixture("texas_srtm90m_tiled_int16.tif"),
        &src,
        &["-srcwin", "64", "64", "192", "192"],
    );
    let pyr = dir.join("pyr");
    retile(&src, &pyr);
    pyr
}

/// `gdal_retile.py -levels 2 -ps 48 48 -r bilinear -targetDir dir src`.
fn retile(src: &Path, dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    run(
        "gdal_retile.py",
        &[
            "-q",
            "-levels",
            "2",
            "-ps",
            "48",
            "48",
            "-r",
            RESAMPLING,
            "-targetDir",
            &dir.to_string_lossy(),
            &src.to_string_lossy(),
        ],
    );
}

/// Four edits: two at the top-left corner (one group) and two at the
/// bottom-left one (another); the right half of the DEM stays as it is.
fn manifest(dir: &Path) -> (PathBuf, Vec<PathBuf>) {
    let sk = dir.join("sketches");
    std::fs::create_dir_all(&sk).unwrap();
    let places = [
        (20.0, 20.0, 0.0, 1.5),
        (20.0, 172.0, 90.0, 0.0),
        (24.0, 18.0, 90.0, 1.5),
        (18.0, 168.0, 0.0, 1.5),
    ];
    let mut paths = Vec::new();
    let mut entries = Vec::new();
    for (k, (c, r, h, d)) in places.into_iter().enumerate() {
        let p = sk.join(format!("e{k}.json"));
        std::fs::write(&p, sketch(c, r, h, d)).unwrap();
        entries.push(format!(r#"{{"id":"e{k}","sketch":"sketches/e{k}.json"}}"#));
        paths.push(p);
    }
    let m = dir.join("manifest.json");
    std::fs::write(&m, format!(r#"{{"edits":[{}]}}"#, entries.join(","))).unwrap();
    (m, paths)
}

/// Every tile of a pyramid (`*.tif`, `1/*.tif`, `2/*.tif`) with its bytes,
/// by relative name.
fn all_tiles(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v = Vec::new();
    for sub in ["", "1", "2"] {
        let d = dir.join(sub);
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.extension().is_some_and(|x| x == "tif") {
                let name = Path::new(sub).join(e.file_name());
                v.push((
                    name.to_string_lossy().into_owned(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    v.sort();
    v
}

fn is_level(name: &str) -> bool {
    name.contains('/')
}

/// Copy a pyramid (tiles and levels) to `to`.
fn copy_pyramid(from: &Path, to: &Path) {
    for (name, bytes) in all_tiles(from) {
        let p = to.join(&name);
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, bytes).unwrap();
    }
}

/// The cells of the tile `name` of pyramid `dir` as GDAL reads them.
fn cells(dir: &Path, name: &str) -> Vec<f64> {
    gdal_values(&dir.join(name)).2
}

fn json(p: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

fn batch(pyr: &Path, m: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    out_of(
        cmd()
            .arg("batch")
            .arg(pyr)
            .arg("--jobs")
            .arg(m)
            .arg("--out")
            .arg(out)
            .args(FLAGS)
            .args(["--pyramid-resampling", RESAMPLING, "--quiet"])
            .args(extra),
    )
}

#[test]
fn a_batch_refreshes_the_pyramid_once_as_edits_one_by_one_and_gdal_retile_do() {
    let tmp = tempfile::tempdir().unwrap();
    let pyr = pyramid(tmp.path());
    let original = all_tiles(&pyr);
    assert_eq!(original.iter().filter(|t| is_level(&t.0)).count(), 5);
    let (m, sketches) = manifest(tmp.path());
    let out = tmp.path().join("out");

    // The reference: one by one, in place, at the same path (the
    // provenance records it); each edit refreshes the levels.
    copy_pyramid(&pyr, &out);
    for s in &sketches {
        let r = out_of(
            cmd()
                .arg("edit")
                .arg(&out)
                .arg("--sketch")
                .arg(s)
                .arg("--in-place")
                .args(FLAGS)
                .args(["--pyramid-resampling", RESAMPLING, "--quiet"]),
        );
        assert!(r.status.success(), "reference edit: {}", stderr(&r));
    }
    let one_by_one = all_tiles(&out);
    let level_cells: Vec<Vec<f64>> = one_by_one
        .iter()
        .filter(|t| is_level(&t.0))
        .map(|t| cells(&out, &t.0))
        .collect();
    std::fs::remove_dir_all(&out).unwrap();

    // The whole batch.
    let r = batch(&pyr, &m, &out, &[]);
    assert!(r.status.success(), "batch: {}", stderr(&r));
    let got = all_tiles(&out);
    let names: Vec<&String> = got.iter().map(|t| &t.0).collect();
    assert_eq!(names, one_by_one.iter().map(|t| &t.0).collect::<Vec<_>>());
    let plan = json(&out.join(".demsketch_batch/plan.json"));
    assert_eq!(plan["groups"].as_array().unwrap().len(), 2, "{plan}");
    let mut written = Vec::new();
    let mut k = 0;
    for ((name, bytes), ((_, want), old)) in got.iter().zip(one_by_one.iter().zip(&original)) {
        if !is_level(name) {
            assert!(
                bytes == want,
                "base tile {name} differs from edits one by one"
            );
            continue;
        }
        assert!(
            cells(&out, name) == level_cells[k],
            "level tile {name}: cells differ from edits one by one"
        );
        k += 1;
        // Rewritten exactly where the one-by-one path rewrote.
        assert_eq!(bytes != &old.1, want != &old.1, "level tile {name}");
        if bytes != &old.1 {
            written.push(name.clone());
        }
    }
    // The left half changed: level 1's two left tiles and level 2's only
    // one; the right two level 1 tiles keep their bytes.
    assert_eq!(written.len(), 3, "{written:?}");
    let s = json(&out.join(".demsketch_batch/summary.json"));
    assert_eq!(s["written"], 4, "{s}");
    assert_eq!(s["pyramid"]["levels"], 2, "{s}");
    assert_eq!(s["pyramid"]["resampling"], RESAMPLING, "{s}");
    let mut listed: Vec<String> = s["pyramid"]["tiles_written"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    listed.sort();
    assert_eq!(listed, written);

    // gdal_retile.py of the edited base makes the same level cells: the
    // base as one GeoTIFF named as the source the pyramid was cut from,
    // with the source's geotransform (the tiles' origins are rounded, a
    // VRT of them has another cell size in the last digit, and bilinear
    // rounds some cells the other way on it).
    let v = tmp.path().join("vrt");
    std::fs::create_dir(&v).unwrap();
    let vrt = v.join("src.vrt");
    let mut args = vec![vrt.to_string_lossy().into_owned()];
    args.extend(
        got.iter()
            .filter(|t| !is_level(&t.0))
            .map(|t| out.join(&t.0).to_string_lossy().into_owned()),
    );
    let a: Vec<&str> = args.iter().map(String::as_str).collect();
    run("gdalbuildvrt", &[&["-q"], &a[..]].concat());
    let gt: Vec<String> = gdalinfo(&tmp.path().join("src").join("src.tif"))["geoTransform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| format!("{:?}", v.as_f64().unwrap()))
        .collect();
    let text = std::fs::read_to_string(&vrt).unwrap();
    let (head, rest) = text.split_once("<GeoTransform>").unwrap();
    let (_, tail) = rest.split_once("</GeoTransform>").unwrap();
    std::fs::write(
        &vrt,
        format!("{head}<GeoTransform>{}</GeoTransform>{tail}", gt.join(", ")),
    )
    .unwrap();
    let edited = tmp.path().join("edited").join("src.tif");
    std::fs::create_dir(edited.parent().unwrap()).unwrap();
    gdal_translate(&vrt, &edited, &[]);
    let want = tmp.path().join("want");
    retile(&edited, &want);
    for (name, _) in got.iter().filter(|t| is_level(&t.0)) {
        let (a, b) = (cells(&out, name), cells(&want, name));
        assert_eq!(a.len(), b.len(), "{name}");
        let off = a.iter().zip(&b).filter(|(x, y)| x != y).count();
        assert_eq!(
            off, 0,
            "level tile {name}: {off} cells differ from gdal_retile.py"
        );
    }

    // Resumed once complete: nothing changes.
    let again = batch(&pyr, &m, &out, &["--resume"]);
    assert!(again.status.success(), "{}", stderr(&again));
    assert!(all_tiles(&out) == got);
    std::fs::remove_dir_all(&out).unwrap();

    // Killed at every commit in turn: each run is SIGKILLed after its
    // first journal, before its renames; the next finishes that commit
    // and goes on to the next.
    let (mut runs, mut pyramid_kills) = (0, 0);
    loop {
        runs += 1;
        assert!(runs <= 30, "the batch does not end");
        let r = out_of(
            cmd()
                .arg("batch")
                .arg(&pyr)
                .arg("--jobs")
                .arg(&m)
                .arg("--out")
                .arg(&out)
                .args(FLAGS)
                .args(["--pyramid-resampling", RESAMPLING, "--quiet", "--resume"])
                .env("DEMSKETCH_TEST_ABORT_AFTER_RENAMES", "0"),
        );
        if r.status.success() {
            break;
        }
        assert_eq!(r.status.code(), None, "not killed: {}", stderr(&r));
        // Killed in the pyramid step: a level tile's journal is left.
        let journal_in = |level: &str| {
            std::fs::read_dir(out.join(level))
                .unwrap()
                .flatten()
                .any(|e| e.file_name().to_string_lossy().starts_with(".demsketch-"))
        };
        if journal_in("1") || journal_in("2") {
            pyramid_kills += 1;
        }
    }
    // Three level tiles, written one after another: a run killed at each.
    // (Two groups' edits can be killed in one run: they commit in
    // parallel.)
    assert_eq!(pyramid_kills, 3, "{runs} runs");
    assert!(runs >= 6, "only {runs} runs");
    assert!(
        all_tiles(&out) == got,
        "killed and resumed: the bytes differ"
    );
    std::fs::remove_dir_all(&out).unwrap();

    // The array-job steps, the indices in a shuffled order.
    let plan = tmp.path().join("plan.json");
    let r = out_of(
        cmd()
            .args(["batch", "plan"])
            .arg(&pyr)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .arg("--plan")
            .arg(&plan)
            .args(FLAGS)
            .args(["--pyramid-resampling", RESAMPLING]),
    );
    assert!(r.status.success(), "plan: {}", stderr(&r));
    assert!(all_tiles(&out) == original, "plan copies the pyramid");
    for i in ["1", "0"] {
        let r = out_of(
            cmd()
                .args(["batch", "run", "--quiet", "--index", i, "--plan"])
                .arg(&plan),
        );
        assert!(r.status.success(), "run {i}: {}", stderr(&r));
    }
    // The levels are the finish step's.
    let ran = all_tiles(&out);
    for ((name, bytes), (_, old)) in ran.iter().zip(&original) {
        if is_level(name) {
            assert!(bytes == old, "{name} written before finish");
        }
    }
    let f = out_of(cmd().args(["batch", "finish", "--plan"]).arg(&plan));
    assert!(f.status.success(), "finish: {}", stderr(&f));
    assert!(all_tiles(&out) == got, "array job: the bytes differ");
}

#[test]
fn an_unknown_pyramid_resampling_is_refused_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let pyr = pyramid(tmp.path());
    let (m, _) = manifest(tmp.path());
    let before = snapshot(tmp.path());
    let out = tmp.path().join("out");
    let o = out_of(
        cmd()
            .arg("batch")
            .arg(&pyr)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .args(["--pyramid-resampling", "bicubic"]),
    );
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("unknown pyramid resampling 'bicubic'"),
        "{err}"
    );
    assert!(snapshot(tmp.path()) == before && !out.exists());
}

/// Every file of a directory (tiles and their `.ovr`), by name.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .filter(|e| e.path().is_file())
        .map(|e| {
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn a_batch_refreshes_internal_and_external_overviews_as_edits_one_by_one_do() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = batch_support::tile_set(tmp.path(), "dem");
    // Internal overviews on the left half, external (.ovr) on the right.
    for ty in 0..batch_support::SIDE {
        for tx in 0..batch_support::SIDE {
            let t = dem.join(format!("tile_{ty}_{tx}.tif"));
            let t = t.to_string_lossy();
            let mut args = vec!["-q", "-r", "average"];
            if tx >= 2 {
                args.push("-ro");
            }
            args.extend([t.as_ref(), "2", "4"]);
            run("gdaladdo", &args);
        }
    }
    assert!(dem.join("tile_0_3.tif.ovr").is_file());
    let (m, sketches) = batch_support::manifest(tmp.path(), 6);
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).unwrap();
    for (name, bytes) in files(&dem) {
        std::fs::write(out.join(name), bytes).unwrap();
    }
    for s in &sketches {
        let r = out_of(
            cmd()
                .arg("edit")
                .arg(&out)
                .arg("--sketch")
                .arg(s)
                .arg("--in-place")
                .args(FLAGS)
                .arg("--quiet"),
        );
        assert!(r.status.success(), "reference edit: {}", stderr(&r));
    }
    let want = files(&out);
    std::fs::remove_dir_all(&out).unwrap();
    let r = out_of(
        cmd()
            .arg("batch")
            .arg(&dem)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .args(FLAGS)
            .arg("--quiet"),
    );
    assert!(r.status.success(), "batch: {}", stderr(&r));
    let got = files(&out);
    assert_eq!(
        got.iter().map(|f| &f.0).collect::<Vec<_>>(),
        want.iter().map(|f| &f.0).collect::<Vec<_>>()
    );
    let differ: Vec<&String> = got
        .iter()
        .zip(&want)
        .filter(|(a, b)| a.1 != b.1)
        .map(|(a, _)| &a.0)
        .collect();
    assert!(
        differ.is_empty(),
        "differ from edits one by one: {differ:?}"
    );
    // The overviews were refreshed: some .ovr changed.
    let before = files(&dem);
    assert!(got
        .iter()
        .zip(&before)
        .any(|(a, b)| a.0.ends_with(".ovr") && a.1 != b.1));
}
