//! View silhouettes: the visible occlusion boundaries of the terrain seen from
//! a viewpoint (section 5.1 of Tassé et al.), i.e. the skyline and every depth
//! discontinuity, where the visible surface passes from a front-facing to a
//! back-facing triangle of the height-field mesh and the view continues onto
//! terrain farther away (or the sky).
//!
//! The extractor works on a rendered [`DepthBuffer`] and the exact
//! [`LocalTerrain`] it was rendered from:
//!
//! 1. Every image column is scanned for pixel pairs where the upper pixel is
//!    much farther than a continuation of the surface below it would be
//!    (inverse camera depth is affine on planar triangles, so a continuous
//!    surface is extrapolated exactly and only real jumps and strong creases
//!    remain as candidates).
//! 2. Each candidate is refined exactly on the column's centre line: the
//!    plane of the column's rays cuts the terrain in a polyline, walked
//!    triangle by triangle from the point the near pixel shows until it
//!    stops rising as seen from the eye (the front-facing/back-facing edge):
//!    the grazing ray there gives the silhouette's sub-pixel position and
//!    the 3D terrain point that forms it; a polyline that rises to the far
//!    pixel's ray is a crease and is rejected. Where the walk is numerically
//!    inconclusive, bisection with exact ray casts takes over; a bracket
//!    whose depth gap closes is a crease and is left at once.
//! 3. Samples of neighbouring columns are linked into polylines ordered along
//!    image x when their depths agree and the pixels between them belong to
//!    the occluding surface.
//! 4. Where a polyline ends against a nearer one it disappears behind it: a
//!    T-junction, recorded with which silhouette occludes which.
//!
//! Samples carry pixel, depth, local-frame point, CRS point and DEM cell, so
//! the sketch matcher can use them directly (see [`SilhouetteSample`]).

use rayon::prelude::*;

use super::FeatureError;
use crate::render::{DepthBuffer, LocalTerrain};
use crate::view::{cross, dot, CameraModel};

/// The triangle walk of [`walk_to_contour`] stands in for the bilinear
/// surface where the two can put a boundary at most this far apart
/// (pixels); elsewhere boundaries are bisected with exact casts. (On the
/// fidelity suite 0.05 px fitted 38 of 72 known changes against 35 at
/// 0.25 px, identity alike, at five times the extraction's time.)
pub const WALK_TOLERANCE_PX: f64 = 0.25;

/// Parameters of silhouette extraction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilhouetteParams {
    /// Relative depth gap left after refinement for a boundary to count as an
    /// occlusion (0.005: the far side is at least 0.5 % farther).
    pub min_jump: f64,
    /// Pre-filter: relative shortfall of the upper pixel's inverse depth
    /// below the linear continuation of the two pixels under it.
    pub prefilter: f64,
    /// Bisection steps per candidate in the fallback refinement by ray
    /// casting (each step halves the bracket, from one pixel).
    pub refine_iterations: u32,
    /// Samples in neighbouring columns are linked when their depths differ by
    /// less than this fraction.
    pub link_depth: f64,
    /// ... and their rows by at most this many pixels.
    pub max_link_dy: f64,
    /// A polyline end is a T-junction when a nearer silhouette passes within
    /// this many pixels.
    pub junction_radius_px: f64,
    /// Polylines with fewer samples are dropped.
    pub min_samples: usize,
}

impl Default for SilhouetteParams {
    fn default() -> Self {
        SilhouetteParams {
            min_jump: 0.005,
            prefilter: 0.01,
            refine_iterations: 10,
            link_depth: 0.08,
            max_link_dy: 48.0,
            junction_radius_px: 3.0,
            min_samples: 2,
        }
    }
}

/// One point of a silhouette: where, in the image and on the terrain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SilhouetteSample {
    /// Image position (pixel coordinates, x on the column centre).
    pub pixel: [f64; 2],
    /// Distance from the eye to the terrain point, metres.
    pub depth: f64,
    /// The terrain point forming the silhouette in the viewpoint's local frame
    /// (ENU metres at the eye, apparent height).
    pub local: [f64; 3],
    /// The same point in the DEM's CRS with its true height: `[x, y, z]`.
    pub world: [f64; 3],
    /// DEM cell `(col, row)` of the triangle the point lies on.
    pub cell: [u32; 2],
    /// Distance to what is seen just beyond the silhouette (infinite: sky).
    pub depth_behind: f64,
}

/// A silhouette polyline, ordered by increasing image x.
#[derive(Debug, Clone, PartialEq)]
pub struct Silhouette {
    pub id: u32,
    pub samples: Vec<SilhouetteSample>,
    /// True when most of it has sky behind it (part of the skyline).
    pub skyline: bool,
}

impl Silhouette {
    /// 3D length in metres of the terrain curve (CRS coordinates; horizontal
    /// units must be metres, i.e. a projected CRS; for geographic DEMs use the
    /// local-frame length [`Silhouette::local_length_m`]).
    pub fn local_length_m(&self) -> f64 {
        self.samples
            .windows(2)
            .map(|w| {
                let (a, b) = (w[0].local, w[1].local);
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
            })
            .sum()
    }

    /// Length of the image polyline in pixels.
    pub fn pixel_length(&self) -> f64 {
        self.samples
            .windows(2)
            .map(|w| (w[0].pixel[0] - w[1].pixel[0]).hypot(w[0].pixel[1] - w[1].pixel[1]))
            .sum()
    }

