//! Breaklines. A synthetic roof (two planes meeting at an oblique, sloping
//! ridge, 10 m cells, Float32 GeoTIFF in UTM 32N) whose ridge cells were
//! blurred, as a coarse or smoothed DEM rounds a ridge: a hard breakline
//! along the ridge restores the kink, every cell within the influence
//! distance equals the analytic roof within 2 mm and every slope between
//! neighbouring cells on one side is the analytic one, right up to the
//! line. On the real fixture (`fixtures/vinschgau_250m_utm32n.tif`) a hard
//! and a soft breakline change nothing beyond their influence distance
//! (bit-identical), and the soft one passes through its heights. Every
//! output is read back with GDAL.

mod common;
mod correct_support;

use std::path::Path;

use common::fixture;
use correct_support::{collection, correct_ok, correct_succeeds, write_f32_geotiff, Raster};
use serde_json::{json, Value};

const CELL: f64 = 10.0;
const N: usize = 80;
/// Ridge direction in pixel space (70 degrees from +x towards +y).
const THETA: f64 = 70.0 * std::f64::consts::PI / 180.0;
const HALF_LENGTH_PX: f64 = 40.0;
/// Slopes across the ridge (negative side, positive side), along it.
const SLOPE_NEG: f64 = 0.35;
const SLOPE_POS: f64 = 0.6;
const SLOPE_ALONG: f64 = 0.08;
const BLUR_M: f64 = 25.0;
const INFLUENCE_M: f64 = 30.0;

/// Along-ridge and signed across-ridge coordinates (metres) of pixel `p`.
fn frame(p: [f64; 2]) -> (f64, f64) {
    let (u, c) = ([THETA.cos(), THETA.sin()], N as f64 / 2.0);
    let (dx, dy) = (p[0] - c, p[1] - c);
    (
        (dx * u[0] + dy * u[1]) * CELL,
        (u[0] * dy - u[1] * dx) * CELL,
    )
}

fn roof(p: [f64; 2]) -> f64 {
    let (t, d) = frame(p);
    let s = if d < 0.0 { SLOPE_NEG } else { SLOPE_POS };
    1500.0 + SLOPE_ALONG * t - s * d.abs()
}

fn centre(c: usize, r: usize) -> [f64; 2] {
    [c as f64 + 0.5, r as f64 + 0.5]
}

/// The roof with the cells within `BLUR_M` of the ridge replaced by the
/// mean of the roof over their 5 x 5 neighbourhood.
fn blurred_roof() -> Vec<f32> {
    let mut v = vec![0f32; N * N];
    for r in 0..N {
        for c in 0..N {
            let p = centre(c, r);
            let z = if frame(p).1.abs() < BLUR_M {
                let mut s = 0.0;
                for dr in -2..=2 {
                    for dc in -2..=2 {
                        s += roof([p[0] + dc as f64, p[1] + dr as f64]);
                    }
                }
                s / 25.0
            } else {
                roof(p)
            };
            v[r * N + c] = z as f32;
        }
    }
    v
}

fn run(dem: &Path, tmp: &Path, name: &str, fc: String) -> (std::path::PathBuf, Value) {
    let features = tmp.join(format!("{name}.geojson"));
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (
        tmp.join(format!("{name}.tif")),
        tmp.join(format!("{name}.json")),
    );
    let r = correct_ok(dem, &features, &out, &rep);
    (out, r)
}

/// Largest error against the roof and largest error of the height
/// difference between 4-neighbours on the same side of the ridge, over
/// the cells within `reach_m` of the ridge and `along_m` of its middle.
/// The ridge as a 3D line in the DEM's CRS with Z on the roof, through
/// the points at `ks` half-lengths from the centre along it.
fn ridge_line(input: &Raster, ks: &[f64]) -> Vec<Vec<f64>> {
    let c = N as f64 / 2.0;
    ks.iter()
        .map(|k| {
            let p = [
                c + k * HALF_LENGTH_PX * THETA.cos(),
                c + k * HALF_LENGTH_PX * THETA.sin(),
            ];
            let q = input.crs(p);
            vec![q[0], q[1], roof(p)]
        })
        .collect()
}

