//! `demsketch edit DEM --sketch FILE --out OUT [--report R] [--renders DIR]
//! [--in-place]`: correct a DEM so that its silhouettes match the strokes of
//! a sketch file, write the corrected GeoTIFF (or the full tile set for a
//! tile directory), the report and the pictures. Nothing is written when
//! anything fails.

use anyhow::Context;
use demsketch::edit::{run as run_edit, EditError, EditOptions};
use demsketch::raster::Destination;
use std::io::IsTerminal;
use std::path::PathBuf;

use super::InternalError;

#[derive(clap::Args, Debug)]
pub struct EditArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// Sketch file (JSON, see DESIGN.md).
    #[arg(long)]
    pub sketch: PathBuf,
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
    /// Write the edit report (JSON) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Write before/after views and a height-change map (PNG) into this directory.
    #[arg(long)]
    pub renders: Option<PathBuf>,
    /// Only the DEM within this distance of each viewpoint is read, metres.
    #[arg(long, default_value_t = 50_000.0)]
    pub max_distance: f64,
    /// Refraction coefficient k (apparent drop (1 - k) d^2 / 2R).
    #[arg(long, default_value_t = 1.0 / 7.0)]
    pub refraction: f64,
    /// Most re-solves per view while lowering protruding silhouettes.
    #[arg(long, default_value_t = 4)]
    pub max_lowering_iterations: usize,
    /// Most re-solves per view while making the strokes the terrain's
    /// occluding contours (0: the paper's constraints and lowering only).
    #[arg(long, default_value_t = 6)]
    pub max_contour_iterations: usize,
    /// Print the report on stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: EditArgs) -> anyhow::Result<()> {
    let destination = match (&args.out, args.in_place) {
        (_, true) => Destination::InPlace,
        (Some(p), false) => Destination::Path(p.clone()),
        (None, false) => anyhow::bail!("give --out OUT or --in-place"),
    };
    let mut opts = EditOptions::new(destination);
    opts.report = args.report.clone();
    opts.renders = args.renders.clone();
    opts.max_distance_m = Some(args.max_distance);
    opts.refraction = args.refraction;
    opts.max_lowering_iterations = args.max_lowering_iterations;
    opts.max_contour_iterations = args.max_contour_iterations;
    opts.progress = std::io::stderr().is_terminal();
    let report = match run_edit(&args.dem, &args.sketch, &opts) {
        Ok(r) => r,
        Err(e) if e.is_user_error() => return Err(e.into()),
        Err(EditError::Internal(m)) => return Err(InternalError(m).into()),
        Err(e) => return Err(InternalError(e.to_string()).into()),
    };
    if args.json {
        println!(
            "{}",
            serde_json::to_string_pretty(&report).context("report")?
        );
    } else {
        for v in &report.views {
            for s in &v.strokes {
                eprintln!(
                    "view \"{}\" stroke \"{}\": {:?}, fitted {:.2}, visible {:.2}, mean {:.2} px",
                    v.name,
                    s.id,
                    s.matched.kind,
                    s.fit.fitted_fraction,
                    s.visible_fraction,
                    s.fit.mean_px
                );
            }
        }
        eprintln!(
            "{} cells changed (max |dz| {:.1} m) in {} file(s), {:.2} s",
            report.changed_cells,
            report.max_abs_displacement_m,
            report.tiles_written.len(),
            report.timings_s.total
        );
    }
    Ok(())
}