    /// The image polyline.
    pub fn pixels(&self) -> Vec<[f64; 2]> {
        self.samples.iter().map(|s| s.pixel).collect()
    }
}

/// Which end of a silhouette a junction is at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CurveEnd {
    /// The first (leftmost) sample.
    Start,
    /// The last (rightmost) sample.
    End,
}

/// A T-junction: silhouette `occluded` ends where it passes behind the nearer
/// silhouette `occluder`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TJunction {
    /// Image position of the junction (on the occluder's polyline).
    pub pixel: [f64; 2],
    pub occluded: u32,
    pub occluder: u32,
    pub end: CurveEnd,
}

/// The silhouettes of one view.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Silhouettes {
    pub curves: Vec<Silhouette>,
    pub junctions: Vec<TJunction>,
}

impl Silhouettes {
    /// Total number of samples.
    pub fn sample_count(&self) -> usize {
        self.curves.iter().map(|c| c.samples.len()).sum()
    }

    /// The topmost silhouette sample of image column `x` (the skyline there),
    /// if any.
    pub fn skyline_at(&self, x: usize) -> Option<&SilhouetteSample> {
        self.curves
            .iter()
            .flat_map(|c| c.samples.iter())
            .filter(|s| s.pixel[0] as usize == x)
            .min_by(|a, b| a.pixel[1].total_cmp(&b.pixel[1]))
    }
}

/// Extract the silhouettes of the view `depth` rendered from `terrain`.
pub fn extract_silhouettes(
    terrain: &LocalTerrain,
    depth: &DepthBuffer,
    params: &SilhouetteParams,
) -> Result<Silhouettes, FeatureError> {
    extract_silhouettes_where(terrain, depth, params, &|_, _, _| true)
}

/// Like [`extract_silhouettes`], refining only the candidates for which
/// `wanted(x, y, near)` holds: an occlusion boundary between rows `y - 1`
/// and `y` of image column `x`, whose near side (row `y`) lies `near`
/// metres away. The samples found are exactly those of the whole
/// extraction there; curves are linked from them alone.
pub fn extract_silhouettes_where(
    terrain: &LocalTerrain,
    depth: &DepthBuffer,
    params: &SilhouetteParams,
    wanted: &(dyn Fn(usize, usize, f32) -> bool + Sync),
) -> Result<Silhouettes, FeatureError> {
    extract_silhouettes_reusing(terrain, depth, params, wanted, None).map(|(s, _)| s)
}

/// The samples of an extraction column by column, before they are linked
/// into curves, kept so that an extraction of the same view on a terrain
/// changed out of some columns' reach can take those columns as they are
/// ([`extract_silhouettes_reusing`]).
#[derive(Debug, Clone, Default)]
pub struct ColumnSamples {
    /// Per image column, its samples (sorted by row).
    pub samples: Vec<Vec<SilhouetteSample>>,
    /// Per image column, beside each sample: the candidate it was refined
    /// from (the row `y` of the near pixel of the boundary between rows
    /// `y - 1` and `y`).
    pub candidates: Vec<Vec<u32>>,
    /// Per image column: every ray its refinement followed, and every
    /// point its walks along the terrain went through, lies within the
    /// rows of [`reach_rows`] (so the cells it read lie under those rows).
    pub confined: Vec<bool>,
}

/// What an extraction takes from an earlier one of the same view instead
/// of refining it ([`extract_silhouettes_reusing`]).
#[derive(Clone, Copy)]
pub enum Reuse<'a> {
    /// The whole columns `x` for which the function holds: the caller
    /// vouches that the extraction would find them again (the same depth
    /// buffer column, the same `wanted`, a terrain unchanged where the
    /// column's refinement reads it; see [`ColumnSamples`]).
    Columns(&'a ColumnSamples, &'a (dyn Fn(usize) -> bool + Sync)),
    /// The candidates `(x, y, near)` for which the function holds (see
    /// [`extract_silhouettes_where`]'s `wanted`): the earlier extraction
    /// refined them on the same terrain (to the bit) from the same depths
    /// and triangles in rows `y - 1 ..= y + 1` of column `x`, so refining
    /// them again gives their samples again. A candidate's refinement
    /// reads nothing else: the terrain, those three pixels (the candidate
    /// test) and the two it brackets. A column with a candidate taken is
    /// [`ColumnSamples::confined`] only where the earlier one was.
    Candidates(
        &'a ColumnSamples,
        &'a (dyn Fn(usize, usize, f32) -> bool + Sync),
    ),
}

/// The image rows (a range of row coordinates, beyond the image on both
/// sides) within which a column's refinement reads the terrain when its
/// [`ColumnSamples::confined`] flag is set: `[-height, 2 height]`.
pub fn reach_rows(height: usize) -> (f64, f64) {
    (-(height as f64), 2.0 * height as f64)
}

