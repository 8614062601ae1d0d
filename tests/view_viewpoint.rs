//! Viewpoint mapping against PROJ's own command line tools: lon/lat to the
//! DEM CRS matches `cs2cs` to 1 mm on the UTM fixtures, meridian convergence
//! matches `proj -V` near a UTM zone edge, and a camera with heading 0 looks
//! at true north (not grid north).

mod view_support;

use demsketch::view::{Camera, CameraModel, Georef, ViewError, Viewpoint};
use view_support::*;

fn cs2cs(epsg: u32, lon: f64, lat: f64) -> (f64, f64) {
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "echo '{lat} {lon}' | cs2cs -f %.6f EPSG:4326 EPSG:{epsg}"
        ))
        .output()
        .unwrap();
    let s = String::from_utf8_lossy(&out.stdout);
    let v: Vec<f64> = s
        .split_whitespace()
        .filter_map(|t| t.parse().ok())
        .collect();
    (v[0], v[1])
}

#[test]
fn lonlat_to_utm_matches_cs2cs_to_1mm() {
    if !have_tool("cs2cs") {
        eprintln!("cs2cs not installed: skipped");
        return;
    }
    let mut worst: f64 = 0.0;
    for (name, epsg) in [
        ("zion_srtm_utm12n.tif", 32612),
        ("vinschgau_250m_utm32n.tif", 32632),
    ] {
        let dem = load(&fixture(name));
        let georef = Georef::new(&dem, name).unwrap();
        for (fx, fy) in [(0.1, 0.2), (0.5, 0.5), (0.9, 0.7), (0.3, 0.95)] {
            let (x, y) = dem
                .geotransform
                .pixel_to_crs(fx * dem.width as f64, fy * dem.height as f64);
            let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
            let (ex, ey) = cs2cs(epsg, lon, lat);
            let (ox, oy) = georef.lonlat_to_crs(lon, lat).unwrap();
            let err = (ox - ex).hypot(oy - ey);
            worst = worst.max(err);
            assert!(err < 1e-3, "{name}: {err} m at {lon},{lat}");
            // And back.
            let (lon2, lat2) = georef.crs_to_lonlat(ox, oy).unwrap();
            assert!((lon2 - lon).abs() < 1e-9 && (lat2 - lat).abs() < 1e-9);
        }
    }
    eprintln!("worst difference to cs2cs: {worst:.2e} m");
}

/// `proj -V` prints "Convergence : ... [ degrees ]".
fn proj_convergence(zone: u32, lon: f64, lat: f64) -> f64 {
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!(
            "echo '{lon} {lat}' | proj -V +proj=utm +zone={zone} +datum=WGS84"
        ))
        .output()
        .unwrap();
    let s = String::from_utf8_lossy(&out.stdout);
    let line = s.lines().find(|l| l.starts_with("Convergence")).unwrap();
    let inner = line.split('[').nth(1).unwrap().split(']').next().unwrap();
    inner.trim().parse().unwrap()
}

