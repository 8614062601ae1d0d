//! Rendering: the depth buffer is exact for the triangulated height field
//! (checked against brute force over every triangle and against an analytic
//! plane), `locate` and projection are inverse on a real DEM, and the shaded
//! image and depth file are written.

mod view_support;

use demsketch::render::{pick, shade, write_png, DepthBuffer, LocalTerrain, ShadeOptions, SKY};
use demsketch::view::{Camera, CameraModel, Curvature, Georef, LocalFrame, Viewpoint};
use view_support::*;

/// Deterministic pseudo-random numbers in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[test]
fn ray_casting_is_exact_on_the_bilinear_height_field() {
    let mut rng = Lcg(7);
    let noise: Vec<f64> = (0..48 * 48).map(|_| rng.next() * 40.0).collect();
    let mut dem = synthetic(48, 48, 25.0, |x, y| {
        100.0 + 30.0 * ((x / 200.0).sin() + (y / 150.0).cos())
    });
    for (v, n) in dem.data.iter_mut().zip(&noise) {
        *v += *n as f32;
    }
    dem.data[20 * 48 + 30] = f32::NAN; // a hole
    let (ex, ey) = dem.geotransform.pixel_to_crs(10.3, 12.7);
    let ground = dem.bilinear(10.3, 12.7).unwrap();
    let frame = LocalFrame::planar(&dem, (ex, ey), ground + 2.0, Curvature::default());
    let terrain = LocalTerrain::new(&dem, &frame, None);
    // A second copy only ever cast with `cast_within` (no horizon index).
    let bounded = LocalTerrain::new(&dem, &frame, None);
    let mut checked = 0;
    let mut worst: f64 = 0.0;
    for _ in 0..400 {
        let az = rng.next() * std::f64::consts::TAU;
        let el = (rng.next() - 0.7) * 0.6;
        let d = [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()];
        let fast = terrain.cast(d, f64::INFINITY);
        let b = bounded.cast_within(d, f64::INFINITY);
        assert_eq!(b.map(|h| h.triangle), fast.map(|h| h.triangle));
        if let (Some(b), Some(f)) = (b, fast) {
            assert!((b.t - f.t).abs() < 1e-9 * f.t.max(1.0));
        }
        // Brute force on the bilinear patches: march the ray in 5 cm steps,
        // then bisect the first step that ends under the surface.
        let above = |t: f64| -> Option<bool> {
            let (vx, vy) = terrain.en_to_v(d[0] * t, d[1] * t);
            if !(vx >= 0.0 && vy >= 0.0) {
                return None;
            }
            let (c, r) = (vx.floor() as usize, vy.floor() as usize);
            if c + 1 >= terrain.nx || r + 1 >= terrain.ny {
                return None;
            }
            let (fx, fy) = (vx - c as f64, vy - r as f64);
            let z = |c, r| terrain.vertex_z(c, r);
            let h = (z(c, r)? * (1.0 - fx) + z(c + 1, r)? * fx) * (1.0 - fy)
                + (z(c, r + 1)? * (1.0 - fx) + z(c + 1, r + 1)? * fx) * fy;
            Some(d[2] * t > h)
        };
        let step = 0.05;
        let mut best: Option<f64> = None;
        let mut t = step;
        while t < 2500.0 {
            if above(t) == Some(false) && above(t - step) != Some(false) {
                let (mut lo, mut hi) = (t - step, t);
                for _ in 0..40 {
                    let mid = 0.5 * (lo + hi);
                    if above(mid) == Some(false) {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
                best = Some(hi);
                break;
            }
            t += step;
        }
        match (fast, best) {
            (None, None) => {}
            (Some(f), Some(b)) => {
                let err = (f.t - b).abs();
                worst = worst.max(err);
                assert!(err < 1e-6 * b.max(1.0) + 1e-9, "t {} vs brute {}", f.t, b);
                checked += 1;
            }
            // a dip under the surface shorter than the march's step
            (Some(f), None) => assert!(
                above(f.t - 1e-6) == Some(true),
                "cast {f:?} where the march found nothing for {d:?}"
            ),
            (f, b) => panic!("fast {f:?} vs brute {b:?} for {d:?}"),
        }
    }
    eprintln!("{checked} hits checked against brute force, worst |dt| {worst:.2e} m");
    assert!(checked > 100);
}

/// Compare the rasterised depth buffer with one exact cast per pixel: the
/// same depth everywhere (up to f32 rounding), the same triangle except
/// where a pixel centre lies on a shared edge (then the depths agree).
fn assert_raster_equals_casting(terrain: &LocalTerrain, cam: &Camera, what: &str) {
    let fast = DepthBuffer::render(terrain, cam);
    let slow = DepthBuffer::render_by_ray_casting(terrain, cam);
    // The rasteriser draws each bilinear patch as triangles within 0.05 px
    // of it, the casts meet the patch exactly: the depths agree to a
    // percent except on pixels at grazing boundaries (under 1 %).
    let (mut terrain_px, mut other_tri, mut differ, mut worst) = (0usize, 0usize, 0usize, 0f64);
    for k in 0..fast.depth.len() {
        let (a, b) = (fast.depth[k] as f64, slow.depth[k] as f64);
        if a.is_finite() != b.is_finite() {
            differ += 1;
            continue;
        }
        if a.is_finite() {
            terrain_px += 1;
            let rel = (a - b).abs() / b;
            if rel < 1e-2 {
                worst = worst.max(rel);
            } else {
                differ += 1;
            }
            other_tri += usize::from(fast.triangle[k] != slow.triangle[k]);
        }
    }
    eprintln!(
        "{what}: {terrain_px} terrain pixels, {differ} differ from ray casting (elsewhere worst relative depth {worst:.1e}), {other_tri} other cell halves"
    );
    assert!(terrain_px > 0);
    assert!(
        differ * 100 <= fast.depth.len(),
        "{what}: {differ} pixels differ"
    );
    assert!(
        other_tri * 100 <= terrain_px,
        "{what}: {other_tri} triangle ids differ"
    );
    // Rendering part of the view gives the very same pixels there: a wavy
    // last row per column, with columns left out and columns rendered whole.
    let (w, h) = (cam.width, cam.height);
    let last: Vec<i32> = (0..w)
        .map(|i| match i % 97 {
            0..=9 => -1,
            10..=19 => h as i32 - 1,
            _ => ((0.5 + 0.4 * (i as f64 / 23.0).sin()) * h as f64) as i32,
        })
        .collect();
    // Rendered into the buffers of another view (the browser app's reuse),
    // of the same size or not: the very same buffer.
    for other_w in [w, w / 2 + 1] {
        let other = Camera::new(
            other_w,
            h,
            cam.heading_deg + 90.0,
            cam.pitch_deg,
            0.0,
            cam.hfov_deg,
        )
        .expect("camera");
        let reused =
            DepthBuffer::render_reusing(terrain, cam, DepthBuffer::render(terrain, &other));
        assert!(
            reused
                .depth
                .iter()
                .map(|d| d.to_bits())
                .eq(fast.depth.iter().map(|d| d.to_bits()))
                && reused.triangle == fast.triangle,
            "{what}: render_reusing differs from render (other view {other_w} px wide)"
        );
    }
    let part = DepthBuffer::render_rows(terrain, cam, &last);
    for j in 0..h {
        for (i, &top) in last.iter().enumerate().take(w) {
            let k = j * w + i;
            if j as i32 <= top {
                assert_eq!(
                    (part.depth[k].to_bits(), part.triangle[k]),
                    (fast.depth[k].to_bits(), fast.triangle[k]),
                    "{what}: render_rows differs at pixel {i} {j}"
                );
            } else {
                assert!(part.depth[k].is_nan() && part.triangle[k] == SKY);
            }
        }
    }
    // Rendering only the rows below that part, the part taken as it is,
    // gives the whole render, every pixel to the bit.
    let first: Vec<i32> = last.iter().map(|&r| (r + 1).clamp(0, h as i32)).collect();
    let below = DepthBuffer::render_below(terrain, cam, &first, &part);
    for k in 0..w * h {
        assert_eq!(
            (below.depth[k].to_bits(), below.triangle[k]),
            (fast.depth[k].to_bits(), fast.triangle[k]),
            "{what}: render_below differs at pixel {} {}",
            k % w,
            k / w
        );
    }
}

#[test]
fn rasterised_depth_buffer_equals_exact_ray_casting() {
    // A noisy synthetic field with a hole, cameras pitched, rolled and
    // looking straight down.
    let mut rng = Lcg(11);
    let mut dem = synthetic(96, 80, 25.0, |x, y| {
        100.0 + 30.0 * ((x / 200.0).sin() + (y / 150.0).cos())
    });
    for v in dem.data.iter_mut() {
        *v += (rng.next() * 40.0) as f32;
    }
    dem.data[20 * 96 + 30] = f32::NAN;
    let (ex, ey) = dem.geotransform.pixel_to_crs(40.3, 52.7);
    let ground = dem.bilinear(40.3, 52.7).unwrap();
    let frame = LocalFrame::planar(&dem, (ex, ey), ground + 2.0, Curvature::default());
    let terrain = LocalTerrain::new(&dem, &frame, None);
    for (k, (hd, p, r, fov)) in [
        (10.0, 0.0, 0.0, 60.0),
        (200.0, -12.0, 0.0, 70.0),
        (95.0, 5.0, 17.0, 50.0),
        (300.0, -89.0, 0.0, 90.0),
    ]
    .into_iter()
    .enumerate()
    {
        let cam = Camera::new(320, 200, hd, p, r, fov).unwrap();
        assert_raster_equals_casting(&terrain, &cam, &format!("synthetic view {k}"));
    }
    // Real DEMs, as `view` renders them.
    for (name, px, py, heading) in [
        ("zion_srtm_utm12n.tif", 210.5, 103.5, 20.0),
        ("vinschgau_250m_utm32n.tif", 101.5, 110.5, 250.0),
    ] {
        let dem = load(&fixture(name));
        let georef = Georef::new(&dem, name).unwrap();
        let (x, y) = dem.geotransform.pixel_to_crs(px, py);
        let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
        let frame = georef
            .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &dem, 1.0 / 7.0)
            .unwrap();
        let terrain = LocalTerrain::new(&dem, &frame, None);
        let cam = Camera::new(800, 450, heading, 1.0, 0.0, 60.0).unwrap();
        assert_raster_equals_casting(&terrain, &cam, name);
    }
}

/// The terrain of what a camera sees (`LocalTerrain::in_view`) renders the
/// same view as the whole terrain: same sky, same depths (up to rounding of
/// the shifted vertex coordinates), the same DEM cells; and it is smaller
/// when the field of view is narrow.
#[test]
fn terrain_in_view_renders_the_same_view() {
    let name = "zion_srtm_utm12n.tif";
    let dem = load(&fixture(name));
    let georef = Georef::new(&dem, name).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(210.5, 103.5);
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let frame = georef
        .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &dem, 1.0 / 7.0)
        .unwrap();
    let whole = LocalTerrain::new(&dem, &frame, None);
    for (heading, pitch, roll, fov, narrower) in [
        (20.0, 1.0, 0.0, 35.0, true),
        (200.0, -10.0, 25.0, 60.0, true),
        (95.0, 3.0, 0.0, 120.0, true),
        (300.0, -89.0, 0.0, 90.0, false),
    ] {
        let cam = Camera::new(400, 240, heading, pitch, roll, fov).unwrap();
        let part = LocalTerrain::in_view(&dem, &frame, None, &cam);
        let what = format!("heading {heading}, pitch {pitch}, roll {roll}, fov {fov}");
        assert_eq!(
            part.nx * part.ny < whole.nx * whole.ny,
            narrower,
            "{what}: {} x {} of {} x {}",
            part.nx,
            part.ny,
            whole.nx,
            whole.ny
        );
        let (a, b) = (
            DepthBuffer::render(&whole, &cam),
            DepthBuffer::render(&part, &cam),
        );
        let mut other_cell = 0;
        for k in 0..a.depth.len() {
            assert_eq!(
                a.triangle[k] == SKY,
                b.triangle[k] == SKY,
                "{what}: pixel {k}"
            );
            if a.triangle[k] == SKY {
                continue;
            }
            let (da, db) = (a.depth[k] as f64, b.depth[k] as f64);
            assert!(
                (da - db).abs() <= 1e-5 * da,
                "{what}: pixel {k}: {da} vs {db}"
            );
            // (DEM cells: `triangle_cell` adds the terrain's offset)
            let (ca, ra, _) = whole.triangle_cell(a.triangle[k]);
            let (cb, rb, _) = part.triangle_cell(b.triangle[k]);
            other_cell += usize::from((ca, ra) != (cb, rb));
        }
        assert!(
            other_cell * 1000 <= a.depth.len(),
            "{what}: {other_cell} pixels on other cells"
        );
    }
}