/// [`extract_silhouettes_where`], also returning the samples column by
/// column. With `reuse`, what it names (whole columns, or single
/// candidates) is taken from an earlier extraction instead of being
/// refined (see [`Reuse`]); the result is the same.
pub fn extract_silhouettes_reusing(
    terrain: &LocalTerrain,
    depth: &DepthBuffer,
    params: &SilhouetteParams,
    wanted: &(dyn Fn(usize, usize, f32) -> bool + Sync),
    reuse: Option<Reuse>,
) -> Result<(Silhouettes, ColumnSamples), FeatureError> {
    let (w, h) = (depth.width, depth.height);
    if depth.depth.len() != w * h || depth.triangle.len() != w * h {
        return Err(FeatureError::InvalidInput(format!(
            "depth buffer holds {} depths for a {w} x {h} image",
            depth.depth.len()
        )));
    }
    if !(params.min_jump > 0.0 && params.link_depth > 0.0 && params.max_link_dy >= 1.0) {
        return Err(FeatureError::InvalidParameter(
            "silhouette min_jump and link_depth must be > 0 and max_link_dy >= 1".into(),
        ));
    }
    let fits = |e: &ColumnSamples| {
        e.samples.len() == w && e.candidates.len() == w && e.confined.len() == w
    };
    let reuse = reuse.filter(|r| match r {
        Reuse::Columns(e, _) | Reuse::Candidates(e, _) => fits(e),
    });
    let kept = |x: usize| -> Option<Column> {
        let Some(Reuse::Columns(earlier, keep)) = reuse else {
            return None;
        };
        (earlier.confined[x] && keep(x)).then(|| Column {
            samples: earlier.samples[x].clone(),
            candidates: earlier.candidates[x].clone(),
            confined: true,
        })
    };
    let taking = match reuse {
        Some(Reuse::Candidates(earlier, take)) => Some((earlier, take)),
        _ => None,
    };
    // Columns in groups: one pass over the group's rows (contiguous in the
    // row-major buffer) makes each column's depths contiguous.
    let columns: Vec<Column> = (0..w.div_ceil(COLUMN_GROUP))
        .into_par_iter()
        .flat_map_iter(|g| {
            let x0 = g * COLUMN_GROUP;
            let x1 = (x0 + COLUMN_GROUP).min(w);
            let taken: Vec<Option<Column>> = (x0..x1).map(kept).collect();
            let cols = if taken.iter().all(Option::is_some) {
                Vec::new()
            } else {
                column_depths(depth, x0, x1)
            };
            taken
                .into_iter()
                .zip(x0..x1)
                .map(|(taken, x)| {
                    taken.unwrap_or_else(|| {
                        column_samples(
                            terrain,
                            depth,
                            params,
                            x,
                            &cols[(x - x0) * h..][..h],
                            wanted,
                            taking,
                        )
                    })
                })
                .collect::<Vec<_>>()
        })
        .collect();
    let mut samples = Vec::with_capacity(w);
    let mut candidates = Vec::with_capacity(w);
    let mut confined = Vec::with_capacity(w);
    for c in columns {
        samples.push(c.samples);
        candidates.push(c.candidates);
        confined.push(c.confined);
    }
    let (curves, where_) = link(depth, params, &samples);
    let junctions = find_junctions(&curves, &where_, params);
    Ok((
        Silhouettes { curves, junctions },
        ColumnSamples {
            samples,
            candidates,
            confined,
        },
    ))
}

/// One column's part of [`ColumnSamples`].
struct Column {
    samples: Vec<SilhouetteSample>,
    candidates: Vec<u32>,
    confined: bool,
}

/// Image columns handled together by one task.
const COLUMN_GROUP: usize = 16;

/// Column-major `(distance, inverse camera depth)` of image columns
/// `x0..x1` (inverse depth 0 for sky). Inverse camera depth is affine along
/// a planar triangle's image, which is what the candidate pre-filter uses.
fn column_depths(db: &DepthBuffer, x0: usize, x1: usize) -> Vec<(f32, f32)> {
    let (w, h) = (db.width, db.height);
    let f = db.camera.focal_px as f32;
    let n = x1 - x0;
    let u2: Vec<f32> = (x0..x1)
        .map(|x| {
            let u = x as f32 + 0.5 - w as f32 / 2.0;
            u * u + f * f
        })
        .collect();
    let mut out = vec![(f32::INFINITY, 0.0); n * h];
    let mut inv = vec![0f32; n];
    for y in 0..h {
        let v = h as f32 / 2.0 - (y as f32 + 0.5);
        let row = &db.depth[y * w + x0..y * w + x1];
        // camera depth = distance * f / |(u, v, f)|; sky (infinite) gives 0
        for ((o, &d), &uu) in inv.iter_mut().zip(row).zip(&u2) {
            *o = (uu + v * v).sqrt() / (d * f);
        }
        for (k, (&d, &iz)) in row.iter().zip(&inv).enumerate() {
            out[k * h + y] = (d, iz);
        }
    }
    out
}

/// The candidates [`column_samples`] takes from an earlier extraction
/// instead of refining them ([`Reuse::Candidates`]), when there is one.
type Taking<'a> = Option<(
    &'a ColumnSamples,
    &'a (dyn Fn(usize, usize, f32) -> bool + Sync),
)>;

