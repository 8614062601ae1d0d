//! Subcommands of the `demsketch` binary and the mapping of errors to exit codes.

pub mod batch;
pub mod correct;
pub mod edit;
pub mod export;
pub mod info;
pub mod locate;
pub mod serve;
pub mod view;

use std::sync::atomic::{AtomicBool, Ordering};

use clap::{Parser, Subcommand};

/// Correct real digital elevation models (GeoTIFF, tile directories, VRT) by
/// sketching the silhouettes the terrain should show from a viewpoint.
#[derive(Parser, Debug)]
#[command(name = "demsketch", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// No progress bars and no notes on stderr: only errors (and what
    /// --json prints on stdout).
    #[arg(long, short = 'q', global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// Also print the time of each stage, and GDAL's own warnings, on
    /// stderr (one line each).
    #[arg(long, short = 'v', global = true)]
    pub verbose: bool,
}

static QUIET: AtomicBool = AtomicBool::new(false);
static VERBOSE: AtomicBool = AtomicBool::new(false);

/// `--quiet` was given.
pub fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// `--verbose` was given.
pub fn verbose() -> bool {
    VERBOSE.load(Ordering::Relaxed)
}

/// A stage's time on stderr, with `--verbose`.
pub fn timing(stage: &str, seconds: f64) {
    if verbose() {
        eprintln!("demsketch: {stage}: {seconds:.3} s");
    }
}

/// GDAL's error handler for the whole process: GDAL's messages never reach
/// the terminal as `ERROR n:` lines (the error that matters comes back from
/// the failing call and is reported once, in one line naming the file);
/// with `--verbose` its warnings and errors are shown, one line each. The
/// handler is the library's ([`demsketch::raster::gdal_errors`]), which
/// also captures the failures of every write so that a write GDAL reports
/// as failed fails.
pub fn install_gdal_error_handler() {
    demsketch::raster::gdal_errors::install_with_echo(|class, number, message| {
        if verbose() {
            eprintln!(
                "demsketch: GDAL {class:?} {number}: {}",
                message.replace('\n', " ")
            );
        }
    });
}

/// PROJ's messages, like GDAL's, never reach the terminal on their own: the
/// failing call's error is reported once, in one line naming the file; with
/// `--verbose` they are shown, one line each.
pub fn install_proj_message_handler() {
    demsketch::view::route_proj_messages(|message| {
        if verbose() {
            use std::io::Write;
            let _ = writeln!(
                std::io::stderr(),
                "demsketch: PROJ: {}",
                message.trim_end().replace('\n', " ")
            );
        }
    });
}

/// Rewrite GDAL-style `-of X` and `-co X` into the `--of` and `--co` flags
/// clap knows (GDAL's utilities spell them with one dash).
pub fn gdal_style_args(args: impl Iterator<Item = std::ffi::OsString>) -> Vec<std::ffi::OsString> {
    args.map(|a| match a.to_str() {
        Some("-of") => "--of".into(),
        Some("-co") => "--co".into(),
        _ => a,
    })
    .collect()
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Describe a DEM: size, tiles, CRS, geotransform, bounds, nodata, encoding, min/max.
    Info(info::InfoArgs),
    /// Render what a person standing at a viewpoint sees (PNG), optionally the depth buffer and viewshed.
    #[command(after_help = view::VIEW_EXAMPLES)]
    View(view::ViewArgs),
    /// Print the terrain point (lon, lat, height, distance) seen at a pixel of a view, as JSON.
    Locate(locate::LocateArgs),
    /// Correct a DEM so that its silhouettes match a sketch: corrected GeoTIFF/tiles, report, pictures.
    #[command(after_help = edit::EDIT_AFTER_HELP)]
    Edit(edit::EditArgs),
    /// Apply corrections drawn in map view (GeoJSON lakes, rivers, control curves) to a DEM.
    #[command(after_help = correct::CORRECT_AFTER_HELP)]
    Correct(correct::CorrectArgs),
    /// Apply many sketches to one DEM (groups of overlapping edits in order, the others in parallel), or run one group of a plan.
    #[command(after_help = batch::BATCH_AFTER_HELP)]
    Batch(batch::BatchArgs),
    /// Export a DEM: web-map tiles (Terrain-RGB, Terrarium), COG, GeoJSON of an edit, STAC item, glTF mesh.
    #[command(after_help = export::EXPORT_AFTER_HELP)]
    Export(export::ExportArgs),
    /// The browser app: map, first-person view, drawing, photo tracing, edit and compare.
    #[command(after_help = serve::SERVE_AFTER_HELP)]
    Serve(serve::ServeArgs),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    QUIET.store(cli.quiet, Ordering::Relaxed);
    VERBOSE.store(cli.verbose, Ordering::Relaxed);
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::View(a) => view::run(a),
        Command::Locate(a) => locate::run(a),
        Command::Edit(a) => edit::run(a),
        Command::Correct(a) => correct::run(a),
        Command::Batch(a) => batch::run(a),
        Command::Export(a) => export::run(a),
        Command::Serve(a) => serve::run(a),
    }
}

/// An error that is the program's fault rather than the input's (exit code 2).
#[derive(Debug, thiserror::Error)]
#[error("internal error: {0}")]
pub struct InternalError(pub String);

/// An edit ran but a stroke's fit is below `--min-fit`, so nothing was
/// written (exit code 3).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BelowMinFit(pub String);

/// 2 for internal errors, 3 for an edit below `--min-fit`, 1 for everything
/// caused by the input.
pub fn exit_code(e: &anyhow::Error) -> i32 {
    if is_broken_pipe(e) {
        return 0;
    }
    if e.chain()
        .any(|c| c.downcast_ref::<InternalError>().is_some())
    {
        2
    } else if e.chain().any(|c| c.downcast_ref::<BelowMinFit>().is_some()) {
        3
    } else {
        1
    }
}

/// True when `e` is a write to a closed pipe (`demsketch ... | head`):
/// the reader has all it wanted, so the program ends quietly.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// Print `text` and a newline on stdout, returning the error (a broken
/// pipe among them) instead of panicking as `println!` does.
pub fn print_stdout(text: &str) -> std::io::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())?;
    out.write_all(b"\n")?;
    out.flush()
}

/// An absolute eye (`what`: `--alt` or a sketch view's `alt_m`) at or
/// below `ground`, the surface the renderer draws at the viewpoint, is
/// refused as `edit` refuses it: the view from inside the terrain shows
/// nothing of it.
pub(crate) fn check_above_ground(
    what: &str,
    height: demsketch::view::EyeHeight,
    ground: f64,
) -> anyhow::Result<()> {
    if let Some(problem) = demsketch::view::below_ground_problem(what, height, ground) {
        anyhow::bail!("{problem}");
    }
    Ok(())
}

/// Parse a pair of numbers written `A<sep>B` (`1600x900`, `412.5,300`) for
/// clap, naming the flag and the part that is wrong.
pub(crate) fn parse_pair<T: std::str::FromStr>(
    s: &str,
    seps: &[char],
    what: &str,
    example: &str,
    names: [&str; 2],
) -> Result<(T, T), String> {
    let (a, b) = s
        .split_once(seps)
        .ok_or_else(|| format!("{what} '{s}' must be written like {example}"))?;
    let a = a
        .trim()
        .parse()
        .map_err(|_| format!("{what} '{s}': bad {}", names[0]))?;
    let b = b
        .trim()
        .parse()
        .map_err(|_| format!("{what} '{s}': bad {}", names[1]))?;
    Ok((a, b))
}