fn roof_errors(r: &Raster, reach_m: f64, along_m: f64) -> (f64, f64) {
    let keep = |c: usize, rr: usize| {
        let (t, d) = frame(centre(c, rr));
        t.abs() <= along_m && d.abs() <= reach_m
    };
    let (mut height, mut slope) = (0f64, 0f64);
    for rr in 0..N {
        for c in 0..N {
            if !keep(c, rr) {
                continue;
            }
            height = height.max((r.at(c, rr) - roof(centre(c, rr))).abs());
            for (cc, r2) in [(c + 1, rr), (c, rr + 1)] {
                if cc >= N || r2 >= N || !keep(cc, r2) {
                    continue;
                }
                let (da, db) = (frame(centre(c, rr)).1, frame(centre(cc, r2)).1);
                if (da < 0.0) != (db < 0.0) {
                    continue;
                }
                let want = roof(centre(cc, r2)) - roof(centre(c, rr));
                let got = r.at(cc, r2) - r.at(c, rr);
                slope = slope.max((got - want).abs());
            }
        }
    }
    (height, slope)
}

/// Least-squares slope across the ridge of the cells on one side
/// (`sign`), within `reach_m` of the ridge and `along_m` of its middle.
fn cross_slope(r: &Raster, sign: f64, reach_m: f64, along_m: f64) -> f64 {
    // Fit z = a + b t + s d by normal equations.
    let mut m = [[0f64; 3]; 3];
    let mut v = [0f64; 3];
    for rr in 0..N {
        for c in 0..N {
            let (t, d) = frame(centre(c, rr));
            if t.abs() > along_m || d.abs() > reach_m || d * sign <= 0.0 {
                continue;
            }
            let x = [1.0, t, d];
            for i in 0..3 {
                for j in 0..3 {
                    m[i][j] += x[i] * x[j];
                }
                v[i] += x[i] * r.at(c, rr);
            }
        }
    }
    // Cramer's rule for the third unknown.
    let det = |a: [[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let mut m3 = m;
    for i in 0..3 {
        m3[i][2] = v[i];
    }
    -sign * det(m3) / det(m)
}

#[test]
fn a_hard_breakline_restores_the_kink_of_a_blurred_roof() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("roof.tif");
    let gt = [600000.0, CELL, 0.0, 5200000.0, 0.0, -CELL];
    write_f32_geotiff(&dem, N, N, gt, 32632, &blurred_roof());
    let input = Raster::read(&dem);
    // The ridge as a 3D line in UTM with Z: both ends and the middle.
    let line = ridge_line(&input, &[-1.0, 0.0, 1.0]);
    let fc = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "breakline", "name": "ridge",
            "influence_m": INFLUENCE_M},
            "geometry": {"type": "LineString", "coordinates": line}}),
        ],
        Some(32632),
    );
    let (out, r) = run(&dem, tmp.path(), "hard", fc);
    let f = &r["corrections"][0];
    assert_eq!(f["kind"], "breakline");
    assert_eq!(f["hard"], true);
    assert_eq!(f["influence_m"], INFLUENCE_M);
    let output = Raster::read(&out);
    assert_eq!((output.w, output.h), (N, N));

    // Away from the line's ends (where the kink fades out).
    let along = HALF_LENGTH_PX * CELL - 2.0 * INFLUENCE_M - 20.0;
    let (h_in, s_in) = roof_errors(&input, 2.0 * INFLUENCE_M, along);
    let (h_out, s_out) = roof_errors(&output, 2.0 * INFLUENCE_M, along);
    let slopes_in = [
        cross_slope(&input, -1.0, INFLUENCE_M, along),
        cross_slope(&input, 1.0, INFLUENCE_M, along),
    ];
    let slopes_out = [
        cross_slope(&output, -1.0, INFLUENCE_M, along),
        cross_slope(&output, 1.0, INFLUENCE_M, along),
    ];
    println!(
        "blurred: max |z - roof| {h_in:.3} m, max neighbour-difference error {s_in:.3} m, \
         cross slopes {:.4} / {:.4}",
        slopes_in[0], slopes_in[1]
    );
    println!(
        "hard breakline: max |z - roof| {h_out:.5} m, max neighbour-difference error {s_out:.5} m, \
         cross slopes {:.5} / {:.5} (analytic {SLOPE_NEG} / {SLOPE_POS})",
        slopes_out[0], slopes_out[1]
    );
    assert!(h_in > 1.0 && s_in > 0.5, "the input is blurred");
    assert!(h_out <= 2e-3, "max |z - roof| {h_out} m");
    // Heights are Float32 near 1500 m (a step of 1.2e-4 m).
    assert!(s_out <= 2e-3, "neighbour differences off by {s_out} m");
    assert!((slopes_out[0] - SLOPE_NEG).abs() <= 1e-4, "{slopes_out:?}");
    assert!((slopes_out[1] - SLOPE_POS).abs() <= 1e-4, "{slopes_out:?}");

    // A soft breakline along the same ridge passes through it but stays
    // smooth across: the kink is not restored (for the comparison in
    // docs/corrections.md).
    let soft = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "breakline", "name": "ridge",
            "hard": false, "influence_m": INFLUENCE_M},
            "geometry": {"type": "LineString", "coordinates": line}}),
        ],
        Some(32632),
    );
    let (out_soft, rs) = run(&dem, tmp.path(), "soft", soft);
    let soft_out = Raster::read(&out_soft);
    let (h_soft, s_soft) = roof_errors(&soft_out, 2.0 * INFLUENCE_M, along);
    println!(
        "soft breakline: max |z - roof| {h_soft:.3} m, max neighbour-difference error {s_soft:.3} m, \
         cross slopes {:.4} / {:.4}, max |DEM - z| on the line {:.4} m",
        cross_slope(&soft_out, -1.0, INFLUENCE_M, along),
        cross_slope(&soft_out, 1.0, INFLUENCE_M, along),
        rs["corrections"][0]["max_curve_error_m"].as_f64().unwrap()
    );
    assert!(h_soft > 10.0 * h_out && s_soft > 10.0 * s_out);

    // Beyond the influence distance, bit-identical.
    let mut beyond = 0;
    for rr in 0..N {
        for cc in 0..N {
            let p = centre(cc, rr);
            let d = segment_distance_m(p, &line_px(&input, &line));
            if d > INFLUENCE_M + 1e-6 {
                beyond += 1;
                assert_eq!(
                    input.at(cc, rr).to_bits(),
                    output.at(cc, rr).to_bits(),
                    "({cc}, {rr}) at {d} m changed"
                );
            }
        }
    }
    assert!(beyond > N * N / 2);
}

