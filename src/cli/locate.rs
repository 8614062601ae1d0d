//! `demsketch locate DEM --lon X --lat Y [camera flags] --pixel X,Y`: the
//! terrain point seen at a pixel of a view, printed as one JSON object
//! (`lon`, `lat`, `height`, `distance`, plus the CRS position and DEM cell).

use super::view::CameraFlags;
use demsketch::raster::Dem;
use demsketch::render::{locate, Scene};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct LocateArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    #[command(flatten)]
    pub camera: CameraFlags,
    /// Pixel coordinates X,Y (origin top-left; pixel centres at +0.5).
    #[arg(long, value_parser = parse_pixel, allow_hyphen_values = true)]
    pub pixel: (f64, f64),
}

fn parse_pixel(s: &str) -> Result<(f64, f64), String> {
    super::parse_pair(s, &[','], "pixel", "X,Y (e.g. 800,450)", ["X", "Y"])
}

pub fn run(args: LocateArgs) -> anyhow::Result<()> {
    let view = args.camera.resolve()?;
    let (x, y) = args.pixel;
    view.camera.check_pixel(x, y)?;
    let dem = Dem::open(&args.dem)?;
    let scene = Scene::open(
        &dem,
        &view.viewpoint,
        args.camera.max_distance,
        args.camera.refraction,
    )?;
    view.check_above_ground(scene.frame.ground)?;
    match locate(&scene.terrain, &view.camera, &scene.georef, x, y)? {
        Some(loc) => {
            super::print_stdout(&serde_json::to_string(&loc)?)?;
            Ok(())
        }
        None => anyhow::bail!(
            "{}: pixel {x},{y} shows sky (no terrain along that ray within the DEM or max distance)",
            args.dem.display()
        ),
    }
}
