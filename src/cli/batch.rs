//! `demsketch batch DEM --jobs MANIFEST --out OUT [--resume]`: apply many
//! sketches to one DEM, the bytes the same as editing a copy of it in place
//! one sketch after another in manifest order; and the array-job steps
//! `batch plan`, `batch run --index N` and `batch finish`. A thin layer
//! over [`demsketch::batch`]: flags, locks, progress and exit codes.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use demsketch::batch::record::Status;
use demsketch::batch::run::{check_stored_plan, clean_output, count_done, lock_output};
use demsketch::batch::{finish, run_all, steps, BatchError, BatchSettings, Plan, Summary};
use demsketch::raster::journal;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::edit::EditFlags;
use super::{BelowMinFit, InternalError};

/// Shown by `demsketch batch --help`.
pub const BATCH_AFTER_HELP: &str = "\
MANIFEST: a JSON file {\"edits\": [{\"id\": \"e1\", \"sketch\": \"sketches/e1.json\"},
{\"id\": \"e2\", \"corrections\": \"fix/lakes.geojson\"}, ...]}, a text file with one
sketch path per line, or a directory of sketch files (*.json, in name
order); paths relative to the manifest.

OUT starts as a copy of DEM; every edit then rewrites OUT in place, exactly
as `demsketch edit OUT --sketch S --in-place` with the same flags would (a
corrections edit: `demsketch correct OUT --features F --in-place`)
(set SOURCE_DATE_EPOCH for byte-identical provenance times). Edits whose
tiles overlap run in manifest order; the others in parallel. Reports:
OUT/.demsketch_batch/reports/, summary: OUT/.demsketch_batch/summary.json.
A killed batch resumes with --resume, without redoing or double-applying an
edit.

Pyramids: a tile directory with levels in subdirectories 1, 2, ... (as
`gdal_retile.py -levels N` makes) is copied with them; the edits leave the
levels and the batch's last step recomputes the level tiles over every
area the edits changed, once, as `gdal_retile.py -r R` computes them (R:
--pyramid-resampling, default near). The level tiles away from the changes
keep their bytes. Internal and external overviews (.ovr) of the tiles are
refreshed by each edit, as `edit --in-place` does.

Array jobs: `demsketch batch plan DEM --jobs M --out OUT --plan plan.json`,
then `demsketch batch run --plan plan.json --index N` for every group N (in
any order, in parallel, on any machine that sees OUT; the index may come
from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX), then `demsketch batch
finish --plan plan.json` (which also refreshes the pyramid levels).

Exit codes:
  0  every edit written
  1  a user error (bad DEM, manifest, plan, index): one line, nothing
     written; or an edit failed on its input (the summary says which)
  2  an internal error
  3  an edit's fit was below --min-fit: it wrote nothing, the others did";

/// The flags of a batch: those every edit runs with (`edit`'s, one
/// group) and the pyramid's resampling.
#[derive(clap::Args, Debug, Clone)]
pub struct BatchFlags {
    #[command(flatten)]
    pub edit: EditFlags,
    /// Resampling of a tile directory's pyramid (subdirectories 1, 2, ... as
    /// `gdal_retile.py -levels` makes), refreshed once at the end of the
    /// batch: the `-r` it was built with (near, bilinear, cubic,
    /// cubicspline, lanczos, average, mode) [default: near].
    #[arg(long, value_parser = |s: &str| demsketch::raster::pyramid::parse_resampling(s).map(str::to_string))]
    pub pyramid_resampling: Option<String>,
}

impl BatchFlags {
    /// The flags as the batch's settings, once `--max-distance`,
    /// `--refraction` and `--min-fit` are checked as `edit` checks them.
    fn settings(&self) -> anyhow::Result<BatchSettings> {
        let e = &self.edit;
        e.check()?;
        Ok(BatchSettings {
            max_distance_m: e.max_distance,
            refraction: e.refraction,
            max_lowering_iterations: e.max_lowering_iterations,
            max_contour_iterations: e.max_contour_iterations,
            min_fit: e.min_fit,
            allow_partial: e.allow_partial,
            pyramid_resampling: self.pyramid_resampling.clone(),
        })
    }
}

#[derive(clap::Args, Debug)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct BatchArgs {
    #[command(subcommand)]
    pub step: Option<BatchStep>,
    /// A GeoTIFF or a directory of GeoTIFF tiles.
    #[arg(required = true)]
    pub dem: Option<PathBuf>,
    /// The manifest: JSON, a text list of sketch files, or a directory of sketches.
    #[arg(long, required = true)]
    pub jobs: Option<PathBuf>,
    /// The corrected DEM (a new file or directory; with --resume, the one
    /// an interrupted batch left).
    #[arg(long, required = true)]
    pub out: Option<PathBuf>,
    /// Finish the batch an interrupted run left in OUT.
    #[arg(long)]
    pub resume: bool,
    #[command(flatten)]
    pub flags: BatchFlags,
    /// Seconds to wait for another demsketch edit of OUT to finish.
    #[arg(long, default_value_t = 300.0)]
    pub lock_timeout: f64,
}

