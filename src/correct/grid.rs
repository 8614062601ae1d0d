//! The working heights of a correction run: one seamless window of the DEM
//! (read across tile boundaries through the tile layer), the input heights
//! and the current ones in `f64`, which every correction updates in turn.
//! At the end [`Grid::write_values`] gives the values for
//! [`crate::raster::Dem::write_back`]: NaN (keep) where a cell is unchanged,
//! so cells no correction reached stay bit-identical.

use crate::deform::CellSize;
use crate::raster::{GeoTransform, HeightMap, Window};

/// Heights over the window every correction may touch.
#[derive(Debug, Clone)]
pub struct Grid {
    /// The window in the DEM grid.
    pub window: Window,
    /// Cell size in metres.
    pub cell: CellSize,
    /// Input heights, as read (NaN = nodata).
    pub base: HeightMap,
    /// Current heights, row-major (NaN = nodata).
    pub values: Vec<f64>,
    /// Cells set to a water surface by a lake or river.
    pub water: Vec<bool>,
}

impl Grid {
    /// A grid starting at the input heights.
    pub fn new(window: Window, cell: CellSize, base: HeightMap) -> Grid {
        let values = base.data.iter().map(|&h| h as f64).collect();
        Grid {
            water: vec![false; window.len()],
            window,
            cell,
            base,
            values,
        }
    }

    pub fn width(&self) -> usize {
        self.window.width
    }

    pub fn height(&self) -> usize {
        self.window.height
    }

    /// The window's geotransform.
    pub fn geotransform(&self) -> GeoTransform {
        self.base.geotransform
    }

    /// DEM pixel coordinates to window pixel coordinates.
    pub fn local(&self, p: [f64; 2]) -> [f64; 2] {
        [p[0] - self.window.col as f64, p[1] - self.window.row as f64]
    }

    /// The current heights as a height map (f32), for sampling and the
    /// deformation's constraint rasteriser.
    pub fn current(&self) -> HeightMap {
        let mut hm = self.base.clone();
        for (d, &v) in hm.data.iter_mut().zip(&self.values) {
            *d = v as f32;
        }
        hm
    }

    /// Bilinear current height at window pixel coordinates.
    pub fn bilinear(&self, p: [f64; 2]) -> Option<f64> {
        let x = p[0] - 0.5;
        let y = p[1] - 0.5;
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (c0, r0) = (x.floor() as usize, y.floor() as usize);
        let (fx, fy) = (x - c0 as f64, y - r0 as f64);
        let c1 = if fx > 0.0 { c0 + 1 } else { c0 };
        let r1 = if fy > 0.0 { r0 + 1 } else { r0 };
        if c1 >= self.width() || r1 >= self.height() {
            return None;
        }
        let h = |c: usize, r: usize| {
            let v = self.values[r * self.width() + c];
            (!v.is_nan()).then_some(v)
        };
        Some(
            h(c0, r0)? * (1.0 - fx) * (1.0 - fy)
                + h(c1, r0)? * fx * (1.0 - fy)
                + h(c0, r1)? * (1.0 - fx) * fy
                + h(c1, r1)? * fx * fy,
        )
    }

    /// Distance in metres between two pixel-space points.
    pub fn metres(&self, a: [f64; 2], b: [f64; 2]) -> f64 {
        ((a[0] - b[0]) * self.cell.hx).hypot((a[1] - b[1]) * self.cell.hy)
    }

    /// Values for write-back: the current height where it differs from the
    /// input, NaN (keep) elsewhere.
    pub fn write_values(&self) -> Vec<f64> {
        self.values
            .iter()
            .zip(&self.base.data)
            .map(|(&v, &h)| {
                if h.is_nan() || v.is_nan() || v == h as f64 {
                    f64::NAN
                } else {
                    v
                }
            })
            .collect()
    }
}
