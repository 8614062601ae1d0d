//! Subcommands of the `demsketch` binary and the mapping of errors to exit codes.

pub mod edit;
pub mod info;
pub mod locate;
pub mod view;

use clap::{Parser, Subcommand};

/// Correct real digital elevation models (GeoTIFF, tile directories, VRT) by
/// sketching the silhouettes the terrain should show from a viewpoint.
#[derive(Parser, Debug)]
#[command(name = "demsketch", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
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
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Info(a) => info::run(a),
        Command::View(a) => view::run(a),
        Command::Locate(a) => locate::run(a),
        Command::Edit(a) => edit::run(a),
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
