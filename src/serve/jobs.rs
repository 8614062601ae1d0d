//! Edits for the browser, one at a time, the others queued. A job is a
//! dry run (the report of `edit --dry-run` and its height change, from
//! which the pictures of `--renders` are drawn when the page fetches
//! them, see [`super::pictures`]) or,
//! once the user accepts a dry run, the real edit of the same sketch
//! written to the command line's `--out`. Both are one call of
//! [`crate::edit::run`] with the options of `demsketch edit` (the edit's
//! own staging, checks and atomic write-back; the DEM's edit lock and
//! journal recovery as `edit` takes them), on a blocking thread. Sketches,
//! reports and pictures live in the server's private working directory.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use indicatif::ProgressBar;
use serde::Serialize;

use super::pictures::picture_names;
use super::state::AppState;
use super::ServeError;
use crate::edit::{run as run_edit, EditError, EditOptions};
use crate::raster::atomic_file::clean_stale;
use crate::raster::edit_lock::{lock_dir, EditLock};
use crate::raster::path_check::{check_outputs, dem_inputs, Output};
use crate::raster::{journal, Destination, LayerKind};
use crate::sketch::SketchFile;

/// A dry run's height change (the edit's `--dz`), in the job's directory.
const DZ_FILE: &str = "dz.tif";

/// What a job does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum JobKind {
    DryRun,
    Write,
}

/// Where a job is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum JobState {
    Queued,
    Running,
    Done,
    Failed,
}

/// A job as the page sees it.
#[derive(Debug, Clone, Serialize)]
pub struct JobView {
    pub id: u64,
    pub kind: JobKind,
    pub state: JobState,
    /// Jobs ahead of this one in the queue.
    pub queued_ahead: usize,
    /// Seconds since it started running (or ran, when finished).
    pub elapsed_s: f64,
    /// While it runs: the stage the edit is in ("matching strokes to
    /// terrain features", ...).
    pub stage: Option<String>,
    /// The edit's report (also when a stroke's fit is below the minimum).
    pub report: Option<serde_json::Value>,
    /// Why it failed, or why a real run would not write (one line).
    pub message: Option<String>,
    /// A real run with the same sketch would write the DEM.
    pub writable: bool,
    /// The DEM was written to OUT (write jobs).
    pub written: bool,
    /// Pictures of a dry run: `/api/jobs/{id}/image/{name}` (drawn when
    /// first fetched).
    pub images: Vec<String>,
    /// For a write job: the dry run it accepts.
    pub accepts: Option<u64>,
}

struct Job {
    view: JobView,
    sketch: Arc<String>,
    allow_partial: bool,
    dir: PathBuf,
    started: Option<Instant>,
    /// The edit's stage bar (hidden), read while the job runs.
    stage: ProgressBar,
    finished: Option<Instant>,
    /// A dry run's pictures drawn so far, by name.
    pictures: BTreeMap<String, Arc<Vec<u8>>>,
}

/// What a dry run's pictures are drawn from ([`Jobs::picture_source`]).
pub enum PictureSource {
    /// Drawn before: the PNG.
    Drawn(Arc<Vec<u8>>),
    /// To draw: the sketch, the edit's height-change file and the
    /// deformation's window (`[col, row, width, height]`).
    ToDraw {
        sketch: Arc<String>,
        dz: PathBuf,
        window: [i64; 4],
    },
}

/// The jobs and the gate that lets one edit run at a time.
pub struct Jobs {
    jobs: Mutex<BTreeMap<u64, Job>>,
    next: Mutex<u64>,
    gate: tokio::sync::Semaphore,
    max_queued: usize,
    /// Woken whenever a job finishes (long-polling requests wait on it).
    pub finished: tokio::sync::Notify,
}

/// Finished jobs kept (their pictures and reports); older ones are removed.
const KEEP_FINISHED: usize = 32;

impl Jobs {
    pub fn new(max_queued: usize) -> Jobs {
        Jobs {
            jobs: Mutex::new(BTreeMap::new()),
            next: Mutex::new(1),
            gate: tokio::sync::Semaphore::new(1),
            max_queued: max_queued.max(1),
            finished: tokio::sync::Notify::new(),
        }
    }