/// Candidates and refined samples of one image column (those `taking`
/// names taken from the earlier extraction instead, see
/// [`Reuse::Candidates`]), and whether its refinement stayed within
/// [`reach_rows`] ([`ColumnSamples::confined`]).
#[allow(clippy::too_many_arguments)]
fn column_samples(
    terrain: &LocalTerrain,
    db: &DepthBuffer,
    p: &SilhouetteParams,
    x: usize,
    col: &[(f32, f32)],
    wanted: &(dyn Fn(usize, usize, f32) -> bool + Sync),
    taking: Taking<'_>,
) -> Column {
    let h = db.height;
    let mut out = Vec::new();
    let mut tags: Vec<u32> = Vec::new();
    let mut confined = true;
    for y in 1..h {
        let (near, wp) = col[y];
        if !near.is_finite() {
            continue;
        }
        let wp = wp as f64;
        let (far, wq) = col[y - 1];
        let wq = wq as f64;
        if far.is_finite() && far as f64 <= near as f64 * (1.0 + p.min_jump) {
            continue;
        }
        if far.is_finite() {
            // Extrapolate from the pixel below only when it shows the same
            // surface: a one-pixel sliver of a range between a nearer
            // ridge and farther terrain has no such neighbour.
            let same_below = y + 1 < h
                && col[y + 1].0.is_finite()
                && near as f64 <= col[y + 1].0 as f64 * (1.0 + p.min_jump);
            let pred = if same_below {
                (2.0 * wp - col[y + 1].1 as f64).min(wp)
            } else {
                wp
            };
            if wq > pred - p.prefilter * wp {
                continue;
            }
        }
        if !wanted(x, y, near) {
            continue;
        }
        match taking.filter(|(_, take)| take(x, y, near)) {
            Some((earlier, _)) => {
                let tag = y as u32;
                for (s, _) in earlier.samples[x]
                    .iter()
                    .zip(&earlier.candidates[x])
                    .filter(|(_, &c)| c == tag)
                {
                    out.push(*s);
                }
                confined &= earlier.confined[x];
            }
            None => refine(terrain, db, p, (x, y), &mut out, &mut confined),
        }
        tags.resize(out.len(), y as u32);
    }
    // Sorted by row as before (a stable sort: the same order), each
    // sample's candidate beside it. The candidates come in row order and
    // their samples mostly do too: a sorted column stays as it is.
    let sorted = out
        .windows(2)
        .all(|p| p[0].pixel[1].total_cmp(&p[1].pixel[1]).is_le());
    if sorted {
        return Column {
            samples: out,
            candidates: tags,
            confined,
        };
    }
    let mut order: Vec<usize> = (0..out.len()).collect();
    order.sort_by(|&a, &b| out[a].pixel[1].total_cmp(&out[b].pixel[1]));
    Column {
        samples: order.iter().map(|&i| out[i]).collect(),
        candidates: order.iter().map(|&i| tags[i]).collect(),
        confined,
    }
}

/// Outcome of following the near surface along a column's plane.
enum Walk {
    /// The occluding contours within the pixel bracket, nearest first:
    /// image row coordinate, local point, triangle.
    Contours(Vec<(f64, [f64; 3], u32)>),
    /// The surface rises continuously to the far pixel's ray: a crease.
    Crease,
    /// Numerically inconclusive (fall back to bisection).
    Inconclusive,
}

/// Longest walk along the near surface, in triangles.
const MAX_WALK: usize = 512;

