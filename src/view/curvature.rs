//! Earth curvature and atmospheric refraction for first-person views and
//! visibility: a point at horizontal distance `d` from the eye appears lower
//! by `(1 - k) d^2 / (2 R)` than on a flat earth. With the default `k = 1/7`
//! this is gdal_viewshed's curvature coefficient 0.85714, so views and
//! viewsheds agree with it. `R` is the WGS84 ellipsoid's Gaussian mean radius
//! of curvature at the viewpoint's latitude (exact to the ellipsoid for the
//! local tangent frame used by [`crate::view::LocalFrame`]).

/// The curvature-and-refraction model: apparent drop `(1 - k) d^2 / (2 R)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Curvature {
    /// Refraction coefficient k (default 1/7).
    pub k: f64,
    /// Earth radius in metres used for the drop.
    pub radius_m: f64,
}

/// WGS84 semi-major axis in metres.
pub const WGS84_A: f64 = 6_378_137.0;
/// WGS84 first eccentricity squared.
pub const WGS84_E2: f64 = 0.006_694_379_990_141_317;

impl Default for Curvature {
    fn default() -> Self {
        Curvature {
            k: 1.0 / 7.0,
            radius_m: 6_371_008.8,
        }
    }
}

impl Curvature {
    /// Curvature with refraction coefficient `k` and the WGS84 Gaussian mean
    /// radius `sqrt(M N)` at latitude `lat_deg`.
    pub fn at_latitude(lat_deg: f64, k: f64) -> Self {
        let (m, n) = radii_of_curvature(lat_deg);
        Curvature {
            k,
            radius_m: (m * n).sqrt(),
        }
    }

    /// No curvature and no refraction (a flat earth): for synthetic tests.
    pub fn flat() -> Self {
        Curvature {
            k: 1.0,
            radius_m: f64::INFINITY,
        }
    }

    /// Coefficient `c` of the drop `c * d^2`.
    #[inline]
    pub fn coefficient(&self) -> f64 {
        if self.radius_m.is_finite() {
            (1.0 - self.k) / (2.0 * self.radius_m)
        } else {
            0.0
        }
    }

    /// Apparent drop in metres at horizontal distance `d` metres.
    #[inline]
    pub fn drop(&self, d: f64) -> f64 {
        self.coefficient() * d * d
    }
}

/// WGS84 meridional (M) and prime-vertical (N) radii of curvature in metres at
/// latitude `lat_deg`.
pub fn radii_of_curvature(lat_deg: f64) -> (f64, f64) {
    let s = lat_deg.to_radians().sin();
    let w2 = 1.0 - WGS84_E2 * s * s;
    let n = WGS84_A / w2.sqrt();
    let m = WGS84_A * (1.0 - WGS84_E2) / (w2 * w2.sqrt());
    (m, n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gdal_coefficient() {
        // gdal_viewshed: drop = 0.85714 * d^2 / D with D = 12 741 994 m.
        let c = Curvature {
            k: 1.0 / 7.0,
            radius_m: 12_741_994.0 / 2.0,
        };
        let d = 10_000.0;
        assert!((c.drop(d) - 0.85714 * d * d / 12_741_994.0).abs() < 1e-3);
    }
}
