//! Interim stand-in for `sketch::view_input` (branch `sketch`): the bridge
//! from a rendered view (camera, local terrain, silhouettes, ridge network)
//! to what matching consumes ([`ViewFeature`]s and a [`ViewProjection`]).
//! Replaced by the sketch module's bridge as soon as that branch lands.

use crate::features::{RidgeNetwork, Silhouettes};
use crate::render::LocalTerrain;
use crate::sketch::{FeatureKind, FeatureSample, ViewFeature, ViewProjection};
use crate::view::{Camera, CameraModel, LocalFrame};

/// [`ViewProjection`] of a real view: the pinhole [`Camera`] in the
/// viewpoint's local frame (eye at the origin) over its [`LocalTerrain`].
pub struct CameraProjection<'a> {
    pub camera: Camera,
    pub terrain: &'a LocalTerrain,
}

impl ViewProjection for CameraProjection<'_> {
    fn project(&self, p: [f64; 3]) -> Option<([f64; 2], f64)> {
        let px = self.camera.project(p)?;
        Some((px, (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()))
    }

    fn unproject(&self, pixel: [f64; 2], depth: f64) -> [f64; 3] {
        let d = self.camera.unproject(pixel);
        [d[0] * depth, d[1] * depth, d[2] * depth]
    }

    fn eye(&self) -> [f64; 3] {
        [0.0, 0.0, 0.0]
    }

    fn image_size(&self) -> (u32, u32) {
        (self.camera.width as u32, self.camera.height as u32)
    }

    fn focal_px(&self) -> f64 {
        self.camera.focal_px
    }

    fn terrain_height(&self, x: f64, y: f64) -> Option<f64> {
        terrain_height(self.terrain, x, y)
    }
}

/// Apparent height of the triangulated terrain at local `(east, north)`.
pub fn terrain_height(t: &LocalTerrain, e: f64, n: f64) -> Option<f64> {
    let (vx, vy) = t.en_to_v(e, n);
    if !(vx >= 0.0 && vy >= 0.0) {
        return None;
    }
    let (c, r) = (vx.floor() as usize, vy.floor() as usize);
    let (fx, fy) = (vx - c as f64, vy - r as f64);
    let c1 = if fx > 0.0 { c + 1 } else { c };
    let r1 = if fy > 0.0 { r + 1 } else { r };
    let z00 = t.vertex_z(c, r)?;
    let z11 = t.vertex_z(c1, r1)?;
    if fx >= fy {
        let z10 = t.vertex_z(c1, r)?;
        Some(z00 + fx * (z10 - z00) + fy * (z11 - z10))
    } else {
        let z01 = t.vertex_z(c, r1)?;
        Some(z00 + fy * (z01 - z00) + fx * (z11 - z01))
    }
}

/// The features of a view for matching: every silhouette polyline, and
/// every ridge line projected into the view, split into x-monotone pieces
/// inside the image. Ids start at `first_id` and are unique.
pub fn view_features(
    silhouettes: &Silhouettes,
    ridges: &RidgeNetwork,
    frame: &LocalFrame,
    camera: &Camera,
    first_id: usize,
) -> Vec<ViewFeature> {
    let mut out = Vec::new();
    let mut id = first_id;
    for s in &silhouettes.curves {
        let samples: Vec<FeatureSample> = s
            .samples
            .iter()
            .map(|p| FeatureSample {
                pixel: p.pixel,
                depth: p.depth,
                world: p.local,
            })
            .collect();
        if samples.len() >= 2 {
            out.push(ViewFeature {
                id,
                kind: FeatureKind::Silhouette,
                samples,
            });
            id += 1;
        }
    }
    let (w, h) = (camera.width as f64, camera.height as f64);
    for line in &ridges.lines {
        let mut piece: Vec<FeatureSample> = Vec::new();
        let mut dir = 0.0f64;
        let mut flush = |piece: &mut Vec<FeatureSample>, out: &mut Vec<ViewFeature>| {
            if piece.len() >= 2 {
                if piece[0].pixel[0] > piece[piece.len() - 1].pixel[0] {
                    piece.reverse();
                }
                out.push(ViewFeature {
                    id,
                    kind: FeatureKind::Ridge,
                    samples: std::mem::take(piece),
                });
                id += 1;
            } else {
                piece.clear();
            }
        };
        for p in &line.points {
            let local = frame.crs_to_local(p[0], p[1], p[2]);
            let proj = camera
                .project(local)
                .filter(|q| q[0] >= 0.0 && q[0] <= w && q[1] >= -h && q[1] <= 2.0 * h);
            let Some(q) = proj else {
                flush(&mut piece, &mut out);
                dir = 0.0;
                continue;
            };
            let sample = FeatureSample {
                pixel: q,
                depth: (local[0] * local[0] + local[1] * local[1] + local[2] * local[2]).sqrt(),
                world: local,
            };
            if let Some(last) = piece.last() {
                let dx = q[0] - last.pixel[0];
                if dx == 0.0 {
                    continue;
                }
                if dir != 0.0 && dx.signum() != dir {
                    let last = *last;
                    flush(&mut piece, &mut out);
                    piece.push(last);
                    dir = dx.signum();
                } else if dir == 0.0 {
                    dir = dx.signum();
                }
            }
            piece.push(sample);
        }
        flush(&mut piece, &mut out);
    }
    out
}
