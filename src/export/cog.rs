//! `export cog`: the DEM as a Cloud Optimized GeoTIFF, written by GDAL's
//! COG driver (tiled, overviews, the IFDs first and the tiles in the order
//! GDAL's `validate_cloud_optimized_geotiff.py` checks). Defaults suit
//! elevation: DEFLATE with the predictor (floating-point for Float
//! bands), 512-pixel blocks, overviews averaged; `-co NAME=VALUE` overrides
//! any of them as for `gdal_translate -of COG`. The DEM's metadata
//! (demsketch's provenance history among it) is copied. Written through
//! GDAL's memory file system and the project's verified writer, staged and
//! renamed ([`crate::raster::atomic_file`]); the written file is read back
//! and its band checksum compared with the source's before it replaces
//! anything.

use std::path::Path;
use std::time::Instant;

use serde::Serialize;

use super::gdal_source::GdalSource;
use super::ExportError;
use crate::raster::atomic_file::StagedOutputs;
use crate::raster::output_format::{check_creation_options, merge_options, write_copy};
use crate::raster::Dem;

/// The COG driver's options demsketch starts from.
pub fn default_options() -> Vec<String> {
    [
        "COMPRESS=DEFLATE",
        "PREDICTOR=YES",
        "BLOCKSIZE=512",
        "OVERVIEWS=AUTO",
        "RESAMPLING=AVERAGE",
        "BIGTIFF=IF_SAFER",
        "NUM_THREADS=ALL_CPUS",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

/// What was written.
#[derive(Debug, Clone, Serialize)]
pub struct CogReport {
    pub out: String,
    pub width: usize,
    pub height: usize,
    pub creation_options: Vec<String>,
    pub overviews: usize,
    pub bytes: u64,
    pub seconds: f64,
}

/// Write `dem_path` as a COG at `out`, with `user_options` (`-co`) over
/// [`default_options`].
pub fn export_cog(
    dem_path: &Path,
    out: &Path,
    user_options: &[String],
) -> Result<CogReport, ExportError> {
    let t0 = Instant::now();
    check_creation_options(user_options).map_err(|m| ExportError::Input {
        path: out.display().to_string(),
        message: m,
    })?;
    let dem = Dem::open(dem_path)?;
    let src = GdalSource::new(&dem)?;
    let ds = src.open()?;
    let options = merge_options(default_options(), user_options);
    let mut staged = StagedOutputs::default();
    let werr = |m: String| ExportError::Write {
        path: out.display().to_string(),
        message: m,
    };
    let tmp = staged.stage(out).map_err(werr)?;
    write_copy(&ds, "COG", &options, &tmp, out)?;
    let overviews = check_copy(&ds, &tmp).map_err(|m| werr(staged.hide(&m)))?;
    let bytes = std::fs::metadata(&tmp).map(|m| m.len()).unwrap_or(0);
    staged.commit().map_err(werr)?;
    Ok(CogReport {
        out: out.display().to_string(),
        width: dem.width,
        height: dem.height,
        creation_options: options,
        overviews,
        bytes,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The written file is a COG (GDAL says LAYOUT=COG) with the source's
/// size and band checksum; its number of overviews.
fn check_copy(src: &gdal::Dataset, written: &Path) -> Result<usize, String> {
    use gdal::Metadata;
    let ds = gdal::Dataset::open(written).map_err(|e| format!("{written:?} does not open: {e}"))?;
    if ds.metadata_item("LAYOUT", "IMAGE_STRUCTURE").as_deref() != Some("COG") {
        return Err(format!(
            "{}: GDAL does not see a COG layout",
            written.display()
        ));
    }
    if ds.raster_size() != src.raster_size() {
        return Err(format!("{}: written with another size", written.display()));
    }
    let (a, b) = (src.rasterband(1), ds.rasterband(1));
    let (a, b) = match (a, b) {
        (Ok(a), Ok(b)) => (a, b),
        _ => return Err(format!("{}: no band 1", written.display())),
    };
    let (w, h) = src.raster_size();
    let sum = |band: &gdal::raster::RasterBand| {
        // SAFETY: a valid band handle and a window inside the band.
        unsafe { gdal_sys::GDALChecksumImage(band.c_rasterband(), 0, 0, w as i32, h as i32) }
    };
    if sum(&a) != sum(&b) {
        return Err(format!(
            "{}: the written heights differ from the DEM's (checksum)",
            written.display()
        ));
    }
    Ok(b.overview_count().unwrap_or(0).max(0) as usize)
}
