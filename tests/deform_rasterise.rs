//! Rasterisation of 3D curve constraints (`demsketch::deform::constraints`
//! through `deform`): on a planar DEM, steep and diagonal curves give a
//! 4-connected constraint band with no gaps, exactly the cells whose
//! bilinear stencil the curve crosses (centre less than one cell from a
//! curve point along both axes), constraint values equal to the analytic
//! `z - H` at the closest curve point, and an edited surface that passes
//! through the curve (bilinearly) to f32 precision: no staircase. Checked on
//! a projected (square cells) and a geographic (non-square cells) grid.

mod deform_support;

use deform_support::write_f32_geotiff;
use demsketch::deform::{deform, CurveConstraint, DeformOptions};
use demsketch::raster::Dem;

/// A planar DEM `H = 1000 + a * col + b * row` (per cell) on `gt`.
#[derive(Clone, Copy)]
struct Case {
    epsg: u32,
    gt: [f64; 6],
    /// Metres per cell, x and y (what the test uses for distances); set per
    /// curve for geographic grids.
    hx: f64,
    hy: f64,
}

const N: usize = 160;
const A: f64 = 0.9;
const B: f64 = -0.6;

fn plane(px: f64, py: f64) -> f64 {
    // Linear in pixel coordinates; cell centres at +0.5.
    1000.0 + A * (px - 0.5) + B * (py - 0.5)
}

fn make_dem(dir: &std::path::Path, case: &Case) -> std::path::PathBuf {
    let mut data = vec![0f32; N * N];
    for r in 0..N {
        for c in 0..N {
            data[r * N + c] = plane(c as f64 + 0.5, r as f64 + 0.5) as f32;
        }
    }
    let path = dir.join(format!("plane_{}.tif", case.epsg));
    write_f32_geotiff(&path, N, N, case.gt, case.epsg, &data, Some(-9999.0));
    path
}

fn to_crs(gt: &[f64; 6], px: f64, py: f64) -> [f64; 2] {
    [gt[0] + px * gt[1], gt[3] + py * gt[5]]
}

/// A polyline in pixel coordinates with `delta = z - H` given at its
/// vertices (linear in between): returns the curve in CRS coordinates.
fn curve(gt: &[f64; 6], px: &[[f64; 3]]) -> CurveConstraint {
    CurveConstraint {
        points: px
            .iter()
            .map(|p| {
                let [x, y] = to_crs(gt, p[0], p[1]);
                [x, y, plane(p[0], p[1]) + p[2]]
            })
            .collect(),
    }
}

/// Closest point (pixel coordinates) of the polyline to `p`, in metres,
/// with the interpolated delta: (distance_m, qx, qy, delta).
fn closest(case: &Case, px: &[[f64; 3]], p: [f64; 2]) -> (f64, f64, f64, f64) {
    let mut best = (f64::INFINITY, 0.0, 0.0, 0.0);
    for w in px.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (ex, ey) = ((b[0] - a[0]) * case.hx, (b[1] - a[1]) * case.hy);
        let (vx, vy) = ((p[0] - a[0]) * case.hx, (p[1] - a[1]) * case.hy);
        let t = ((vx * ex + vy * ey) / (ex * ex + ey * ey)).clamp(0.0, 1.0);
        let d = (vx - t * ex).hypot(vy - t * ey);
        if d < best.0 {
            best = (
                d,
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            );
        }
    }
    best
}

