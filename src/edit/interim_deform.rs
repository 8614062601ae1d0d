//! Interim stand-in for `deform::deform` (branch `deform`), with exactly the
//! interface the edit pipeline codes against: placed curves in the DEM's CRS
//! become displacement constraints `delta = z - H(x, y)` on the DEM grid, the
//! multigrid solver diffuses them (Laplace, `M = 0` beyond the influence
//! distance), and `H' = H + M` on the affected window. It is replaced by
//! `crate::deform` as soon as that branch lands; only `pipeline.rs` names it.
#![allow(dead_code)]

use crate::deform::multigrid::{solve, MultigridOptions};
use crate::raster::{Dem, HeightMap, RasterError, Window};

/// A placed 3D curve: DEM CRS x, y and absolute height z.
#[derive(Debug, Clone, PartialEq)]
pub struct CurveConstraint {
    pub points: Vec<[f64; 3]>,
}

/// Options of [`deform`].
#[derive(Debug, Clone, Default)]
pub struct DeformOptions {
    /// Radius of influence, metres (`None`: from the curves' extent).
    pub influence_m: Option<f64>,
}

/// Solver figures of one deformation.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct DeformStats {
    pub constrained_cells: usize,
    pub cycles: usize,
    pub relative_residual: f64,
    pub influence_m: f64,
}

/// The result of a deformation on the affected window of the DEM.
#[derive(Debug, Clone)]
pub struct Deformation {
    /// The window of the DEM grid that was solved.
    pub window: Window,
    /// `M` over the window, row-major (0 on nodata).
    pub displacement: Vec<f32>,
    /// `H` over the window (NaN = nodata).
    pub base: HeightMap,
    /// Indices of the DEM tiles the displacement touches.
    pub affected_tiles: Vec<usize>,
    pub stats: DeformStats,
}

impl Deformation {
    /// `H + M` on the window.
    pub fn edited(&self) -> HeightMap {
        let mut h = self.base.clone();
        for (v, m) in h.data.iter_mut().zip(&self.displacement) {
            if !v.is_nan() {
                *v += *m;
            }
        }
        h
    }

    /// Values for `Dem::write_back` over `window`: NaN = keep.
    pub fn write_values(&self) -> Vec<f64> {
        self.base
            .data
            .iter()
            .zip(&self.displacement)
            .map(|(&h, &m)| {
                if h.is_nan() || m == 0.0 {
                    f64::NAN
                } else {
                    (h + m) as f64
                }
            })
            .collect()
    }
}

