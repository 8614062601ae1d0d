//! Running a batch: the output prepared as a copy of the DEM
//! ([`prepare_output`]), one group's edits applied in manifest order with
//! the batch journal ([`run_group`]), every group at once on rayon's pool
//! ([`run_all`]), and the summary of what every edit did ([`finish`]).
//!
//! Each edit is [`crate::edit::run`] on the output in place, with the
//! options of `demsketch edit OUT --in-place` ([`super::BatchSettings`]),
//! its report in the state directory's `reports/`. Locks: a whole batch and
//! [`finish`] hold the output's edit lock exclusively; the workers of an
//! array job ([`run_group`] in separate processes) hold it shared, each
//! finishing only the interrupted edit journals of its own group's tiles.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use rayon::prelude::*;
use serde::Serialize;

use super::footprint::contains;
use super::manifest::EditKind;
use super::plan::{tile_name, Plan, PlannedEdit};
use super::record::{
    reports_dir, state_dir, tile_digests, tiles_dir, was_applied, Done, GroupRecords, Pending,
    Status, STATE_NAME,
};
use super::{io_err, BatchError};
use crate::edit::EditError;
use crate::raster::atomic_file::{commit_guard, parent_dir, sync_dir, Staging};
use crate::raster::edit_lock::EditLock;
use crate::raster::provenance::sha256_hex;
use crate::raster::{journal, Dem, LayerKind};

/// Called once per edit finished, with its record (`before`: recorded
/// done by an earlier run and skipped); must be callable from several
/// threads.
pub trait BatchProgress: Sync {
    fn edit_done(&self, done: &Done, before: bool);
}

impl<F: Fn(&Done, bool) + Sync> BatchProgress for F {
    fn edit_done(&self, done: &Done, before: bool) {
        self(done, before)
    }
}

/// What one group did.
#[derive(Debug, Clone)]
pub struct GroupOutcome {
    pub group: usize,
    /// Records of its edits, in order (those done before included).
    pub done: Vec<Done>,
    /// Edits skipped because an earlier run had done them.
    pub skipped: usize,
}

/// Copy the DEM to `out` as the batch's starting point: every GeoTIFF of
/// a tile directory (and its sidecars) into a new directory, or a single
/// GeoTIFF (and its sidecars), staged beside `out` and renamed into place
/// last, so that `out` exists only complete. `out` must not exist.
pub fn prepare_output(plan: &Plan, dem: &Dem) -> Result<(), BatchError> {
    let (dem_path, out) = (plan.dem.as_path(), plan.out.as_path());
    if out.exists() {
        return Err(io_err(out, "already exists"));
    }
    let parent = parent_dir(out);
    if !parent.is_dir() {
        return Err(io_err(out, "its parent directory does not exist"));
    }
    // Staging left by a prepare that was killed.
    let _ = crate::raster::atomic_file::clean_stale(parent);
    let staging = Staging::new_in(parent)
        .map_err(|e| io_err(out, format!("cannot create a staging directory: {e}")))?;
    let copy = |from: &Path, to: &Path| -> Result<(), BatchError> {
        reflink_copy::reflink_or_copy(from, to)
            .map_err(|e| io_err(out, format!("cannot copy {}: {e}", from.display())))?;
        std::fs::File::open(to)
            .and_then(|f| f.sync_all())
            .map_err(|e| io_err(out, e))?;
        crate::raster::sidecars::copy_unchanged(from, to)?;
        Ok(())
    };
    match dem.kind {
        LayerKind::TileDirectory => {
            dem.tiles.par_iter().try_for_each(|t| {
                copy(
                    &t.path,
                    &staging.file(t.path.file_name().unwrap_or_default()),
                )
            })?;
            // The pyramid levels (gdal_retile.py -levels), each level's
            // tiles in its subdirectory.
            if let Some(p) = super::pyramid::check(dem_path, dem)? {
                for (k, level) in p.level_tiles().iter().enumerate() {
                    let dir = staging.path().join((k + 1).to_string());
                    std::fs::create_dir(&dir).map_err(|e| io_err(out, e))?;
                    level
                        .par_iter()
                        .try_for_each(|t| copy(t, &dir.join(t.file_name().unwrap_or_default())))?;
                }
            }
            // The plan goes in with the tiles: an OUT that exists is always
            // one with its plan.
            write_plan_file(&staging.path().join(STATE_NAME), plan)?;
            let _commit = commit_guard();
            let kept = staging.keep();
            use std::os::unix::fs::PermissionsExt;
            let _ = std::fs::set_permissions(&kept, std::fs::Permissions::from_mode(0o755));
            std::fs::rename(&kept, out).map_err(|e| {
                let _ = std::fs::remove_dir_all(&kept);
                io_err(out, e)
            })?;
        }
        LayerKind::GeoTiff => {
            let name = out.file_name().unwrap_or_default();
            let tmp = staging.file(name);
            copy(dem_path, &tmp)?;
            write_plan_file(&state_dir(out), plan)?;
            let _commit = commit_guard();
            for s in [".ovr", ".aux.xml"] {
                let staged = crate::raster::sidecars::with_suffix(&tmp, s);
                if staged.is_file() {
                    std::fs::rename(&staged, crate::raster::sidecars::with_suffix(out, s))
                        .map_err(|e| io_err(out, e))?;
                }
            }
            std::fs::rename(&tmp, out).map_err(|e| io_err(out, e))?;
        }
        LayerKind::Gdal => {
            return Err(io_err(
                dem_path,
                "batch edits need a GeoTIFF or a directory of GeoTIFF tiles",
            ))
        }
    }
    let _ = sync_dir(parent);
    Ok(())
}