#[test]
fn depth_of_a_flat_plane_is_analytic() {
    let dem = synthetic(400, 400, 10.0, |_, _| 50.0);
    let (ex, ey) = dem.geotransform.pixel_to_crs(200.0, 200.0);
    let frame = LocalFrame::planar(&dem, (ex, ey), 60.0, Curvature::flat());
    let terrain = LocalTerrain::new(&dem, &frame, None);
    let cam = Camera::new(320, 180, 30.0, -10.0, 5.0, 60.0).unwrap();
    let db = DepthBuffer::render(&terrain, &cam);
    let mut worst: f64 = 0.0;
    for j in 0..180 {
        for i in 0..320 {
            let d = cam.unproject([i as f64 + 0.5, j as f64 + 0.5]);
            let depth = db.depth_at(i, j) as f64;
            if d[2] < 0.0 {
                let t = 10.0 / -d[2];
                let (hx, hy) = (d[0] * t, d[1] * t);
                if hx.abs() < 1990.0 && hy.abs() < 1990.0 {
                    worst = worst.max((depth - t).abs() / t);
                }
            } else {
                assert!(depth.is_infinite());
            }
        }
    }
    eprintln!("flat plane: worst relative depth error {worst:.2e}");
    assert!(worst < 1e-5);
}

#[test]
fn locate_and_project_are_inverse_for_1000_pixels() {
    let name = "zion_srtm_utm12n.tif";
    let dem = load(&fixture(name));
    let georef = Georef::new(&dem, name).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(200.5, 300.5);
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let frame = georef
        .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &dem, 1.0 / 7.0)
        .unwrap();
    let terrain = LocalTerrain::new(&dem, &frame, None);
    let cam = Camera::new(1600, 900, 20.0, -2.0, 3.0, 70.0).unwrap();
    let mut rng = Lcg(42);
    let (mut n, mut tries, mut worst) = (0, 0, 0.0f64);
    while n < 1000 {
        tries += 1;
        assert!(tries < 100_000, "too few terrain pixels");
        let (px, py) = (rng.next() * 1600.0, rng.next() * 900.0);
        let Some(loc) = demsketch::render::locate(&terrain, &cam, &georef, px, py).unwrap() else {
            continue;
        };
        // Back from lon/lat through PROJ to the CRS and the camera.
        let (cx, cy) = georef.lonlat_to_crs(loc.lon, loc.lat).unwrap();
        let p = demsketch::render::project_point(&frame, &cam, cx, cy, loc.height).unwrap();
        let err = (p[0] - px).hypot(p[1] - py);
        worst = worst.max(err);
        assert!(err < 0.5, "pixel ({px},{py}) -> {loc:?} -> {p:?}");
        // The located height is the DEM surface there.
        let h = pick(&terrain, &cam, px, py).unwrap();
        assert!((h.z - loc.height).abs() < 1e-9);
        n += 1;
    }
    eprintln!("1000 located pixels reproject within {worst:.2e} px ({tries} tries)");
}