/// Why a deformation failed.
#[derive(Debug, thiserror::Error)]
pub enum DeformError {
    #[error(transparent)]
    Raster(#[from] RasterError),
    #[error("{0}")]
    Invalid(String),
    #[error("solver: {0}")]
    Solver(String),
}

/// Metric cell size (hx, hy) of the DEM grid near `(x, y)`.
fn cell_size_m(dem: &Dem, y: f64) -> (f64, f64) {
    let (gx, gy) = dem.geotransform.pixel_size();
    let (gx, gy) = (gx.abs(), gy.abs());
    if dem.crs.geographic {
        let lat = y.to_radians();
        (gx * 111_320.0 * lat.cos().max(0.01), gy * 110_540.0)
    } else {
        (gx, gy)
    }
}

/// Deform `dem` so that its surface passes through `curves`.
pub fn deform(
    dem: &Dem,
    curves: &[CurveConstraint],
    opts: &DeformOptions,
) -> Result<Deformation, DeformError> {
    let pts: Vec<(f64, f64, f64)> = curves
        .iter()
        .flat_map(|c| c.points.iter())
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .filter_map(|p| {
            dem.geotransform
                .crs_to_pixel(p[0], p[1])
                .map(|(px, py)| (px, py, p[2]))
        })
        .collect();
    if pts.is_empty() {
        return Err(DeformError::Invalid(
            "no curve point lies on the DEM".into(),
        ));
    }
    let (mut c0, mut r0, mut c1, mut r1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for &(px, py, _) in &pts {
        c0 = c0.min(px);
        r0 = r0.min(py);
        c1 = c1.max(px);
        r1 = r1.max(py);
    }
    let ymid = dem
        .geotransform
        .pixel_to_crs((c0 + c1) / 2.0, (r0 + r1) / 2.0)
        .1;
    let (hx, hy) = cell_size_m(dem, ymid);
    let extent = ((c1 - c0) * hx).hypot((r1 - r0) * hy);
    let influence = opts
        .influence_m
        .filter(|v| v.is_finite() && *v > 0.0)
        .unwrap_or_else(|| (0.5 * extent).max(20.0 * hx.max(hy)));
    let (mx, my) = (influence / hx + 2.0, influence / hy + 2.0);
    let win = Window::new(
        (c0 - mx).floor() as i64,
        (r0 - my).floor() as i64,
        ((c1 - c0) + 2.0 * mx).ceil() as usize + 1,
        ((r1 - r0) + 2.0 * my).ceil() as usize + 1,
    );
    let win = win
        .intersect(&dem.full_window())
        .ok_or_else(|| DeformError::Invalid("curves lie outside the DEM".into()))?;
    let base = dem.read_height_map(win)?;
    let (nx, ny) = (win.width, win.height);

    // Rasterise: sample each segment every quarter cell, average delta per cell.
    let mut sum = vec![0.0f64; nx * ny];
    let mut count = vec![0u32; nx * ny];
    let (ox, oy) = (win.col as f64, win.row as f64);
    let mut add = |px: f64, py: f64, z: f64| {
        let (lx, ly) = (px - ox, py - oy);
        if lx < 0.0 || ly < 0.0 {
            return;
        }
        let (c, r) = (lx as usize, ly as usize);
        if c >= nx || r >= ny {
            return;
        }
        if let Some(h) = base
            .bilinear(lx, ly)
            .or_else(|| base.get(c, r).map(f64::from))
        {
            sum[r * nx + c] += z - h;
            count[r * nx + c] += 1;
        }
    };
    for curve in curves {
        let p: Vec<(f64, f64, f64)> = curve
            .points
            .iter()
            .filter_map(|p| {
                dem.geotransform
                    .crs_to_pixel(p[0], p[1])
                    .map(|(px, py)| (px, py, p[2]))
            })
            .collect();
        if p.len() == 1 {
            add(p[0].0, p[0].1, p[0].2);
        }
        for w in p.windows(2) {
            let (a, b) = (w[0], w[1]);
            let n = (((b.0 - a.0).abs().max((b.1 - a.1).abs())) * 4.0)
                .ceil()
                .max(1.0) as usize;
            for s in 0..=n.min(1_000_000) {
                let t = s as f64 / n as f64;
                add(
                    a.0 + (b.0 - a.0) * t,
                    a.1 + (b.1 - a.1) * t,
                    a.2 + (b.2 - a.2) * t,
                );
            }
        }
    }

    // Fixed cells: constraints, nodata (0), and everything beyond the
    // influence distance from the constraints (0), by a chamfer distance.
    let mut dist = vec![f64::INFINITY; nx * ny];
    let mut fixed = vec![false; nx * ny];
    let mut values = vec![0.0f32; nx * ny];
    let mut constrained = 0;
    for i in 0..nx * ny {
        if count[i] > 0 {
            fixed[i] = true;
            values[i] = (sum[i] / count[i] as f64) as f32;
            dist[i] = 0.0;
            constrained += 1;
        }
    }
    let d = hx.hypot(hy);
    for j in 0..ny {
        for i in 0..nx {
            let k = j * nx + i;
            let mut v = dist[k];
            if i > 0 {
                v = v.min(dist[k - 1] + hx);
            }
            if j > 0 {
                v = v.min(dist[k - nx] + hy);
                if i > 0 {
                    v = v.min(dist[k - nx - 1] + d);
                }
                if i + 1 < nx {
                    v = v.min(dist[k - nx + 1] + d);
                }
            }
            dist[k] = v;
        }
    }
    for j in (0..ny).rev() {
        for i in (0..nx).rev() {
            let k = j * nx + i;
            let mut v = dist[k];
            if i + 1 < nx {
                v = v.min(dist[k + 1] + hx);
            }
            if j + 1 < ny {
                v = v.min(dist[k + nx] + hy);
                if i + 1 < nx {
                    v = v.min(dist[k + nx + 1] + d);
                }
                if i > 0 {
                    v = v.min(dist[k + nx - 1] + d);
                }
            }
            dist[k] = v;
        }
    }
    for k in 0..nx * ny {
        if !fixed[k] && (dist[k] >= influence || base.data[k].is_nan()) {
            fixed[k] = true;
            values[k] = 0.0;
        }
    }
    let stats = match solve(
        nx,
        ny,
        hx,
        hy,
        &fixed,
        &mut values,
        &MultigridOptions::default(),
    ) {
        Ok(s) => s,
        Err(crate::deform::multigrid::MultigridError::NotConverged { stats }) => stats,
        Err(e) => return Err(DeformError::Solver(e.to_string())),
    };
    for (v, h) in values.iter_mut().zip(&base.data) {
        if h.is_nan() {
            *v = 0.0;
        }
    }
    let touched = {
        let (mut a, mut b, mut c, mut e) = (usize::MAX, usize::MAX, 0usize, 0usize);
        for j in 0..ny {
            for i in 0..nx {
                if values[j * nx + i] != 0.0 {
                    a = a.min(i);
                    b = b.min(j);
                    c = c.max(i);
                    e = e.max(j);
                }
            }
        }
        (a != usize::MAX)
            .then(|| Window::new(win.col + a as i64, win.row + b as i64, c - a + 1, e - b + 1))
    };
    let affected_tiles = touched.map(|t| dem.tiles_touching(&t)).unwrap_or_default();
    Ok(Deformation {
        window: win,
        displacement: values,
        base,
        affected_tiles,
        stats: DeformStats {
            constrained_cells: constrained,
            cycles: stats.cycles,
            relative_residual: stats.relative_residual,
            influence_m: influence,
        },
    })
}