/// Find the occluding contour above the near pixel `(x, y)` exactly, without
/// casting rays: the rays of image column `x` (through the pixel centres
/// `x + 0.5`) span a plane through the eye; its intersection with the
/// terrain is a polyline, walked triangle by triangle away from the eye from
/// the point the near pixel shows. The contour is the first point where the
/// polyline, seen from the eye, stops rising (a front-facing/back-facing
/// edge) and stays below for a relative depth of `min_jump` behind it
/// (lower bumps within that distance are crossed: they hide nothing of
/// consequence); the grazing ray there is the silhouette's sub-pixel row. A
/// polyline that rises to the far pixel's ray is a crease. This is the limit
/// the bisection of [`refine_bracket`] converges to, at the cost of a few
/// triangle steps. Where farther terrain rises above that contour's ray
/// before the far pixel's hit, a second contour lies within the same pixel
/// (stacked ridges, T-junctions): the contour's ray is cast on from there
/// (skipping the empty space below it with the cast index) and the walk
/// resumes where it meets the terrain.
/// Clears `confined` when a point of the walk lies outside [`reach_rows`]
/// (or behind the camera).
fn walk_to_contour(
    terrain: &LocalTerrain,
    db: &DepthBuffer,
    (x, y): (usize, usize),
    min_jump: f64,
    confined: &mut bool,
) -> Walk {
    let (reach_lo, reach_hi) = reach_rows(db.height);
    let cam = &db.camera;
    let k = y * db.width + x;
    let (tri0, t_a) = (db.triangle[k], db.depth[k] as f64);
    let (w, h, f) = (cam.width as f64, cam.height as f64, cam.focal_px);
    let px = x as f64 + 0.5;
    let u = px - w / 2.0;
    let (fw, rt, up) = (cam.forward, cam.right, cam.up);
    // In-plane outward axis and the plane's normal.
    let a = [
        f * fw[0] + u * rt[0],
        f * fw[1] + u * rt[1],
        f * fw[2] + u * rt[2],
    ];
    let nrm = cross(a, up);
    let row_of = |p: [f64; 3]| -> Option<f64> {
        let z = dot(p, fw);
        (z > 0.0).then(|| h / 2.0 - f * dot(p, up) / z)
    };
    let Some(q0) = ray_point(cam, px, y as f64 + 0.5, t_a) else {
        return Walk::Inconclusive;
    };
    let far_y = y as f64 - 0.5;
    let t_b = db.depth[(y - 1) * db.width + x] as f64;
    // the highest point so far of the rising stretch being followed
    let (mut best_y, mut best, mut best_tri, mut best_d) = (y as f64 + 0.5, q0, tri0, t_a);
    let mut found: Vec<(f64, [f64; 3], u32)> = Vec::new();
    let (cx, cy) = (terrain.cells_x(), terrain.ny.saturating_sub(1));
    // (a far layer's cells are not this grid's: the bisection decides)
    if cx == 0 || tri0 == crate::render::SKY || terrain.is_far_triangle(tri0) {
        return Walk::Inconclusive;
    }
    let cell = (tri0 / 2) as usize;
    let (mut c, mut r, mut half) = (cell % cx, cell / cx, tri0 % 2);
    let mut entry: Option<[(usize, usize); 2]> = None;
    for _ in 0..MAX_WALK {
        let g = if half == 0 {
            [(c, r), (c + 1, r), (c + 1, r + 1)]
        } else {
            [(c, r), (c, r + 1), (c + 1, r + 1)]
        };
        let mut pv = [[0.0; 3]; 3];
        for (i, &(vc, vr)) in g.iter().enumerate() {
            match terrain.vertex_local(vc, vr) {
                Some(p) => pv[i] = p,
                // a hole: the surface ends at the best point so far
                None if entry.is_some() => {
                    found.push((best_y, best, best_tri));
                    return Walk::Contours(found);
                }
                None => return Walk::Inconclusive,
            }
        }
        let sd = [dot(nrm, pv[0]), dot(nrm, pv[1]), dot(nrm, pv[2])];
        // the crossing edges other than the entry; at the start, the one
        // farther out along the plane
        let mut exit: Option<(usize, [f64; 3])> = None;
        for e in 0..3 {
            let (i, j) = (e, (e + 1) % 3);
            if (sd[i] >= 0.0) == (sd[j] >= 0.0) {
                continue;
            }
            if let Some(en) = entry {
                if (en[0] == g[i] && en[1] == g[j]) || (en[0] == g[j] && en[1] == g[i]) {
                    continue;
                }
            }
            let s = sd[i] / (sd[i] - sd[j]);
            let xp = [
                pv[i][0] + s * (pv[j][0] - pv[i][0]),
                pv[i][1] + s * (pv[j][1] - pv[i][1]),
                pv[i][2] + s * (pv[j][2] - pv[i][2]),
            ];
            if exit.is_none_or(|(_, q)| dot(xp, a) > dot(q, a)) {
                exit = Some((e, xp));
            }
        }
        let Some((e, xp)) = exit else {
            return Walk::Inconclusive;
        };
        let Some(yx) = row_of(xp) else {
            *confined = false;
            return Walk::Inconclusive;
        };
        if !(yx >= reach_lo && yx <= reach_hi) {
            *confined = false;
        }
        let dx = dot(xp, xp).sqrt();
        let tri = (2 * (r * cx + c) + half as usize) as u32;
        if yx < best_y {
            if yx <= far_y {
                // rises to the far pixel's ray: a crease (or the far
                // surface itself behind an earlier contour)
                return if found.is_empty() {
                    Walk::Crease
                } else {
                    Walk::Contours(found)
                };
            }
            (best_y, best, best_tri, best_d) = (yx, xp, tri, dx);
        } else if dx > best_d * (1.0 + min_jump) {
            found.push((best_y, best, best_tri));
            // Farther terrain that rises above this contour's ray before
            // the far pixel's hit holds another contour within the pixel:
            // it starts exactly where that ray first meets the terrain
            // beyond here (the ray lies in the column plane, so the hit is
            // on the walked polyline), found by the cast index instead of
            // walking every triangle in between.
            let d = cam.unproject([px, best_y]);
            let Some(hit) = terrain.cast_segment(d, dx, t_b) else {
                return Walk::Contours(found);
            };
            let q = [d[0] * hit.t, d[1] * hit.t, d[2] * hit.t];
            (best, best_tri, best_d) = (q, hit.triangle, hit.t);
            let cell = (hit.triangle / 2) as usize;
            (c, r, half) = (cell % cx, cell / cx, hit.triangle % 2);
            entry = None;
            continue;
        }
        // Step across the exit edge (see the triangle layout of LocalTerrain).
        let next = match (half, e) {
            (0, 0) => (r > 0).then(|| (c, r.wrapping_sub(1), 1)),
            (0, 1) => (c + 1 < cx).then_some((c + 1, r, 1)),
            (1, 0) => (c > 0).then(|| (c.wrapping_sub(1), r, 0)),
            (1, 1) => (r + 1 < cy).then_some((c, r + 1, 0)),
            (_, _) => Some((c, r, 1 - half)),
        };
        let Some((nc, nr, nh)) = next else {
            // the edge of the terrain: an occlusion boundary
            found.push((best_y, best, best_tri));
            return Walk::Contours(found);
        };
        entry = Some([g[e], g[(e + 1) % 3]]);
        (c, r, half) = (nc, nr, nh);
    }
    if found.is_empty() {
        Walk::Inconclusive
    } else {
        Walk::Contours(found)
    }
}

/// The point at distance `t` along the ray through pixel coordinates `(px, py)`.
fn ray_point(cam: &crate::view::Camera, px: f64, py: f64, t: f64) -> Option<[f64; 3]> {
    if !t.is_finite() {
        return None;
    }
    let d = cam.unproject([px, py]);
    Some([d[0] * t, d[1] * t, d[2] * t])
}

/// One side of a bisection bracket: row coordinate, hit distance (infinite
/// for sky) and triangle hit.
#[derive(Clone, Copy)]
struct Side {
    y: f64,
    t: f64,
    tri: u32,
    /// Whether `t` is an exact cast's first hit (not the rasteriser's depth).
    exact: bool,
}