#[test]
fn shaded_view_of_zion_is_written() {
    let name = "zion_srtm_utm12n.tif";
    let dem = load(&fixture(name));
    let georef = Georef::new(&dem, name).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(200.5, 300.5);
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let frame = georef
        .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &dem, 1.0 / 7.0)
        .unwrap();
    let terrain = LocalTerrain::new(&dem, &frame, Some(15_000.0));
    let cam = Camera::new(400, 225, 0.0, 0.0, 0.0, 60.0).unwrap();
    let db = DepthBuffer::render(&terrain, &cam);
    let f = db.terrain_fraction();
    assert!(f > 0.3 && f < 1.0, "terrain fraction {f}");
    let rgb = shade(&db, &terrain, &ShadeOptions::default());
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("v.png");
    write_png(&p, 400, 225, &rgb).unwrap();
    let dp = dir.path().join("d.tif");
    demsketch::render::write_depth_tiff(&db, &dp).unwrap();
    assert!(std::fs::metadata(&p).unwrap().len() > 1000);
    // Max distance: nothing beyond 15 km.
    assert!(db.depth.iter().all(|d| !d.is_finite() || *d < 15_100.0));
}

/// `Scene::open_wedge` reads only the box of the camera's wedge and builds
/// the terrain `Scene::open_in_view` builds from the whole square: the same
/// DEM cells, the same vertex heights and frame to the bit (the eye's pixel
/// moved by whole cells), the same depth buffer and triangle of every
/// pixel; with or without a maximum distance, narrow and wide views.
#[test]
fn wedge_scene_is_the_in_view_scene_read_in_part() {
    use demsketch::raster::Dem;
    use demsketch::render::Scene;
    let dem = Dem::open(&fixture("zion_srtm_utm12n.tif")).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(210.5, 103.5);
    let georef = Georef::for_crs(&dem.crs, "zion").unwrap();
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let vp = Viewpoint::above_surface(lon, lat, 1.7);
    for (heading, pitch, fov, max_d) in [
        (20.0, 1.0, 35.0, None),
        (200.0, -10.0, 60.0, Some(9000.0)),
        (95.0, 3.0, 120.0, None),
        (300.0, -89.0, 90.0, Some(20000.0)),
    ] {
        let what = format!("heading {heading}, pitch {pitch}, fov {fov}, {max_d:?}");
        let cam = Camera::new(320, 180, heading, pitch, 0.0, fov).unwrap();
        let full = Scene::open_in_view(&dem, &vp, max_d, 1.0 / 7.0, &cam).unwrap();
        let part = Scene::open_wedge(&dem, &vp, max_d, 1.0 / 7.0, &cam).unwrap();
        let (a, b) = (&full.terrain, &part.terrain);
        assert_eq!(
            (
                full.window_offset.0 + a.col0 as i64,
                full.window_offset.1 + a.row0 as i64
            ),
            (
                part.window_offset.0 + b.col0 as i64,
                part.window_offset.1 + b.row0 as i64
            ),
            "{what}: origin"
        );
        assert_eq!((a.nx, a.ny), (b.nx, b.ny), "{what}: size");
        assert_eq!(
            (part.window.width, part.window.height),
            (b.nx, b.ny),
            "{what}: only the terrain's cells are read"
        );
        assert!(
            a.z.iter()
                .zip(&b.z)
                .all(|(p, q)| p.to_bits() == q.to_bits()),
            "{what}: vertex heights"
        );
        assert_eq!(
            (a.frame.ground, a.frame.eye_alt, a.frame.p),
            (b.frame.ground, b.frame.eye_alt, b.frame.p),
            "{what}: frame"
        );
        let (da, db) = (DepthBuffer::render(a, &cam), DepthBuffer::render(b, &cam));
        assert!(
            da.depth
                .iter()
                .zip(&db.depth)
                .all(|(p, q)| p.to_bits() == q.to_bits()),
            "{what}: depths"
        );
        assert_eq!(da.triangle, db.triangle, "{what}: triangles");
    }
}

