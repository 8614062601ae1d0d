//! Breaklines: 3D lines across which the terrain's slope changes (a ridge,
//! a terrace edge, a road shoulder, the toe of an embankment), the
//! breaklines of the USGS lidar base specification.
//!
//! A **hard** breakline lets the surface kink across the line but never
//! blend across it. It is applied as the classic TIN-with-breaklines
//! method of lidar processing and GIS (ArcGIS "TIN to raster" with
//! hardlines, LAStools' `las2dem` with breaklines): the cells within the
//! influence distance of the line (the *band*) are re-interpolated,
//! linearly, from a constrained Delaunay triangulation
//! ([`spade::ConstrainedDelaunayTriangulation`]) whose vertices are the
//! line's vertices (densified to one per cell, heights linear along each
//! segment) and the valid cells of a two-cell ring just beyond the band
//! (current heights), and whose constraint edges are the line's segments.
//! No triangle crosses a constraint edge, so every band cell is
//! interpolated from the line and the cells on its own side only: where
//! the terrain on each side is a plane through the line (a roof), the
//! result is exactly those two planes, right up to the line. The
//! alternatives were weighed: a Laplacian (multigrid) solve with the line
//! held blends across it by construction (it is harmonic through the
//! line); cutting the grid graph along the line and solving each side
//! apart is harmonic, not planar, so it bends the slopes next to the line;
//! natural-neighbour interpolation is not defined across constraint edges.
//! The band stops square at the line's ends: cells beyond an end (whose
//! nearest point of the line is the end itself) are not re-interpolated
//! but support the triangulation, so the kink fades out towards the ends
//! and nothing changes past them. Cells beyond the band keep their heights
//! exactly (bit-identical); band cells outside the triangulation's hull
//! (at the DEM's edge) are left as they are.
//!
//! A **soft** breakline is a positional constraint with smoothing across:
//! the surface passes through the line and stays smooth across it, which
//! is a control curve with a narrow influence ([`super::control_curve`]).

use spade::handles::FixedVertexHandle;
use spade::Triangulation;
use spade::{ConstrainedDelaunayTriangulation, HasPosition, Point2, PositionInTriangulation};

use super::grid::Grid;

/// Width, in cells, of the ring of cells beyond the band that supports the
/// triangulation.
const RING_CELLS: f64 = 2.0;

/// Default influence distance of a breakline: three cells of the larger
/// cell side.
pub fn default_influence_m(cell: crate::deform::CellSize) -> f64 {
    3.0 * cell.hx.max(cell.hy)
}

/// The distance beyond the influence that the triangulation reads.
pub fn support_m(cell: crate::deform::CellSize) -> f64 {
    RING_CELLS * cell.hx.max(cell.hy)
}

/// What a hard breakline did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BreaklineResult {
    /// Valid cells within the influence distance.
    pub band_cells: usize,
    /// Band cells outside the triangulation (left as they are).
    pub outside_hull: usize,
    /// Cells whose height changed.
    pub cells_changed: usize,
    /// Largest `|new - old|`, metres.
    pub max_abs_dz_m: f64,
}

/// Why a hard breakline could not be applied.
#[derive(Debug, thiserror::Error)]
pub enum BreaklineError {
    #[error("no valid DEM cell lies within the influence distance of the breakline")]
    NothingInBand,
    #[error("no valid DEM cell beyond the influence distance to interpolate from")]
    NoSupport,
    #[error("triangulation: {0}")]
    Triangulation(String),
}

/// A vertex of the triangulation: metres in the window, and a height.
#[derive(Debug, Clone, Copy)]
struct Vertex {
    pos: Point2<f64>,
    z: f64,
}

impl HasPosition for Vertex {
    type Scalar = f64;
    fn position(&self) -> Point2<f64> {
        self.pos
    }
}

type Cdt = ConstrainedDelaunayTriangulation<Vertex>;

/// The line in window metres (`[x, y, z]`), densified so that no segment
/// is longer than one cell; consecutive duplicates dropped.
fn line_metres(grid: &Grid, points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let gt = grid.geotransform();
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let px: Vec<[f64; 3]> = points
        .iter()
        .filter_map(|p| {
            gt.crs_to_pixel(p[0], p[1])
                .map(|(x, y)| [x * hx, y * hy, p[2]])
        })
        .collect();
    let step = hx.min(hy);
    let mut out: Vec<[f64; 3]> = Vec::new();
    for (k, seg) in px.windows(2).enumerate() {
        let (a, b) = (seg[0], seg[1]);
        let n = ((b[0] - a[0]).hypot(b[1] - a[1]) / step).ceil().max(1.0) as usize;
        let last = if k + 2 == px.len() { n } else { n - 1 };
        for j in 0..=last {
            let t = j as f64 / n as f64;
            let q = [
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            ];
            if out.last().is_none_or(|l| l[0] != q[0] || l[1] != q[1]) {
                out.push(q);
            }
        }
    }
    out
}

