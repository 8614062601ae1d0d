//! One edit at a time, applied whole: two concurrent in-place edits of one
//! tile directory both land (the edit lock); a process killed between its
//! renames is finished by the next edit (the journal), or rolled back when
//! its staged files are gone; SIGINT and SIGTERM leave no temporary file;
//! temporary files of dead processes are removed; the lock timeout fails
//! in one line.

mod common;
mod write_support;

use std::path::Path;
use std::time::{Duration, Instant};

use write_support::*;

/// The values after applying A then B to a fresh tile directory, in order.
fn sequential_reference(root: &Path, a: &Path, b: &Path) -> Vec<(String, Vec<f64>)> {
    let dem = tile_dir(root, "reference");
    for s in [a, b] {
        let o = edit(&dem, s, &["--in-place"]);
        assert!(o.status.success(), "reference edit: {}", stderr(&o));
    }
    values(&dem)
}

#[test]
fn concurrent_in_place_edits_never_lose_one() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = sketches(tmp.path());
    let pristine = tile_dir(tmp.path(), "pristine");
    let before = values(&pristine);
    let want = sequential_reference(tmp.path(), &a, &b);
    // Each sketch changes two tiles, disjoint from the other's.
    let changed: Vec<bool> = before.iter().zip(&want).map(|(x, y)| x.1 != y.1).collect();
    assert_eq!(
        changed,
        vec![true, true, true, true],
        "both edits change their tiles"
    );
    let trials = 50;
    for t in 0..trials {
        let dem = tmp.path().join(format!("t{t}"));
        copy_dir(&pristine, &dem);
        let mut pa = edit_cmd(&dem, &a, &["--in-place"]).spawn().unwrap();
        let mut pb = edit_cmd(&dem, &b, &["--in-place"]).spawn().unwrap();
        let (ra, rb) = (pa.wait().unwrap(), pb.wait().unwrap());
        assert!(
            ra.success() && rb.success(),
            "trial {t}: exit codes {ra:?} {rb:?}"
        );
        assert_eq!(values(&dem), want, "trial {t}: an edit was lost");
        assert!(temporaries(&dem).is_empty(), "trial {t}: temporaries left");
        std::fs::remove_dir_all(&dem).unwrap();
    }
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir(to).unwrap();
    for e in std::fs::read_dir(from).unwrap().flatten() {
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

#[test]
fn a_kill_between_renames_is_finished_by_the_next_edit() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = sketches(tmp.path());
    let pristine = tile_dir(tmp.path(), "pristine");
    let want = sequential_reference(tmp.path(), &a, &b);
    let trials = 20;
    for t in 0..trials {
        let dem = tmp.path().join(format!("k{t}"));
        copy_dir(&pristine, &dem);
        // Edit A rewrites two tiles: killed after 0 renames (journal
        // written, nothing replaced) or after 1 (half-applied).
        let n = (t % 2).to_string();
        let killed = edit_cmd(&dem, &a, &["--in-place"])
            .env("DEMSKETCH_TEST_ABORT_AFTER_RENAMES", &n)
            .output()
            .unwrap();
        assert_eq!(killed.status.code(), None, "trial {t}: killed by a signal");
        assert!(
            !temporaries(&dem).is_empty(),
            "trial {t}: the staged tiles are left"
        );
        let rerun = edit(&dem, &b, &["--in-place"]);
        let err = stderr(&rerun);
        assert!(rerun.status.success(), "trial {t}: rerun failed: {err}");
        let note: Vec<&str> = err.lines().filter(|l| l.contains("half-applied")).collect();
        assert_eq!(
            note.len(),
            1,
            "trial {t}: one line says the edit was finished: {err}"
        );
        assert!(note[0].contains(dem.to_str().unwrap()), "{}", note[0]);
        assert_eq!(
            values(&dem),
            want,
            "trial {t}: not as if A ran once, whole, then B"
        );
        assert!(temporaries(&dem).is_empty(), "trial {t}: temporaries left");
        std::fs::remove_dir_all(&dem).unwrap();
    }
}