    fn lock(&self) -> Result<std::sync::MutexGuard<'_, BTreeMap<u64, Job>>, ServeError> {
        self.jobs
            .lock()
            .map_err(|_| ServeError::Internal("the job table's lock is poisoned".into()))
    }

    /// The job `id` as the page sees it.
    pub fn view(&self, id: u64) -> Result<JobView, ServeError> {
        let jobs = self.lock()?;
        let job = jobs
            .get(&id)
            .ok_or_else(|| ServeError::NotFound(format!("no job {id}")))?;
        let mut v = job.view.clone();
        v.queued_ahead = jobs
            .values()
            .filter(|j| {
                j.view.id < id && matches!(j.view.state, JobState::Queued | JobState::Running)
            })
            .count();
        v.elapsed_s = match (job.started, job.finished) {
            (Some(s), Some(f)) => (f - s).as_secs_f64(),
            (Some(s), None) => s.elapsed().as_secs_f64(),
            _ => 0.0,
        };
        v.stage = (job.view.state == JobState::Running)
            .then(|| job.stage.message())
            .filter(|m| !m.is_empty());
        Ok(v)
    }

    /// Picture `name` of job `id` (only names the job lists): drawn
    /// already, or what to draw it from.
    pub fn picture_source(&self, id: u64, name: &str) -> Result<PictureSource, ServeError> {
        let jobs = self.lock()?;
        let job = jobs
            .get(&id)
            .ok_or_else(|| ServeError::NotFound(format!("no job {id}")))?;
        if !job.view.images.iter().any(|n| n == name) {
            return Err(ServeError::NotFound(format!(
                "job {id} has no picture '{name}'"
            )));
        }
        if let Some(png) = job.pictures.get(name) {
            return Ok(PictureSource::Drawn(png.clone()));
        }
        let window = job
            .view
            .report
            .as_ref()
            .and_then(|r| r.pointer("/deformation/window"))
            .and_then(|w| serde_json::from_value::<[i64; 4]>(w.clone()).ok())
            .ok_or_else(|| ServeError::Internal(format!("job {id}: no deformation window")))?;
        Ok(PictureSource::ToDraw {
            sketch: job.sketch.clone(),
            dz: job.dir.join(DZ_FILE),
            window,
        })
    }

    /// Keep picture `name` of job `id`, drawn, for the next requests.
    pub fn keep_picture(&self, id: u64, name: &str, png: Arc<Vec<u8>>) {
        if let Ok(mut jobs) = self.lock() {
            if let Some(job) = jobs.get_mut(&id) {
                job.pictures.insert(name.to_string(), png);
            }
        }
    }

    /// Discard a finished dry run: its pictures and report are removed.
    pub fn reject(&self, id: u64) -> Result<(), ServeError> {
        let mut jobs = self.lock()?;
        let job = jobs
            .get(&id)
            .ok_or_else(|| ServeError::NotFound(format!("no job {id}")))?;
        if matches!(job.view.state, JobState::Queued | JobState::Running) {
            return Err(ServeError::Conflict(format!("job {id} has not finished")));
        }
        if let Some(job) = jobs.remove(&id) {
            let _ = std::fs::remove_dir_all(&job.dir);
        }
        Ok(())
    }

    /// The sketch and options of a finished dry run that a real run would
    /// write, for [`submit`] of its write job.
    fn acceptable(&self, id: u64) -> Result<(Arc<String>, bool), ServeError> {
        let jobs = self.lock()?;
        let job = jobs
            .get(&id)
            .ok_or_else(|| ServeError::NotFound(format!("no job {id}")))?;
        if job.view.kind != JobKind::DryRun {
            return Err(ServeError::Conflict(format!("job {id} is not a dry run")));
        }
        if job.view.state != JobState::Done {
            return Err(ServeError::Conflict(format!(
                "dry run {id} has not finished"
            )));
        }
        if !job.view.writable {
            return Err(ServeError::Conflict(format!(
                "dry run {id}: a real run would not write ({})",
                job.view.message.as_deref().unwrap_or("see the report")
            )));
        }
        Ok((job.sketch.clone(), job.allow_partial))
    }

    /// Remove the oldest finished jobs beyond [`KEEP_FINISHED`].
    fn prune(jobs: &mut BTreeMap<u64, Job>) {
        let finished: Vec<u64> = jobs
            .values()
            .filter(|j| matches!(j.view.state, JobState::Done | JobState::Failed))
            .map(|j| j.view.id)
            .collect();
        for id in finished
            .iter()
            .take(finished.len().saturating_sub(KEEP_FINISHED))
        {
            if let Some(j) = jobs.remove(id) {
                let _ = std::fs::remove_dir_all(&j.dir);
            }
        }
    }
}