#[test]
fn meridian_convergence_near_zone_edge_matches_proj_and_heading_is_true_north() {
    if !have_tool("proj") {
        eprintln!("proj not installed: skipped");
        return;
    }
    // Zion DEM is in UTM zone 12 (central meridian -111); -113.95 is 0.05
    // degrees from the zone's western edge.
    let dem = load(&fixture("zion_srtm_utm12n.tif"));
    let georef = Georef::new(&dem, "zion").unwrap();
    for (lon, lat) in [(-113.95, 37.3), (-113.99, 45.0), (-108.02, 37.3)] {
        let ours = georef.meridian_convergence_deg(lon, lat).unwrap();
        let theirs = proj_convergence(12, lon, lat);
        eprintln!("convergence at {lon},{lat}: ours {ours:.8} proj {theirs:.8}");
        assert!((ours - theirs).abs() < 1e-6, "{ours} vs {theirs}");
    }
    // A camera with heading 0 at a viewpoint in the DEM looks along the
    // meridian: a point due north (same lon) projects onto the centre column.
    let (x, y) = dem.geotransform.pixel_to_crs(30.5, 250.5);
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let frame = georef
        .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &dem, 1.0 / 7.0)
        .unwrap();
    let cam = Camera::new(1600, 900, 0.0, 0.0, 0.0, 60.0).unwrap();
    let (nx, ny) = georef.lonlat_to_crs(lon, lat + 0.05).unwrap();
    let p = cam
        .project(frame.crs_to_local(nx, ny, frame.eye_alt))
        .unwrap();
    assert!(
        (p[0] - 800.0).abs() < 0.5,
        "due north appears at x = {}",
        p[0]
    );
    // Grid north lies at bearing = convergence from true north (PROJ sign).
    let gb = frame.grid_north_bearing_deg();
    let conv = georef.meridian_convergence_deg(lon, lat).unwrap();
    assert!(
        (gb - conv).abs() < 1e-6,
        "grid north bearing {gb}, convergence {conv}"
    );
    // Heading 90: a point due east on the parallel's tangent appears centred.
    let cam = Camera::new(1600, 900, 90.0, 0.0, 0.0, 60.0).unwrap();
    let (ex, ey) = georef.lonlat_to_crs(lon + 0.01, lat).unwrap();
    let p = cam
        .project(frame.crs_to_local(ex, ey, frame.eye_alt))
        .unwrap();
    assert!(
        (p[0] - 800.0).abs() < 2.0,
        "due east appears at x = {}",
        p[0]
    );
}

#[test]
fn geographic_dem_gets_metric_frame() {
    let dem = load(&fixture("arenal_aster30m_epsg4326.tif"));
    let georef = Georef::new(&dem, "arenal").unwrap();
    let (x, y) = dem.geotransform.pixel_to_crs(80.5, 60.5);
    let frame = georef
        .local_frame(&Viewpoint::above_surface(x, y, 1.7), &dem, 1.0 / 7.0)
        .unwrap();
    // One cell east is 1 arc-second of longitude: N cos(lat) * pi / 180 / 3600.
    let (e, n) = frame.pixel_to_en(81.5, 60.5);
    let expect = 6_378_137.0 / (1.0 - 0.00669438 * (10.47f64.to_radians().sin()).powi(2)).sqrt()
        * 10.47f64.to_radians().cos()
        * (1.0f64 / 3600.0).to_radians();
    assert!(
        (e - expect).abs() < 0.05 && n.abs() < 1e-9,
        "{e} {n} vs {expect}"
    );
    // Eye height above the bilinear surface.
    assert!((frame.eye_alt - frame.ground - 1.7).abs() < 1e-9);
    assert!((frame.ground - dem.get(80, 60).unwrap() as f64).abs() < 1e-6);
}

#[test]
fn viewpoint_outside_or_on_nodata_is_a_clear_error() {
    let dem = load(&fixture("zion_srtm_utm12n.tif"));
    let georef = Georef::new(&dem, "zion_srtm_utm12n.tif").unwrap();
    let e = georef
        .local_frame(
            &Viewpoint::above_surface(-100.0, 37.3, 1.7),
            &dem,
            1.0 / 7.0,
        )
        .unwrap_err();
    assert!(matches!(e, ViewError::OutsideDem { .. }));
    let msg = e.to_string();
    assert!(msg.contains("zion_srtm_utm12n.tif") && msg.contains("outside") && !msg.contains('\n'));
    // First nodata cell of the reprojected DEM (its corners are nodata).
    let k = dem
        .data
        .iter()
        .position(|v| v.is_nan())
        .expect("zion utm has nodata corners");
    let (c, r) = (k % dem.width, k / dem.width);
    let (x, y) = dem
        .geotransform
        .pixel_to_crs(c as f64 + 0.5, r as f64 + 0.5);
    let (lon, lat) = georef.crs_to_lonlat(x, y).unwrap();
    let e = georef
        .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &dem, 1.0 / 7.0)
        .unwrap_err();
    assert!(matches!(e, ViewError::OnNodata { .. }), "{e}");
}