/// Squared distance from `p` to the segment `a`-`b` (2D), and where along
/// it the perpendicular foot lies (`t`, unclamped: below 0 before `a`,
/// above 1 after `b`).
fn segment_d2(p: [f64; 2], a: [f64; 3], b: [f64; 3]) -> (f64, f64) {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let raw = if len2 > 0.0 {
        ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2
    } else {
        0.0
    };
    let t = raw.clamp(0.0, 1.0);
    let (ex, ey) = (a[0] + t * dx - p[0], a[1] + t * dy - p[1]);
    (ex * ex + ey * ey, raw)
}

/// Squared distance in m^2 from every cell centre of the window to the
/// line, for the cells within `reach_m` of it (infinity elsewhere), and
/// whether the nearest point of the line is one of its ends with the cell
/// beyond it (in the end caps): each segment visits only the cells of its
/// own bounding box grown by `reach_m`.
fn distance_to_line(grid: &Grid, line: &[[f64; 3]], reach_m: f64) -> (Vec<f64>, Vec<bool>) {
    let (w, h) = (grid.width(), grid.height());
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let mut d2 = vec![f64::INFINITY; w * h];
    let mut cap = vec![false; w * h];
    let range = |lo: f64, hi: f64, cell: f64, n: usize| {
        let a = ((lo - reach_m) / cell - 0.5).floor().max(0.0) as usize;
        let b = (((hi + reach_m) / cell - 0.5).ceil().max(0.0) as usize + 1).min(n);
        a..b
    };
    let segs: Vec<([f64; 3], [f64; 3])> = if line.len() == 1 {
        vec![(line[0], line[0])]
    } else {
        line.windows(2).map(|s| (s[0], s[1])).collect()
    };
    let last = segs.len() - 1;
    for (k, (a, b)) in segs.into_iter().enumerate() {
        for r in range(a[1].min(b[1]), a[1].max(b[1]), hy, h) {
            for c in range(a[0].min(b[0]), a[0].max(b[0]), hx, w) {
                let p = [(c as f64 + 0.5) * hx, (r as f64 + 0.5) * hy];
                let i = r * w + c;
                let (d, t) = segment_d2(p, a, b);
                if d < d2[i] {
                    d2[i] = d;
                    cap[i] = (k == 0 && t < 0.0) || (k == last && t > 1.0);
                }
            }
        }
    }
    (d2, cap)
}

/// The triangulation of the ring cells (`support`, window indices) and the
/// line, the line's segments as constraint edges.
fn triangulate(grid: &Grid, support: &[usize], line: &[[f64; 3]]) -> Result<Cdt, BreaklineError> {
    let w = grid.width();
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let verts: Vec<Vertex> = support
        .iter()
        .map(|&i| Vertex {
            pos: Point2::new(((i % w) as f64 + 0.5) * hx, ((i / w) as f64 + 0.5) * hy),
            z: grid.values[i],
        })
        .collect();
    let mut cdt =
        Cdt::bulk_load(verts).map_err(|e| BreaklineError::Triangulation(e.to_string()))?;
    let handles: Vec<FixedVertexHandle> = line
        .iter()
        .map(|q| {
            cdt.insert(Vertex {
                pos: Point2::new(q[0], q[1]),
                z: q[2],
            })
            .map_err(|e| BreaklineError::Triangulation(e.to_string()))
        })
        .collect::<Result<_, _>>()?;
    for pair in handles.windows(2) {
        if !cdt.can_add_constraint(pair[0], pair[1]) {
            return Err(BreaklineError::Triangulation(
                "a segment of the breakline crosses another one".into(),
            ));
        }
        cdt.add_constraint(pair[0], pair[1]);
    }
    Ok(cdt)
}

/// The triangulation's linear height at `p`, `None` outside its hull.
fn interpolate(cdt: &Cdt, p: Point2<f64>) -> Option<f64> {
    match cdt.locate(p) {
        PositionInTriangulation::OnVertex(v) => Some(cdt.vertex(v).data().z),
        PositionInTriangulation::OnEdge(e) => {
            let e = cdt.directed_edge(e);
            let (a, b) = (*e.from().data(), *e.to().data());
            let (dx, dy) = (b.pos.x - a.pos.x, b.pos.y - a.pos.y);
            let len2 = dx * dx + dy * dy;
            let t = ((p.x - a.pos.x) * dx + (p.y - a.pos.y) * dy) / len2;
            Some(a.z + t.clamp(0.0, 1.0) * (b.z - a.z))
        }
        PositionInTriangulation::OnFace(f) => {
            let f = cdt.face(f);
            let weights = f.barycentric_interpolation(p);
            let vs = f.vertices();
            Some((0..3).map(|k| weights[k] * vs[k].data().z).sum())
        }
        PositionInTriangulation::OutsideOfConvexHull(_)
        | PositionInTriangulation::NoTriangulation => None,
    }
}

