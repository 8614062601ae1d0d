//! `demsketch correct DEM --features F.geojson --out OUT [--in-place]
//! [--report R] [--water-mask M] [--renders DIR] [--dry-run] [--json]`: apply corrections drawn in map view
//! (lakes, rivers, control curves and their cross-sections, breaklines,
//! landforms from silhouette strokes of `--sketch` and noise regions; see
//! `demsketch::correct`) and write the
//! corrected DEM through the same atomic write-back as `edit`.

use anyhow::Context;
use demsketch::correct::{run as run_correct, CorrectOptions};
use std::path::PathBuf;
use std::time::Duration;

use demsketch::raster::edit_lock::{lock_dir, EditLock};
use demsketch::raster::journal;

use super::edit::OutputFlags;
use super::InternalError;

/// Shown by `--help`.
pub const CORRECT_AFTER_HELP: &str = "\
Features (GeoJSON FeatureCollection, lon/lat or the CRS its \"crs\" member names),
by their \"kind\" property:
  lake           Polygon/MultiPolygon (holes = islands); level_m (default: the
                 lowest shoreline height), blend_m (default: 2 cells)
  river          LineString centreline, width_m; blend_m; flow \"line\" (the
                 line runs downstream, default) or \"auto\" (lower end = outlet);
                 or a Polygon reach (flow along its axis, from the higher end)
  control_curve  LineString with Z heights or heights_m; influence_m
  cross_section  LineString with Z heights or heights_m crossing a control
                 curve; control_curve (its id or name); heights relative
  breakline      LineString with Z heights, heights_m or height_m; hard true
                 (default: may kink across the line, never blend) or false
                 (soft: smooth across); influence_m (default: 3 cells)
  landform       Polygon boundary (null geometry: the default capsule);
                 silhouette {\"view\": NAME, \"stroke\": ID} naming a stroke
                 of --sketch; shadow (LineString, optional)
  noise_region   Polygon; noise_stroke (as silhouette); amplitude_m

Exit codes:
  0  written (with --dry-run: a real run would write it)
  1  a user error (bad DEM, features or flags): one line naming the file and
     the feature; nothing written
  2  an internal error; nothing written";

#[derive(clap::Args, Debug)]
pub struct CorrectArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// Corrections as a GeoJSON FeatureCollection (as QGIS writes it).
    #[arg(long)]
    pub features: PathBuf,
    /// The sketch file whose views and strokes the landform and
    /// noise_region features name (its strokes are not matched as an edit).
    #[arg(long, value_name = "SKETCH.json")]
    pub sketch: Option<PathBuf>,
    #[command(flatten)]
    pub output: OutputFlags,
    /// Write the report (JSON) here.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Compute everything and write the report, never the DEM.
    #[arg(long)]
    pub dry_run: bool,
    /// Print the report on stdout.
    #[arg(long)]
    pub json: bool,
    /// Also write the water cells of lakes and rivers (1, else 0) as a Byte
    /// GeoTIFF on the grid of the corrected window (written on dry runs too).
    #[arg(long, value_name = "MASK.tif")]
    pub water_mask: Option<PathBuf>,
    /// Write pictures here: map_before.png and map_after.png (hillshade of
    /// the corrected window, features drawn) and height_change.png.
    #[arg(long, value_name = "DIR")]
    pub renders: Option<PathBuf>,
    /// Resampling of a tile directory's pyramid (subdirectories 1, 2, ... as
    /// `gdal_retile.py -levels` makes them), recomputed over the change after
    /// an in-place correction, as given to gdal_retile.py -r [default: near].
    #[arg(long, value_parser = |s: &str| demsketch::raster::pyramid::parse_resampling(s).map(str::to_string))]
    pub pyramid_resampling: Option<String>,
}

pub fn run(args: CorrectArgs) -> anyhow::Result<()> {
    let destination = args.output.destination()?;
    if let Some(out) = &args.output.out {
        if !args.dem.is_dir() {
            demsketch::raster::output_format::output_driver(out, None)
                .map_err(|m| anyhow::anyhow!(m))?;
        }
    }
    // One edit or correction of a DEM at a time, as for `edit`; an edit a
    // killed run left half-applied is finished or undone first.
    let _lock = if lock_dir(&args.dem).is_dir() && args.dem.exists() {
        let lock = EditLock::acquire(&args.dem, Duration::from_secs(300), |m| {
            eprintln!("demsketch: {m}")
        })?;
        for note in journal::recover(&args.dem, &lock.dir)? {
            eprintln!("demsketch: {note}");
        }
        Some(lock)
    } else {
        None
    };
    let mut opts = CorrectOptions::new(destination);
    opts.report = args.report.clone();
    opts.dry_run = args.dry_run;
    if let Some(m) = &args.water_mask {
        demsketch::raster::output_format::output_driver(m, None).map_err(|e| anyhow::anyhow!(e))?;
    }
    opts.water_mask = args.water_mask.clone();
    opts.renders = args.renders.clone();
    opts.sketch = args.sketch.clone();
    opts.write.pyramid_resampling = args.pyramid_resampling.clone();
    let report = match run_correct(&args.dem, &args.features, &opts) {
        Ok(r) => r,
        Err(e) if e.is_user_error() => return Err(e.into()),
        Err(e) => return Err(InternalError(e.to_string()).into()),
    };
    super::timing("solve", report.timings_s.solve);
    super::timing("write", report.timings_s.write);
    super::timing("total", report.timings_s.total);
    if args.json {
        super::print_stdout(&serde_json::to_string_pretty(&report).context("report")?)
            .context("stdout")?;
    } else if !super::quiet() {
        for f in &report.corrections {
            eprintln!(
                "feature {}{}: {}, {} cells changed, max |dz| {:.2} m",
                f.index,
                f.id.as_deref()
                    .map(|i| format!(" (\"{i}\")"))
                    .unwrap_or_default(),
                f.kind,
                f.cells_changed,
                f.max_abs_dz_m
            );
        }
        let verb = if report.written {
            "cells changed"
        } else {
            "cells would change (dry run, nothing written)"
        };
        eprintln!("{}: {} {verb}", report.output, report.changed_cells);
    }
    Ok(())
}
