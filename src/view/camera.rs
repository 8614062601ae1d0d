//! The pinhole camera of `DESIGN.md` in a viewpoint's local frame
//! (east-north-up metres at the eye, see [`crate::view::LocalFrame`]):
//! square pixels, principal point at the image centre, `hfov` across the
//! width, heading clockwise from true north, pitch up positive, roll
//! clockwise positive. Pixel `(i, j)` covers `[i, i+1) x [j, j+1)`, so its
//! centre is `(i + 0.5, j + 0.5)`; `x` goes right and `y` down.
//!
//! [`CameraModel`] is the small trait other modules (sketch matching,
//! silhouettes) use, so that they work with any camera that can project a
//! local point to a pixel and unproject a pixel to a ray.

use super::ViewError;

/// What a camera must do for the rest of the pipeline. Points and rays are in
/// the local frame of the viewpoint (ENU metres, eye at the origin).
pub trait CameraModel {
    /// Image width and height in pixels.
    fn size(&self) -> (usize, usize);
    /// Pixel coordinates of local point `p`, `None` when it is behind the camera.
    fn project(&self, p: [f64; 3]) -> Option<[f64; 2]>;
    /// Unit direction of the ray through pixel coordinates `px` (eye at origin).
    fn unproject(&self, px: [f64; 2]) -> [f64; 3];
}

/// A pinhole camera at the origin of a local frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub width: usize,
    pub height: usize,
    /// Heading in degrees clockwise from true north.
    pub heading_deg: f64,
    /// Pitch in degrees, up positive.
    pub pitch_deg: f64,
    /// Roll in degrees, clockwise positive.
    pub roll_deg: f64,
    /// Horizontal field of view across the width, degrees.
    pub hfov_deg: f64,
    /// Focal length in pixels.
    pub focal_px: f64,
    /// Camera axes in the local frame: forward, right, up (image up).
    pub forward: [f64; 3],
    pub right: [f64; 3],
    pub up: [f64; 3],
}

/// Working memory of rendering and silhouette extraction per image pixel
/// (an upper estimate).
const BYTES_PER_PIXEL: u64 = 64;

/// Pixel coordinates outside a camera's image, or not numbers (one line).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error(
    "pixel {},{} lies outside the {width}x{height} image",
    crate::num::Num(*x),
    crate::num::Num(*y)
)]
pub struct PixelOutside {
    pub x: f64,
    pub y: f64,
    pub width: usize,
    pub height: usize,
}

impl Camera {
    /// Pixel coordinates `(x, y)` lie on the image: `0 <= x <= width`,
    /// `0 <= y <= height` (origin top-left, pixel centres at +0.5; the far
    /// edges are the last pixels' edges). `locate` ([`crate::render::locate`])
    /// checks its pixel so, for the command line and the browser app alike.
    ///
    /// ```
    /// let c = demsketch::view::Camera::new(800, 450, 0.0, 0.0, 0.0, 60.0).unwrap();
    /// assert!(c.check_pixel(400.5, 225.5).is_ok());
    /// let e = c.check_pixel(900.0, f64::NAN).unwrap_err();
    /// assert_eq!(e.to_string(), "pixel 900,NaN lies outside the 800x450 image");
    /// ```
    pub fn check_pixel(&self, x: f64, y: f64) -> Result<(), PixelOutside> {
        let (w, h) = (self.width as f64, self.height as f64);
        if x >= 0.0 && y >= 0.0 && x <= w && y <= h {
            Ok(())
        } else {
            Err(PixelOutside {
                x,
                y,
                width: self.width,
                height: self.height,
            })
        }
    }