#[derive(clap::Subcommand, Debug)]
pub enum BatchStep {
    /// Plan the batch into independent groups and prepare OUT (a copy of DEM).
    Plan(PlanArgs),
    /// Run one group of a plan (for array-job engines).
    Run(RunArgs),
    /// Finish a planned batch: check every group ran, refresh the pyramid
    /// levels (if any), write the summary.
    Finish(FinishArgs),
}

#[derive(clap::Args, Debug)]
pub struct PlanArgs {
    /// A GeoTIFF or a directory of GeoTIFF tiles.
    pub dem: PathBuf,
    #[arg(long)]
    pub jobs: PathBuf,
    /// The corrected DEM (must not exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Where the plan goes (JSON).
    #[arg(long)]
    pub plan: PathBuf,
    #[command(flatten)]
    pub flags: BatchFlags,
}

#[derive(clap::Args, Debug)]
pub struct RunArgs {
    #[arg(long)]
    pub plan: PathBuf,
    /// The group to run (0-based) [default: $SLURM_ARRAY_TASK_ID, else
    /// $JOB_COMPLETION_INDEX].
    #[arg(long)]
    pub index: Option<String>,
    /// Seconds to wait for a demsketch edit of OUT to finish.
    #[arg(long, default_value_t = 300.0)]
    pub lock_timeout: f64,
}

#[derive(clap::Args, Debug)]
pub struct FinishArgs {
    #[arg(long)]
    pub plan: PathBuf,
    #[arg(long, default_value_t = 300.0)]
    pub lock_timeout: f64,
}

/// A batch error as the CLI's error (exit 2 for internal ones).
fn cli_err(e: BatchError) -> anyhow::Error {
    if e.is_user_error() {
        anyhow::Error::new(e)
    } else {
        InternalError(e.to_string()).into()
    }
}

pub fn run(args: BatchArgs) -> anyhow::Result<()> {
    match args.step {
        Some(BatchStep::Plan(a)) => plan(a),
        Some(BatchStep::Run(a)) => run_index(a),
        Some(BatchStep::Finish(a)) => finish_step(a),
        None => whole(args),
    }
}

/// Read the manifest and the DEM and plan the batch (nothing written).
fn make_plan(dem: &Path, jobs: &Path, out: &Path, flags: &BatchFlags) -> anyhow::Result<Plan> {
    steps::make_plan(dem, jobs, out, flags.settings()?).map_err(cli_err)
}

/// Copy the DEM to OUT, the plan with it.
fn prepare(plan: &Plan) -> anyhow::Result<()> {
    steps::prepare(plan).map_err(cli_err)
}

fn waiting(m: &str) {
    eprintln!("demsketch: {m}");
}

fn timeout(s: f64) -> Duration {
    Duration::from_secs_f64(if s.is_finite() && s >= 0.0 {
        s.min(1e9)
    } else {
        300.0
    })
}

