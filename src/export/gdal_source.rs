//! The DEM as one dataset GDAL opens, for the exports that go through
//! GDAL (the tile warps of [`super::xyz_tiles`], the COG of [`super::cog`]):
//! a single file (or a GDAL virtual path) as it is, a directory of tiles as
//! a VRT mosaic of its tiles (as `gdalbuildvrt` makes it) kept in GDAL's
//! memory file system while the export runs. Each thread opens its own
//! handle ([`GdalSource::open`]): GDAL datasets are not shared between
//! threads.

use std::path::{Path, PathBuf};

use super::ExportError;
use crate::raster::{Dem, LayerKind};

/// Where GDAL reads the DEM from.
pub struct GdalSource {
    /// What to open: the DEM's path, or the in-memory VRT of its tiles.
    pub path: PathBuf,
    /// The DEM as the user named it (for messages).
    pub dem_path: PathBuf,
    /// The in-memory VRT to remove when done.
    vsimem: Option<PathBuf>,
}

impl GdalSource {
    /// The GDAL dataset of `dem`: its file, or a VRT of its tiles.
    pub fn new(dem: &Dem) -> Result<GdalSource, ExportError> {
        if dem.kind != LayerKind::TileDirectory {
            return Ok(GdalSource {
                path: dem.path.clone(),
                dem_path: dem.path.clone(),
                vsimem: None,
            });
        }
        use std::sync::atomic::{AtomicU64, Ordering};
        static N: AtomicU64 = AtomicU64::new(0);
        let vrt = PathBuf::from(format!(
            "/vsimem/demsketch-export-{}-{}.vrt",
            std::process::id(),
            N.fetch_add(1, Ordering::SeqCst)
        ));
        let gerr = |e: gdal::errors::GdalError| ExportError::Input {
            path: dem.path.display().to_string(),
            message: format!(
                "GDAL: {}",
                crate::raster::atomic_file::one_line(&e.to_string())
            ),
        };
        let tiles = dem
            .tiles
            .iter()
            .map(|t| gdal::Dataset::open(&t.path))
            .collect::<Result<Vec<_>, _>>()
            .map_err(gerr)?;
        // Dropping the VRT dataset writes it to /vsimem.
        drop(gdal::programs::raster::build_vrt(Some(&vrt), &tiles, None).map_err(gerr)?);
        Ok(GdalSource {
            path: vrt.clone(),
            dem_path: dem.path.clone(),
            vsimem: Some(vrt),
        })
    }

    /// A new handle on the dataset (one per thread).
    pub fn open(&self) -> Result<gdal::Dataset, ExportError> {
        gdal::Dataset::open(&self.path).map_err(|e| ExportError::Input {
            path: self.dem_path.display().to_string(),
            message: format!(
                "GDAL cannot open it: {}",
                crate::raster::atomic_file::one_line(&e.to_string())
            ),
        })
    }

    /// The path GDAL opens.
    pub fn gdal_path(&self) -> &Path {
        &self.path
    }
}

impl Drop for GdalSource {
    fn drop(&mut self) {
        if let Some(p) = &self.vsimem {
            let _ = gdal::vsi::unlink_mem_file(p);
        }
    }
}