    /// A camera; errors on an empty image or a field of view outside (0, 180).
    pub fn new(
        width: usize,
        height: usize,
        heading_deg: f64,
        pitch_deg: f64,
        roll_deg: f64,
        hfov_deg: f64,
    ) -> Result<Self, ViewError> {
        if width == 0 || height == 0 || width > 65_535 || height > 65_535 {
            return Err(ViewError::BadCamera(format!(
                "image size {width}x{height} must be between 1x1 and 65535x65535"
            )));
        }
        // Rendering keeps a few buffers per pixel (depth, ids, colour,
        // silhouette maps): refuse an image they cannot fit in memory
        // rather than abort on allocation.
        let need = (width as u64) * (height as u64) * BYTES_PER_PIXEL;
        let budget = crate::raster::geotiff::memory_budget();
        if need > budget {
            return Err(ViewError::BadCamera(format!(
                "image size {width}x{height} needs about {} MB, more than the memory budget of {} MB (DEMSKETCH_MEMORY_BUDGET_MB)",
                need >> 20,
                budget >> 20
            )));
        }
        if !(hfov_deg > 0.0 && hfov_deg < 180.0) {
            return Err(ViewError::BadCamera(format!(
                "hfov {hfov_deg} must lie strictly between 0 and 180 degrees"
            )));
        }
        if !(heading_deg.is_finite() && pitch_deg.abs() <= 90.0 && roll_deg.is_finite()) {
            return Err(ViewError::BadCamera(format!(
                "heading {heading_deg}, pitch {pitch_deg}, roll {roll_deg}: pitch must be within [-90, 90]"
            )));
        }
        let (h, p, r) = (
            heading_deg.to_radians(),
            pitch_deg.to_radians(),
            roll_deg.to_radians(),
        );
        let fwd = [h.sin() * p.cos(), h.cos() * p.cos(), p.sin()];
        let right0 = [h.cos(), -h.sin(), 0.0];
        let up0 = cross(right0, fwd);
        let (s, c) = r.sin_cos();
        let right = [
            c * right0[0] - s * up0[0],
            c * right0[1] - s * up0[1],
            c * right0[2] - s * up0[2],
        ];
        let up = [
            s * right0[0] + c * up0[0],
            s * right0[1] + c * up0[1],
            s * right0[2] + c * up0[2],
        ];
        Ok(Camera {
            width,
            height,
            heading_deg,
            pitch_deg,
            roll_deg,
            hfov_deg,
            focal_px: width as f64 / 2.0 / (hfov_deg.to_radians() / 2.0).tan(),
            forward: fwd,
            right,
            up,
        })
    }

    /// Unnormalised ray direction through pixel coordinates `(x, y)`.
    #[inline]
    pub fn ray(&self, x: f64, y: f64) -> [f64; 3] {
        let u = x - self.width as f64 / 2.0;
        let v = self.height as f64 / 2.0 - y;
        let f = self.focal_px;
        [
            f * self.forward[0] + u * self.right[0] + v * self.up[0],
            f * self.forward[1] + u * self.right[1] + v * self.up[1],
            f * self.forward[2] + u * self.right[2] + v * self.up[2],
        ]
    }

    /// Vertical field of view in degrees.
    pub fn vfov_deg(&self) -> f64 {
        2.0 * (self.height as f64 / 2.0 / self.focal_px)
            .atan()
            .to_degrees()
    }
}

impl CameraModel for Camera {
    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    #[inline]
    fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let z = dot(p, self.forward);
        if z <= 0.0 {
            return None;
        }
        let u = dot(p, self.right) * self.focal_px / z;
        let v = dot(p, self.up) * self.focal_px / z;
        Some([u + self.width as f64 / 2.0, self.height as f64 / 2.0 - v])
    }

    #[inline]
    fn unproject(&self, px: [f64; 2]) -> [f64; 3] {
        normalize(self.ray(px[0], px[1]))
    }
}

#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline]
pub(crate) fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_pixel_looks_along_heading() {
        let c = Camera::new(100, 50, 90.0, 0.0, 0.0, 60.0).unwrap();
        let d = c.unproject([50.0, 25.0]);
        assert!((d[0] - 1.0).abs() < 1e-12 && d[1].abs() < 1e-12);
        // The right edge is 30 degrees right of east, i.e. south of east.
        let d = c.unproject([100.0, 25.0]);
        assert!((d[1].atan2(d[0]).to_degrees() + 30.0).abs() < 1e-9);
    }

    #[test]
    fn project_unproject_round_trip_with_roll() {
        let c = Camera::new(1600, 900, 33.0, 5.0, 12.0, 50.0).unwrap();
        for &(x, y) in &[(0.5, 0.5), (800.0, 450.0), (1599.5, 10.25), (3.0, 899.0)] {
            let d = c.unproject([x, y]);
            let p = c.project([d[0] * 1e4, d[1] * 1e4, d[2] * 1e4]).unwrap();
            assert!((p[0] - x).abs() < 1e-6 && (p[1] - y).abs() < 1e-6);
        }
        // Clockwise roll of the camera (seen from behind it): the horizon
        // turns counter-clockwise in the image, so a point ahead-right at
        // the height of the optical axis appears above the centre row.
        let q = c.project([
            c.forward[0] + 0.1 * (33f64.to_radians().cos()),
            c.forward[1] - 0.1 * (33f64.to_radians().sin()),
            c.forward[2],
        ]);
        assert!(q.unwrap()[1] < 450.0);
    }
}