/// The report path of an edit.
pub fn report_path(state: &Path, e: &PlannedEdit) -> PathBuf {
    reports_dir(state).join(format!("{:05}-{}.json", e.index, e.id))
}

/// Check that the sketch is the one planned.
fn check_sketch(plan_path: &Path, e: &PlannedEdit) -> Result<(), BatchError> {
    let bytes = std::fs::read(&e.sketch).map_err(|err| BatchError::Plan {
        path: plan_path.display().to_string(),
        message: format!("edit \"{}\": sketch {}: {err}", e.id, e.sketch.display()),
    })?;
    if sha256_hex(&bytes) != e.sketch_sha256 {
        return Err(BatchError::Plan {
            path: plan_path.display().to_string(),
            message: format!(
                "edit \"{}\": sketch {} changed since the plan was made; plan again",
                e.id,
                e.sketch.display()
            ),
        });
    }
    Ok(())
}

/// Check that what an edit wrote (`changed_cells` within window `w`, in
/// `tiles_written`) lies inside its footprint.
fn check_footprint(
    e: &PlannedEdit,
    w: [i64; 4],
    changed_cells: usize,
    tiles_written: &[String],
) -> Result<(), BatchError> {
    let win = crate::raster::Window::new(w[0], w[1], w[2].max(0) as usize, w[3].max(0) as usize);
    let outside = |m: String| BatchError::Footprint {
        id: e.id.clone(),
        message: m,
    };
    if changed_cells > 0 && !contains(&e.footprint_window(), &win) {
        return Err(outside(format!(
            "its deformation window {w:?} leaves the footprint {:?} the plan gave it; its group stops (please report this)",
            e.footprint
        )));
    }
    for t in tiles_written {
        let n = tile_name(Path::new(t));
        if !e.tiles.contains(&n) {
            return Err(outside(format!(
                "it wrote tile {n}, outside its planned tiles; its group stops (please report this)"
            )));
        }
    }
    Ok(())
}

/// Errors of the surroundings rather than of the sketch (reading or
/// writing files: a full disk, permissions): they stop the group without
/// recording the edit, so that a resumed run tries it again.
fn environment(e: &EditError) -> bool {
    use crate::raster::RasterError;
    matches!(
        e,
        EditError::Write { .. }
            | EditError::Raster(
                RasterError::Io { .. }
                    | RasterError::Write { .. }
                    | RasterError::ChangedSinceOpened { .. }
            )
    )
}

/// The record of edit `e`, which took `seconds`, that wrote nothing.
fn unwritten(e: &PlannedEdit, status: Status, message: String, seconds: f64) -> Done {
    Done {
        id: e.id.clone(),
        index: e.index,
        group: e.group,
        status,
        tiles_written: Vec::new(),
        changed_cells: 0,
        report: None,
        message: Some(message),
        seconds,
        window: None,
    }
}

/// The record of edit `e`, which took `seconds` and wrote `tiles_written`
/// (`changed_cells` cells within window `w`) and `report`, once checked
/// against its footprint.
fn written(
    e: &PlannedEdit,
    (w, changed_cells, tiles_written): ([i64; 4], usize, &[String]),
    report: PathBuf,
    seconds: f64,
) -> Result<Done, BatchError> {
    check_footprint(e, w, changed_cells, tiles_written)?;
    Ok(Done {
        id: e.id.clone(),
        index: e.index,
        group: e.group,
        status: Status::Written,
        tiles_written: tiles_written
            .iter()
            .map(|t| tile_name(Path::new(t)))
            .collect(),
        changed_cells,
        report: Some(report),
        message: None,
        seconds,
        window: (changed_cells > 0).then_some(w),
    })
}

