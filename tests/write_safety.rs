//! Write safety: a full disk leaves every file as it was (exit 1, one line
//! naming the target, no temporary left) for `edit --in-place`, `edit
//! --out` and `view --out/--depth`; symlinks planted at temporary names are
//! never followed; outputs naming an input or each other are refused;
//! unchanged tiles of a tile-directory output are copies (hard links only
//! with `--link`); an in-place edit keeps a tile's mode; relative symlinked
//! tiles are copied by content; a broken tile symlink is an error.

mod common;
mod write_support;

use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::*;
use write_support::*;

/// A small file system that is full: a 400 KB tmpfs when mounting is
/// permitted, else `None` (the caller then limits the file size with
/// `prlimit --fsize`). Unmounted on drop.
struct FullDisk {
    dir: tempfile::TempDir,
    mounted: bool,
}

impl FullDisk {
    fn new() -> FullDisk {
        let dir = tempfile::tempdir().unwrap();
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", "size=400k", "tmpfs"])
            .arg(dir.path())
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false);
        FullDisk { dir, mounted }
    }
    fn path(&self) -> &Path {
        self.dir.path()
    }
    /// Fill what is left of the tmpfs.
    fn fill(&self) {
        if self.mounted {
            use std::io::Write;
            let mut f = std::fs::File::create(self.path().join("filler")).unwrap();
            let block = vec![0u8; 1024];
            while f.write_all(&block).is_ok() {}
            let _ = f.sync_all();
        }
    }
}

impl FullDisk {
    /// Fill the tmpfs, then free `kb` KB of it again.
    fn fill_leaving(&self, kb: u64) {
        self.fill();
        let filler = self.path().join("filler");
        let len = std::fs::metadata(&filler).unwrap().len();
        let f = std::fs::OpenOptions::new()
            .write(true)
            .open(&filler)
            .unwrap();
        f.set_len(len.saturating_sub(kb * 1024)).unwrap();
    }
}

impl Drop for FullDisk {
    fn drop(&mut self) {
        if self.mounted {
            let _ = Command::new("umount").arg(self.dir.path()).output();
        }
    }
}

/// Run demsketch with `args` on the full disk (or under a 1 KB file size
/// limit where no tmpfs could be mounted).
fn run_full(disk: &FullDisk, args: &[&str]) -> Output {
    let bin = env!("CARGO_BIN_EXE_demsketch");
    let mut c = if disk.mounted {
        Command::new(bin)
    } else {
        let mut c = Command::new("prlimit");
        c.args(["--fsize=1024", bin]);
        c
    };
    c.args(args).env("GDAL_PAM_ENABLED", "NO").output().unwrap()
}

/// Expect a clean failure: exit 1, one line naming `target` (and no
/// temporary name), every file under `root` byte-identical, no temporary.
fn expect_unchanged(
    root: &Path,
    out: &Output,
    target: &Path,
    before: &[(PathBuf, Vec<u8>)],
    what: &str,
) {
    let err = stderr(out);
    assert_eq!(out.status.code(), Some(1), "{what}: exit code; {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{what}: one line: {err}");
    assert!(
        err.contains(&target.display().to_string()),
        "{what}: names {}: {err}",
        target.display()
    );
    assert!(
        !err.contains(".demsketch-") && !err.contains("/vsimem"),
        "{what}: names a temporary: {err}"
    );
    assert!(
        temporaries(root).is_empty(),
        "{what}: {:?}",
        temporaries(root)
    );
    assert!(snapshot(root) == before, "{what}: files changed");
}

