//! Silhouettes on synthetic terrains with known answers: a cone behind a
//! ridge, two overlapping hills, a hill behind a hill. The analytic outline of
//! each object in image column `x` is the largest elevation angle of its
//! surface along the column's azimuth (the view is level, so a column is a
//! vertical plane); detected silhouettes and T-junctions must match these
//! within 1 px.

use demsketch::features::{extract_silhouettes, SilhouetteParams, Silhouettes};
use demsketch::raster::{Crs, GeoTransform, HeightMap};
use demsketch::render::{DepthBuffer, LocalTerrain};
use demsketch::view::{Camera, CameraModel, Curvature, LocalFrame};

const CELL: f64 = 2.0;
const N: usize = 1000; // 2 km x 2 km
const EYE: (f64, f64, f64) = (1000.0, 100.0, 30.0);
const W: usize = 800;
const H: usize = 400;
const HFOV: f64 = 50.0;

/// A bump of height `h` and radius `r` at `(cx, cy)`; `cone` for a linear profile.
#[derive(Clone, Copy)]
enum Shape {
    Hill {
        cx: f64,
        cy: f64,
        r: f64,
        h: f64,
    },
    Cone {
        cx: f64,
        cy: f64,
        r: f64,
        h: f64,
    },
    /// East-west ridge at northing `cy`, Gaussian profile of `sigma` metres.
    Ridge {
        cy: f64,
        sigma: f64,
        h: f64,
    },
}

impl Shape {
    fn height(&self, x: f64, y: f64) -> f64 {
        match *self {
            Shape::Hill { cx, cy, r, h } => {
                let q = ((x - cx).powi(2) + (y - cy).powi(2)) / (r * r);
                if q < 1.0 {
                    h * (1.0 - q).powi(2)
                } else {
                    0.0
                }
            }
            Shape::Cone { cx, cy, r, h } => {
                let d = (x - cx).hypot(y - cy);
                (h * (1.0 - d / r)).max(0.0)
            }
            Shape::Ridge { cy, sigma, h } => h * (-(y - cy).powi(2) / (2.0 * sigma * sigma)).exp(),
        }
    }
    fn support(&self, x: f64, y: f64) -> bool {
        match *self {
            Shape::Hill { cx, cy, r, .. } | Shape::Cone { cx, cy, r, .. } => {
                (x - cx).hypot(y - cy) < r
            }
            Shape::Ridge { cy, sigma, .. } => (y - cy).abs() < 4.0 * sigma,
        }
    }
}

struct Scene {
    shapes: Vec<Shape>,
    map: HeightMap,
    terrain: LocalTerrain,
    camera: Camera,
    sil: Silhouettes,
}

fn scene(shapes: Vec<Shape>) -> Scene {
    let mut data = Vec::with_capacity(N * N);
    for r in 0..N {
        for c in 0..N {
            let (x, y) = (CELL * (c as f64 + 0.5), CELL * (N as f64 - r as f64 - 0.5));
            data.push(shapes.iter().map(|s| s.height(x, y)).sum::<f64>() as f32);
        }
    }
    let map = HeightMap {
        width: N,
        height: N,
        data,
        geotransform: GeoTransform::north_up(0.0, CELL * N as f64, CELL, CELL),
        crs: Crs {
            epsg: None,
            wkt: String::new(),
            proj: None,
            geographic: false,
        },
    };
    let frame = LocalFrame::planar(&map, (EYE.0, EYE.1), EYE.2, Curvature::flat());
    let terrain = LocalTerrain::new(&map, &frame, None);
    let camera = Camera::new(W, H, 0.0, 0.0, 0.0, HFOV).expect("camera");
    let db = DepthBuffer::render(&terrain, &camera);
    let sil =
        extract_silhouettes(&terrain, &db, &SilhouetteParams::default()).expect("silhouettes");
    Scene {
        shapes,
        map,
        terrain,
        camera,
        sil,
    }
}

impl Scene {
    fn height(&self, x: f64, y: f64) -> f64 {
        self.shapes.iter().map(|s| s.height(x, y)).sum()
    }

    /// Marches column `x`'s azimuth; returns (max tan elevation, distance)
    /// over the points accepted by `keep`, and whether the maximum lies
    /// strictly inside (a tangent: an occluding contour) rather than at the
    /// last accepted point.
    fn march(&self, x: usize, keep: &dyn Fn(f64, f64) -> bool) -> Option<(f64, f64, bool)> {
        let f = self.camera.focal_px;
        let u = x as f64 + 0.5 - W as f64 / 2.0;
        let l = (f * f + u * u).sqrt();
        let (dx, dy) = (u / l, f / l);
        let (lo, hi) = (CELL * 0.5, CELL * (N as f64 - 0.5));
        let mut best: Option<(f64, f64)> = None;
        let mut last_s = 0.0;
        let mut s = 1.0;
        loop {
            let (px, py) = (EYE.0 + dx * s, EYE.1 + dy * s);
            if px < lo || px > hi || py < lo || py > hi {
                break;
            }
            if keep(px, py) {
                let t = (self.height(px, py) - EYE.2) / s;
                if best.is_none_or(|b| t > b.0) {
                    best = Some((t, s));
                }
                last_s = s;
            }
            s += 0.25;
        }
        best.map(|(t, s)| (t, s, s < last_s - 1.0))
    }