/// Run one edit of the plan; its record.
fn run_edit(
    plan: &Plan,
    plan_path: &Path,
    state: &Path,
    e: &PlannedEdit,
) -> Result<Done, BatchError> {
    check_sketch(plan_path, e)?;
    let report = report_path(state, e);
    if e.kind == EditKind::Corrections {
        return run_corrections(plan, e, report);
    }
    let opts = plan.settings.edit_options(Some(report.clone()));
    let t = Instant::now();
    let result = crate::edit::run(&plan.out, &e.sketch, &opts);
    let seconds = t.elapsed().as_secs_f64();
    let kept_report = report.is_file().then(|| report.clone());
    match result {
        Ok(r) => written(
            e,
            (r.deformation.window, r.changed_cells, &r.tiles_written),
            report,
            seconds,
        ),
        Err(err @ EditError::BelowMinFit { .. }) => Ok(Done {
            report: kept_report,
            ..unwritten(e, Status::BelowMinFit, err.to_string(), seconds)
        }),
        Err(err) if err.is_user_error() && !environment(&err) => Ok(Done {
            report: kept_report,
            ..unwritten(
                e,
                Status::Failed,
                err.to_string().replace('\n', " "),
                seconds,
            )
        }),
        Err(err) => Err(BatchError::Edit {
            id: e.id.clone(),
            source: Box::new(err),
        }),
    }
}

/// Run one corrections edit of the plan, as `demsketch correct OUT
/// --features F --in-place --report R` would; its record. A bad feature
/// (found at planning already, so only if the DEM changed under it) is
/// recorded as failed, as a sketch's user error is.
fn run_corrections(plan: &Plan, e: &PlannedEdit, report: PathBuf) -> Result<Done, BatchError> {
    let mut opts = crate::correct::CorrectOptions::new(crate::raster::Destination::InPlace);
    opts.report = Some(report.clone());
    // The pyramid is the batch's final step (super::pyramid).
    opts.write.defer_pyramid = true;
    let t = Instant::now();
    let result = crate::correct::run(&plan.out, &e.sketch, &opts);
    let seconds = t.elapsed().as_secs_f64();
    match result {
        Ok(r) => written(
            e,
            (r.window, r.changed_cells, &r.tiles_written),
            report,
            seconds,
        ),
        Err(err @ crate::correct::CorrectError::Input(_)) => Ok(unwritten(
            e,
            Status::Failed,
            err.to_string().replace('\n', " "),
            seconds,
        )),
        Err(err) => Err(BatchError::Correct {
            id: e.id.clone(),
            source: Box::new(err),
        }),
    }
}

/// Run group `g` of `plan` (read from `plan_path`): every edit not yet
/// recorded done, in order, each with its pending record first and its
/// done record once its tiles are in place. Does not lock: the caller
/// holds the output's edit lock (shared or exclusive) and has finished the
/// interrupted edit journals of the group's tiles.
pub fn run_group(
    plan: &Plan,
    plan_path: &Path,
    g: usize,
    progress: &dyn BatchProgress,
) -> Result<GroupOutcome, BatchError> {
    let group = plan.groups.get(g).ok_or_else(|| BatchError::Plan {
        path: plan_path.display().to_string(),
        message: format!(
            "group index {g} is out of range: the plan has {} groups (0 to {})",
            plan.groups.len(),
            plan.groups.len().saturating_sub(1)
        ),
    })?;
    let state = state_dir(&plan.out);
    let tiles = tiles_dir(&plan.out);
    let records = GroupRecords::new(&state, g);
    std::fs::create_dir_all(reports_dir(&state)).map_err(|e| io_err(&state, e))?;
    let mut outcome = GroupOutcome {
        group: g,
        done: Vec::new(),
        skipped: 0,
    };
    for &k in &group.edits {
        let e = &plan.edits[k];
        if let Some(d) = records.done(k)? {
            outcome.skipped += 1;
            progress.edit_done(&d, true);
            outcome.done.push(d);
            continue;
        }
        if let Some(p) = records.pending(k)? {
            if was_applied(&tiles, &p)? {
                let report = report_path(&state, e);
                let d = Done {
                    id: e.id.clone(),
                    index: k,
                    group: g,
                    status: Status::Recovered,
                    tiles_written: Vec::new(),
                    changed_cells: 0,
                    report: report.is_file().then_some(report),
                    message: Some(
                        "applied by a run killed before it was recorded; not applied again".into(),
                    ),
                    seconds: 0.0,
                    window: None,
                };
                records.write_done(&d)?;
                progress.edit_done(&d, false);
                outcome.done.push(d);
                continue;
            }
        }
        let pending = Pending {
            id: e.id.clone(),
            tiles: tile_digests(&tiles, &e.tiles)?,
        };
        records.write_pending(k, &pending)?;
        let d = run_edit(plan, plan_path, &state, e)?;
        records.write_done(&d)?;
        progress.edit_done(&d, false);
        outcome.done.push(d);
    }
    Ok(outcome)
}

