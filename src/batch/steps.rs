//! The array-job steps of a batch as library calls, shared by
//! `demsketch batch plan / run --index N / finish` and the Python package
//! (`demsketch.batch_plan`, `demsketch.batch_run`, `demsketch.batch_finish`,
//! and `demsketch.dask`, which runs every index on a Dask cluster):
//!
//! - [`plan_to_file`]: read the manifest and the DEM, plan, copy the DEM to
//!   the output (with the plan), write the plan file;
//! - [`run_index`]: one group, under the output's shared edit lock, after
//!   finishing the interrupted edit journals of the group's tiles; an index
//!   run again (a retried task) applies nothing twice (the batch journal,
//!   [`super::record`]);
//! - [`finish_plan`]: under the exclusive lock, finish every interrupted
//!   edit journal, remove the temporary files of dead runs, refresh the
//!   pyramid levels of a tile directory that has them (once every edit is
//!   done, [`super::pyramid`]) and write the summary of every edit's
//!   record.

use std::path::Path;
use std::time::Duration;

use super::run::{check_stored_plan, clean_output, lock_output, recover_group};
use super::{finish, io_err, prepare_output, run_group, BatchError, BatchProgress, GroupOutcome};
use super::{BatchSettings, Manifest, Plan, Summary};
use crate::raster::{journal, Dem};

/// Read the manifest and the DEM and plan the batch (nothing written).
pub fn make_plan(
    dem: &Path,
    jobs: &Path,
    out: &Path,
    settings: BatchSettings,
) -> Result<Plan, BatchError> {
    let manifest = Manifest::read(jobs)?;
    let layer = Dem::open(dem)?;
    Plan::build(dem, &layer, &manifest, out, settings)
}

/// Copy the DEM to the plan's output, the plan with it.
pub fn prepare(plan: &Plan) -> Result<(), BatchError> {
    let layer = Dem::open(&plan.dem)?;
    prepare_output(plan, &layer)
}

/// `demsketch batch plan`: plan the batch of `jobs` on `dem` into `out`
/// (which must not exist), prepare `out` and write the plan to
/// `plan_path` (atomically).
pub fn plan_to_file(
    dem: &Path,
    jobs: &Path,
    out: &Path,
    plan_path: &Path,
    settings: BatchSettings,
) -> Result<Plan, BatchError> {
    let parent = crate::raster::atomic_file::parent_dir(plan_path);
    if !parent.is_dir() {
        return Err(io_err(plan_path, "its parent directory does not exist"));
    }
    if out.exists() {
        return Err(io_err(out, "already exists; give a new --out"));
    }
    let plan = make_plan(dem, jobs, out, settings)?;
    prepare(&plan)?;
    let text = plan.to_json();
    crate::raster::atomic_file::replace_file(
        plan_path,
        |tmp| std::fs::write(tmp, text.as_bytes()).map_err(|e| e.to_string()),
        |tmp| {
            (std::fs::read_to_string(tmp).map_err(|e| e.to_string())? == text)
                .then_some(())
                .ok_or_else(|| "it reads back different".to_string())
        },
    )
    .map_err(|m| io_err(plan_path, m))?;
    Ok(plan)
}

/// `demsketch batch run --plan P --index G`: run group `g` of the plan
/// at `plan_path`, waiting at most `timeout` for the shared lock; each
/// recovery note and lock wait goes to `note`.
pub fn run_index(
    plan_path: &Path,
    g: usize,
    timeout: Duration,
    note: &mut dyn FnMut(&str),
    progress: &dyn BatchProgress,
) -> Result<(Plan, GroupOutcome), BatchError> {
    let plan = Plan::read(plan_path)?;
    if g >= plan.groups.len() {
        return Err(BatchError::Plan {
            path: plan_path.display().to_string(),
            message: format!(
                "group index {g} is out of range: the plan has {} groups (0 to {})",
                plan.groups.len(),
                plan.groups.len().saturating_sub(1)
            ),
        });
    }
    check_stored_plan(&plan, plan_path)?;
    let _lock = lock_output(&plan, true, timeout, |m| note(m))?;
    for n in recover_group(&plan, g)? {
        note(&n);
    }
    let outcome = run_group(&plan, plan_path, g, progress)?;
    Ok((plan, outcome))
}

/// `demsketch batch finish --plan P`: the summary of every edit's record
/// (written to `STATE/summary.json`), after finishing the interrupted
/// edit journals and removing the temporary files of dead runs, under the
/// exclusive lock (waiting at most `timeout`).
pub fn finish_plan(
    plan_path: &Path,
    timeout: Duration,
    note: &mut dyn FnMut(&str),
) -> Result<Summary, BatchError> {
    let plan = Plan::read(plan_path)?;
    check_stored_plan(&plan, plan_path)?;
    let _lock = lock_output(&plan, false, timeout, |m| note(m))?;
    let notes = journal::recover(&plan.out, &super::record::tiles_dir(&plan.out))?;
    for n in notes.into_iter().chain(clean_output(&plan)) {
        note(&n);
    }
    finish(&plan, plan_path, None, note)
}
