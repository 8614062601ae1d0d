//! `demsketch edit DEM --sketch FILE --out OUT [--report R] [--renders DIR]
//! [--in-place] [--min-fit F] [--allow-partial] [--dry-run] [--link]
//! [--lock-timeout S]`: correct a DEM so that its silhouettes match the
//! strokes of a sketch file, write the corrected GeoTIFF (or the full tile
//! set for a tile directory), the report and the pictures. Nothing is
//! written when anything fails; when a stroke's fit is below `--min-fit`
//! only the report and pictures are (exit 3).
//!
//! Before anything is read, the edit takes the DEM's edit lock (one edit
//! at a time, [`demsketch::raster::edit_lock`]), finishes or undoes an
//! edit a killed run left half-applied ([`demsketch::raster::journal`]),
//! removes temporary files of dead runs, and refuses outputs that name an
//! input or each other ([`demsketch::raster::path_check`]).

use anyhow::Context;
use demsketch::edit::{run_opened, EditError, EditOptions, EditReport};
use demsketch::raster::Destination;
use demsketch::view::{check_min_fit, check_view_settings, SettingNames};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Duration;

use super::{BelowMinFit, InternalError};

/// Exit codes of `edit`, shown by `--help`.
pub const EDIT_AFTER_HELP: &str = "\
Exit codes:
  0  the edit was written (with --dry-run: a real run would write it)
  1  a user error (bad DEM, sketch or flags): one line naming the file and the
     problem; nothing written
  2  an internal error; nothing written
  3  the edit ran but a stroke's fit (fitted_fraction) is below --min-fit and
     --allow-partial was not given: the DEM is not written, the report and the
     pictures are (each stroke has a status and a reason); with --dry-run, the
     same: a real run would not write

A dry run computes the whole edit and writes the report and pictures, never
the DEM: its exit code says what a real run with the same flags would do.

Safety: every file is written to a temporary file beside its target, read
back and checked, then renamed into place; a full disk or any write error
leaves every file as it was (exit 1). One edit of a DEM runs at a time (a
second waits, at most --lock-timeout seconds); an edit killed half-way is
finished by the next edit of the DEM, which says so; SIGINT and SIGTERM
remove temporary files (exit 130 / 143). --out, --report and --renders may
not name the DEM, one of its tiles, the sketch, or each other.";

#[derive(clap::Args, Debug)]
pub struct EditArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// Sketch file (JSON: views, each with a viewpoint, a camera and strokes in pixels; `options`; see docs/user_guide.md, sections 2 and 3).
    #[arg(long)]
    pub sketch: PathBuf,
    #[command(flatten)]
    pub output: OutputFlags,
    /// Write the edit report (JSON) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Write before/after views and a height-change map (PNG) into this directory.
    #[arg(long)]
    pub renders: Option<PathBuf>,
    #[command(flatten)]
    pub flags: EditFlags,
    /// Compute the edit, write the report and pictures, never the DEM; the
    /// exit code is the one a real run would give (0 or 3).
    #[arg(long)]
    pub dry_run: bool,
    /// Print the report on stdout.
    #[arg(long)]
    pub json: bool,
    /// Format of --out, a GDAL driver name as gdal_translate's -of (written
    /// -of or --of) [default: from the extension: .tif/.tiff GeoTIFF (a COG
    /// stays a COG), .asc Arc/Info ASCII grid, ...; no extension: GeoTIFF].
    #[arg(long = "of", value_name = "FORMAT")]
    pub format: Option<String>,
    /// Creation option NAME=VALUE for --out, as gdal_translate's -co
    /// (repeatable; for a GeoTIFF they override the input's layout and
    /// encoding, and the whole file is re-encoded).
    #[arg(long = "co", value_name = "NAME=VALUE")]
    pub creation_options: Vec<String>,
    /// Resampling of the overviews refreshed over the change [default: the
    /// one the file records (RESAMPLING metadata), else average].
    #[arg(long, value_parser = parse_overview_resampling)]
    pub overview_resampling: Option<String>,
    /// Resampling of a tile directory's pyramid (subdirectories 1, 2, ... as
    /// `gdal_retile.py -levels` makes them), whose tiles over the change
    /// are recomputed after an in-place edit: near, bilinear, cubic,
    /// cubicspline, lanczos, average or mode, as given to gdal_retile.py -r
    /// [default: near, its default].
    #[arg(long, value_parser = parse_pyramid_resampling)]
    pub pyramid_resampling: Option<String>,
    /// Also write the height change (new minus old height, DEM units) as a
    /// Float32 GeoTIFF on the grid of the changed window, nodata -9999
    /// outside the DEM's valid cells. Written on dry runs too.
    #[arg(long, value_name = "DZ.tif")]
    pub dz: Option<PathBuf>,
    /// Tile-directory --out: hard-link the unchanged tiles to the input's
    /// instead of copying them (a tool that later modifies such an output
    /// tile in place then modifies the input too).
    #[arg(long)]
    pub link: bool,
    /// Seconds to wait for another demsketch edit of the same DEM (or of a
    /// DEM in the same directory) to finish before giving up (exit 1).
    #[arg(long, default_value_t = 300.0, value_parser = parse_lock_timeout)]
    pub lock_timeout: f64,
}