fn check_case(case: &Case) {
    let tmp = tempfile::tempdir().unwrap();
    let path = make_dem(tmp.path(), case);
    let dem = Dem::open(&path).unwrap();
    // Steep in plan (3 rows per column) and steep in height (delta from
    // 50 m to 350 m); a 45-degree polyline through cell centres and corners
    // with a bend; a shallow one (1 row per 7 columns) going down.
    let polylines: Vec<Vec<[f64; 3]>> = vec![
        vec![[40.3, 20.7, 50.0], [85.1, 140.2, 350.0]],
        vec![
            [100.5, 20.5, 0.0],
            [140.5, 60.5, 120.0],
            [150.0, 130.0, -40.0],
        ],
        vec![[10.2, 150.3, -80.0], [120.7, 134.9, 30.0]],
    ];
    for px in &polylines {
        let c = curve(&case.gt, px);
        let mut case = Case { ..*case };
        if case.epsg == 4326 {
            // Geographic: cells sized at the latitude of the curve's bbox
            // centre, as the library does.
            let ys: Vec<f64> = c.points.iter().map(|p| p[1]).collect();
            let lat = 0.5
                * (ys.iter().cloned().fold(f64::INFINITY, f64::min)
                    + ys.iter().cloned().fold(f64::NEG_INFINITY, f64::max));
            let cs = demsketch::deform::locality::cell_size_m(
                &demsketch::raster::GeoTransform(case.gt),
                true,
                lat,
            );
            (case.hx, case.hy) = (cs.hx, cs.hy);
        }
        let case = &case;
        let stencil = stencil_distance(px, 4000);
        let d = deform(&dem, std::slice::from_ref(&c), &DeformOptions::default()).unwrap();
        let win = d.window;
        let edited = d.edited();
        // 1. The constrained set is exactly the union of the curve's bilinear
        // stencils.
        let mut mismatches = 0;
        let mut worst_delta: f64 = 0.0;
        for row in 0..win.height {
            for col in 0..win.width {
                let k = row * win.width + col;
                let p = [
                    (win.col as usize + col) as f64 + 0.5,
                    (win.row as usize + row) as f64 + 0.5,
                ];
                let (dist, qx, qy, delta) = closest(case, px, p);
                // Sampled L-infinity distance (pixels) to the curve; cells
                // within the sampling error of the boundary are not judged.
                let linf = if dist < 1.5 * case.hx.max(case.hy) {
                    stencil(p)
                } else {
                    f64::INFINITY // Euclidean > 1.5 cells: L-infinity > 1.06.
                };
                let want = linf < 1.0;
                if want != d.constrained[k] && (linf - 1.0).abs() > 2e-3 {
                    mismatches += 1;
                }
                if d.constrained[k] {
                    // 2. Values: the analytic delta at the closest point
                    // (H is planar, so bilinear H at q is the plane).
                    let _ = (qx, qy);
                    let err = (d.displacement[k] as f64 - delta).abs();
                    worst_delta = worst_delta.max(err);
                }
            }
        }
        assert_eq!(
            mismatches, 0,
            "constrained set differs from the stencil band"
        );
        assert!(
            worst_delta < 1e-3,
            "constraint values off the analytic line by {worst_delta} m"
        );
        // 3. The band is 4-connected (no gaps, no diagonal leaks).
        let comps = components4(&d.constrained, win.width, win.height);
        assert_eq!(comps, 1, "constraint band has {comps} 4-connected parts");
        // 4. No staircase: the edited surface, interpolated bilinearly,
        // passes through the curve away from its vertices.
        let mut worst = 0f64;
        for w in px.windows(2) {
            for s in 0..=2000 {
                let t = s as f64 / 2000.0;
                let q = [
                    w[0][0] + t * (w[1][0] - w[0][0]),
                    w[0][1] + t * (w[1][1] - w[0][1]),
                ];
                let near_vertex = px
                    .iter()
                    .any(|v| (q[0] - v[0]).abs().max((q[1] - v[1]).abs()) < 2.0);
                if near_vertex {
                    continue;
                }
                let z = plane(q[0], q[1]) + w[0][2] + t * (w[1][2] - w[0][2]);
                let h = edited
                    .bilinear(q[0] - win.col as f64, q[1] - win.row as f64)
                    .unwrap();
                worst = worst.max((h - z).abs());
            }
        }
        eprintln!(
            "EPSG:{} curve {:?}: {} constrained cells, max |H'(q) - z(q)| = {worst:.2e} m, \
             max constraint error {worst_delta:.2e} m, cycles {}, residual {:.1e}",
            case.epsg,
            px.first().unwrap(),
            d.stats.constrained_cells,
            d.stats.cycles,
            d.stats.relative_residual
        );
        assert!(worst < 2e-3, "edited surface misses the curve by {worst} m");
    }
}

/// The L-infinity distance in pixels from a point to the polyline, by
/// sampling each segment at `samples` points (error at most the sample
/// spacing).
fn stencil_distance(px: &[[f64; 3]], samples: usize) -> impl Fn([f64; 2]) -> f64 + '_ {
    move |p: [f64; 2]| {
        let mut best = f64::INFINITY;
        for w in px.windows(2) {
            // Skip segments clearly far away.
            let (x0, x1) = (w[0][0].min(w[1][0]), w[0][0].max(w[1][0]));
            let (y0, y1) = (w[0][1].min(w[1][1]), w[0][1].max(w[1][1]));
            if p[0] < x0 - 3.0 || p[0] > x1 + 3.0 || p[1] < y0 - 3.0 || p[1] > y1 + 3.0 {
                continue;
            }
            for s in 0..=samples {
                let t = s as f64 / samples as f64;
                let q = [
                    w[0][0] + t * (w[1][0] - w[0][0]),
                    w[0][1] + t * (w[1][1] - w[0][1]),
                ];
                best = best.min((p[0] - q[0]).abs().max((p[1] - q[1]).abs()));
            }
        }
        best
    }
}

fn components4(mask: &[bool], w: usize, h: usize) -> usize {
    let mut seen = vec![false; mask.len()];
    let mut comps = 0;
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        comps += 1;
        let mut stack = vec![start];
        seen[start] = true;
        while let Some(k) = stack.pop() {
            let (c, r) = (k % w, k / w);
            let mut push = |nk: usize| {
                if mask[nk] && !seen[nk] {
                    seen[nk] = true;
                    stack.push(nk);
                }
            };
            if c > 0 {
                push(k - 1);
            }
            if c + 1 < w {
                push(k + 1);
            }
            if r > 0 {
                push(k - w);
            }
            if r + 1 < h {
                push(k + w);
            }
        }
    }
    comps
}

#[test]
fn projected_square_cells() {
    check_case(&Case {
        epsg: 32612,
        gt: [320_000.0, 10.0, 0.0, 4_120_000.0, 0.0, -10.0],
        hx: 10.0,
        hy: 10.0,
    });
}

#[test]
fn geographic_non_square_cells() {
    // 3 arc-second cells at 37.2 N: about 74 m wide and 92.5 m tall.
    let lat: f64 = 37.2;
    let cell = 1.0 / 1200.0;
    let top = lat + 0.5 * N as f64 * cell;
    let gt = [-113.0, cell, 0.0, top, 0.0, -cell];
    // The same cell size the library uses (WGS84 radii at the curves'
    // latitude); the curves' bbox centre is near `lat`.
    let c =
        demsketch::deform::locality::cell_size_m(&demsketch::raster::GeoTransform(gt), true, lat);
    assert!((c.hx - 74.0).abs() < 1.0 && (c.hy - 92.5).abs() < 1.0);
    check_case(&Case {
        epsg: 4326,
        gt,
        hx: c.hx,
        hy: c.hy,
    });
}