    fn y_of(&self, x: usize, tan: f64) -> f64 {
        let f = self.camera.focal_px;
        let u = x as f64 + 0.5 - W as f64 / 2.0;
        H as f64 / 2.0 - tan * (f * f + u * u).sqrt()
    }

    /// Analytic skyline row of column `x`.
    fn skyline(&self, x: usize) -> Option<f64> {
        self.march(x, &|_, _| true).map(|(t, _, _)| self.y_of(x, t))
    }

    /// Analytic occluding contour of shape `k` in column `x`: (row, distance).
    fn outline(&self, k: usize, x: usize) -> Option<(f64, f64)> {
        let s = self.shapes[k];
        match self.march(x, &|px, py| s.support(px, py)) {
            Some((t, d, true)) => Some((self.y_of(x, t), d)),
            _ => None,
        }
    }

    /// Analytic horizon (the DEM's far border, seen over flat ground).
    fn border(&self, x: usize) -> (f64, f64) {
        let f = self.camera.focal_px;
        let u = x as f64 + 0.5 - W as f64 / 2.0;
        let l = (f * f + u * u).sqrt();
        let (dx, dy) = (u / l, f / l);
        let hi = CELL * (N as f64 - 0.5);
        let lo = CELL * 0.5;
        let mut s = (hi - EYE.1) / dy;
        if dx > 0.0 {
            s = s.min((hi - EYE.0) / dx);
        } else if dx < 0.0 {
            s = s.min((lo - EYE.0) / dx);
        }
        (self.y_of(x, -EYE.2 / s), s)
    }

    /// All detected samples of column `x`: (row, depth, curve id).
    fn detected(&self, x: usize) -> Vec<(f64, f64, u32)> {
        self.sil
            .curves
            .iter()
            .flat_map(|c| c.samples.iter().map(move |s| (s, c.id)))
            .filter(|(s, _)| s.pixel[0] as usize == x)
            .map(|(s, id)| (s.pixel[1], s.depth, id))
            .collect()
    }

    /// Every column's skyline is detected within 1 px.
    fn check_skyline(&self) {
        let mut worst = 0.0f64;
        for x in 0..W {
            let want = self.skyline(x).expect("terrain in every column");
            let got = self
                .sil
                .skyline_at(x)
                .unwrap_or_else(|| panic!("no skyline in column {x}"));
            let e = (got.pixel[1] - want).abs();
            worst = worst.max(e);
            assert!(
                e <= 1.0,
                "column {x}: skyline at {} instead of {want}",
                got.pixel[1]
            );
        }
        eprintln!("skyline: worst error {worst:.3} px over {W} columns");
    }

    /// Where shape `k`'s outline is visible in front of farther terrain
    /// (not the skyline), it is detected within 1 px; returns columns checked.
    fn check_outline(&self, k: usize) -> usize {
        let mut checked = 0;
        let mut worst = 0.0f64;
        for x in 0..W {
            let Some((y, d)) = self.outline(k, x) else {
                continue;
            };
            // visible: nothing nearer covers it (skyline of everything nearer is lower)
            let covered = (0..self.shapes.len()).any(|j| {
                j != k
                    && self
                        .outline(j, x)
                        .is_some_and(|(yj, dj)| dj < d && yj < y + 2.0)
            });
            let sky = self.skyline(x).expect("skyline");
            let (yb, _) = self.border(x);
            if covered || (y - sky).abs() < 2.0 || y > yb - 2.0 {
                continue;
            }
            let best = self
                .detected(x)
                .iter()
                .map(|s| (s.0 - y).abs())
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(best);
            assert!(
                best <= 1.0,
                "shape {k} column {x}: outline at {y}, nearest detection {best} px away"
            );
            checked += 1;
        }
        eprintln!("shape {k}: {checked} occluding columns, worst error {worst:.3} px");
        checked
    }