/// Queue a dry run of `sketch` (validated JSON text).
pub fn submit_dry_run(
    state: &AppState,
    sketch: String,
    allow_partial: bool,
) -> Result<u64, ServeError> {
    submit(
        state,
        JobKind::DryRun,
        Arc::new(sketch),
        allow_partial,
        None,
    )
}

/// Queue the real edit of dry run `id`'s sketch, written to OUT.
pub fn submit_accept(state: &AppState, id: u64) -> Result<u64, ServeError> {
    if state.config.out.is_none() {
        return Err(ServeError::Conflict(
            "the server was started without --out: nothing can be written".into(),
        ));
    }
    let (sketch, allow_partial) = state.jobs.acceptable(id)?;
    submit(state, JobKind::Write, sketch, allow_partial, Some(id))
}

fn submit(
    state: &AppState,
    kind: JobKind,
    sketch: Arc<String>,
    allow_partial: bool,
    accepts: Option<u64>,
) -> Result<u64, ServeError> {
    let id = {
        let mut jobs = state.jobs.lock()?;
        let active = jobs
            .values()
            .filter(|j| matches!(j.view.state, JobState::Queued | JobState::Running))
            .count();
        if active >= state.jobs.max_queued {
            return Err(ServeError::Busy(format!(
                "{active} edits are queued or running: try again when one has finished"
            )));
        }
        let id = {
            let mut next = state
                .jobs
                .next
                .lock()
                .map_err(|_| ServeError::Internal("job counter lock poisoned".into()))?;
            let id = *next;
            *next += 1;
            id
        };
        let dir = state.workdir.path().join(format!("job-{id}"));
        jobs.insert(
            id,
            Job {
                view: JobView {
                    id,
                    kind,
                    state: JobState::Queued,
                    queued_ahead: 0,
                    elapsed_s: 0.0,
                    stage: None,
                    report: None,
                    message: None,
                    writable: false,
                    written: false,
                    images: Vec::new(),
                    accepts,
                },
                sketch,
                allow_partial,
                dir,
                started: None,
                stage: ProgressBar::hidden(),
                finished: None,
                pictures: BTreeMap::new(),
            },
        );
        Jobs::prune(&mut jobs);
        id
    };
    let st = state.clone();
    tokio::spawn(async move {
        let Ok(_permit) = st.jobs.gate.acquire().await else {
            return;
        };
        let inputs = match st.jobs.lock() {
            Ok(mut jobs) => jobs.get_mut(&id).map(|j| {
                j.view.state = JobState::Running;
                j.started = Some(Instant::now());
                (
                    j.sketch.clone(),
                    j.allow_partial,
                    j.dir.clone(),
                    j.stage.clone(),
                )
            }),
            Err(_) => None,
        };
        let Some((sketch, allow_partial, dir, stage)) = inputs else {
            return;
        };
        let st2 = st.clone();
        let outcome = tokio::task::spawn_blocking(move || {
            run_job(&st2, kind, &sketch, allow_partial, &dir, stage)
        })
        .await
        .unwrap_or_else(|e| Outcome::failed(format!("internal error: the edit stopped: {e}")));
        if let Ok(mut jobs) = st.jobs.lock() {
            if let Some(j) = jobs.get_mut(&id) {
                j.finished = Some(Instant::now());
                j.view.state = if outcome.failed {
                    JobState::Failed
                } else {
                    JobState::Done
                };
                j.view.report = outcome.report;
                j.view.message = outcome.message;
                j.view.writable = outcome.writable;
                j.view.written = outcome.written;
                j.view.images = outcome.images;
            }
        }
        st.jobs.finished.notify_waiters();
    });
    Ok(id)
}

/// What a job gave.
struct Outcome {
    failed: bool,
    report: Option<serde_json::Value>,
    message: Option<String>,
    writable: bool,
    written: bool,
    images: Vec<String>,
}

impl Outcome {
    fn failed(message: String) -> Outcome {
        Outcome {
            failed: true,
            report: None,
            message: Some(message),
            writable: false,
            written: false,
            images: Vec::new(),
        }
    }
}