/// Progress of the edits: a bar with the ETA on a terminal; with
/// --verbose elsewhere, one line per edit.
fn progress_bar(total: usize) -> ProgressBar {
    let on = std::io::stderr().is_terminal() && !super::quiet();
    let target = if on {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let pb = ProgressBar::with_draw_target(Some(total as u64), target);
    if let Ok(style) = ProgressStyle::with_template(
        "{bar:30} {pos}/{len} edits [{elapsed_precise} < ETA {eta_precise}] {msg}",
    ) {
        pb.set_style(style);
    }
    pb
}

/// One edit done: the bar moves (edits done by an earlier run were
/// counted before it started).
fn report_progress(pb: &ProgressBar, d: &demsketch::batch::record::Done, before: bool) {
    if before {
        return;
    }
    pb.inc(1);
    pb.set_message(format!("{}: {:?}", d.id, d.status));
    if super::verbose() && pb.is_hidden() {
        eprintln!(
            "demsketch: edit \"{}\" ({}/{}): {:?}, {} cells, {:.2} s, ETA {:.0} s",
            d.id,
            pb.position(),
            pb.length().unwrap_or(0),
            d.status,
            d.changed_cells,
            d.seconds,
            pb.eta().as_secs_f64()
        );
    }
}

/// One line about the summary, and its exit status.
fn conclude(s: &Summary) -> anyhow::Result<()> {
    if !super::quiet() {
        eprintln!(
            "{}: {} of {} edits written in {} groups ({} below --min-fit, {} failed, {} recovered), {} cells changed in {} tiles{}{}",
            s.out.display(),
            s.written,
            s.edits,
            s.groups,
            s.below_min_fit,
            s.failed,
            s.recovered,
            s.changed_cells,
            s.tiles_written,
            s.pyramid
                .as_ref()
                .map(|p| format!(
                    ", {} pyramid tiles of {} levels refreshed",
                    p.tiles_written.len(),
                    p.levels
                ))
                .unwrap_or_default(),
            s.wall_seconds
                .map(|w| format!(", {w:.1} s ({:.2} edits/s)", s.edits as f64 / w.max(1e-9)))
                .unwrap_or_default()
        );
    }
    if !s.incomplete.is_empty() {
        anyhow::bail!(
            "{}: {} edits not done (groups {:?}); run them, then finish again",
            s.out.display(),
            s.incomplete.len(),
            s.incomplete_groups
        );
    }
    if s.failed > 0 {
        let ids: Vec<&str> = s
            .records
            .iter()
            .filter(|d| d.status == Status::Failed)
            .map(|d| d.id.as_str())
            .collect();
        anyhow::bail!(
            "{}: {} edits failed on their input ({}); see {}",
            s.out.display(),
            s.failed,
            ids.join(", "),
            demsketch::batch::record::state_dir(&s.out)
                .join("summary.json")
                .display()
        );
    }
    if s.below_min_fit > 0 {
        return Err(BelowMinFit(format!(
            "{}: {} edits below --min-fit wrote nothing (the others did); see the summary",
            s.out.display(),
            s.below_min_fit
        ))
        .into());
    }
    Ok(())
}

/// `demsketch batch DEM --jobs M --out OUT`: everything in this process.
fn whole(args: BatchArgs) -> anyhow::Result<()> {
    let (Some(dem), Some(jobs), Some(out)) = (&args.dem, &args.jobs, &args.out) else {
        anyhow::bail!("give DEM, --jobs MANIFEST and --out OUT");
    };
    let t = Instant::now();
    let plan = make_plan(dem, jobs, out, &args.flags)?;
    let stored = demsketch::batch::record::state_dir(&plan.out).join("plan.json");
    if plan.out.exists() {
        if !args.resume {
            anyhow::bail!(
                "{}: already exists; give --resume to finish the batch an interrupted run left there, or another --out",
                out.display()
            );
        }
        check_stored_plan(&plan, &stored).map_err(cli_err)?;
    } else {
        prepare(&plan)?;
    }
    let _lock = lock_output(&plan, false, timeout(args.lock_timeout), waiting).map_err(cli_err)?;
    let notes = journal::recover(&plan.out, &demsketch::batch::record::tiles_dir(&plan.out))?;
    for n in notes.into_iter().chain(clean_output(&plan)) {
        if !super::quiet() {
            eprintln!("demsketch: {n}");
        }
    }
    let pb = progress_bar(plan.edits.len());
    pb.set_position(count_done(&plan, None) as u64);
    pb.reset_eta();
    let progress =
        |d: &demsketch::batch::record::Done, before: bool| report_progress(&pb, d, before);
    let ran = run_all(&plan, &stored, &progress);
    pb.finish_and_clear();
    ran.map_err(cli_err)?;
    let mut note = |m: &str| {
        if !super::quiet() {
            eprintln!("demsketch: {m}");
        }
    };
    let summary =
        finish(&plan, &stored, Some(t.elapsed().as_secs_f64()), &mut note).map_err(cli_err)?;
    conclude(&summary)
}

/// `demsketch batch plan`.
fn plan(a: PlanArgs) -> anyhow::Result<()> {
    let plan = steps::plan_to_file(&a.dem, &a.jobs, &a.out, &a.plan, a.flags.settings()?)
        .map_err(cli_err)?;
    if !super::quiet() {
        eprintln!(
            "{}: {} edits in {} groups; run `demsketch batch run --plan {} --index N` for N = 0 to {}, then `demsketch batch finish --plan {}`",
            a.plan.display(),
            plan.edits.len(),
            plan.groups.len(),
            a.plan.display(),
            plan.groups.len().saturating_sub(1),
            a.plan.display()
        );
    }
    Ok(())
}

/// The group index: `--index`, else SLURM_ARRAY_TASK_ID, else
/// JOB_COMPLETION_INDEX.
fn group_index(a: &RunArgs) -> anyhow::Result<usize> {
    let (text, from) = match &a.index {
        Some(i) => (i.clone(), "--index".to_string()),
        None => ["SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"]
            .iter()
            .find_map(|v| std::env::var(v).ok().map(|x| (x, format!("${v}"))))
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "give --index N (or set SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX)"
                )
            })?,
    };
    text.trim()
        .parse()
        .map_err(|_| anyhow::anyhow!("{from} '{text}' is not a group index (0, 1, 2, ...)"))
}