    /// The analytic T-junction where far outline `far` passes behind near
    /// outline `near` (None for the horizon): detected within 1 px, with the
    /// right occluder.
    fn check_junctions(&self, near: usize, far: Option<usize>) -> usize {
        let yf = |x: usize| match far {
            Some(k) => self.outline(k, x).map(|v| v.0),
            None => Some(self.border(x).0),
        };
        let mut found = 0;
        let mut prev: Option<(usize, f64)> = None;
        for x in 0..W {
            let (Some((yn, _)), Some(yfar)) = (self.outline(near, x), yf(x)) else {
                prev = None;
                continue;
            };
            let diff = yn - yfar; // > 0: far outline above (visible)
                                  // the far outline must not be hidden by a third, nearer shape
            let dfar = match far {
                Some(k) => self.outline(k, x).map(|v| v.1).unwrap_or(f64::INFINITY),
                None => self.border(x).1,
            };
            let hidden = (0..self.shapes.len()).any(|j| {
                j != near
                    && Some(j) != far
                    && self
                        .outline(j, x)
                        .is_some_and(|(yj, dj)| dj < dfar && yj < yfar + 1.0)
            });
            if hidden {
                prev = None;
                continue;
            }
            if let Some((px, pd)) = prev {
                if (pd > 0.0) != (diff > 0.0) {
                    let t = pd / (pd - diff);
                    let jx = px as f64 + 0.5 + t;
                    let jy = {
                        let a = self.outline(near, px).map(|v| v.0).unwrap_or(yn);
                        a + t * (yn - a)
                    };
                    let best = self
                        .sil
                        .junctions
                        .iter()
                        .map(|j| ((j.pixel[0] - jx).hypot(j.pixel[1] - jy), j))
                        .min_by(|a, b| a.0.total_cmp(&b.0));
                    let (dist, j) =
                        best.unwrap_or_else(|| panic!("no junction at all, expected ({jx}, {jy})"));
                    assert!(
                        dist <= 1.0,
                        "junction expected at ({jx:.2}, {jy:.2}), nearest {:?} at {dist:.2} px",
                        j
                    );
                    let occ = &self.sil.curves[j.occluder as usize];
                    let occd = &self.sil.curves[j.occluded as usize];
                    assert!(occ.samples[0].depth < occd.samples[0].depth);
                    eprintln!(
                        "junction ({jx:.2}, {jy:.2}) found at {:?}, {dist:.3} px",
                        j.pixel
                    );
                    found += 1;
                }
            }
            prev = Some((x, diff));
        }
        found
    }

    /// Samples are where they say: their 3D point projects onto their pixel
    /// and lies on the terrain.
    fn check_samples(&self) {
        for c in &self.sil.curves {
            assert!(
                c.samples.windows(2).all(|w| w[0].pixel[0] < w[1].pixel[0]),
                "not ordered along x"
            );
            for s in &c.samples {
                let p = self.camera.project(s.local).expect("in front");
                assert!((p[0] - s.pixel[0]).abs() < 0.01 && (p[1] - s.pixel[1]).abs() < 0.01);
                let z = self.height(s.world[0], s.world[1]);
                assert!(
                    (s.world[2] - z).abs() < 0.6,
                    "sample z {} vs terrain {z}",
                    s.world[2]
                );
                let (d, _) = (s.local[0].hypot(s.local[1]).hypot(s.local[2]), 0);
                assert!((d - s.depth).abs() < 1e-6 * d.max(1.0));
                let (col, row) = (s.cell[0] as usize, s.cell[1] as usize);
                assert!(col < self.map.width && row < self.map.height);
            }
        }
        let _ = &self.terrain;
    }
}

#[test]
fn cone_behind_a_ridge() {
    let s = scene(vec![
        Shape::Ridge {
            cy: 700.0,
            sigma: 40.0,
            h: 60.0,
        },
        Shape::Cone {
            cx: 1101.0,
            cy: 1301.0,
            r: 300.0,
            h: 160.0,
        },
    ]);
    s.check_samples();
    s.check_skyline();
    assert!(s.check_outline(0) > 100, "ridge in front of the cone");
    assert_eq!(
        s.check_junctions(0, Some(1)),
        2,
        "two T-junctions where the cone's flanks pass behind the ridge"
    );
}

#[test]
fn two_overlapping_hills() {
    let s = scene(vec![
        Shape::Hill {
            cx: 941.0,
            cy: 1001.0,
            r: 200.0,
            h: 120.0,
        },
        Shape::Hill {
            cx: 1161.0,
            cy: 1501.0,
            r: 300.0,
            h: 200.0,
        },
    ]);
    s.check_samples();
    s.check_skyline();
    assert!(s.check_outline(0) > 5);
    assert_eq!(
        s.check_junctions(0, Some(1)),
        1,
        "the far hill's flank passes behind the near one"
    );
    // both hills hide the horizon on their outer flanks
    assert!(s.check_junctions(0, None) + s.check_junctions(1, None) >= 2);
}

#[test]
fn hill_behind_a_hill_forms_t_junctions() {
    let s = scene(vec![
        Shape::Hill {
            cx: 1001.0,
            cy: 801.0,
            r: 260.0,
            h: 110.0,
        },
        Shape::Hill {
            cx: 1001.0,
            cy: 1501.0,
            r: 400.0,
            h: 300.0,
        },
    ]);
    s.check_samples();
    s.check_skyline();
    assert!(s.check_outline(0) > 50);
    assert_eq!(s.check_junctions(0, Some(1)), 2);
}
