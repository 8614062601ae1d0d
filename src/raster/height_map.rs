//! The working array of the pipeline: heights in metres as `f32` on a
//! georeferenced grid, with nodata as NaN. Rendering, feature extraction and
//! deformation all operate on a `HeightMap`; the tile layer produces it from
//! any window of a DEM and write-back consumes it.

use super::{Crs, GeoTransform};

/// Heights on a regular grid. Row-major, `data[row * width + col]`, row 0 at
/// the top (north for north-up DEMs). Nodata cells are `f32::NAN`.
#[derive(Debug, Clone)]
pub struct HeightMap {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
    /// Geotransform of this array (of the window, not of the whole DEM).
    pub geotransform: GeoTransform,
    pub crs: Crs,
}

impl HeightMap {
    /// The cells `col..col + width`, `row..row + height` (clipped to the
    /// map) as a height map of their own, georeferenced where they lie.
    pub fn crop(&self, col: usize, row: usize, width: usize, height: usize) -> HeightMap {
        let (c0, r0) = (col.min(self.width), row.min(self.height));
        let (w, h) = (width.min(self.width - c0), height.min(self.height - r0));
        let mut data = Vec::with_capacity(w * h);
        for r in r0..r0 + h {
            data.extend_from_slice(&self.data[r * self.width + c0..r * self.width + c0 + w]);
        }
        let g = self.geotransform.0;
        let (c, r) = (c0 as f64, r0 as f64);
        HeightMap {
            width: w,
            height: h,
            data,
            geotransform: GeoTransform([
                g[0] + c * g[1] + r * g[2],
                g[1],
                g[2],
                g[3] + c * g[4] + r * g[5],
                g[4],
                g[5],
            ]),
            crs: self.crs.clone(),
        }
    }

    /// Height at integer cell `(col, row)`, `None` outside or on nodata.
    #[inline]
    pub fn get(&self, col: usize, row: usize) -> Option<f32> {
        if col >= self.width || row >= self.height {
            return None;
        }
        let v = self.data[row * self.width + col];
        (!v.is_nan()).then_some(v)
    }

    /// Bilinear height at pixel-space `(px, py)` (cell centres at +0.5), or
    /// `None` outside the grid or next to nodata.
    pub fn bilinear(&self, px: f64, py: f64) -> Option<f64> {
        let ([h00, h10, h01, h11], fx, fy) = self.stencil(px, py)?;
        Some(
            h00 * (1.0 - fx) * (1.0 - fy)
                + h10 * fx * (1.0 - fy)
                + h01 * (1.0 - fx) * fy
                + h11 * fx * fy,
        )
    }

    /// The four cell-centre heights around pixel-space `(px, py)` (`h00`,
    /// `h10`, `h01`, `h11`) and the position between them, `None` outside
    /// the grid or next to nodata.
    fn stencil(&self, px: f64, py: f64) -> Option<([f64; 4], f64, f64)> {
        let x = px - 0.5;
        let y = py - 0.5;
        if !(x >= 0.0 && y >= 0.0) {
            return None;
        }
        let (c0, r0) = (x.floor() as usize, y.floor() as usize);
        let (fx, fy) = (x - c0 as f64, y - r0 as f64);
        let c1 = if fx > 0.0 { c0 + 1 } else { c0 };
        let r1 = if fy > 0.0 { r0 + 1 } else { r0 };
        let h = |c, r| self.get(c, r).map(|v| v as f64);
        Some(([h(c0, r0)?, h(c1, r0)?, h(c0, r1)?, h(c1, r1)?], fx, fy))
    }

    /// Smallest and largest valid height, `None` when everything is nodata.
    pub fn min_max(&self) -> Option<(f32, f32)> {
        let mut it = self.data.iter().copied().filter(|v| !v.is_nan());
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v))))
    }
}