/// `demsketch batch run --plan P --index N`.
fn run_index(a: RunArgs) -> anyhow::Result<()> {
    let g = group_index(&a)?;
    // The plan is read here for the progress bar's length only;
    // [`steps::run_index`] reads and checks it.
    let plan = Plan::read(&a.plan).map_err(cli_err)?;
    let pb = progress_bar(plan.groups.get(g).map_or(0, |x| x.edits.len()));
    pb.set_position(count_done(&plan, Some(g)) as u64);
    pb.reset_eta();
    let progress =
        |d: &demsketch::batch::record::Done, before: bool| report_progress(&pb, d, before);
    let mut note = |m: &str| {
        if !super::quiet() {
            eprintln!("demsketch: {m}");
        }
    };
    let ran = steps::run_index(&a.plan, g, timeout(a.lock_timeout), &mut note, &progress);
    pb.finish_and_clear();
    let (plan, outcome) = ran.map_err(cli_err)?;
    if !super::quiet() {
        let written = outcome
            .done
            .iter()
            .filter(|d| d.status == Status::Written)
            .count();
        eprintln!(
            "{}: group {g}: {} edits done ({} written, {} done before)",
            plan.out.display(),
            outcome.done.len(),
            written,
            outcome.skipped
        );
    }
    Ok(())
}

/// `demsketch batch finish --plan P`.
fn finish_step(a: FinishArgs) -> anyhow::Result<()> {
    let mut note = |m: &str| {
        if !super::quiet() {
            eprintln!("demsketch: {m}");
        }
    };
    let summary =
        steps::finish_plan(&a.plan, timeout(a.lock_timeout), &mut note).map_err(cli_err)?;
    conclude(&summary)
}