/// Finish the interrupted edit journals of group `g`'s tiles (for a worker
/// holding the shared lock): one note per journal.
pub fn recover_group(plan: &Plan, g: usize) -> Result<Vec<String>, BatchError> {
    let Some(group) = plan.groups.get(g) else {
        return Ok(Vec::new());
    };
    let mine =
        |names: &[String]| !names.is_empty() && names.iter().all(|n| group.tiles.contains(n));
    Ok(journal::recover_where(
        &plan.out,
        &tiles_dir(&plan.out),
        mine,
    )?)
}

/// How many edits of `plan` (of group `g` only, when given) are recorded
/// done.
pub fn count_done(plan: &Plan, g: Option<usize>) -> usize {
    let state = state_dir(&plan.out);
    plan.edits
        .iter()
        .filter(|e| g.is_none_or(|g| e.group == g))
        .filter(|e| {
            GroupRecords::new(&state, e.group)
                .done(e.index)
                .ok()
                .flatten()
                .is_some()
        })
        .count()
}

/// Take the output's edit lock: `shared` for an array-job worker.
pub fn lock_output(
    plan: &Plan,
    shared: bool,
    timeout: Duration,
    waiting: impl FnMut(&str),
) -> Result<EditLock, BatchError> {
    let lock = if shared {
        EditLock::acquire_shared(&plan.out, timeout, waiting)?
    } else {
        EditLock::acquire(&plan.out, timeout, waiting)?
    };
    Ok(lock)
}

/// Run every group of `plan` (read from `plan_path`) on rayon's pool,
/// each in order inside; every group runs to its end even when another
/// fails. The caller holds the output's edit lock exclusively and has
/// finished its interrupted edit journals.
pub fn run_all(
    plan: &Plan,
    plan_path: &Path,
    progress: &dyn BatchProgress,
) -> Result<Vec<GroupOutcome>, BatchError> {
    let results: Vec<Result<GroupOutcome, BatchError>> = (0..plan.groups.len())
        .into_par_iter()
        .map(|g| run_group(plan, plan_path, g, progress))
        .collect();
    results.into_iter().collect()
}

/// The batch summary (`STATE/summary.json`).
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub out: PathBuf,
    pub plan: PathBuf,
    pub edits: usize,
    pub groups: usize,
    pub written: usize,
    pub below_min_fit: usize,
    pub failed: usize,
    pub recovered: usize,
    /// Edits not recorded done (their groups did not finish).
    pub incomplete: Vec<String>,
    /// Groups with an edit not done.
    pub incomplete_groups: Vec<usize>,
    pub changed_cells: usize,
    /// Distinct tiles rewritten by the batch.
    pub tiles_written: usize,
    /// Sum of the edits' own times, seconds.
    pub edit_seconds: f64,
    /// Wall time of this run, seconds (when one process ran the batch).
    pub wall_seconds: Option<f64>,
    /// Per edit, in manifest order.
    pub records: Vec<Done>,
    /// The pyramid step, on a tile directory with pyramid levels, once
    /// every edit is done ([`super::pyramid`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pyramid: Option<super::pyramid::PyramidDone>,
}

impl Summary {
    /// True when every edit is done and none failed or fell below --min-fit.
    pub fn complete(&self) -> bool {
        self.incomplete.is_empty()
    }
}

