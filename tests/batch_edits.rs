//! `demsketch batch` (issue 15, items 3 and 4) on a 4 x 4 tile set of a
//! real fixture: the tiles are byte-identical to applying the edits one by
//! one with `demsketch edit OUT --in-place` (with the same
//! SOURCE_DATE_EPOCH, at the same path); killing the batch with SIGKILL at
//! pseudo-random moments and resuming gives the same bytes, every edit
//! applied once; the array-job steps (plan, every index in a shuffled
//! order in separate processes, two at a time, finish) give the same bytes;
//! bad input (a missing sketch, a bad plan, an index out of range) exits 1
//! with one line and writes nothing.

mod batch_support;
mod common;

use batch_support::*;
use serde_json::Value;
use std::path::Path;
use std::time::Duration;

fn state(out: &Path) -> std::path::PathBuf {
    out.join(".demsketch_batch")
}

fn json(p: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
}

fn stderr(o: &std::process::Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// `demsketch batch DEM --jobs M --out OUT` with FLAGS and `extra`.
fn batch(dem: &Path, m: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    out_of(
        cmd()
            .arg("batch")
            .arg(dem)
            .arg("--jobs")
            .arg(m)
            .arg("--out")
            .arg(out)
            .args(FLAGS)
            .args(extra),
    )
}

/// A small deterministic pseudo-random sequence in [0, 1).
fn lcg(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

/// Names under `dir` (recursively) of demsketch temporary files.
fn temporaries(dir: &Path) -> Vec<String> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if n.starts_with(".demsketch-") {
            v.push(n);
        } else if e.path().is_dir() {
            v.extend(temporaries(&e.path()));
        }
    }
    v
}

#[test]
fn batch_equals_edits_one_by_one() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (m, sketches) = manifest(tmp.path(), 6);
    let out = tmp.path().join("out");
    let (want, changed) = reference(&dem, &sketches, &out);
    assert!(
        changed.iter().filter(|&&c| c > 0).count() >= 5,
        "the sketches must change cells: {changed:?}"
    );
    let r = batch(&dem, &m, &out, &[]);
    assert!(r.status.success(), "batch failed: {}", stderr(&r));
    let got = tiles(&out);
    assert_eq!(differing(&got, &want), Vec::<String>::new(), "tiles differ");
    assert_ne!(tiles(&dem), got, "the batch changed nothing");
    // GDAL reads every tile, and the edited ones differ from the input.
    let (a, b) = (gdal_checksums(&dem), gdal_checksums(&out));
    assert!(a.iter().zip(&b).filter(|(x, y)| x != y).count() >= 3);

    // The plan: independent groups and groups of overlapping edits.
    let plan = json(&state(&out).join("plan.json"));
    let groups = plan["groups"].as_array().unwrap();
    assert_eq!(groups.len(), 4, "{plan}");
    let sizes: Vec<usize> = groups
        .iter()
        .map(|g| g["edits"].as_array().unwrap().len())
        .collect();
    assert_eq!(sizes, vec![2, 1, 2, 1]);

    // One report per edit, and the summary.
    let reports = std::fs::read_dir(state(&out).join("reports"))
        .unwrap()
        .count();
    assert_eq!(reports, 6);
    let s = json(&state(&out).join("summary.json"));
    assert_eq!(s["written"], 6, "{s}");
    assert_eq!(s["edits"], 6);
    let cells: u64 = changed.iter().sum();
    assert_eq!(s["changed_cells"].as_u64().unwrap(), cells);
    assert!(temporaries(&out).is_empty(), "{:?}", temporaries(&out));

    // Running it again without --resume refuses to touch OUT.
    let again = batch(&dem, &m, &out, &[]);
    assert_eq!(again.status.code(), Some(1), "{}", stderr(&again));
    assert_eq!(tiles(&out), got);
    // With --resume: every edit is done already; nothing changes.
    let resumed = batch(&dem, &m, &out, &["--resume"]);
    assert!(resumed.status.success(), "{}", stderr(&resumed));
    assert_eq!(tiles(&out), got);
}