#[test]
fn a_full_disk_leaves_every_file_as_it_was() {
    let disk = FullDisk::new();
    let root = disk.path();
    let (a, _) = sketches(root);
    let tiles = tile_dir(root, "tiles");
    let single = crop(root);
    // Outputs that exist already must keep their bytes too.
    let old_png = root.join("view.png");
    std::fs::write(&old_png, b"old picture").unwrap();
    let report = root.join("report.json");
    disk.fill();
    let before = snapshot(root);
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (a_s, tiles_s, single_s) = (s(&a), s(&tiles), s(&single));
    let out_dir = root.join("out");
    let out_tif = root.join("out.tif");
    let depth = root.join("depth.tif");
    let cases: Vec<(Vec<String>, PathBuf, &str)> = vec![
        (
            vec![
                "edit".into(),
                tiles_s.clone(),
                "--sketch".into(),
                a_s.clone(),
                "--min-fit".into(),
                "0".into(),
                "--in-place".into(),
                "--report".into(),
                s(&report),
            ],
            // The report's space is claimed first.
            report.clone(),
            "edit --in-place --report (tile directory)",
        ),
        (
            vec![
                "edit".into(),
                tiles_s.clone(),
                "--sketch".into(),
                a_s.clone(),
                "--min-fit".into(),
                "0".into(),
                "--in-place".into(),
            ],
            // One of the tiles edit A rewrites (tile_1_0 or tile_1_1).
            tiles.join("tile_1_"),
            "edit --in-place (tile directory)",
        ),
        (
            vec![
                "edit".into(),
                single_s.clone(),
                "--sketch".into(),
                a_s.clone(),
                "--min-fit".into(),
                "0".into(),
                "--in-place".into(),
            ],
            single.clone(),
            "edit --in-place (single file)",
        ),
        (
            vec![
                "edit".into(),
                tiles_s.clone(),
                "--sketch".into(),
                a_s.clone(),
                "--min-fit".into(),
                "0".into(),
                "--out".into(),
                s(&out_dir),
            ],
            out_dir.clone(),
            "edit --out (tile directory)",
        ),
        (
            vec![
                "edit".into(),
                single_s.clone(),
                "--sketch".into(),
                a_s.clone(),
                "--min-fit".into(),
                "0".into(),
                "--out".into(),
                s(&out_tif),
            ],
            out_tif.clone(),
            "edit --out (single file)",
        ),
        (
            vec![
                "view".into(),
                tiles_s.clone(),
                "--sketch".into(),
                a_s.clone(),
                "--out".into(),
                s(&old_png),
                "--depth".into(),
                s(&depth),
            ],
            old_png.clone(),
            "view --out --depth",
        ),
    ];
    for (args, target, what) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = run_full(&disk, &args);
        expect_unchanged(root, &out, &target, &before, what);
    }
}

#[test]
fn room_for_the_tiles_but_not_the_report_changes_nothing() {
    let disk = FullDisk::new();
    if !disk.mounted {
        eprintln!("no tmpfs could be mounted: skipped (needs a disk with a given free space)");
        return;
    }
    let root = disk.path();
    let (a, _) = sketches(root);
    let tiles = tile_dir(root, "tiles");
    // The two new tiles need about 6 KB; the report's space is claimed
    // (tens of KB) before any tile is replaced.
    disk.fill_leaving(24);
    let before = snapshot(root);
    let report = root.join("report.json");
    let out = run_full(
        &disk,
        &[
            "edit",
            tiles.to_str().unwrap(),
            "--sketch",
            a.to_str().unwrap(),
            "--min-fit",
            "0",
            "--in-place",
            "--report",
            report.to_str().unwrap(),
        ],
    );
    expect_unchanged(root, &out, &report, &before, "report does not fit");
}

#[test]
fn the_depth_buffer_alone_on_a_full_disk() {
    let disk = FullDisk::new();
    let root = disk.path();
    let (a, _) = sketches(root);
    let single = crop(root);
    let png = root.join("ok.png");
    disk.fill();
    let before = snapshot(root);
    let depth = root.join("depth.tif");
    let out = run_full(
        &disk,
        &[
            "view",
            single.to_str().unwrap(),
            "--sketch",
            a.to_str().unwrap(),
            "--out",
            png.to_str().unwrap(),
            "--depth",
            depth.to_str().unwrap(),
        ],
    );
    // Either output may be the first that does not fit; neither is written.
    let err = stderr(&out);
    let target = if err.contains("depth.tif") {
        depth
    } else {
        png
    };
    expect_unchanged(root, &out, &target, &before, "view --depth");
}

