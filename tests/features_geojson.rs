//! Features of real views (Vinschgau, Zion) and their GeoJSON export:
//! silhouettes exist across the view and their samples are consistent; the
//! GeoJSON holds LineStrings with lon, lat, z inside the DEM's bounds and the
//! documented properties.

use std::path::Path;

use demsketch::features::geojson::{feature_collection, to_lonlat_with_georef, write_geojson};
use demsketch::features::{detect_ridges, extract_silhouettes, RidgeParams, SilhouetteParams};
use demsketch::raster::read_height_map;
use demsketch::render::{DepthBuffer, LocalTerrain};
use demsketch::view::{Camera, CameraModel, Georef, Viewpoint};

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

fn check_view(name: &str, lon: f64, lat: f64, heading: f64) {
    let map = read_height_map(&fixture(name)).expect("read fixture");
    let georef = Georef::new(&map, name).expect("georef");
    let frame = georef
        .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &map, 1.0 / 7.0)
        .expect("viewpoint");
    let terrain = LocalTerrain::new(&map, &frame, None);
    let camera = Camera::new(800, 450, heading, 2.0, 0.0, 60.0).expect("camera");
    let db = DepthBuffer::render(&terrain, &camera);
    let sil =
        extract_silhouettes(&terrain, &db, &SilhouetteParams::default()).expect("silhouettes");
    let ridges = detect_ridges(&map, &RidgeParams::default()).expect("ridges");

    // A skyline in (nearly) every column that shows terrain under sky.
    let mut with_sky = 0;
    let mut found = 0;
    for x in 0..db.width {
        let col_has_sky = db.depth_at(x, 0).is_infinite();
        let col_has_terrain = (0..db.height).any(|y| db.depth_at(x, y).is_finite());
        if col_has_sky && col_has_terrain {
            with_sky += 1;
            if sil
                .skyline_at(x)
                .is_some_and(|s| s.depth_behind.is_infinite())
            {
                found += 1;
            }
        }
    }
    assert!(with_sky > 0);
    assert!(
        found as f64 >= 0.99 * with_sky as f64,
        "skyline in {found} of {with_sky} columns"
    );
    assert!(
        sil.curves.len() > 3,
        "only {} silhouettes",
        sil.curves.len()
    );
    let (zmin, zmax) = map.min_max().expect("heights");
    for c in &sil.curves {
        for s in &c.samples {
            let p = camera.project(s.local).expect("in front");
            assert!((p[0] - s.pixel[0]).abs() < 0.01 && (p[1] - s.pixel[1]).abs() < 0.01);
            assert!(s.world[2] > zmin as f64 - 1.0 && s.world[2] < zmax as f64 + 1.0);
        }
    }
    eprintln!(
        "{name}: {} silhouettes ({} samples), {} T-junctions, {} ridge lines",
        sil.curves.len(),
        sil.sample_count(),
        sil.junctions.len(),
        ridges.lines.len()
    );

    let to_ll = to_lonlat_with_georef(&georef);
    let fc = feature_collection(Some(&sil), Some(&ridges), &to_ll).expect("geojson");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("features.geojson");
    write_geojson(&path, &fc).expect("write");
    let back: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).expect("read back")).expect("json");
    assert_eq!(back["type"], "FeatureCollection");
    let feats = back["features"].as_array().expect("features");
    let (mut n_sil, mut n_ridge) = (0, 0);
    for f in feats {
        let props = &f["properties"];
        let kind = props["kind"].as_str().expect("kind");
        if kind == "t_junction" {
            assert_eq!(f["geometry"]["type"], "Point");
            continue;
        }
        assert_eq!(f["geometry"]["type"], "LineString");
        assert!(props["id"].is_u64());
        assert!(props["length"].as_f64().expect("length") >= 0.0);
        for p in f["geometry"]["coordinates"].as_array().expect("coords") {
            let (lo, la, z) = (
                p[0].as_f64().unwrap_or(f64::NAN),
                p[1].as_f64().unwrap_or(f64::NAN),
                p[2].as_f64().unwrap_or(f64::NAN),
            );
            assert!(
                (lo - lon).abs() < 1.0 && (la - lat).abs() < 1.0,
                "({lo}, {la}) far from the DEM"
            );
            assert!(z > zmin as f64 - 1.0 && z < zmax as f64 + 1.0);
        }
        match kind {
            "silhouette" => {
                n_sil += 1;
                let px = props["pixels"].as_array().expect("pixels");
                assert_eq!(
                    px.len(),
                    f["geometry"]["coordinates"]
                        .as_array()
                        .map_or(0, |a| a.len())
                );
            }
            "ridge" => n_ridge += 1,
            k => panic!("unexpected kind {k}"),
        }
    }
    assert_eq!(n_sil, sil.curves.len());
    assert_eq!(n_ridge, ridges.lines.len());
}

