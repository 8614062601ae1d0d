//! The edit benchmark's case, shared by `benches/edit.rs` and
//! `examples/edit_profile.rs`: the Zion fixture resampled to 512 x 512 with
//! `gdal_translate -outsize` (real terrain, about 70 x 84 m cells) and a
//! sketch of 10 strokes traced from the view's longest silhouettes, each
//! lifted by up to 5 px in its middle (a small change, as a user correcting
//! a skyline would draw).

use demsketch::features::{extract_silhouettes, SilhouetteParams};
use demsketch::raster::Dem;
use demsketch::render::{DepthBuffer, Scene};
use demsketch::view::{Camera, Viewpoint};
use std::path::Path;
use std::process::Command;

const VIEW: (f64, f64, f64) = (-112.90, 37.40, 200.0);
const SIZE: (usize, usize) = (1024, 512);

/// A 512 x 512 DEM and a sketch of 10 strokes in `dir`.
pub fn setup(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/zion_srtm_utm12n.tif");
    let dem_path = dir.join("zion512.tif");
    let st = Command::new("gdal_translate")
        .args(["-q", "-outsize", "512", "512", "-r", "bilinear"])
        .arg(&src)
        .arg(&dem_path)
        .env("GDAL_PAM_ENABLED", "NO")
        .status()
        .expect("run gdal_translate");
    assert!(st.success());
    let dem = Dem::open(&dem_path).unwrap();
    let (lon, lat, heading) = VIEW;
    let camera = Camera::new(SIZE.0, SIZE.1, heading, -1.0, 0.0, 35.0).unwrap();
    let scene = Scene::open(
        &dem,
        &Viewpoint::above_surface(lon, lat, 1.7),
        Some(50_000.0),
        1.0 / 7.0,
    )
    .unwrap();
    let t = std::time::Instant::now();
    let depth = DepthBuffer::render(&scene.terrain, &camera);
    let t_render = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let sil = extract_silhouettes(&scene.terrain, &depth, &SilhouetteParams::default()).unwrap();
    let t_sil = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let ridges = demsketch::features::detect_ridges(&scene.window, &Default::default()).unwrap();
    eprintln!(
        "stage parts: render {t_render:.3} s, silhouettes {t_sil:.3} s, ridges {:.3} s ({} lines)",
        t.elapsed().as_secs_f64(),
        ridges.lines.len()
    );
    let mut curves: Vec<_> = sil.curves.iter().filter(|c| c.samples.len() > 30).collect();
    curves.sort_by_key(|c| std::cmp::Reverse(c.samples.len()));
    let strokes: Vec<_> = curves
        .iter()
        .take(10)
        .enumerate()
        .map(|(k, c)| {
            let n = c.samples.len();
            let (a, b) = (n / 5, 4 * n / 5);
            let (x0, x1) = (c.samples[a].pixel[0], c.samples[b - 1].pixel[0]);
            let pts: Vec<[f64; 2]> = c.samples[a..b]
                .iter()
                .step_by(3)
                .map(|s| {
                    let t = (s.pixel[0] - x0) / (x1 - x0).max(1.0);
                    [
                        s.pixel[0],
                        s.pixel[1] - 5.0 * (std::f64::consts::PI * t).sin(),
                    ]
                })
                .collect();
            serde_json::json!({"id": format!("s{k}"), "points": pts})
        })
        .collect();
    let sketch = serde_json::json!({
        "views": [{
            "name": "bench",
            "viewpoint": {"lon": lon, "lat": lat},
            "camera": {"heading_deg": heading, "pitch_deg": -1.0, "hfov_deg": 35.0,
                       "width": SIZE.0, "height": SIZE.1},
            "strokes": strokes
        }],
        "options": {"influence_m": 1500.0}
    });
    let sk = dir.join("sketch.json");
    std::fs::write(&sk, serde_json::to_string(&sketch).unwrap()).unwrap();
    (dem_path, sk)
}