#[test]
fn planted_symlinks_at_temporary_names_are_never_followed() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    let victim = tmp.path().join("victim.txt");
    std::fs::write(&victim, b"precious").unwrap();
    // The names the old scheme used (`.NAME.demsketch-PID.tmp`), for the
    // PIDs the next processes are likely to get, and the new prefix.
    let last: u32 = std::fs::read_to_string("/proc/sys/kernel/ns_last_pid")
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(1000);
    let mut planted = Vec::new();
    for pid in last..last + 200 {
        for name in ["tile_1_0.tif", "tile_1_1.tif", "report.json"] {
            let p = dem.join(format!(".{name}.demsketch-{pid}.tmp"));
            std::os::unix::fs::symlink(&victim, &p).unwrap();
            planted.push(p);
        }
        let p = tmp.path().join(format!(".report.json.demsketch-{pid}.tmp"));
        std::os::unix::fs::symlink(&victim, &p).unwrap();
        planted.push(p);
    }
    let report = tmp.path().join("report.json");
    let o = edit(
        &dem,
        &a,
        &["--in-place", "--report", report.to_str().unwrap()],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
    assert!(
        planted.iter().all(|p| p.is_symlink()),
        "planted links left alone"
    );
    assert!(report.is_file());
}

#[test]
fn outputs_naming_an_input_or_each_other_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (a, _) = sketches(root);
    let dem = tile_dir(root, "dem");
    let single = crop(root);
    let hard = root.join("hard.tif");
    std::fs::hard_link(&single, &hard).unwrap();
    let link = root.join("link.tif");
    std::os::unix::fs::symlink("crop.tif", &link).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let tile = dem.join("tile_0_0.tif");
    let vrt = root.join("m.vrt");
    let mut args = vec!["-q".to_string(), s(&vrt)];
    for e in std::fs::read_dir(&dem).unwrap().flatten() {
        args.push(s(&e.path()));
    }
    run(
        "gdalbuildvrt",
        &args.iter().map(String::as_str).collect::<Vec<_>>(),
    );
    let cases: Vec<(Vec<String>, String)> = vec![
        (
            vec![s(&dem), "--in-place".into(), "--report".into(), s(&tile)],
            s(&tile),
        ),
        (
            vec![s(&dem), "--in-place".into(), "--report".into(), s(&a)],
            s(&a),
        ),
        (
            vec![
                s(&single),
                "--in-place".into(),
                "--report".into(),
                s(&single),
            ],
            s(&single),
        ),
        (vec![s(&single), "--out".into(), s(&single)], s(&single)),
        (vec![s(&single), "--out".into(), s(&link)], s(&link)),
        (
            vec![
                s(&single),
                "--out".into(),
                "x.tif".into(),
                "--report".into(),
                s(&hard),
            ],
            s(&hard),
        ),
        (
            vec![
                s(&single),
                "--out".into(),
                s(&root.join("o.tif")),
                "--report".into(),
                s(&root.join("o.tif")),
            ],
            s(&root.join("o.tif")),
        ),
        (vec![s(&dem), "--out".into(), s(&dem)], s(&dem)),
        // A VRT's source tile.
        (vec![s(&vrt), "--out".into(), s(&tile)], s(&tile)),
        (
            vec![s(&dem), "--out".into(), s(&dem.join("sub"))],
            s(&dem.join("sub")),
        ),
        (
            vec![
                s(&dem),
                "--out".into(),
                s(&root.join("o")),
                "--renders".into(),
                s(root),
            ],
            s(root),
        ),
        (
            vec![
                s(&dem),
                "--out".into(),
                s(&root.join("o")),
                "--renders".into(),
                s(&dem),
            ],
            s(&dem),
        ),
    ];
    for (extra, target) in cases {
        let before = snapshot(root);
        let mut args = vec![
            "edit".to_string(),
            extra[0].clone(),
            "--sketch".into(),
            s(&a),
            "--min-fit".into(),
            "0".into(),
        ];
        args.extend(extra[1..].iter().cloned());
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = demsketch(&args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.starts_with(&format!("demsketch: {target}: ")),
            "{args:?}: {err}"
        );
        assert!(snapshot(root) == before, "{args:?}: files changed");
    }
    // view: an output naming the DEM or another output.
    for (flag, path) in [("--depth", s(&single)), ("--depth", s(&root.join("v.png")))] {
        let before = snapshot(root);
        let o = demsketch(&[
            "view",
            &s(&single),
            "--sketch",
            &s(&a),
            "--out",
            &s(&root.join("v.png")),
            flag,
            &path,
        ]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(snapshot(root) == before);
    }
}