#[test]
fn vinschgau_view_features_and_geojson() {
    check_view("vinschgau_250m_utm32n.tif", 10.6959, 46.6597, 200.0);
}

#[test]
fn zion_view_features_and_geojson() {
    check_view("zion_srtm_utm12n.tif", -113.0463, 37.3225, 30.0);
}

/// Draw a view with its silhouettes (red) and T-junctions (blue) to
/// `$DEMSKETCH_VIEW_PNG/` (run with `--ignored` to look at them).
#[test]
#[ignore]
fn draw_views() {
    let dir = std::env::var("DEMSKETCH_VIEW_PNG").unwrap_or_else(|_| "/tmp".into());
    for (name, lon, lat, heading) in [
        ("vinschgau_250m_utm32n.tif", 10.6959, 46.6597, 200.0),
        ("zion_srtm_utm12n.tif", -113.0463, 37.3225, 30.0),
    ] {
        let map = read_height_map(&fixture(name)).expect("read fixture");
        let georef = Georef::new(&map, name).expect("georef");
        let frame = georef
            .local_frame(&Viewpoint::above_surface(lon, lat, 1.7), &map, 1.0 / 7.0)
            .expect("viewpoint");
        let terrain = LocalTerrain::new(&map, &frame, None);
        let camera = Camera::new(1600, 900, heading, 2.0, 0.0, 60.0).expect("camera");
        let db = DepthBuffer::render(&terrain, &camera);
        let sil = extract_silhouettes(&terrain, &db, &SilhouetteParams::default()).expect("sil");
        let (w, h) = (db.width, db.height);
        let mut img = vec![0u8; w * h * 3];
        for (i, d) in db.depth.iter().enumerate() {
            let v = if d.is_finite() {
                (255.0 * (1.0 - (*d as f64 / 30_000.0).min(1.0)).powf(0.5)) as u8
            } else {
                0
            };
            let c = if d.is_finite() {
                [v / 2 + 40, v / 2 + 60, v / 3 + 30]
            } else {
                [150, 190, 235]
            };
            img[i * 3..i * 3 + 3].copy_from_slice(&c);
        }
        let mut put = |x: f64, y: f64, c: [u8; 3]| {
            if x >= 0.0 && y >= 0.0 && (x as usize) < w && (y as usize) < h {
                let i = (y as usize * w + x as usize) * 3;
                img[i..i + 3].copy_from_slice(&c);
            }
        };
        for c in &sil.curves {
            for s in c.samples.windows(2) {
                for k in 0..=10 {
                    let t = k as f64 / 10.0;
                    let x = s[0].pixel[0] + t * (s[1].pixel[0] - s[0].pixel[0]);
                    let y = s[0].pixel[1] + t * (s[1].pixel[1] - s[0].pixel[1]);
                    put(x, y, [255, 30, 30]);
                }
            }
        }
        for j in &sil.junctions {
            for dx in -3..=3 {
                for dy in -3..=3 {
                    put(
                        j.pixel[0] + dx as f64,
                        j.pixel[1] + dy as f64,
                        [30, 60, 255],
                    );
                }
            }
        }
        let f = std::fs::File::create(format!("{dir}/view_{name}.png")).expect("png");
        let mut enc = png::Encoder::new(std::io::BufWriter::new(f), w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .expect("header")
            .write_image_data(&img)
            .expect("data");
    }
}