/// Gather every edit's record into the summary and, once every edit is
/// done, refresh the output's pyramid levels ([`super::pyramid`]); write
/// the summary (`STATE/summary.json`, atomically). `wall` is the run's wall
/// time; each recovery note goes to `note`. The caller holds the output's
/// edit lock exclusively.
pub fn finish(
    plan: &Plan,
    plan_path: &Path,
    wall: Option<f64>,
    note: &mut dyn FnMut(&str),
) -> Result<Summary, BatchError> {
    let state = state_dir(&plan.out);
    let mut s = Summary {
        out: plan.out.clone(),
        plan: std::path::absolute(plan_path).unwrap_or_else(|_| plan_path.to_path_buf()),
        edits: plan.edits.len(),
        groups: plan.groups.len(),
        written: 0,
        below_min_fit: 0,
        failed: 0,
        recovered: 0,
        incomplete: Vec::new(),
        incomplete_groups: Vec::new(),
        changed_cells: 0,
        tiles_written: 0,
        edit_seconds: 0.0,
        wall_seconds: wall,
        records: Vec::new(),
        pyramid: None,
    };
    let mut tiles = std::collections::BTreeSet::new();
    for e in &plan.edits {
        match GroupRecords::new(&state, e.group).done(e.index)? {
            Some(d) => {
                match d.status {
                    Status::Written => s.written += 1,
                    Status::BelowMinFit => s.below_min_fit += 1,
                    Status::Failed => s.failed += 1,
                    Status::Recovered => s.recovered += 1,
                }
                s.changed_cells += d.changed_cells;
                s.edit_seconds += d.seconds;
                tiles.extend(d.tiles_written.iter().cloned());
                s.records.push(d);
            }
            None => {
                s.incomplete.push(e.id.clone());
                if !s.incomplete_groups.contains(&e.group) {
                    s.incomplete_groups.push(e.group);
                }
            }
        }
    }
    s.tiles_written = tiles.len();
    if s.incomplete.is_empty() {
        s.pyramid = super::pyramid::refresh(plan, &s.records, note)?;
    }
    let text = serde_json::to_vec_pretty(&s).map_err(|e| BatchError::Internal(e.to_string()))?;
    let path = state.join("summary.json");
    crate::raster::atomic_file::replace_file(
        &path,
        |tmp| std::fs::write(tmp, &text).map_err(|e| e.to_string()),
        |tmp| {
            (std::fs::read(tmp).map_err(|e| e.to_string())? == text)
                .then_some(())
                .ok_or_else(|| "it reads back different".to_string())
        },
    )
    .map_err(|m| io_err(&path, m))?;
    Ok(s)
}

/// Write the plan into state directory `state` (`STATE/plan.json`), where
/// workers and resumed runs compare theirs with it.
fn write_plan_file(state: &Path, plan: &Plan) -> Result<PathBuf, BatchError> {
    std::fs::create_dir_all(state).map_err(|e| io_err(state, e))?;
    let path = state.join("plan.json");
    let text = plan.to_json();
    crate::raster::atomic_file::replace_file(
        &path,
        |tmp| std::fs::write(tmp, text.as_bytes()).map_err(|e| e.to_string()),
        |tmp| {
            (std::fs::read_to_string(tmp).map_err(|e| e.to_string())? == text)
                .then_some(())
                .ok_or_else(|| "it reads back different".to_string())
        },
    )
    .map_err(|m| io_err(&path, m))?;
    Ok(path)
}

/// Check that `plan` is the plan the output was prepared with.
pub fn check_stored_plan(plan: &Plan, plan_path: &Path) -> Result<(), BatchError> {
    let bad = |m: String| BatchError::Plan {
        path: plan_path.display().to_string(),
        message: m,
    };
    if !plan.out.exists() {
        return Err(bad(format!(
            "its output {} does not exist (run `demsketch batch plan` first)",
            plan.out.display()
        )));
    }
    let stored = state_dir(&plan.out).join("plan.json");
    let text = std::fs::read_to_string(&stored).map_err(|_| {
        bad(format!(
            "{} is not the output of a batch plan (no {})",
            plan.out.display(),
            stored.display()
        ))
    })?;
    let theirs: Plan =
        serde_json::from_str(&text).map_err(|e| bad(format!("{}: {e}", stored.display())))?;
    if &theirs != plan {
        return Err(bad(format!(
            "is not the plan {} was prepared with ({}); plan again into a new output",
            plan.out.display(),
            stored.display()
        )));
    }
    Ok(())
}

/// Remove temporary files of dead runs in the output's directories: the
/// tiles' directory and every directory of the batch's state (group
/// records, reports, summary), only where no worker can be live: under the
/// exclusive lock.
pub fn clean_output(plan: &Plan) -> Vec<String> {
    let mut notes = crate::raster::atomic_file::clean_stale(&tiles_dir(&plan.out));
    let mut dirs = vec![state_dir(&plan.out)];
    while let Some(d) = dirs.pop() {
        notes.extend(crate::raster::atomic_file::clean_stale(&d));
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let plain_dir = e.file_type().map(|t| t.is_dir()).unwrap_or(false);
            let temporary = e.file_name().to_string_lossy().starts_with(".demsketch-");
            if plain_dir && !temporary {
                dirs.push(e.path());
            }
        }
    }
    notes
}