#[test]
fn killed_batches_resume_to_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (m, sketches) = manifest(tmp.path(), 6);
    let out = tmp.path().join("out");
    let (want, _) = reference(&dem, &sketches, &out);
    let mut seed = 15u64;
    let mut kills = 0;
    for _ in 0..5 {
        let delay = 0.05 + 0.35 * lcg(&mut seed);
        let mut child = cmd()
            .arg("batch")
            .arg(&dem)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .args(FLAGS)
            .arg("--resume")
            .arg("--quiet")
            // A pause between an edit's journal and its renames, so that
            // kills land there too.
            .env("DEMSKETCH_TEST_SLEEP_BEFORE_COMMIT_MS", "300")
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_secs_f64(delay));
        if child.try_wait().unwrap().is_none() {
            child.kill().unwrap(); // SIGKILL
            kills += 1;
        }
        child.wait().unwrap();
    }
    assert!(kills >= 3, "only {kills} of the runs were killed");
    let r = batch(&dem, &m, &out, &["--resume"]);
    assert!(r.status.success(), "resume failed: {}", stderr(&r));
    assert_eq!(differing(&tiles(&out), &want), Vec::<String>::new());
    let s = json(&state(&out).join("summary.json"));
    let records = s["records"].as_array().unwrap();
    assert_eq!(records.len(), 6, "{s}");
    let ids: Vec<&str> = records.iter().map(|r| r["id"].as_str().unwrap()).collect();
    assert_eq!(ids, vec!["e00", "e01", "e02", "e03", "e04", "e05"]);
    assert!(temporaries(&out).is_empty(), "{:?}", temporaries(&out));
}

#[test]
fn array_job_indices_in_any_order_give_the_same_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (m, sketches) = manifest(tmp.path(), 6);
    let out = tmp.path().join("out");
    let (want, _) = reference(&dem, &sketches, &out);
    let plan = tmp.path().join("plan.json");
    let r = out_of(
        cmd()
            .args(["batch", "plan"])
            .arg(&dem)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .arg("--plan")
            .arg(&plan)
            .args(FLAGS),
    );
    assert!(r.status.success(), "plan failed: {}", stderr(&r));
    assert_eq!(tiles(&out), tiles(&dem), "plan copies the DEM");
    let n = json(&plan)["groups"].as_array().unwrap().len();
    assert_eq!(n, 4);
    // A shuffled order, two processes at a time; the index given three ways.
    let order = [2usize, 0, 3, 1];
    for pair in order.chunks(2) {
        let children: Vec<std::process::Child> = pair
            .iter()
            .map(|&i| {
                let mut c = cmd();
                c.args(["batch", "run", "--quiet", "--plan"]).arg(&plan);
                match i {
                    0 => c.env("SLURM_ARRAY_TASK_ID", "0"),
                    1 => c.env("JOB_COMPLETION_INDEX", "1"),
                    _ => c.args(["--index", &i.to_string()]),
                };
                c.stderr(std::process::Stdio::piped()).spawn().unwrap()
            })
            .collect();
        for c in children {
            let o = c.wait_with_output().unwrap();
            assert!(o.status.success(), "run failed: {}", stderr(&o));
        }
    }
    let done = tiles(&out);
    assert_eq!(differing(&done, &want), Vec::<String>::new());
    // An index run again (a retried task) applies nothing twice.
    let again = out_of(
        cmd()
            .args(["batch", "run", "--index", "2", "--plan"])
            .arg(&plan),
    );
    assert!(again.status.success(), "{}", stderr(&again));
    assert_eq!(tiles(&out), done);
    let f = out_of(cmd().args(["batch", "finish", "--plan"]).arg(&plan));
    assert!(f.status.success(), "finish failed: {}", stderr(&f));
    assert_eq!(json(&state(&out).join("summary.json"))["written"], 6);
}

#[test]
fn finish_before_every_group_ran_says_which() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (m, _) = manifest(tmp.path(), 6);
    let out = tmp.path().join("out");
    let plan = tmp.path().join("plan.json");
    let r = out_of(
        cmd()
            .args(["batch", "plan"])
            .arg(&dem)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .arg("--plan")
            .arg(&plan)
            .args(FLAGS),
    );
    assert!(r.status.success(), "{}", stderr(&r));
    let one = out_of(
        cmd()
            .args(["batch", "run", "--index", "1", "--plan"])
            .arg(&plan),
    );
    assert!(one.status.success(), "{}", stderr(&one));
    let f = out_of(cmd().args(["batch", "finish", "--plan"]).arg(&plan));
    assert_eq!(f.status.code(), Some(1), "{}", stderr(&f));
    let e = stderr(&f);
    assert!(e.contains("not done") && e.contains("[0, 2, 3]"), "{e}");
}