/// Bisect between the centres of rows `y` (near) and `y - 1` (far) of column
/// `x` towards the largest depth gap; a gap that closes is a crease and gives
/// nothing. When the bracket holds several boundaries (two silhouettes within
/// one pixel, as at a T-junction) the remaining sub-brackets are searched too.
/// `confined` is cleared when a walk leaves [`reach_rows`].
fn refine(
    terrain: &LocalTerrain,
    db: &DepthBuffer,
    p: &SilhouetteParams,
    (x, y): (usize, usize),
    out: &mut Vec<SilhouetteSample>,
    confined: &mut bool,
) {
    let w = db.width;
    // The walk follows the cells' two triangles; where they can put the
    // boundary farther than [`WALK_TOLERANCE_PX`] from the bilinear
    // patches' the view shows, the bisection by exact casts (on the
    // patches) decides.
    let k = y * w + x;
    let planar = 0.25 * terrain.twist_around(db.triangle[k]) * db.camera.focal_px
        <= WALK_TOLERANCE_PX * db.depth[k] as f64;
    let walk = if planar {
        walk_to_contour(terrain, db, (x, y), p.min_jump, confined)
    } else {
        Walk::Inconclusive
    };
    match walk {
        Walk::Crease => return,
        Walk::Contours(found) => {
            for (k, &(yc, local, tri)) in found.iter().enumerate() {
                let behind = match found.get(k + 1) {
                    Some(next) => dot(next.1, next.1).sqrt(),
                    None => {
                        let fb = db.depth[(y - 1) * w + x];
                        if fb.is_finite() {
                            fb as f64
                        } else {
                            f64::INFINITY
                        }
                    }
                };
                let (cx, cy, cz) = terrain.frame.local_to_crs(local);
                let (c, r, _) = terrain.triangle_cell(tri);
                out.push(SilhouetteSample {
                    pixel: [x as f64 + 0.5, yc],
                    depth: dot(local, local).sqrt(),
                    local,
                    world: [cx, cy, cz],
                    cell: [c as u32, r as u32],
                    depth_behind: behind,
                });
            }
            return;
        }
        Walk::Inconclusive => {}
    }
    let near = Side {
        y: y as f64 + 0.5,
        t: db.depth[y * w + x] as f64,
        tri: db.triangle[y * w + x],
        exact: false,
    };
    let fb = db.depth[(y - 1) * w + x];
    let far = Side {
        y: y as f64 - 0.5,
        t: if fb.is_finite() {
            fb as f64
        } else {
            f64::INFINITY
        },
        tri: db.triangle[(y - 1) * w + x],
        exact: false,
    };
    refine_bracket(terrain, db, p, x, near, far, 2, out);
}

#[allow(clippy::too_many_arguments)]
fn refine_bracket(
    terrain: &LocalTerrain,
    db: &DepthBuffer,
    p: &SilhouetteParams,
    x: usize,
    near0: Side,
    far0: Side,
    depth_left: u32,
    out: &mut Vec<SilhouetteSample>,
) {
    let cam = &db.camera;
    let px = x as f64 + 0.5;
    let (mut a, mut b) = (near0, far0);
    let closed = |a: &Side, b: &Side| b.t.is_finite() && b.t <= a.t * (1.0 + p.min_jump);
    for _ in 0..p.refine_iterations {
        // A gap that has closed is a crease: the rays between the two
        // sides meet the terrain between their distances (in a column's
        // plane a higher ray's first hit is never nearer), so it stays
        // closed. Most candidates end here, after two or three casts.
        if closed(&a, &b) {
            return;
        }
        let ym = 0.5 * (a.y + b.y);
        let d = cam.unproject([px, ym]);
        match cast_between(terrain, cam, px, d, &a, &b) {
            Some(hit) if nearer_in_log(a.t, hit.t, b.t) => {
                a = Side {
                    y: ym,
                    t: hit.t,
                    tri: hit.triangle,
                    exact: true,
                };
            }
            Some(hit) => {
                b = Side {
                    y: ym,
                    t: hit.t,
                    tri: hit.triangle,
                    exact: true,
                }
            }
            None => {
                b = Side {
                    y: ym,
                    t: f64::INFINITY,
                    tri: u32::MAX,
                    exact: true,
                }
            }
        }
    }
    if closed(&a, &b) {
        return;
    }
    let da = cam.unproject([px, a.y]);
    let local = [da[0] * a.t, da[1] * a.t, da[2] * a.t];
    let (cx, cy, cz) = terrain.frame.local_to_crs(local);
    let (c, r, _) = terrain.triangle_cell(a.tri);
    out.push(SilhouetteSample {
        pixel: [px, 0.5 * (a.y + b.y)],
        depth: a.t,
        local,
        world: [cx, cy, cz],
        cell: [c as u32, r as u32],
        depth_behind: b.t,
    });
    if depth_left == 0 {
        return;
    }
    if a.t > near0.t * (1.0 + p.min_jump) {
        refine_bracket(terrain, db, p, x, near0, a, depth_left - 1, out);
    }
    if b.t.is_finite() && far0.t > b.t * (1.0 + p.min_jump) {
        refine_bracket(terrain, db, p, x, b, far0, depth_left - 1, out);
    }
}

/// The first hit of the ray `d` of a bisection between sides `a` (near)
/// and `b` (far) of one column. The ray passes above the near side's ray,
/// which met no terrain before `a.t`, so the cast starts well short of it
/// (by the cheap block index, without building the per-view horizon
/// index). Where the far side hits terrain, the ray's cells are walked
/// from the near side's on, [`CELL_WALK`] at most: in a column's plane a
/// ray between two others first meets the terrain between where they do,
/// most often in the same cell or the next (the traversal is the fallback
/// where the walk's check refuses or it ends).
/// Most cells a bisection's ray is walked through before the traversal
/// takes over.
const CELL_WALK: usize = 8;