/// The edit's options: those of `demsketch edit` with the server's
/// `--max-distance`, `--refraction` and `--min-fit`.
pub fn edit_options(
    state: &AppState,
    destination: Destination,
    allow_partial: bool,
) -> EditOptions {
    let mut opts = EditOptions::new(destination);
    opts.max_distance_m = Some(state.config.max_distance_m);
    opts.refraction = state.config.refraction;
    opts.min_fit = state.config.min_fit;
    opts.allow_partial = allow_partial;
    opts
}

/// Run one job on this (blocking) thread.
fn run_job(
    state: &AppState,
    kind: JobKind,
    sketch: &str,
    allow_partial: bool,
    dir: &Path,
    stage: ProgressBar,
) -> Outcome {
    match run_job_inner(state, kind, sketch, allow_partial, dir, stage) {
        Ok(o) => o,
        Err(m) => Outcome::failed(m),
    }
}

fn run_job_inner(
    state: &AppState,
    kind: JobKind,
    sketch: &str,
    allow_partial: bool,
    dir: &Path,
    stage: ProgressBar,
) -> Result<Outcome, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("internal error: {}: {e}", dir.display()))?;
    let sketch_path = dir.join("sketch.json");
    std::fs::write(&sketch_path, sketch)
        .map_err(|e| format!("internal error: {}: {e}", sketch_path.display()))?;
    let dem = &state.config.dem;
    let tiles = state.dem.kind == LayerKind::TileDirectory;
    let (destination, _lock) = match kind {
        JobKind::DryRun => {
            // Never written by a dry run; names what a real run would write.
            let target = match &state.config.out {
                Some(o) => o.clone(),
                None => dir.join(if tiles { "corrected" } else { "corrected.tif" }),
            };
            (Destination::Path(target), None)
        }
        JobKind::Write => {
            let Some(out) = state.config.out.clone() else {
                return Err("the server was started without --out".into());
            };
            let lock = take_edit_lock(dem)?;
            let outputs = [Output {
                flag: "--out".into(),
                path: out.clone(),
                is_dir: tiles,
            }];
            check_outputs(&dem_inputs(&state.dem), &outputs).map_err(|e| e.to_string())?;
            (Destination::Path(out), lock)
        }
    };
    let mut opts = edit_options(state, destination, allow_partial);
    opts.dry_run = kind == JobKind::DryRun;
    opts.stage = Some(stage);
    opts.report = Some(dir.join("report.json"));
    if kind == JobKind::DryRun {
        // The pictures are drawn from the height change when fetched.
        opts.dz = Some(dir.join(DZ_FILE));
    }
    let result = run_edit(dem, &sketch_path, &opts);
    let images = match SketchFile::from_json_str(sketch, "sketch") {
        Ok(s) if dir.join(DZ_FILE).is_file() => picture_names(&s),
        _ => Vec::new(),
    };
    let to_value = |r: &crate::edit::EditReport| serde_json::to_value(r).ok();
    Ok(match result {
        Ok(report) => Outcome {
            failed: false,
            report: to_value(&report),
            message: None,
            writable: true,
            written: report.written,
            images,
        },
        Err(e @ EditError::BelowMinFit { .. }) => {
            let report = match &e {
                EditError::BelowMinFit { report, .. } => to_value(report),
                _ => None,
            };
            Outcome {
                failed: false,
                report,
                message: Some(e.to_string()),
                writable: false,
                written: false,
                images,
            }
        }
        Err(e) => Outcome {
            images,
            ..Outcome::failed(e.to_string())
        },
    })
}

/// Take the DEM's edit lock, finish or undo an edit a killed run left, and
/// remove temporary files of dead runs, as `demsketch edit` does.
fn take_edit_lock(dem: &Path) -> Result<Option<EditLock>, String> {
    if !(lock_dir(dem).is_dir() && dem.exists()) {
        return Ok(None);
    }
    let lock =
        EditLock::acquire(dem, Duration::from_secs(300), |_| {}).map_err(|e| e.to_string())?;
    for note in journal::recover(dem, &lock.dir).map_err(|e| e.to_string())? {
        eprintln!("demsketch serve: {note}");
    }
    for note in clean_stale(&lock.dir) {
        eprintln!("demsketch serve: {note}");
    }
    Ok(Some(lock))
}
