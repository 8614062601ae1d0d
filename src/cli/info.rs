//! `demsketch info DEM [--json]`.

use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens (VRT...).
    pub dem: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    let _ = args;
    anyhow::bail!("info: not implemented yet")
}
