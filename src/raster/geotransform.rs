//! The affine map between pixel and CRS coordinates, in GDAL's six-number
//! order: `x = gt[0] + px * gt[1] + py * gt[2]`, `y = gt[3] + px * gt[4] + py * gt[5]`.
//! Pixel coordinates follow DESIGN.md: pixel (i, j) covers [i, i+1) x [j, j+1),
//! so the centre of pixel (i, j) is at (i + 0.5, j + 0.5).

use serde::{Deserialize, Serialize};

/// GDAL-ordered affine geotransform (PixelIsArea convention: the corner of
/// pixel (0, 0) is at `(gt[0], gt[3])`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeoTransform(pub [f64; 6]);

impl GeoTransform {
    /// A north-up transform with the top-left corner at `(x0, y0)` and square
    /// or rectangular pixels of `dx` by `dy` (dy positive; rows go south).
    pub fn north_up(x0: f64, y0: f64, dx: f64, dy: f64) -> Self {
        GeoTransform([x0, dx, 0.0, y0, 0.0, -dy])
    }

    /// CRS coordinates of the pixel-space point `(px, py)`.
    ///
    /// ```
    /// use demsketch::raster::GeoTransform;
    /// let gt = GeoTransform::north_up(500_000.0, 4_200_000.0, 30.0, 30.0);
    /// assert_eq!(gt.pixel_to_crs(0.5, 0.5), (500_015.0, 4_199_985.0));
    /// ```
    pub fn pixel_to_crs(&self, px: f64, py: f64) -> (f64, f64) {
        let g = &self.0;
        (g[0] + px * g[1] + py * g[2], g[3] + px * g[4] + py * g[5])
    }

    /// Pixel-space coordinates of the CRS point `(x, y)`, or `None` when the
    /// transform is singular.
    pub fn crs_to_pixel(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let g = &self.0;
        let det = g[1] * g[5] - g[2] * g[4];
        if det == 0.0 || !det.is_finite() {
            return None;
        }
        let dx = x - g[0];
        let dy = y - g[3];
        Some(((dx * g[5] - dy * g[2]) / det, (dy * g[1] - dx * g[4]) / det))
    }

    /// True when the transform has no rotation or shear terms.
    pub fn is_north_up(&self) -> bool {
        self.0[2] == 0.0 && self.0[4] == 0.0
    }

    /// Pixel width and height in CRS units (both positive).
    pub fn pixel_size(&self) -> (f64, f64) {
        let g = &self.0;
        (g[1].hypot(g[4]), g[2].hypot(g[5]))
    }

    /// The transform of the sub-window whose top-left pixel is `(x0, y0)`.
    pub fn offset(&self, x0: f64, y0: f64) -> Self {
        let (x, y) = self.pixel_to_crs(x0, y0);
        let g = self.0;
        GeoTransform([x, g[1], g[2], y, g[4], g[5]])
    }

    /// Bounds `[xmin, ymin, xmax, ymax]` in CRS units of a `width` x `height` raster.
    pub fn bounds(&self, width: usize, height: usize) -> [f64; 4] {
        let corners = [
            self.pixel_to_crs(0.0, 0.0),
            self.pixel_to_crs(width as f64, 0.0),
            self.pixel_to_crs(0.0, height as f64),
            self.pixel_to_crs(width as f64, height as f64),
        ];
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for (x, y) in corners {
            b[0] = b[0].min(x);
            b[1] = b[1].min(y);
            b[2] = b[2].max(x);
            b[3] = b[3].max(y);
        }
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_rotation() {
        let gt = GeoTransform([100.0, 2.0, 0.5, 50.0, 0.25, -3.0]);
        let (x, y) = gt.pixel_to_crs(12.25, 7.5);
        let (px, py) = gt.crs_to_pixel(x, y).expect("invertible");
        assert!((px - 12.25).abs() < 1e-12 && (py - 7.5).abs() < 1e-12);
    }
}