/// The silhouettes' bisection intersects a single cell's patch where both
/// sides of its bracket hit that cell (`LocalTerrain::cast_from_cell`): on
/// rays whose traversal hit lies in a cell, that cell alone gives the same
/// hit, and a cell the ray meets only after an earlier hit is refused.
#[test]
fn a_cast_in_the_cell_of_the_hit_equals_the_traversal() {
    let mut rng = Lcg(11);
    let noise: Vec<f64> = (0..48 * 48).map(|_| rng.next() * 40.0).collect();
    let mut dem = synthetic(48, 48, 25.0, |x, y| {
        100.0 + 30.0 * ((x / 200.0).sin() + (y / 150.0).cos())
    });
    for (v, n) in dem.data.iter_mut().zip(&noise) {
        *v += *n as f32;
    }
    let (ex, ey) = dem.geotransform.pixel_to_crs(10.3, 12.7);
    let ground = dem.bilinear(10.3, 12.7).unwrap();
    let frame = LocalFrame::planar(&dem, (ex, ey), ground + 2.0, Curvature::default());
    let terrain = LocalTerrain::new(&dem, &frame, None);
    let (mut same, mut refused, mut walks) = (0, 0, 0);
    for _ in 0..400 {
        let az = rng.next() * std::f64::consts::TAU;
        let el = (rng.next() - 0.7) * 0.6;
        let d = [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()];
        let Some(hit) = terrain.cast_segment(d, 0.0, f64::INFINITY) else {
            continue;
        };
        let cell = terrain
            .cast_from_cell(d, hit.triangle, 0.0, hit.t, 1)
            .expect("the cell of the hit");
        assert_eq!(cell.triangle, hit.triangle);
        assert!(
            (cell.t - hit.t).abs() < 1e-9 * hit.t.max(1.0),
            "{cell:?} vs {hit:?}"
        );
        same += 1;
        // Walked from a cell the ray crosses before the hit.
        let back = (hit.t - 70.0).max(0.0);
        let (bx, by) = terrain.en_to_v(d[0] * back, d[1] * back);
        let cx = terrain.nx as i64 - 1;
        let (bc, br) = (bx.floor() as i64, by.floor() as i64);
        if bc >= 0 && br >= 0 && bc < cx && br < terrain.ny as i64 - 1 {
            let id = (2 * (br * cx + bc)) as u32;
            if let Some(walked) = terrain.cast_from_cell(d, id, back, hit.t, 16) {
                assert_eq!(walked.triangle, hit.triangle);
                assert!((walked.t - hit.t).abs() < 1e-9 * hit.t.max(1.0));
                walks += 1;
            }
        }
        // The next cell along the ray lies beyond the hit, under the
        // terrain where the ray enters it: refused.
        let (vx, vy) = terrain.en_to_v(d[0] * hit.t, d[1] * hit.t);
        let (gx, gy) = terrain.en_to_v(d[0] * (hit.t + 60.0), d[1] * (hit.t + 60.0));
        let (c0, r0) = (vx.floor() as i64, vy.floor() as i64);
        let (c1, r1) = (gx.floor() as i64, gy.floor() as i64);
        if (c1, r1) != (c0, r0) && c1 >= 0 && r1 >= 0 && c1 < cx && r1 < terrain.ny as i64 - 1 {
            let id = (2 * (r1 * cx + c1)) as u32;
            if let Some(later) = terrain.cast_from_cell(d, id, hit.t, f64::INFINITY, 1) {
                // only where the ray came out above the terrain again
                assert!(later.t > hit.t, "{later:?} before {hit:?}");
            } else {
                refused += 1;
            }
        }
    }
    assert!(same > 100, "{same} rays checked");
    assert!(refused > 20, "{refused} later cells refused");
    assert!(walks > 50, "{walks} walks over several cells");
}
/// `LocalTerrain::with_heights` (the edit's re-renders) gives the terrain a
/// build over a copy of the grid with those heights swapped in gives: the
/// same vertex heights to the bit, the same depth buffer and triangles.
#[test]
fn patched_terrain_is_the_terrain_of_the_patched_grid() {
    use demsketch::raster::Dem;
    use demsketch::render::Scene;
    let dem = Dem::open(&fixture("zion_srtm_utm12n.tif")).unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(210.5, 103.5);
    let georef = Georef::for_crs(&dem.crs, "zion").unwrap();
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let vp = Viewpoint::above_surface(lon, lat, 1.7);
    let cam = Camera::new(320, 180, 200.0, -3.0, 0.0, 60.0).unwrap();
    let scene = Scene::open_wedge(&dem, &vp, Some(9000.0), 1.0 / 7.0, &cam).unwrap();
    // A bump over a rectangle partly outside the terrain's cells.
    let (w, h) = (scene.window.width, scene.window.height);
    let rect = (w / 3, h / 4, w + 5, h / 2);
    let bump = |c: usize, r: usize| -> Option<f32> {
        let v = scene.window.get(c, r)?;
        (c % 7 != 0).then(|| v + 0.37 * ((c + 3 * r) % 11) as f32)
    };
    let mut map = scene.window.clone();
    for r in rect.1..rect.3.min(h) {
        for c in rect.0..rect.2.min(w) {
            if let Some(v) = bump(c, r) {
                map.data[r * w + c] = v;
            }
        }
    }
    let want = LocalTerrain::over(&map, &scene.frame, Some(9000.0));
    // Rendered first, the terrain has its block ranges: the patched
    // terrain patches them (and takes its height range from them).
    drop(DepthBuffer::render(&scene.terrain, &cam));
    scene.terrain.build_cast_index();
    let got = scene.terrain.with_heights(rect, &bump);
    // The cast index and block ranges patched, not built again: the same
    // bits as a build over the patched grid.
    assert_same_terrain(&got, &want, &cam, "patched once");
    assert!(got.z.iter().zip(&scene.terrain.z).any(|(p, q)| p != q));
    // Patched again (the heights shared, the patches merged): the same as
    // building over both changes.
    let rect2 = (w / 5, h / 3, w / 2, h / 3 + 9);
    let lower = |c: usize, r: usize| -> Option<f32> {
        let v = map.get(c, r)?;
        (r % 3 != 1).then_some(v - 2.5)
    };
    let mut map2 = map.clone();
    for r in rect2.1..rect2.3 {
        for c in rect2.0..rect2.2 {
            if let Some(v) = lower(c, r) {
                map2.data[r * w + c] = v;
            }
        }
    }
    let want2 = LocalTerrain::over(&map2, &scene.frame, Some(9000.0));
    drop(DepthBuffer::render(&got, &cam));
    let got2 = got.with_heights(rect2, &lower);
    assert_same_terrain(&got2, &want2, &cam, "patched twice");
}

