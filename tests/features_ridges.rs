//! Ridge detection (PPA): a synthetic Gaussian-profile ridge with a known
//! crest, and the main ridge networks of the Zion and Vinschgau fixtures.

use demsketch::features::{detect_ridges, RidgeParams};
use demsketch::raster::{Crs, GeoTransform, HeightMap};

fn synthetic(width: usize, height: usize, f: impl Fn(f64, f64) -> f64) -> HeightMap {
    let mut data = Vec::with_capacity(width * height);
    for r in 0..height {
        for c in 0..width {
            data.push(f(c as f64 + 0.5, r as f64 + 0.5) as f32);
        }
    }
    HeightMap {
        width,
        height,
        data,
        geotransform: GeoTransform::north_up(500_000.0, 4_000_000.0, 30.0, 30.0),
        crs: Crs {
            epsg: Some(32612),
            wkt: String::new(),
            proj: None,
            geographic: false,
        },
    }
}

/// Load a fixture with GDAL (nodata becomes NaN).
fn load(name: &str) -> HeightMap {
    let path = format!("{}/fixtures/{name}", env!("CARGO_MANIFEST_DIR"));
    let ds = gdal::Dataset::open(&path).expect("open fixture");
    let band = ds.rasterband(1).expect("band 1");
    let (w, h) = ds.raster_size();
    let nodata = band.no_data_value();
    let buf = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .expect("read band");
    let data = buf
        .data()
        .iter()
        .map(|&v| match nodata {
            Some(nd) if v == nd || (nd < -1e30 && v < -1e30) => f32::NAN,
            _ => v as f32,
        })
        .collect();
    let srs = ds.spatial_ref().expect("srs");
    HeightMap {
        width: w,
        height: h,
        data,
        geotransform: GeoTransform(ds.geo_transform().expect("geotransform")),
        crs: Crs {
            epsg: srs.auth_code().ok().map(|c| c as u32),
            wkt: srs.to_wkt().unwrap_or_default(),
            proj: None,
            geographic: srs.is_geographic(),
        },
    }
}

#[test]
fn gaussian_ridge_is_found_within_one_cell_of_its_crest() {
    // Crest along the line y = 0.35 x + 30 (pixel space), Gaussian profile
    // across it (sigma 6 cells) on a gentle slope along it.
    let (a, b) = (0.35f64, 30.0f64);
    let norm = (1.0 + a * a).sqrt();
    let dist = |x: f64, y: f64| (y - a * x - b) / norm;
    let map = synthetic(160, 120, |x, y| {
        let d = dist(x, y);
        200.0 + 0.5 * x + 800.0 * (-d * d / (2.0 * 36.0)).exp()
    });
    let net = detect_ridges(&map, &RidgeParams::default()).expect("ridges");
    assert!(!net.lines.is_empty(), "no ridge found");
    let longest = net
        .lines
        .iter()
        .max_by(|p, q| p.length_m.total_cmp(&q.length_m))
        .expect("a line");
    // The crest crosses the whole 160-cell grid: ~171 cells long.
    let crest_len_m = 160.0 * norm * 30.0;
    assert!(
        longest.length_m > 0.85 * crest_len_m,
        "longest line {} m of {} m",
        longest.length_m,
        crest_len_m
    );
    for line in &net.lines {
        for p in net.line_pixels(line) {
            let d = dist(p[0], p[1]).abs();
            assert!(
                d <= 1.0,
                "line {} vertex {:?} is {d} cells off the crest",
                line.id,
                p
            );
        }
    }
    // CRS coordinates and heights agree with the pixel positions.
    let (pixels, points) = (net.line_pixels(longest), net.line_points(longest));
    let p = pixels[pixels.len() / 2];
    let q = points[pixels.len() / 2];
    assert!((q[0] - (500_000.0 + p[0] * 30.0)).abs() < 1e-6);
    assert!((q[1] - (4_000_000.0 - p[1] * 30.0)).abs() < 1e-6);
    assert!(q[2] > 900.0);
}