/// Re-interpolates the cells within `influence_m` of the hard breakline
/// `points` (`[x, y, z]` in the DEM's CRS) from the constrained Delaunay
/// triangulation (see the module documentation).
pub fn apply_hard(
    grid: &mut Grid,
    points: &[[f64; 3]],
    influence_m: f64,
) -> Result<BreaklineResult, BreaklineError> {
    let line = line_metres(grid, points);
    let outer = influence_m + support_m(grid.cell);
    let (d2, cap) = distance_to_line(grid, &line, outer);
    let tol = 1.0 + 1e-9;
    let (mut band, mut support) = (Vec::new(), Vec::new());
    for (i, &d) in d2.iter().enumerate() {
        if grid.values[i].is_nan() || d.is_infinite() {
            continue;
        }
        let d = d.sqrt();
        if d <= influence_m * tol && !cap[i] {
            band.push(i);
        } else if d <= outer * tol {
            support.push(i);
        }
    }
    if band.is_empty() {
        return Err(BreaklineError::NothingInBand);
    }
    if support.is_empty() {
        return Err(BreaklineError::NoSupport);
    }
    let cdt = triangulate(grid, &support, &line)?;
    let w = grid.width();
    let (hx, hy) = (grid.cell.hx, grid.cell.hy);
    let mut res = BreaklineResult {
        band_cells: band.len(),
        outside_hull: 0,
        cells_changed: 0,
        max_abs_dz_m: 0.0,
    };
    let new: Vec<Option<f64>> = band
        .iter()
        .map(|&i| {
            let p = Point2::new(((i % w) as f64 + 0.5) * hx, ((i / w) as f64 + 0.5) * hy);
            interpolate(&cdt, p)
        })
        .collect();
    for (&i, z) in band.iter().zip(new) {
        let Some(z) = z.filter(|z| z.is_finite()) else {
            res.outside_hull += 1;
            continue;
        };
        let old = grid.values[i];
        if z != old {
            res.cells_changed += 1;
            res.max_abs_dz_m = res.max_abs_dz_m.max((z - old).abs());
            grid.values[i] = z;
        }
    }
    Ok(res)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deform::CellSize;
    use crate::raster::{Crs, GeoTransform, HeightMap, Window};

    /// A roof over a 40 x 40 grid of 10 m cells: ridge along x = 200 m at
    /// 100 m, slopes 0.3 (west) and 0.6 (east); the ridge cells blurred.
    fn roof() -> (Grid, impl Fn(f64) -> f64) {
        let (w, h) = (40, 40);
        let z = |x: f64| {
            if x < 200.0 {
                100.0 - 0.3 * (200.0 - x)
            } else {
                100.0 - 0.6 * (x - 200.0)
            }
        };
        let mut data = vec![0f32; w * h];
        for r in 0..h {
            for c in 0..w {
                let x = (c as f64 + 0.5) * 10.0;
                let blur = (x - 200.0).abs() < 25.0;
                data[r * w + c] = if blur { 95.0 } else { z(x) as f32 };
            }
        }
        let gt = GeoTransform([0.0, 10.0, 0.0, 400.0, 0.0, -10.0]);
        let base = HeightMap {
            width: w,
            height: h,
            geotransform: gt,
            data,
            crs: Crs {
                epsg: None,
                wkt: String::new(),
                proj: None,
                geographic: false,
            },
        };
        let cell = CellSize { hx: 10.0, hy: 10.0 };
        (Grid::new(Window::new(0, 0, w, h), cell, base), z)
    }

    #[test]
    fn a_hard_breakline_restores_the_roof_up_to_the_ridge() {
        let (mut grid, z) = roof();
        // The ridge from y = 399 to y = 1 (CRS), at 100 m.
        let line = [[200.0, 399.0, 100.0], [200.0, 1.0, 100.0]];
        let res = apply_hard(&mut grid, &line, 30.0).unwrap();
        assert!(res.cells_changed > 0);
        for r in 5..35 {
            for c in 0..40 {
                let x = (c as f64 + 0.5) * 10.0;
                let v = grid.values[r * 40 + c];
                assert!((v - z(x)).abs() < 1e-6, "({c}, {r}): {v} vs {}", z(x));
            }
        }
    }

    #[test]
    fn cells_beyond_the_influence_keep_their_heights() {
        let (mut grid, _) = roof();
        let before = grid.values.clone();
        let line = [[200.0, 399.0, 100.0], [200.0, 1.0, 100.0]];
        apply_hard(&mut grid, &line, 30.0).unwrap();
        for r in 0..40 {
            for c in 0..40 {
                let x = (c as f64 + 0.5) * 10.0;
                if (x - 200.0).abs() > 30.0 {
                    let i = r * 40 + c;
                    assert_eq!(before[i].to_bits(), grid.values[i].to_bits());
                }
            }
        }
    }
}