/// One line on stderr, naming `what`.
fn one_line_naming(o: &std::process::Output, what: &str) {
    let e = stderr(o);
    assert_eq!(e.trim_end().lines().count(), 1, "not one line: {e}");
    assert!(e.contains(what), "does not name {what}: {e}");
}

#[test]
fn bad_input_exits_1_with_one_line_and_writes_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (m, _) = manifest(tmp.path(), 3);
    let before = common::snapshot(tmp.path());

    // A manifest naming a sketch that does not exist.
    let bad = tmp.path().join("missing.json");
    std::fs::write(
        &bad,
        r#"{"edits":[{"id":"a","sketch":"sketches/e00.json"},{"id":"b","sketch":"sketches/nope.json"}]}"#,
    )
    .unwrap();
    let out = tmp.path().join("out");
    let r = batch(&dem, &bad, &out, &[]);
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "nope.json");
    assert!(!out.exists());
    let plan = tmp.path().join("plan.json");
    let r = out_of(
        cmd()
            .args(["batch", "plan"])
            .arg(&dem)
            .arg("--jobs")
            .arg(&bad)
            .arg("--out")
            .arg(&out)
            .arg("--plan")
            .arg(&plan),
    );
    assert_eq!(r.status.code(), Some(1));
    one_line_naming(&r, "nope.json");
    assert!(!out.exists() && !plan.exists());
    std::fs::remove_file(&bad).unwrap();

    // A viewpoint off the DEM.
    let off = tmp.path().join("off.json");
    std::fs::write(&off, sketch(20.0, 20.0, 0.0, 0.0).replace("-97.", "-98.")).unwrap();
    let offm = tmp.path().join("off.txt");
    std::fs::write(&offm, "off.json\n").unwrap();
    let r = batch(&dem, &offm, &out, &[]);
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "outside the DEM");
    assert!(!out.exists());
    std::fs::remove_file(&off).unwrap();
    std::fs::remove_file(&offm).unwrap();
    assert_eq!(
        common::snapshot(tmp.path()),
        before,
        "something was written"
    );

    // A bad plan file.
    let garbage = tmp.path().join("garbage.json");
    std::fs::write(&garbage, "{\"format\": 3}").unwrap();
    let before = common::snapshot(tmp.path());
    let r = out_of(
        cmd()
            .args(["batch", "run", "--index", "0", "--plan"])
            .arg(&garbage),
    );
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "garbage.json");
    let r = out_of(cmd().args(["batch", "finish", "--plan"]).arg(&garbage));
    assert_eq!(r.status.code(), Some(1));
    one_line_naming(&r, "garbage.json");
    assert_eq!(
        common::snapshot(tmp.path()),
        before,
        "something was written"
    );
    std::fs::remove_file(&garbage).unwrap();

    // A good plan, then an index out of range (flag and environment), a
    // bad index, and the plan edited after it was made.
    let r = out_of(
        cmd()
            .args(["batch", "plan"])
            .arg(&dem)
            .arg("--jobs")
            .arg(&m)
            .arg("--out")
            .arg(&out)
            .arg("--plan")
            .arg(&plan)
            .args(FLAGS),
    );
    assert!(r.status.success(), "{}", stderr(&r));
    let before = common::snapshot(tmp.path());
    let r = out_of(
        cmd()
            .args(["batch", "run", "--index", "9", "--plan"])
            .arg(&plan),
    );
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "out of range");
    let r = out_of(
        cmd()
            .args(["batch", "run", "--plan"])
            .arg(&plan)
            .env("SLURM_ARRAY_TASK_ID", "12"),
    );
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "out of range");
    let r = out_of(
        cmd()
            .args(["batch", "run", "--index", "x", "--plan"])
            .arg(&plan),
    );
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "--index");
    let r = out_of(cmd().args(["batch", "run", "--plan"]).arg(&plan));
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "SLURM_ARRAY_TASK_ID");
    assert_eq!(
        common::snapshot(tmp.path()),
        before,
        "something was written"
    );
    let mut p = json(&plan);
    p["settings"]["min_fit"] = Value::from(0.5);
    let edited = tmp.path().join("edited.json");
    std::fs::write(&edited, p.to_string()).unwrap();
    let before = common::snapshot(tmp.path());
    let r = out_of(
        cmd()
            .args(["batch", "run", "--index", "0", "--plan"])
            .arg(&edited),
    );
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    one_line_naming(&r, "edited.json");
    assert_eq!(
        common::snapshot(tmp.path()),
        before,
        "something was written"
    );
}

