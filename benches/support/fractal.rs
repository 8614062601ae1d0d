//! The synthetic DEM of the feature benchmarks (deterministic multi-octave
//! value noise on a 30 m grid in UTM 32N) and their viewpoint, shared by
//! `benches/features.rs`, `examples/features_profile.rs` and
//! `examples/ridges_timing.rs`.

// Each includer uses only some of the generators.
#![allow(dead_code)]

use demsketch::raster::{Crs, GeoTransform, HeightMap};
use demsketch::view::{Camera, Curvature, LocalFrame};

/// The benchmarks' view of the `n` x `n` fractal DEM `map`: the eye 1.7 m
/// above the ground a quarter of the way up from the south edge, looking
/// north across the DEM (heading 10, pitch 1 degree, hfov 60), in a `vw` x
/// `vh` image.
pub fn bench_view(map: &HeightMap, n: usize, vw: usize, vh: usize) -> (LocalFrame, Camera) {
    let (ex, ey) = (500_000.0 + 15.0 * n as f64, 4_000_000.0 + 7.5 * n as f64);
    let (px, py) = map.geotransform.crs_to_pixel(ex, ey).unwrap_or((0.0, 0.0));
    let ground = map.bilinear(px, py).unwrap_or(0.0);
    let frame = LocalFrame::planar(
        map,
        (ex, ey),
        ground + 1.7,
        Curvature::at_latitude(46.0, 1.0 / 7.0),
    );
    let camera = Camera::new(vw, vh, 10.0, 1.0, 0.0, 60.0).expect("camera");
    (frame, camera)
}

/// Deterministic multi-octave value noise, mountains of ~1500 m relief.
pub fn fractal(n: usize) -> HeightMap {
    fractal_rect(n, n)
}

/// The same noise on a `w` x `h` grid.
pub fn fractal_rect(w: usize, h: usize) -> HeightMap {
    fn hash(x: i64, y: i64, o: u64) -> f64 {
        let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ o.wrapping_mul(0x1656_67B1_9E37_79F9);
        h ^= h >> 29;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 32;
        (h >> 11) as f64 / (1u64 << 53) as f64
    }
    fn noise(x: f64, y: f64, o: u64) -> f64 {
        let (xi, yi) = (x.floor(), y.floor());
        let (fx, fy) = (x - xi, y - yi);
        let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
        let (xi, yi) = (xi as i64, yi as i64);
        let a = hash(xi, yi, o) + sx * (hash(xi + 1, yi, o) - hash(xi, yi, o));
        let b = hash(xi, yi + 1, o) + sx * (hash(xi + 1, yi + 1, o) - hash(xi, yi + 1, o));
        a + sy * (b - a)
    }
    let mut data = vec![0f32; w * h];
    use rayon::prelude::*;
    data.par_chunks_mut(w).enumerate().for_each(|(r, row)| {
        for (c, v) in row.iter_mut().enumerate() {
            // features ~ 9 km at the coarsest octave, whatever the DEM size
            let (x, y) = (c as f64 / 300.0, r as f64 / 300.0);
            let mut z = 0.0;
            let mut amp = 1000.0;
            let mut f = 1.0;
            for o in 0..7 {
                z += amp * noise(x * f, y * f, o);
                amp *= 0.5;
                f *= 2.0;
            }
            *v = z as f32;
        }
    });
    HeightMap {
        width: w,
        height: h,
        data,
        geotransform: GeoTransform::north_up(500_000.0, 4_000_000.0 + 30.0 * h as f64, 30.0, 30.0),
        crs: Crs {
            epsg: Some(32632),
            wkt: String::new(),
            proj: None,
            geographic: false,
        },
    }
}