fn cast_between(
    terrain: &LocalTerrain,
    cam: &crate::view::Camera,
    px: f64,
    d: [f64; 3],
    a: &Side,
    b: &Side,
) -> Option<crate::render::RayHit> {
    let t0 = 0.9 * a.t;
    let mut walked_to = None;
    if a.tri != crate::render::SKY && b.t.is_finite() {
        match terrain.cast_from_cell_walk(d, a.tri, t0, a.t, CELL_WALK) {
            Ok(hit) => return Some(hit),
            Err(stop) => walked_to = stop,
        }
    }
    let mut start = traversal_start(terrain, cam, px, d, a, t0);
    // The cells the walk found clear need no second look: the traversal
    // starts at the first one it did not test (at its entry, as the
    // traversal computes it, so that the hit is the same bit for bit).
    if let Some(e) = walked_to.and_then(|(c, r)| terrain.cell_entry_at(d, c, r)) {
        if e > start {
            start = e;
        }
    }
    terrain.cast_segment(d, start, f64::INFINITY)
}

/// Where the traversal of [`cast_between`] may start without changing its
/// answer, at or after `t0`: the entry of the cell the ray crosses at the
/// least distance its hit can lie at. The column's plane holds both rays
/// and `d` passes above the near side's ray, which meets nothing before
/// its hit `A`; so `d` meets nothing before it has gone as far along the
/// plane's outward axis as `A`, i.e. before `dot(A, axis)`, where grazing
/// rays (the cast's costly part) run closest to the terrain. The cell's
/// entry is the traversal's own (the exit of the cell before it), so that
/// the hit, computed from there, is the very one a start at `t0` gives
/// (bit for bit). Only after an exact hit: the rasteriser's depth of the
/// bracket's first near side is no bound.
fn traversal_start(
    terrain: &LocalTerrain,
    cam: &crate::view::Camera,
    px: f64,
    d: [f64; 3],
    a: &Side,
    t0: f64,
) -> f64 {
    if !a.exact || !a.t.is_finite() {
        return t0;
    }
    let f = cam.focal_px;
    let u = px - cam.width as f64 / 2.0;
    let (fw, rt) = (cam.forward, cam.right);
    let axis = [
        f * fw[0] + u * rt[0],
        f * fw[1] + u * rt[1],
        f * fw[2] + u * rt[2],
    ];
    let da = cam.unproject([px, a.y]);
    let along = dot(da, axis) / dot(axis, axis).sqrt();
    let t_least = a.t * along * (1.0 - 1e-9);
    match terrain.cell_entry(d, t_least) {
        Some(e) if e > t0 && e <= t_least => e,
        _ => t0,
    }
}

/// `(t / ta).ln() < (tb / t).ln()`: is `t` nearer to `ta` than to `tb` on
/// a log scale (the bisection's split)? Decided by the ratios themselves
/// where they differ by more than a billionth (the logarithm is monotonic
/// and its rounding error far smaller), by the logarithms as written
/// elsewhere (equal or nearly equal ratios, infinite or zero ones), so
/// that the answer is the logarithms' in every case, at a fraction of
/// their cost.
#[inline]
fn nearer_in_log(ta: f64, t: f64, tb: f64) -> bool {
    let (x, y) = (t / ta, tb / t);
    let ordinary = x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite();
    if ordinary && (x - y).abs() > 1e-9 * x.max(y) {
        x < y
    } else {
        x.ln() < y.ln()
    }
}

/// Can sample `a` of column `x` be linked to sample `b` of column `x + 1`?
/// Returns the link cost.
fn link_cost(
    db: &DepthBuffer,
    p: &SilhouetteParams,
    x: usize,
    a: &SilhouetteSample,
    b: &SilhouetteSample,
) -> Option<f64> {
    let dy = b.pixel[1] - a.pixel[1];
    if dy.abs() > p.max_link_dy {
        return None;
    }
    let ratio = (b.depth / a.depth).ln().abs();
    if ratio > (1.0 + p.link_depth).ln() {
        return None;
    }
    // Pixels between the two samples must show the occluding surface, not
    // what lies behind it.
    if dy.abs() > 1.0 {
        let limit = a.depth.max(b.depth) * (1.0 + p.link_depth);
        let (col, y0, y1) = if dy < 0.0 {
            (x + 1, b.pixel[1], a.pixel[1])
        } else {
            (x, a.pixel[1], b.pixel[1])
        };
        let r0 = (y0 - 0.5).ceil().max(0.0) as usize;
        let r1 = ((y1 - 0.5).floor().max(0.0) as usize).min(db.height - 1);
        for r in r0..=r1 {
            if db.depth_at(col, r) as f64 > limit {
                return None;
            }
        }
    }
    Some(dy.abs() + 20.0 * ratio)
}