#[test]
fn unchanged_output_tiles_are_copies_unless_linked() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    let input_before = snapshot(&dem);
    let out = tmp.path().join("out");
    let o = edit(&dem, &a, &["--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    // tile_0_0 is not touched by edit A: a copy, so editing it in place
    // with GDAL leaves the input alone.
    let unchanged = out.join("tile_0_0.tif");
    assert_eq!(
        std::fs::read(&unchanged).unwrap(),
        std::fs::read(dem.join("tile_0_0.tif")).unwrap()
    );
    assert_ne!(
        std::fs::metadata(&unchanged).unwrap().ino(),
        std::fs::metadata(dem.join("tile_0_0.tif")).unwrap().ino()
    );
    run(
        "gdal_edit.py",
        &["-mo", "TOUCHED=yes", unchanged.to_str().unwrap()],
    );
    run("gdaladdo", &["-q", unchanged.to_str().unwrap(), "2"]);
    assert!(
        snapshot(&dem) == input_before,
        "the input changed with its output"
    );
    let mode = std::fs::metadata(&out).unwrap().permissions().mode() & 0o777;
    assert_ne!(mode, 0o700, "the output directory has an ordinary mode");
    // With --link: hard links.
    let linked = tmp.path().join("linked");
    let o = edit(&dem, &a, &["--out", linked.to_str().unwrap(), "--link"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::metadata(linked.join("tile_0_0.tif"))
            .unwrap()
            .ino(),
        std::fs::metadata(dem.join("tile_0_0.tif")).unwrap().ino()
    );
}

#[test]
fn an_in_place_edit_keeps_mode_owner_and_xattrs() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let dem = tile_dir(tmp.path(), "dem");
    let tile = dem.join("tile_1_0.tif");
    std::fs::set_permissions(&tile, std::fs::Permissions::from_mode(0o600)).unwrap();
    let xattr_ok = xattr::set(&tile, "user.demsketch_test", b"kept").is_ok();
    let owner = std::fs::metadata(&tile).unwrap();
    let o = edit(&dem, &a, &["--in-place"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let after = std::fs::metadata(&tile).unwrap();
    assert_ne!(after.ino(), owner.ino(), "the tile was rewritten");
    assert_eq!(after.permissions().mode() & 0o7777, 0o600);
    assert_eq!((after.uid(), after.gid()), (owner.uid(), owner.gid()));
    if xattr_ok {
        assert_eq!(
            xattr::get(&tile, "user.demsketch_test").unwrap().as_deref(),
            Some(&b"kept"[..])
        );
    }
}

#[test]
fn relative_symlinked_tiles_are_copied_by_content() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, _) = sketches(tmp.path());
    let real = tile_dir(tmp.path(), "real");
    let dem = tmp.path().join("links");
    std::fs::create_dir(&dem).unwrap();
    for e in std::fs::read_dir(&real).unwrap().flatten() {
        let rel = Path::new("../real").join(e.file_name());
        std::os::unix::fs::symlink(rel, dem.join(e.file_name())).unwrap();
    }
    let deep = tmp.path().join("x/y");
    std::fs::create_dir_all(&deep).unwrap();
    let out = deep.join("out");
    let o = edit(&dem, &a, &["--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let tiles: Vec<PathBuf> = std::fs::read_dir(&out)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .collect();
    assert_eq!(tiles.len(), 4, "{tiles:?}");
    for t in &tiles {
        assert!(!t.is_symlink() && t.is_file(), "{}", t.display());
        gdal_values(t);
    }
    assert_eq!(
        std::fs::read(out.join("tile_0_0.tif")).unwrap(),
        std::fs::read(real.join("tile_0_0.tif")).unwrap()
    );
}

#[test]
fn a_broken_tile_symlink_is_an_error_naming_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tile_dir(tmp.path(), "dem");
    let broken = dem.join("tile_9_9.tif");
    std::os::unix::fs::symlink("../gone/tile.tif", &broken).unwrap();
    let o = demsketch(&["info", dem.to_str().unwrap()]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.contains(broken.to_str().unwrap()) && err.contains("broken"),
        "{err}"
    );
}
