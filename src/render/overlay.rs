//! Drawing 3D terrain curves over a rendered view: a curve given in the DEM's
//! CRS (x, y, true height), such as a ridge line, is projected into the
//! camera and only the parts that the eye actually sees are kept, by
//! comparing each vertex's distance with the depth buffer around its pixel.
//! `demsketch view --overlay ridges` uses this to draw the ridge network on
//! the picture; silhouettes need no test (they are visible by construction).

use super::depth_buffer::DepthBuffer;
use super::terrain::LocalTerrain;
use crate::view::CameraModel;

/// Parts of the 3D polyline `points` (CRS `[x, y, z]`, z the true height)
/// visible in the view `depth` rendered over `terrain`, as image polylines
/// (pixel coordinates). A vertex counts as visible when the terrain seen in
/// the 3 x 3 pixels around its projection is not nearer than the vertex by
/// more than `tolerance_m` plus 2 % of its distance (the curve lies on the
/// surface, up to smoothing and one cell of discretisation). Vertices behind
/// the camera or outside the image split the curve.
pub fn visible_polylines(
    terrain: &LocalTerrain,
    depth: &DepthBuffer,
    points: &[[f64; 3]],
    tolerance_m: f64,
) -> Vec<Vec<[f64; 2]>> {
    let frame = &terrain.frame;
    let cam = &depth.camera;
    let (w, h) = (depth.width as f64, depth.height as f64);
    let mut out = Vec::new();
    let mut cur: Vec<[f64; 2]> = Vec::new();
    for p in points {
        let local = frame.crs_to_local(p[0], p[1], p[2]);
        let dist = (local[0] * local[0] + local[1] * local[1] + local[2] * local[2]).sqrt();
        let seen = cam.project(local).filter(|q| {
            q[0] >= 0.0 && q[1] >= 0.0 && q[0] < w && q[1] < h && {
                let (i, j) = (q[0] as usize, q[1] as usize);
                let mut far = 0f32;
                for jj in j.saturating_sub(1)..=(j + 1) {
                    for ii in i.saturating_sub(1)..=(i + 1) {
                        far = far.max(depth.depth_at(ii, jj));
                    }
                }
                far as f64 >= dist - tolerance_m - 0.02 * dist
            }
        });
        match seen {
            Some(q) => cur.push(q),
            None => {
                if cur.len() >= 2 {
                    out.push(std::mem::take(&mut cur));
                } else {
                    cur.clear();
                }
            }
        }
    }
    if cur.len() >= 2 {
        out.push(cur);
    }
    out
}
