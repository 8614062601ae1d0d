//! `demsketch serve DEM [--out OUT] [--underlay FILE] [--port P] [--bind ADDR] [--open]`: the
//! browser app on 127.0.0.1 ([`demsketch::serve`]). Prints the URL on
//! stdout; `--open` asks the desktop (xdg-open) to open it.

use std::net::{IpAddr, SocketAddr};
use std::path::PathBuf;

use demsketch::serve::{serve_blocking, ServeConfig, ServeError};
use demsketch::view::{check_min_fit, check_view_settings, SettingNames};

use super::InternalError;

/// Notes shown at the end of `demsketch serve --help`.
pub const SERVE_AFTER_HELP: &str = "\
The app: a map of the DEM (click to place the viewpoint, drag to set the
heading), the first-person view rendered by demsketch with its silhouettes
and ridges, strokes drawn with mouse, pen or touch (over-sketching, undo,
several views), a photo traced under the view, and the edit: a dry run
shows the report and the before/after pictures, Accept writes the corrected
DEM to --out through the same code as `demsketch edit` (each accepted edit
starts again from DEM). The sketch downloads as the JSON `demsketch edit
--sketch` reads. Only DEM is read and only --out written: no path comes from
the browser. Without --out the app only makes dry runs.";

#[derive(clap::Args, Debug)]
pub struct ServeArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// Where an accepted edit is written (as `edit --out`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Port to listen on (0: any free port).
    #[arg(long, default_value_t = 8642)]
    pub port: u16,
    /// Address to listen on (the default keeps the app on this machine).
    #[arg(long, default_value = "127.0.0.1")]
    pub bind: IpAddr,
    /// Open the app in the desktop's browser (xdg-open).
    #[arg(long)]
    pub open: bool,
    /// Only the DEM within this distance of a viewpoint is read, metres.
    #[arg(long, default_value_t = 50_000.0, allow_hyphen_values = true)]
    pub max_distance: f64,
    /// A raster (an orthophoto or any GeoTIFF: RGB or one band) drawn with
    /// the map's hillshade, reprojected onto the map by GDAL.
    #[arg(long, value_name = "FILE")]
    pub underlay: Option<PathBuf>,
    /// Least fitted share of each stroke for an edit to be written (as `edit --min-fit`).
    #[arg(long, default_value_t = demsketch::edit::DEFAULT_MIN_FIT, allow_hyphen_values = true)]
    pub min_fit: f64,
}

pub fn run(args: ServeArgs) -> anyhow::Result<()> {
    check_view_settings(Some(args.max_distance), 1.0 / 7.0, SettingNames::Flags)?;
    check_min_fit(args.min_fit, SettingNames::Flags)?;
    let mut config = ServeConfig::new(args.dem.clone(), args.out.clone());
    config.max_distance_m = args.max_distance;
    config.min_fit = args.min_fit;
    config.underlay = args.underlay.clone();
    let open = args.open;
    let result = serve_blocking(config, SocketAddr::new(args.bind, args.port), |addr| {
        let url = format!("http://{addr}/");
        let _ = super::print_stdout(&format!("demsketch serve: {url}"));
        if !super::quiet() {
            eprintln!("demsketch serve: press Ctrl-C to stop");
        }
        if open {
            if let Err(e) = std::process::Command::new("xdg-open").arg(&url).spawn() {
                eprintln!("demsketch serve: cannot open a browser ({e}); open {url}");
            }
        }
    });
    match result {
        Ok(()) => Ok(()),
        Err(ServeError::Internal(m)) => Err(InternalError(m).into()),
        // The library's messages name the file (DEM or --out) already.
        Err(e) => Err(anyhow::anyhow!("{e}")),
    }
}