#[test]
fn flat_and_tilted_planes_have_no_ridges() {
    let flat = synthetic(64, 64, |_, _| 100.0);
    assert!(detect_ridges(&flat, &RidgeParams::default())
        .expect("ok")
        .lines
        .is_empty());
    let tilt = synthetic(64, 64, |x, y| 3.0 * x + 1.5 * y);
    assert!(detect_ridges(&tilt, &RidgeParams::default())
        .expect("ok")
        .lines
        .is_empty());
}

#[test]
fn branching_ridges_form_a_graph_with_a_branch_point() {
    // A Y: two Gaussian ridges meeting at (60, 60) with a third going south.
    let seg = |x: f64, y: f64, (x0, y0): (f64, f64), (x1, y1): (f64, f64)| {
        let (dx, dy) = (x1 - x0, y1 - y0);
        let t = (((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
        let (px, py) = (x0 + t * dx, y0 + t * dy);
        ((x - px).powi(2) + (y - py).powi(2)).sqrt()
    };
    let map = synthetic(120, 120, |x, y| {
        let c = (60.0, 60.0);
        let d = seg(x, y, c, (10.0, 10.0))
            .min(seg(x, y, c, (110.0, 10.0)))
            .min(seg(x, y, c, (60.0, 115.0)));
        1000.0 * (-d * d / 50.0).exp() - 0.5 * ((x - 60.0).powi(2) + (y - 60.0).powi(2)).sqrt()
    });
    let net = detect_ridges(&map, &RidgeParams::default()).expect("ridges");
    let branch = net.nodes.iter().filter(|n| n.degree >= 3).count();
    assert!(branch >= 1, "no branch point among {:?}", net.nodes);
    assert!(net.lines.len() >= 3);
    let total: f64 = net.total_length_m() / 30.0;
    assert!(total > 0.8 * (70.7 + 70.7 + 55.0), "total {total} cells");
}

/// Share of ridge vertices that stand above the mean of their 7 x 7
/// neighbourhood (a ridge lies on locally high ground).
fn share_on_high_ground(map: &HeightMap, net: &demsketch::features::RidgeNetwork) -> f64 {
    let (mut n, mut high) = (0usize, 0usize);
    for line in &net.lines {
        for p in net.line_pixels(line) {
            let (c, r) = (p[0] as usize, p[1] as usize);
            let z = match map.get(c, r) {
                Some(z) => z as f64,
                None => continue,
            };
            let (mut s, mut k) = (0.0, 0usize);
            for rr in r.saturating_sub(3)..(r + 4).min(map.height) {
                for cc in c.saturating_sub(3)..(c + 4).min(map.width) {
                    if let Some(v) = map.get(cc, rr) {
                        s += v as f64;
                        k += 1;
                    }
                }
            }
            n += 1;
            if z >= s / k as f64 {
                high += 1;
            }
        }
    }
    high as f64 / n.max(1) as f64
}

/// The highest cell of the DEM (the main summit) is on or next to the network,
/// and the network reaches across much of the DEM.
fn check_main_network(map: &HeightMap, net: &demsketch::features::RidgeNetwork, min_km: f64) {
    let total_km = net.total_length_m() / 1000.0;
    eprintln!(
        "{} candidates, {} lines, {} nodes, {total_km:.1} km, on high ground {:.3}",
        net.candidate_cells,
        net.lines.len(),
        net.nodes.len(),
        share_on_high_ground(map, net)
    );
    assert!(total_km > min_km, "ridge network only {total_km} km");
    let share = share_on_high_ground(map, net);
    assert!(
        share > 0.95,
        "only {share} of ridge vertices on high ground"
    );
    let (imax, _) = map
        .data
        .iter()
        .enumerate()
        .filter(|(_, v)| !v.is_nan())
        .max_by(|a, b| a.1.total_cmp(b.1))
        .expect("data");
    let (cx, cy) = (
        (imax % map.width) as f64 + 0.5,
        (imax / map.width) as f64 + 0.5,
    );
    let near = net
        .lines
        .iter()
        .flat_map(|l| net.line_pixels(l).iter())
        .map(|p| (p[0] - cx).hypot(p[1] - cy))
        .fold(f64::INFINITY, f64::min);
    assert!(
        near <= 2.0,
        "summit ({cx}, {cy}) is {near} cells from the network"
    );
    // The longest connected lines are long: the main ridges are not chopped up.
    let mut lens: Vec<f64> = net.lines.iter().map(|l| l.length_m).collect();
    lens.sort_by(|a, b| b.total_cmp(a));
    let cell = map.geotransform.pixel_size().0;
    assert!(lens[0] > 15.0 * cell, "longest line {} m", lens[0]);
}

#[test]
fn zion_main_ridge_network() {
    let map = load("zion_srtm_utm12n.tif");
    let net = detect_ridges(&map, &RidgeParams::default()).expect("ridges");
    check_main_network(&map, &net, 200.0);
}

#[test]
fn vinschgau_main_ridge_network() {
    let map = load("vinschgau_250m_utm32n.tif");
    let net = detect_ridges(&map, &RidgeParams::default()).expect("ridges");
    check_main_network(&map, &net, 300.0);
}

/// Draw the ridge network over a hillshade (run with `--ignored` and
/// `DEMSKETCH_RIDGE_PNG=dir` to look at it).
#[test]
#[ignore]
fn draw_fixture_ridges() {
    let dir = std::env::var("DEMSKETCH_RIDGE_PNG").unwrap_or_else(|_| "/tmp".into());
    for name in ["zion_srtm_utm12n.tif", "vinschgau_250m_utm32n.tif"] {
        let map = load(name);
        let net = detect_ridges(&map, &RidgeParams::default()).expect("ridges");
        let (w, h) = (map.width, map.height);
        let s = 3usize;
        let mut img = vec![0u8; w * s * h * s * 3];
        let cell = map.geotransform.pixel_size().0;
        for r in 0..h {
            for c in 0..w {
                let z = |cc: usize, rr: usize| {
                    map.get(cc.min(w - 1), rr.min(h - 1)).unwrap_or(0.0) as f64
                };
                let dx = (z(c + 1, r) - z(c.saturating_sub(1), r)) / (2.0 * cell);
                let dy = (z(c, r + 1) - z(c, r.saturating_sub(1))) / (2.0 * cell);
                let n = (dx * dx + dy * dy + 1.0).sqrt();
                let v = ((-dx + dy + 1.0) / (n * 3f64.sqrt())).clamp(0.0, 1.0);
                for yy in 0..s {
                    for xx in 0..s {
                        let i = ((r * s + yy) * w * s + c * s + xx) * 3;
                        img[i..i + 3].fill((40.0 + 200.0 * v) as u8);
                    }
                }
            }
        }
        for l in &net.lines {
            for seg in net.line_pixels(l).windows(2) {
                for k in 0..=8 {
                    let t = k as f64 / 8.0;
                    let px = seg[0][0] + t * (seg[1][0] - seg[0][0]);
                    let py = seg[0][1] + t * (seg[1][1] - seg[0][1]);
                    let (x, y) = ((px * s as f64) as usize, (py * s as f64) as usize);
                    for (x, y) in [(x, y), (x + 1, y), (x, y + 1)] {
                        if x < w * s && y < h * s {
                            let i = (y * w * s + x) * 3;
                            img[i..i + 3].copy_from_slice(&[255, 40, 20]);
                        }
                    }
                }
            }
            for n in &l.nodes {
                if let Some(n) = net.nodes.get(*n as usize) {
                    let (x, y) = (n.cell[0] as usize * s + 1, n.cell[1] as usize * s + 1);
                    let i = (y * w * s + x) * 3;
                    img[i..i + 3].copy_from_slice(&[30, 120, 255]);
                }
            }
        }
        let f = std::fs::File::create(format!("{dir}/ridges_{name}.png")).expect("png");
        let mut enc = png::Encoder::new(std::io::BufWriter::new(f), (w * s) as u32, (h * s) as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .expect("header")
            .write_image_data(&img)
            .expect("data");
    }
}
