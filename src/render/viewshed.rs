//! Visibility from the eye: which DEM cells can be seen, the library side of
//! `demsketch view --viewshed vis.tif`. A cell is visible when the straight
//! line of sight (in the local frame, so curvature and refraction with k =
//! 1/7 are included, as gdal_viewshed's coefficient 0.85714) from the eye to
//! the terrain point at the cell centre plus a target height is not blocked
//! by the triangulated terrain. Each line of sight is cast exactly with
//! [`LocalTerrain::cast`]; rows run in parallel. The result is on the DEM's
//! own grid, 255 visible / 0 not (nodata cells and cells beyond the maximum
//! distance are 0), like gdal_viewshed's output.

use super::atomic::write_atomically;
use super::terrain::LocalTerrain;
use super::RenderError;
use crate::raster::{Crs, GeoTransform, HeightMap};
use rayon::prelude::*;
use std::path::Path;

/// A viewshed on the grid of the DEM the terrain was built from.
#[derive(Debug, Clone)]
pub struct Viewshed {
    pub width: usize,
    pub height: usize,
    /// 255 visible, 0 not visible; row-major.
    pub data: Vec<u8>,
    pub geotransform: GeoTransform,
    pub crs: Crs,
}

impl Viewshed {
    /// Share of valid cells (`mask` true) that are visible.
    pub fn visible_count(&self) -> usize {
        self.data.iter().filter(|&&v| v == 255).count()
    }
}

/// Viewshed of `terrain` on the grid of `dem` (the height map the terrain
/// was built from: the whole DEM or the window within the maximum view
/// distance, like gdal_viewshed's `-md` output extent) for a target
/// `target_height` metres above the surface.
pub fn viewshed(terrain: &LocalTerrain, dem: &HeightMap, target_height: f64) -> Viewshed {
    let (width, height) = (dem.width, dem.height);
    let mut data = vec![0u8; width * height];
    data.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(row, out)| {
            if row < terrain.row0 || row >= terrain.row0 + terrain.ny {
                return;
            }
            let r = row - terrain.row0;
            for c in 0..terrain.nx {
                let col = terrain.col0 + c;
                if col >= width {
                    break;
                }
                let Some(p) = terrain.vertex_local(c, r) else {
                    continue;
                };
                let target = [p[0], p[1], p[2] + target_height];
                let dist =
                    (target[0] * target[0] + target[1] * target[1] + target[2] * target[2]).sqrt();
                if dist.hypot(0.0) < 1e-9 {
                    out[col] = 255;
                    continue;
                }
                let d = [target[0] / dist, target[1] / dist, target[2] / dist];
                let limit = dist - (1e-6 * dist + 1e-3);
                if limit <= 0.0 || terrain.cast(d, limit).is_none() {
                    out[col] = 255;
                }
            }
        });
    Viewshed {
        width,
        height,
        data,
        geotransform: dem.geotransform,
        crs: dem.crs.clone(),
    }
}

/// Write `vs` as a single-band Byte GeoTIFF with the DEM's georeferencing.
pub fn write_viewshed_tiff(vs: &Viewshed, path: &Path) -> Result<(), RenderError> {
    write_atomically(
        path,
        |tmp| {
            let werr = |e: gdal::errors::GdalError| RenderError::Write {
                path: path.display().to_string(),
                message: e.to_string().lines().next().unwrap_or("").to_string(),
            };
            crate::raster::atomic_file::through_memory(tmp, None, |tmp| {
                let driver = gdal::DriverManager::get_driver_by_name("GTiff").map_err(werr)?;
                let mut ds = driver
                    .create_with_band_type::<u8, _>(tmp, vs.width, vs.height, 1)
                    .map_err(werr)?;
                ds.set_geo_transform(&vs.geotransform.0).map_err(werr)?;
                let srs = vs.crs.gdal_definition();
                if !srs.is_empty() {
                    if let Ok(sr) = gdal::spatial_ref::SpatialRef::from_definition(&srs) {
                        ds.set_spatial_ref(&sr).map_err(werr)?;
                    }
                }
                let mut band = ds.rasterband(1).map_err(werr)?;
                let mut buf = gdal::raster::Buffer::new((vs.width, vs.height), vs.data.clone());
                band.write((0, 0), (vs.width, vs.height), &mut buf)
                    .map_err(werr)?;
                ds.flush_cache().map_err(werr)?;
                ds.close().map_err(werr)?;
                Ok::<(), RenderError>(())
            })
            .map_err(|message| RenderError::Write {
                path: path.display().to_string(),
                message,
            })
        },
        |tmp| super::atomic::verify_band(tmp, vs.width, vs.height, &vs.data),
    )
}