#[test]
fn an_unfinished_edit_whose_staged_files_are_gone_is_rolled_back() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    let before = values(&dem);
    let killed = edit_cmd(&dem, &a, &["--in-place"])
        .env("DEMSKETCH_TEST_ABORT_AFTER_RENAMES", "0")
        .output()
        .unwrap();
    assert_eq!(killed.status.code(), None);
    // Damage the staged tiles: the journal can no longer be rolled forward.
    for p in temporaries(&dem) {
        for f in std::fs::read_dir(&p).unwrap().flatten() {
            if f.path().extension().is_some_and(|e| e == "tif") {
                std::fs::remove_file(f.path()).unwrap();
            }
        }
    }
    let dry = edit(&dem, &b, &["--in-place", "--dry-run"]);
    let err = stderr(&dry);
    assert!(dry.status.success(), "{err}");
    assert_eq!(
        err.lines().filter(|l| l.contains("rolled back")).count(),
        1,
        "{err}"
    );
    assert_eq!(
        values(&dem),
        before,
        "nothing of the unfinished edit applied"
    );
    assert!(temporaries(&dem).is_empty());
}

/// Spawn an in-place edit that sleeps before its renames, wait until its
/// staged files exist, send `signal`, and check it exits `code` leaving
/// the DEM byte-identical and no temporary file.
fn interrupted(signal: rustix::process::Signal, code: i32) {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    let before = common::snapshot(tmp.path());
    let child = edit_cmd(&dem, &a, &["--in-place"])
        .env("DEMSKETCH_TEST_SLEEP_BEFORE_COMMIT_MS", "20000")
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while temporaries(&dem)
        .iter()
        .all(|p| !p.join("journal.json").exists())
    {
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "no staged files appeared"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let pid = rustix::process::Pid::from_raw(child.id() as i32).unwrap();
    rustix::process::kill_process(pid, signal).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(
        start.elapsed() < Duration::from_secs(15),
        "the signal ended the edit"
    );
    assert_eq!(out.status.code(), Some(code), "{}", stderr(&out));
    assert!(
        temporaries(tmp.path()).is_empty(),
        "{:?}",
        temporaries(tmp.path())
    );
    assert_eq!(common::snapshot(tmp.path()), before, "files changed");
}

#[test]
fn no_temporary_file_survives_sigint_or_sigterm() {
    interrupted(rustix::process::Signal::INT, 130);
    interrupted(rustix::process::Signal::TERM, 143);
}

#[test]
fn temporaries_of_dead_processes_are_removed() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    // A PID that is certainly dead: a child that has exited.
    let dead = std::process::Command::new("true").spawn().unwrap();
    let pid = dead.id();
    dead.wait_with_output().unwrap();
    let stale_dir = dem.join(format!(".demsketch-{pid}-abcdefghij.tmp"));
    std::fs::create_dir(&stale_dir).unwrap();
    std::fs::write(stale_dir.join("tile_0_0.tif"), b"half").unwrap();
    let old_style = dem.join(format!(".tile_0_1.tif.demsketch-{pid}.tmp"));
    std::fs::write(&old_style, b"half").unwrap();
    // A live process's staging directory is left alone.
    let live = dem.join(format!(".demsketch-{}-abcdefghij.tmp", std::process::id()));
    std::fs::create_dir(&live).unwrap();
    let o = edit(&dem, &a, &["--in-place"]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    assert!(
        !stale_dir.exists() && !old_style.exists(),
        "stale temporaries removed"
    );
    assert!(live.exists(), "a live process's directory kept");
    assert_eq!(
        err.lines().filter(|l| l.contains("did not finish")).count(),
        2,
        "{err}"
    );
}

#[test]
fn a_second_edit_waits_for_the_lock_or_fails_in_one_line() {
    use rustix::fs::{flock, FlockOperation, Mode, OFlags};
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    let fd = rustix::fs::open(
        &dem,
        OFlags::RDONLY | OFlags::DIRECTORY | OFlags::CLOEXEC,
        Mode::empty(),
    )
    .unwrap();
    flock(&fd, FlockOperation::LockExclusive).unwrap();
    let before = common::snapshot(tmp.path());
    let o = edit(&dem, &a, &["--in-place", "--lock-timeout", "0"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains(dem.to_str().unwrap()) && err.contains("--lock-timeout"),
        "{err}"
    );
    assert_eq!(common::snapshot(tmp.path()), before);
    // Released while the second edit waits: it goes on, saying it waited.
    // The lock is released only once the edit says it waits (a loaded
    // machine may take seconds to get there).
    let mut child = edit_cmd(&dem, &a, &["--in-place", "--lock-timeout", "120"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut pipe = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut first = String::new();
    std::io::BufRead::read_line(&mut pipe, &mut first).unwrap();
    drop(fd);
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut pipe, &mut rest).unwrap();
    let status = child.wait().unwrap();
    let err = format!("{first}{rest}");
    assert!(status.success(), "{err}");
    assert!(
        err.lines().next().unwrap_or("").contains("waiting"),
        "{err}"
    );
}