/// Where an edit or a correction writes: `--out` or `--in-place` (the
/// flags of `edit` and `correct`).
#[derive(clap::Args, Debug, Clone)]
pub struct OutputFlags {
    /// Corrected GeoTIFF (single-file DEM) or directory receiving the full
    /// tile set (tile directory).
    #[arg(
        long,
        required_unless_present = "in_place",
        conflicts_with = "in_place"
    )]
    pub out: Option<PathBuf>,
    /// Rewrite the changed tiles of the input in place (atomically).
    #[arg(long)]
    pub in_place: bool,
}

impl OutputFlags {
    /// The destination the flags name (clap requires one of the two).
    pub fn destination(&self) -> anyhow::Result<Destination> {
        Ok(match (&self.out, self.in_place) {
            (_, true) => Destination::InPlace,
            (Some(p), false) => Destination::Path(p.clone()),
            (None, false) => anyhow::bail!("give --out OUT or --in-place"),
        })
    }
}

/// The flags every edit runs with, `edit`'s and `batch`'s (a batch runs
/// each edit as `edit --in-place` with the same flags).
#[derive(clap::Args, Debug, Clone)]
pub struct EditFlags {
    /// Only the DEM within this distance of each viewpoint is read, metres.
    #[arg(long, default_value_t = 50_000.0, allow_hyphen_values = true)]
    pub max_distance: f64,
    /// Refraction coefficient k (apparent drop (1 - k) d^2 / 2R).
    #[arg(long, default_value_t = 1.0 / 7.0, allow_hyphen_values = true)]
    pub refraction: f64,
    /// Most re-solves per view while lowering protruding silhouettes.
    #[arg(long, default_value_t = 4)]
    pub max_lowering_iterations: usize,
    /// Most re-solves per view while making the strokes the terrain's
    /// occluding contours (0: the paper's constraints and lowering only).
    #[arg(long, default_value_t = 6)]
    pub max_contour_iterations: usize,
    /// Least share of a stroke's pixel columns that must be fitted (the
    /// report's fit.fitted_fraction), a number >= 0, for an edit to be
    /// written; below it the edit writes no DEM and the exit code is 3.
    /// Above 1: never written.
    #[arg(long, default_value_t = demsketch::edit::DEFAULT_MIN_FIT, allow_hyphen_values = true)]
    pub min_fit: f64,
    /// Write the edit even when a stroke's fit is below --min-fit (the
    /// report still marks those strokes "partial" or "unfitted").
    #[arg(long)]
    pub allow_partial: bool,
}

impl EditFlags {
    /// The library's rules for `--max-distance`, `--refraction` and
    /// `--min-fit`, before any work.
    pub fn check(&self) -> anyhow::Result<()> {
        check_view_settings(
            Some(self.max_distance),
            self.refraction,
            SettingNames::Flags,
        )?;
        check_min_fit(self.min_fit, SettingNames::Flags)?;
        Ok(())
    }

    /// Set the options the flags give.
    pub fn apply(&self, opts: &mut EditOptions) {
        opts.max_distance_m = Some(self.max_distance);
        opts.refraction = self.refraction;
        opts.max_lowering_iterations = self.max_lowering_iterations;
        opts.max_contour_iterations = self.max_contour_iterations;
        opts.min_fit = self.min_fit;
        opts.allow_partial = self.allow_partial;
    }
}

fn parse_overview_resampling(s: &str) -> Result<String, String> {
    demsketch::raster::overviews::parse_resampling(s).map(str::to_string)
}

fn parse_pyramid_resampling(s: &str) -> Result<String, String> {
    demsketch::raster::pyramid::parse_resampling(s).map(str::to_string)
}

fn parse_lock_timeout(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("--lock-timeout '{s}' is not a number of seconds"))?;
    if !(v.is_finite() && (0.0..=1e9).contains(&v)) {
        return Err(format!(
            "--lock-timeout {v} is not a number of seconds >= 0"
        ));
    }
    Ok(v)
}