#[test]
fn text_lists_and_directories_are_manifests_too() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (m, _) = manifest(tmp.path(), 6);
    let list = tmp.path().join("list.txt");
    let names: Vec<String> = (0..6).map(|k| format!("sketches/e{k:02}.json")).collect();
    std::fs::write(&list, format!("# six edits\n{}\n", names.join("\n"))).unwrap();
    let plan_of = |manifest: &Path, name: &str| -> Value {
        let plan = tmp.path().join(format!("{name}.plan.json"));
        let r = out_of(
            cmd()
                .args(["batch", "plan"])
                .arg(&dem)
                .arg("--jobs")
                .arg(manifest)
                .arg("--out")
                .arg(tmp.path().join(name))
                .arg("--plan")
                .arg(&plan)
                .args(FLAGS),
        );
        assert!(r.status.success(), "{}", stderr(&r));
        json(&plan)
    };
    let groups = |p: &Value| p["groups"].clone();
    let a = plan_of(&m, "a");
    assert_eq!(groups(&plan_of(&list, "b")), groups(&a));
    assert_eq!(
        groups(&plan_of(&tmp.path().join("sketches"), "c")),
        groups(&a)
    );
}

#[test]
fn a_single_geotiff_is_one_group_and_equals_edits_one_by_one() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("dem.tif");
    common::gdal_translate(
        &common::fixture("texas_srtm90m_tiled_int16.tif"),
        &dem,
        &["-srcwin", "64", "64", "192", "192", "-co", "COMPRESS=LZW"],
    );
    let (m, sketches) = manifest(tmp.path(), 3);
    let out = tmp.path().join("out.tif");
    std::fs::copy(&dem, &out).unwrap();
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
        assert!(r.status.success(), "{}", stderr(&r));
    }
    let want = std::fs::read(&out).unwrap();
    assert_ne!(
        want,
        std::fs::read(&dem).unwrap(),
        "the edits changed nothing"
    );
    std::fs::remove_file(&out).unwrap();
    let r = batch(&dem, &m, &out, &[]);
    assert!(r.status.success(), "batch failed: {}", stderr(&r));
    assert!(
        std::fs::read(&out).unwrap() == want,
        "the batch's file differs"
    );
    let st = tmp.path().join(".out.tif.demsketch_batch");
    let plan = json(&st.join("plan.json"));
    assert_eq!(plan["groups"].as_array().unwrap().len(), 1);
    assert_eq!(json(&st.join("summary.json"))["written"], 3);
    common::gdalinfo(&out);
}

/// A lake polygon (lon/lat) over cells `c0..c1` x `r0..r1` of the tile set.
fn lake(c0: f64, r0: f64, c1: f64, r1: f64) -> String {
    let ring: Vec<String> = [(c0, r0), (c1, r0), (c1, r1), (c0, r1), (c0, r0)]
        .iter()
        .map(|&(c, r)| {
            let (lon, lat) = lonlat(c, r);
            format!("[{lon},{lat}]")
        })
        .collect();
    format!(
        r#"{{"type":"FeatureCollection","features":[{{"type":"Feature",
 "properties":{{"kind":"lake","name":"pond"}},
 "geometry":{{"type":"Polygon","coordinates":[[{}]]}}}}]}}"#,
        ring.join(",")
    )
}

