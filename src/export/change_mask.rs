//! Where an edit changed the DEM, as a mask of cells on a georeferenced
//! grid: read from the height-change GeoTIFF `demsketch edit --dz` writes
//! (cells whose |dz| exceeds a threshold, nodata excluded), or from an edit
//! report (`--report`: the deformation's window on the DEM grid, all of it,
//! when the edit wrote anything). The tile exporter rewrites only the tiles
//! over the mask ([`super::xyz_tiles`]); the GeoJSON export outlines it
//! ([`super::change_footprint`]).

use std::path::Path;

use super::ExportError;
use crate::raster::{Crs, Dem, GeoTransform};

/// Changed cells on a grid.
#[derive(Debug, Clone)]
pub struct ChangeMask {
    pub width: usize,
    pub height: usize,
    /// Of the mask's grid (the dz raster's, or the window's on the DEM).
    pub geotransform: GeoTransform,
    pub crs: Crs,
    /// Row-major, true where the cell changed.
    pub changed: Vec<bool>,
    /// Largest |dz| over the changed cells, metres (`None` from a report
    /// without a dz raster: the report's `max_abs_displacement_m`).
    pub max_abs_dz_m: Option<f64>,
    /// Where the mask came from (for messages and GeoJSON properties).
    pub source: String,
}

impl ChangeMask {
    /// Number of changed cells.
    pub fn count(&self) -> usize {
        self.changed.iter().filter(|&&c| c).count()
    }

    /// The runs of changed cells, row by row: `(row, col_start, col_end)`
    /// with `col_end` exclusive.
    pub fn runs(&self) -> Vec<(usize, usize, usize)> {
        let mut runs = Vec::new();
        for r in 0..self.height {
            let row = &self.changed[r * self.width..(r + 1) * self.width];
            let mut c = 0;
            while c < self.width {
                if row[c] {
                    let start = c;
                    while c < self.width && row[c] {
                        c += 1;
                    }
                    runs.push((r, start, c));
                } else {
                    c += 1;
                }
            }
        }
        runs
    }
}

/// A `min_dz` (`--min-dz`) that is not a number of metres >= 0 (one line).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("--min-dz {} must be a number of metres >= 0", crate::num::Num(*.0))]
pub struct MinDzError(pub f64);

/// The threshold of a changed cell, |dz| > `min_dz`, is a finite number of
/// metres >= 0 (0: every cell the edit moved). [`read`] and [`from_dz`]
/// check it; a caller with a flag checks it before any work.
pub fn check_min_dz(min_dz: f64) -> Result<(), MinDzError> {
    if min_dz.is_finite() && min_dz >= 0.0 {
        Ok(())
    } else {
        Err(MinDzError(min_dz))
    }
}

/// Read the mask from `path`: a `.json` edit report (its deformation
/// window on `dem`'s grid) or a height-change raster (cells with
/// |dz| > `min_dz`, [`check_min_dz`]).
pub fn read(path: &Path, dem: &Dem, min_dz: f64) -> Result<ChangeMask, ExportError> {
    check_min_dz(min_dz)?;
    let is_json = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json {
        from_report(path, dem)
    } else {
        from_dz(path, min_dz)
    }
}

/// The cells of a dz raster whose |dz| exceeds `min_dz` ([`check_min_dz`]).
pub fn from_dz(path: &Path, min_dz: f64) -> Result<ChangeMask, ExportError> {
    check_min_dz(min_dz)?;
    let dz = Dem::open(path)?;
    let map = dz.read_height_map(dz.full_window())?;
    let mut max_abs: f64 = 0.0;
    let changed: Vec<bool> = map
        .data
        .iter()
        .map(|&v| {
            let c = v.is_finite() && (v as f64).abs() > min_dz;
            if c {
                max_abs = max_abs.max((v as f64).abs());
            }
            c
        })
        .collect();
    Ok(ChangeMask {
        width: map.width,
        height: map.height,
        geotransform: map.geotransform,
        crs: map.crs,
        changed,
        max_abs_dz_m: Some(max_abs),
        source: path.display().to_string(),
    })
}

/// The deformation window of an edit report, on `dem`'s grid; empty when
/// the report says nothing was written or no cell changed.
pub fn from_report(path: &Path, dem: &Dem) -> Result<ChangeMask, ExportError> {
    let report = super::edit_report::read(path)?;
    let bad = |m: &str| ExportError::Input {
        path: path.display().to_string(),
        message: m.to_string(),
    };
    let w = report
        .window
        .ok_or_else(|| bad("no deformation.window: not an edit report"))?;
    let (col, row, width, height) = (w[0], w[1], w[2], w[3]);
    if width <= 0 || height <= 0 || col < 0 || row < 0 {
        return Err(bad("deformation.window is empty or negative"));
    }
    if (col + width) as usize > dem.width || (row + height) as usize > dem.height {
        return Err(bad(&format!(
            "deformation.window {w:?} lies outside the {} x {} DEM {} (a report of another DEM?)",
            dem.width,
            dem.height,
            dem.path.display()
        )));
    }
    let (width, height) = (width as usize, height as usize);
    let any = report.written && report.changed_cells > 0;
    Ok(ChangeMask {
        width,
        height,
        geotransform: dem.geotransform.offset(col as f64, row as f64),
        crs: dem.crs.clone(),
        changed: vec![any; width * height],
        max_abs_dz_m: Some(report.max_abs_displacement_m),
        source: path.display().to_string(),
    })
}