/// `demsketch edit`: check the outputs, take the lock and open the DEM
/// ([`demsketch::edit::guard`]), run the edit, then print its summary or
/// its report.
pub fn run(args: EditArgs) -> anyhow::Result<()> {
    args.flags.check()?;
    let destination = destination_of(&args)?;
    let opts = options_of(&args, destination);
    // The lock, recovery of a killed edit and the output checks
    // ([`demsketch::edit::guard`]), each note one line on stderr.
    // The DEM the guard opened is the one the edit runs on (opened once).
    let (_lock, dem) = demsketch::edit::guard::prepare_open(
        &args.dem,
        &args.sketch,
        &opts,
        Duration::from_secs_f64(args.lock_timeout),
        // (`--quiet` silences them, as GDAL's `-q` does all but errors:
        // under load the wait for another edit's lock, one of them, made
        // a quiet edit talk.)
        &mut |m| {
            if !super::quiet() {
                eprintln!("demsketch: {m}")
            }
        },
    )?;
    let report = match run_opened(dem, &args.dem, &args.sketch, &opts) {
        Ok(r) => r,
        Err(e @ EditError::BelowMinFit { .. }) => {
            if let (true, EditError::BelowMinFit { report, .. }) = (args.json, &e) {
                super::print_stdout(&serde_json::to_string_pretty(report).context("report")?)
                    .context("stdout")?;
            }
            return Err(BelowMinFit(e.to_string()).into());
        }
        Err(e) if e.is_user_error() => return Err(e.into()),
        Err(EditError::Internal(m)) => return Err(InternalError(m).into()),
        Err(e) => return Err(InternalError(e.to_string()).into()),
    };
    print_timings(&report);
    if args.json {
        super::print_stdout(&serde_json::to_string_pretty(&report).context("report")?)
            .context("stdout")?;
    } else if !super::quiet() {
        print_summary(&report);
    }
    Ok(())
}

/// Where the edit writes (`--out` or `--in-place`), after checking that
/// the outputs' formats and creation options can be written, before any
/// work.
fn destination_of(args: &EditArgs) -> anyhow::Result<Destination> {
    let destination = args.output.destination()?;
    if let Some(out) = &args.output.out {
        if !args.dem.is_dir() {
            demsketch::raster::output_format::output_driver(out, args.format.as_deref())
                .map_err(|m| anyhow::anyhow!(m))?;
        } else if args
            .format
            .as_deref()
            .is_some_and(|f| !f.eq_ignore_ascii_case("GTiff"))
        {
            anyhow::bail!(
                "{}: a tile directory is written as GeoTIFF tiles; -of {} is not supported",
                out.display(),
                args.format.as_deref().unwrap_or_default()
            );
        }
    }
    if let Some(dz) = &args.dz {
        demsketch::raster::output_format::output_driver(dz, None)
            .map_err(|m| anyhow::anyhow!(m))?;
    }
    demsketch::raster::output_format::check_creation_options(&args.creation_options)
        .map_err(|m| anyhow::anyhow!(m))?;
    Ok(destination)
}

/// The library's edit options from the command line.
fn options_of(args: &EditArgs, destination: Destination) -> EditOptions {
    let mut opts = EditOptions::new(destination);
    opts.write.link_unchanged = args.link;
    opts.write.format = args.format.clone();
    opts.write.creation_options = args.creation_options.clone();
    opts.write.overview_resampling = args.overview_resampling.clone();
    opts.write.pyramid_resampling = args.pyramid_resampling.clone();
    opts.dz = args.dz.clone();
    opts.report = args.report.clone();
    opts.renders = args.renders.clone();
    args.flags.apply(&mut opts);
    opts.progress = std::io::stderr().is_terminal() && !super::quiet();
    opts.dry_run = args.dry_run;
    opts
}

/// The report's stage times on stderr, under `--timings`.
fn print_timings(report: &EditReport) {
    let t = &report.timings_s;
    for (stage, secs) in [
        ("load", t.load),
        ("features", t.features),
        ("matching", t.matching),
        ("deformation", t.deformation),
        ("lowering", t.lowering),
        ("write", t.write),
        ("total", t.total),
    ] {
        super::timing(stage, secs);
    }
}

/// One line per stroke (its match, fit, visibility and reason), then one
/// for the edit (what was written, or what a real run would change).
fn print_summary(report: &EditReport) {
    for v in &report.views {
        for s in &v.strokes {
            eprintln!(
                "view \"{}\" stroke \"{}\": {:?}, fitted {:.2}, visible {:.2}, mean {:.2} px{}",
                v.name,
                s.id,
                s.matched.kind,
                s.fit.fitted_fraction,
                s.visible_fraction,
                s.fit.mean_px,
                s.reason
                    .as_deref()
                    .map(|r| format!(" ({r})"))
                    .unwrap_or_default()
            );
        }
    }
    if report.matching.stopped_early {
        eprintln!(
            "matching stopped at its budget of {} nodes (best assignment found kept)",
            report.matching.node_budget
        );
    }
    if report.written {
        eprintln!(
            "{}: {} cells changed (max |dz| {:.1} m) in {} file(s), {:.2} s",
            report.output,
            report.changed_cells,
            report.max_abs_displacement_m,
            report.tiles_written.len(),
            report.timings_s.total
        );
    } else {
        eprintln!(
            "{}: dry run, nothing written; a real run would change {} cells (max |dz| {:.1} m), {:.2} s",
            report.output,
            report.changed_cells,
            report.max_abs_displacement_m,
            report.timings_s.total
        );
    }
}