/// Two terrains are the same to the bit: cast index and block ranges,
/// vertex heights, height range, grid, and what they render (depth and
/// triangles).
fn assert_same_terrain(got: &LocalTerrain, want: &LocalTerrain, cam: &Camera, what: &str) {
    assert!(
        demsketch::render::acceleration_bits(got) == demsketch::render::acceleration_bits(want),
        "{what}: cast index and block ranges"
    );
    assert_eq!(
        (got.nx, got.ny, got.col0, got.row0),
        (want.nx, want.ny, want.col0, want.row0),
        "{what}: grid"
    );
    assert!(
        got.z
            .iter()
            .zip(&want.z)
            .all(|(p, q)| p.to_bits() == q.to_bits()),
        "{what}: vertex heights"
    );
    assert_eq!(
        got.height_range(),
        want.height_range(),
        "{what}: height range"
    );
    let (da, db) = (
        DepthBuffer::render(got, cam),
        DepthBuffer::render(want, cam),
    );
    assert!(
        da.depth
            .iter()
            .zip(&db.depth)
            .all(|(p, q)| p.to_bits() == q.to_bits()),
        "{what}: depth"
    );
    assert_eq!(da.triangle, db.triangle, "{what}: triangles");
}

/// The silhouettes' bisection starts its traversals at the entry of a cell
/// the ray crosses before its hit (`LocalTerrain::cell_entry`) instead of
/// well short of it: the hit is the same, bit for bit, from any such cell,
/// with the full cast index and with the coarse one, and from the first
/// cell that a walk of `cast_from_cell_walk` which met nothing did not test.
#[test]
fn a_traversal_from_a_cell_entry_finds_the_same_hit_bit_for_bit() {
    let mut rng = Lcg(23);
    let noise: Vec<f64> = (0..64 * 64).map(|_| rng.next() * 40.0).collect();
    let mut dem = synthetic(64, 64, 25.0, |x, y| {
        100.0 + 30.0 * ((x / 200.0).sin() + (y / 150.0).cos())
    });
    for (v, n) in dem.data.iter_mut().zip(&noise) {
        *v += *n as f32;
    }
    let (ex, ey) = dem.geotransform.pixel_to_crs(20.3, 22.7);
    let ground = dem.bilinear(20.3, 22.7).unwrap();
    let frame = LocalFrame::planar(&dem, (ex, ey), ground + 2.0, Curvature::default());
    let coarse = LocalTerrain::new(&dem, &frame, None);
    let full = LocalTerrain::new(&dem, &frame, None);
    full.build_cast_index();
    let (mut checked, mut resumed) = (0, 0);
    for _ in 0..400 {
        let az = rng.next() * std::f64::consts::TAU;
        let el = (rng.next() - 0.7) * 0.3;
        let d = [az.sin() * el.cos(), az.cos() * el.cos(), el.sin()];
        for terrain in [&coarse, &full] {
            let Some(hit) = terrain.cast_segment(d, 0.0, f64::INFINITY) else {
                continue;
            };
            for k in 1..=8 {
                let t = hit.t * k as f64 / 8.0;
                let Some(e) = terrain.cell_entry(d, t) else {
                    continue;
                };
                assert!(e <= t, "entry {e} after {t}");
                let from = terrain.cast_segment(d, e, f64::INFINITY);
                assert_eq!(from, Some(hit), "from the cell entered at {e} (of {t})");
                checked += 1;
                // A cell walk from there that meets nothing in two cells:
                // the traversal from the first cell it did not test.
                let (vx, vy) = terrain.en_to_v(d[0] * t, d[1] * t);
                let (c, r) = (vx.floor() as usize, vy.floor() as usize);
                let id = (2 * (r * terrain.cells_x() + c)) as u32;
                if let Err(Some((nc, nr))) = terrain.cast_from_cell_walk(d, id, e, t, 2) {
                    if let Some(e2) = terrain.cell_entry_at(d, nc, nr) {
                        let from = terrain.cast_segment(d, e2, f64::INFINITY);
                        assert_eq!(from, Some(hit), "after a walk, from {e2}");
                        resumed += 1;
                    }
                }
            }
        }
    }
    assert!(checked > 500, "{checked} starts checked");
    assert!(resumed > 100, "{resumed} starts after a cell walk checked");
}