#[test]
fn corrections_in_a_manifest_equal_correct_in_place_in_manifest_order() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (_, sketches) = manifest(tmp.path(), 4);
    // A lake on the tiles of the first sketches (after two of them, before
    // the fourth: the order matters there), and one across the corner of
    // four tiles (its own group).
    std::fs::create_dir(tmp.path().join("fix")).unwrap();
    let near = tmp.path().join("fix/near.geojson");
    std::fs::write(&near, lake(14.0, 24.0, 30.0, 34.0)).unwrap();
    let corner = tmp.path().join("fix/corner.geojson");
    std::fs::write(&corner, lake(88.0, 86.0, 104.0, 110.0)).unwrap();
    let m = tmp.path().join("manifest.json");
    std::fs::write(
        &m,
        r#"{"edits":[{"id":"e00","sketch":"sketches/e00.json"},
 {"id":"e01","sketch":"sketches/e01.json"},
 {"id":"near","corrections":"fix/near.geojson"},
 {"id":"e02","sketch":"sketches/e02.json"},
 {"id":"e03","sketch":"sketches/e03.json"},
 {"corrections":"fix/corner.geojson"}]}"#,
    )
    .unwrap();

    // The reference: each applied in turn, in place, by edit or correct.
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).unwrap();
    for (name, bytes) in tiles(&dem) {
        std::fs::write(out.join(name), bytes).unwrap();
    }
    let steps: Vec<(&str, &Path)> = vec![
        ("edit", &sketches[0]),
        ("edit", &sketches[1]),
        ("correct", &near),
        ("edit", &sketches[2]),
        ("edit", &sketches[3]),
        ("correct", &corner),
    ];
    for (what, input) in &steps {
        let mut c = cmd();
        c.arg(what).arg(&out).arg("--in-place").arg("--quiet");
        if *what == "edit" {
            c.arg("--sketch").arg(input).args(FLAGS);
        } else {
            c.arg("--features").arg(input);
        }
        let r = out_of(&mut c);
        assert!(r.status.success(), "reference {what}: {}", stderr(&r));
    }
    let want = tiles(&out);
    std::fs::remove_dir_all(&out).unwrap();

    let r = batch(&dem, &m, &out, &[]);
    assert!(r.status.success(), "batch failed: {}", stderr(&r));
    let got = tiles(&out);
    assert_eq!(differing(&got, &want), Vec::<String>::new(), "tiles differ");
    // The corner lake changed the four tiles at the corner, and GDAL reads
    // every tile.
    let changed: Vec<String> = differing(&tiles(&dem), &got);
    for t in [
        "tile_1_1.tif",
        "tile_1_2.tif",
        "tile_2_1.tif",
        "tile_2_2.tif",
    ] {
        assert!(
            changed.contains(&t.to_string()),
            "{t} unchanged: {changed:?}"
        );
    }
    assert_eq!(gdal_checksums(&out).len(), SIDE * SIDE);

    let plan = json(&state(&out).join("plan.json"));
    let kinds: Vec<&str> = plan["edits"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap())
        .collect();
    assert_eq!(
        kinds,
        [
            "sketch",
            "sketch",
            "corrections",
            "sketch",
            "sketch",
            "corrections"
        ]
    );
    assert_eq!(plan["edits"][5]["id"], "corner", "id from the file stem");
    let s = json(&state(&out).join("summary.json"));
    assert_eq!(s["written"], 6, "{s}");
    let rep = json(&state(&out).join("reports").join("00002-near.json"));
    assert_eq!(rep["corrections"][0]["kind"], "lake", "{rep}");
}

#[test]
fn a_bad_corrections_edit_stops_the_batch_before_anything_is_written() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_set(tmp.path(), "dem");
    let (_, _) = manifest(tmp.path(), 1);
    let bad = tmp.path().join("bad.geojson");
    std::fs::write(
        &bad,
        lake(10.0, 10.0, 20.0, 20.0).replace("\"lake\"", "\"glacier\""),
    )
    .unwrap();
    let m = tmp.path().join("manifest.json");
    std::fs::write(
        &m,
        r#"{"edits":[{"id":"e00","sketch":"sketches/e00.json"},{"id":"ice","corrections":"bad.geojson"}]}"#,
    )
    .unwrap();
    let out = tmp.path().join("out");
    let r = batch(&dem, &m, &out, &[]);
    assert_eq!(r.status.code(), Some(1), "{}", stderr(&r));
    let e = stderr(&r);
    assert_eq!(e.trim().lines().count(), 1, "one line: {e}");
    assert!(
        e.contains("manifest.json") && e.contains("edit \"ice\""),
        "{e}"
    );
    assert!(e.contains("unknown kind \"glacier\""), "{e}");
    assert!(!out.exists(), "OUT was written");
}