fn line_px(r: &Raster, line: &[Vec<f64>]) -> Vec<[f64; 2]> {
    line.iter().map(|q| r.pixel(q[0], q[1])).collect()
}

/// Distance in metres (square cells of `CELL`, or `cell`) from pixel `p`
/// to the polyline `px`.
fn distance_px(p: [f64; 2], px: &[[f64; 2]]) -> f64 {
    px.windows(2)
        .map(|s| {
            let (a, b) = (s[0], s[1]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let t =
                (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
            (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
        })
        .fold(f64::INFINITY, f64::min)
}

/// True when the nearest point of the polyline `px` to `p` is one of its
/// ends with `p` beyond it (the band of a hard breakline stops there).
fn in_end_cap(p: [f64; 2], px: &[[f64; 2]]) -> bool {
    let last = px.len() - 2;
    let (mut best, mut cap) = (f64::INFINITY, false);
    for (k, s) in px.windows(2).enumerate() {
        let (a, b) = (s[0], s[1]);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let raw = ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / (dx * dx + dy * dy);
        let t = raw.clamp(0.0, 1.0);
        let d = (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy);
        if d < best {
            best = d;
            cap = (k == 0 && raw < 0.0) || (k == last && raw > 1.0);
        }
    }
    cap
}

fn segment_distance_m(p: [f64; 2], px: &[[f64; 2]]) -> f64 {
    distance_px(p, px) * CELL
}

const FIXTURE: &str = "vinschgau_250m_utm32n.tif";
const LINE_PX: [[f64; 2]; 3] = [[150.3, 62.7], [158.1, 66.2], [166.6, 64.4]];

/// Breaklines on the real fixture: heights the terrain's plus `dz` at the
/// vertices; cells beyond the influence distance bit-identical.
fn fixture_case(hard: bool, influence_m: f64, dz: f64) -> (Raster, Raster, Value) {
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture(FIXTURE);
    let input = Raster::read(&dem);
    let cell = input.gt[1];
    let coords: Vec<Vec<f64>> = LINE_PX
        .iter()
        .map(|&p| {
            let q = input.crs(p);
            vec![q[0], q[1], input.bilinear(p).unwrap() + dz]
        })
        .collect();
    let fc = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "breakline", "name": "terrace",
            "hard": hard, "influence_m": influence_m},
            "geometry": {"type": "LineString", "coordinates": coords}}),
        ],
        Some(32632),
    );
    let (out, r) = run(&dem, tmp.path(), "fixture", fc);
    let output = Raster::read(&out);
    let (mut changed, mut beyond) = (0, 0);
    for rr in 0..input.h {
        for cc in 0..input.w {
            let (a, b) = (input.at(cc, rr), output.at(cc, rr));
            let d = distance_px(centre(cc, rr), &LINE_PX) * cell;
            let same = a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
            changed += usize::from(!same);
            // Soft breaklines move the cells of the bilinear stencil too
            // (the control curve's constraint reach, one cell diagonal).
            let reach = if hard { 0.0 } else { cell * 2f64.sqrt() };
            if d > influence_m + reach + 1e-6 {
                beyond += 1;
                assert!(same, "({cc}, {rr}) at {d:.0} m changed: {a} -> {b}");
            }
        }
    }
    assert!(changed > 0);
    assert!(beyond > input.w * input.h / 2);
    assert_eq!(r["changed_cells"], changed);
    (input, output, r)
}