/// Link column samples into polylines. Returns the curves and, per column,
/// the (curve, index) of each sample kept.
#[allow(clippy::type_complexity)]
fn link(
    db: &DepthBuffer,
    p: &SilhouetteParams,
    columns: &[Vec<SilhouetteSample>],
) -> (Vec<Silhouette>, Vec<Vec<(u32, u32)>>) {
    let w = columns.len();
    // curve of each sample, per column
    let mut owner: Vec<Vec<usize>> = Vec::with_capacity(w);
    let mut chains: Vec<Vec<(usize, usize)>> = Vec::new();
    for x in 0..w {
        let mut own = vec![usize::MAX; columns[x].len()];
        if x > 0 {
            let prev = &columns[x - 1];
            let mut pairs = Vec::new();
            for (i, a) in prev.iter().enumerate() {
                for (j, b) in columns[x].iter().enumerate() {
                    if let Some(c) = link_cost(db, p, x - 1, a, b) {
                        pairs.push((c, i, j));
                    }
                }
            }
            pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut used_prev = vec![false; prev.len()];
            for (_, i, j) in pairs {
                if used_prev[i] || own[j] != usize::MAX {
                    continue;
                }
                used_prev[i] = true;
                own[j] = owner[x - 1][i];
                chains[own[j]].push((x, j));
            }
        }
        for (j, o) in own.iter_mut().enumerate() {
            if *o == usize::MAX {
                *o = chains.len();
                chains.push(vec![(x, j)]);
            }
        }
        owner.push(own);
    }
    let mut where_: Vec<Vec<(u32, u32)>> = columns.iter().map(|_| Vec::new()).collect();
    let mut curves = Vec::new();
    for chain in chains {
        if chain.len() < p.min_samples.max(1) {
            continue;
        }
        let id = curves.len() as u32;
        let samples: Vec<SilhouetteSample> = chain.iter().map(|&(x, j)| columns[x][j]).collect();
        for (k, &(x, _)) in chain.iter().enumerate() {
            where_[x].push((id, k as u32));
        }
        let sky = samples
            .iter()
            .filter(|s| s.depth_behind.is_infinite())
            .count();
        curves.push(Silhouette {
            id,
            skyline: 2 * sky > samples.len(),
            samples,
        });
    }
    (curves, where_)
}

/// T-junctions at the ends of polylines that meet a nearer silhouette.
fn find_junctions(
    curves: &[Silhouette],
    where_: &[Vec<(u32, u32)>],
    p: &SilhouetteParams,
) -> Vec<TJunction> {
    let mut out = Vec::new();
    let w = where_.len();
    for c in curves {
        for end in [CurveEnd::Start, CurveEnd::End] {
            let n = c.samples.len();
            let (s, inner, cols): (&SilhouetteSample, &SilhouetteSample, [isize; 2]) = match end {
                CurveEnd::Start => {
                    let x = c.samples[0].pixel[0] as isize;
                    (&c.samples[0], &c.samples[1.min(n - 1)], [x, x - 1])
                }
                CurveEnd::End => {
                    let x = c.samples[n - 1].pixel[0] as isize;
                    (
                        &c.samples[n - 1],
                        &c.samples[n.saturating_sub(2)],
                        [x, x + 1],
                    )
                }
            };
            let mut best: Option<(f64, u32, usize)> = None;
            for &col in &cols {
                if col < 0 || col as usize >= w {
                    continue;
                }
                for &(id, k) in &where_[col as usize] {
                    if id == c.id {
                        continue;
                    }
                    let o = &curves[id as usize].samples[k as usize];
                    let dy = (o.pixel[1] - s.pixel[1]).abs();
                    if dy <= p.junction_radius_px
                        && o.depth * (1.0 + p.link_depth) < s.depth
                        && best.is_none_or(|b| dy < b.0)
                    {
                        best = Some((dy, id, k as usize));
                    }
                }
            }
            let Some((_, occ, k)) = best else { continue };
            let pixel = junction_point(s, inner, &curves[occ as usize], k).unwrap_or(s.pixel);
            out.push(TJunction {
                pixel,
                occluded: c.id,
                occluder: occ,
                end,
            });
        }
    }
    out
}

/// Intersection of the extension of the occluded polyline's end segment
/// (`inner` -> `end`) with the occluder's segments around its sample `k`.
fn junction_point(
    end: &SilhouetteSample,
    inner: &SilhouetteSample,
    occluder: &Silhouette,
    k: usize,
) -> Option<[f64; 2]> {
    let (p0, p1) = (inner.pixel, end.pixel);
    let d = [p1[0] - p0[0], p1[1] - p0[1]];
    if d[0] == 0.0 && d[1] == 0.0 {
        return None;
    }
    let lo = k.saturating_sub(2);
    let hi = (k + 3).min(occluder.samples.len());
    let mut best: Option<(f64, [f64; 2])> = None;
    for i in lo..hi.saturating_sub(1) {
        let (q0, q1) = (occluder.samples[i].pixel, occluder.samples[i + 1].pixel);
        let e = [q1[0] - q0[0], q1[1] - q0[1]];
        let den = d[0] * e[1] - d[1] * e[0];
        if den.abs() < 1e-12 {
            continue;
        }
        let r = [q0[0] - p0[0], q0[1] - p0[1]];
        let t = (r[0] * e[1] - r[1] * e[0]) / den;
        let s = (r[0] * d[1] - r[1] * d[0]) / den;
        if (-1e-9..=1.0 + 1e-9).contains(&s) && t >= 0.0 {
            let pt = [p0[0] + t * d[0], p0[1] + t * d[1]];
            let dist = (pt[0] - p1[0]).hypot(pt[1] - p1[1]);
            if dist <= 3.0 && best.is_none_or(|b| dist < b.0) {
                best = Some((dist, pt));
            }
        }
    }
    best.map(|b| b.1)
}