#[test]
fn a_hard_breakline_on_the_fixture_changes_nothing_beyond_its_influence() {
    let (_, output, r) = fixture_case(true, 750.0, 20.0);
    let f = &r["corrections"][0];
    assert_eq!(f["hard"], true);
    assert!(f["band_cells"].as_u64().unwrap() >= f["cells_changed"].as_u64().unwrap());
    // The line is 20 m above the terrain at its vertices: the cells next
    // to it (within half a cell) are lifted on average; every valid cell
    // within the influence distance is in the band.
    let input = Raster::read(&fixture(FIXTURE));
    let cell = input.gt[1];
    let (mut lift, mut near, mut band) = (0.0, 0, 0);
    for rr in 0..input.h {
        for cc in 0..input.w {
            let d = distance_px(centre(cc, rr), &LINE_PX) * cell;
            if input.at(cc, rr).is_nan() {
                continue;
            }
            band += usize::from(d <= 750.0 + 1e-6 && !in_end_cap(centre(cc, rr), &LINE_PX));
            if d <= 0.5 * cell {
                lift += output.at(cc, rr) - input.at(cc, rr);
                near += 1;
            }
        }
    }
    let lift = lift / near as f64;
    println!("{near} cells within half a cell of the line, lifted by {lift:.2} m on average");
    assert!(near >= 8 && lift > 5.0, "{near} cells, mean lift {lift} m");
    assert_eq!(f["band_cells"], band);
}

#[test]
fn a_soft_breakline_on_the_fixture_passes_through_its_heights() {
    let (_, _, r) = fixture_case(false, 1000.0, 20.0);
    let f = &r["corrections"][0];
    assert_eq!(f["hard"], false);
    let err = f["max_curve_error_m"].as_f64().unwrap();
    assert!(err <= 0.05, "soft breakline missed by {err} m");
}

#[test]
fn renders_show_the_map_before_and_after_and_the_height_change() {
    let tmp = tempfile::tempdir().unwrap();
    let dem = tmp.path().join("roof.tif");
    let gt = [600000.0, CELL, 0.0, 5200000.0, 0.0, -CELL];
    write_f32_geotiff(&dem, N, N, gt, 32632, &blurred_roof());
    let input = Raster::read(&dem);
    let line = ridge_line(&input, &[-1.0, 1.0]);
    let features = tmp.path().join("ridge.geojson");
    std::fs::write(
        &features,
        collection(
            vec![
                json!({"type": "Feature", "properties": {"kind": "breakline", "name": "ridge",
                "influence_m": INFLUENCE_M},
                "geometry": {"type": "LineString", "coordinates": line}}),
            ],
            Some(32632),
        ),
    )
    .unwrap();
    let renders = tmp.path().join("renders");
    let out = tmp.path().join("out.tif");
    correct_succeeds(
        &dem,
        &features,
        &out,
        &["--renders", &renders.to_string_lossy()],
    );
    for name in ["map_before.png", "map_after.png", "height_change.png"] {
        let p = renders.join(name);
        // GDAL reads each picture: three Byte bands.
        let ds = gdal::Dataset::open(&p).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(ds.raster_count(), 3, "{name}");
        let (w, h) = ds.raster_size();
        assert!(w >= 200 && h >= 200, "{name}: {w} x {h}");
    }
    // The breakline is drawn (magenta) on both maps.
    for name in ["map_before.png", "map_after.png"] {
        let ds = gdal::Dataset::open(renders.join(name)).unwrap();
        let (w, h) = ds.raster_size();
        let band = |b: usize| {
            ds.rasterband(b)
                .unwrap()
                .read_as::<u8>((0, 0), (w, h), (w, h), None)
                .unwrap()
                .data()
                .to_vec()
        };
        let (r, g, b) = (band(1), band(2), band(3));
        let magenta = (0..w * h)
            .filter(|&i| r[i] == 220 && g[i] == 30 && b[i] == 190)
            .count();
        assert!(magenta > 100, "{name}: {magenta} breakline pixels");
    }
}
