//! Landforms from silhouettes (Gain et al. 2009, sections 3 and 4) and
//! noise regions (their region mode), as map-view corrections.
//!
//! A `landform` feature names a stroke of a sketch view (`silhouette:
//! {"view", "stroke"}`), so it needs the sketch (`demsketch correct
//! --sketch`). [`resolve`] places the stroke as the paper's silhouette
//! mode does (section 3.1): every pixel on the vertical surface through
//! the terrain points under its two end pixels, by the same geometry as
//! the edit's free stretches
//! ([`crate::edit::stretch_placement::place_on_end_surface`]; where its
//! end test, which refuses an end within 3 px of any depth step of 0.5%,
//! refuses both, on the vertical plane through the terrain the two end
//! pixels show, see [`place_on_end_pixels`]), or, with a
//! `shadow` LineString, on the vertical ruled surface through the shadow
//! (the paper's re-projection once the shadow is edited). The default
//! shadow is the surface's trace on the ground (the placed curve's map
//! projection); the default boundary is the paper's capsule: the smoothed
//! silhouette's shoulders (from each end to where it levels off, see
//! [`SHOULDER_TOP`]) give base lengths `d1`, `d2`, the capsule's radius is their mean and
//! its spine the shadow between the shoulders, so a single peak gets a
//! round footprint and a ridge an elongated one. The feature's Polygon
//! replaces it. Both defaults are in the report as GeoJSON, to be edited
//! in a GIS and given back.
//!
//! [`apply_landform`] then follows section 4. Every cell inside the
//! boundary is attached to a shadow point (arc length `t`): the one at
//! its projection on the base line through the shadow's end points (the
//! paper's parametrisation; the closest one if the shadow folds back over
//! that line), and gets its relative position `a` between shadow and
//! boundary (eqn 1). *Noise* (eqn 2, [`super::wavelet_noise`]): the stroke's height profile is
//! decomposed into detail bands by an à-trous (undecimated) binomial
//! pyramid, `D_i = I_i - I_{i+1}`; the bands' deviations (up to
//! [`NOISE_SCALE_DIVISOR`]-th of the stroke's length) are fitted by an
//! exponential decay, as the paper fits the sketched variances, and each
//! band the DEM's cells can carry becomes a layer of smooth value noise of
//! that scale and deviation, blended in with the paper's weight
//! `W = (a^2 - 1)^2`. *Deformation* (eqn 3): the silhouette's height above
//! the (noisy) ground under it, split into the same bands, is added band by
//! band with that weight, the finer bands within a boundary scaled in by
//! the filter widths' ratio (at least [`MIN_BOUNDARY_SCALE`]); every
//! cross-section is then at most as high as the silhouette above its shadow
//! point, so from the view the crest is the stroke. Last, the cells within
//! [`CORRECTION_CELLS`] of the placed curve take the project's multigrid
//! solve ([`super::control_curve::solve_in`]) that makes the DEM pass
//! through the curve's rasterised heights. Cells outside the boundary stay
//! bit-identical. Noise and solve are functions of the DEM's global cell
//! indices, so a tile set gives the single file's result. (A harmonic
//! solve of the whole footprint from the curve, tried first, bulges above
//! the silhouette's shoulders where the curve is concave: the judge fitted
//! it at 0.74; the cross-sections fit it at 0.99.)
//!
//! On the real fixtures (docs/landform_real.md) what the judge still
//! misses on landforms 8 or more cells across is at the feet: columns
//! where the stroke starts under the hillside behind its end (nearer
//! terrain just above it, which a landform that never digs cannot hide),
//! and the corner where the stroke leaves the ground, which falls between
//! two cell centres. A chord-safe hold of the cells there was tried and
//! not kept (`tools/fidelity/experiments/landform_chord_safe_hold.patch`),
//! nor was holding the cells beyond a stroke's ends under its rise
//! extended past them (`landform_foot_lines.patch`: one foot fitted, the
//! held-out Zion 90 m tests lost). Strokes whose feet stand on a visible
//! crest (`landform_real.py --feet crest`), showable from their first
//! column, miss only there and, for sharp peaks, at the peak.
//!
//! A `noise_region` (region mode, section 3.3) adds the noise of its
//! `noise_stroke` (placed the same way, for its scale in metres; it is not
//! interpolated) inside its Polygon, blended in over the coarsest band's
//! scale from the region's edge; `amplitude_m` rescales its deviation.

use std::collections::HashMap;

use geo::{ConvexHull, Coord, Distance, Euclidean, Intersects, LineString, MultiPoint};
use geo::{MultiPolygon, Point, Polygon};

use crate::deform::{CellSize, CurveConstraint};
use crate::edit::rendered_view::RenderedView;
use crate::edit::stretch_placement::place_on_end_surface;
use crate::raster::{Dem, Window};
use crate::render::Scene;
use crate::sketch::{SceneProjection, SketchFile, ViewProjection, ViewSpec};
use crate::view::CameraModel;

use super::grid::Grid;
use super::wavelet_noise::{smooth, spectrum, NoiseField, Spectrum, NOISE_SCALE_DIVISOR};
use super::{Correction, CorrectionKind};

/// A stroke of a sketch view, as a feature names it.
#[derive(Debug, Clone, PartialEq)]
pub struct StrokeRef {
    pub view: String,
    pub stroke: String,
}

/// A stroke placed in the DEM's space, with the footprint it acts on.
#[derive(Debug, Clone)]
pub struct Placed {
    /// The placed stroke, `[x, y, z]`: DEM CRS and absolute heights, one
    /// point per image pixel along the stroke.
    pub curve: Vec<[f64; 3]>,
    /// The curve in the DEM's pixel space (its shadow in map view).
    pub shadow_px: Vec<[f64; 2]>,
    /// The footprint, DEM pixel space: the boundary (landforms) or the
    /// region (noise regions).
    pub boundary: MultiPolygon<f64>,
    /// True when `boundary` is the default capsule.
    pub default_boundary: bool,
    /// True when both stroke ends stood on terrain (the vertical surface
    /// through them), false for the drawing plane through one end; `None`
    /// when a shadow was given.
    pub both_ends: Option<bool>,
    /// The shoulders' base lengths `[d1, d2]`, metres (landforms).
    pub shoulders_m: [f64; 2],
    /// The sight-line bound of the footprint's cells (landforms).
    pub sight: Option<Sight>,
}

/// Per cell of a window of the DEM (global cell indices), the highest
/// absolute height at which the cell centre still appears at least
/// [`SIGHT_MARGIN_PX`] below the stroke from its view (beyond the stroke's
/// ends, below its nearest end's row; NaN where the cell cannot be
/// projected). Gain et al. make the terrain interpolate the
/// silhouette; on sloping ground their displacement also lifts the ground
/// behind the shadow above the sight line through the silhouette, so the
/// crest the view sees is not the stroke (on the Zion fixture up to 2.5 px
/// above it near the stroke's ends). Cells are held below this bound.
#[derive(Debug, Clone)]
pub struct Sight {
    pub window: Window,
    pub max_z: Vec<f64>,
    /// Per cell, the absolute height at which the cell centre appears on
    /// the stroke itself (the sight cone through the silhouette; NaN
    /// outside its columns).
    pub cone_z: Vec<f64>,
}

/// How far below the stroke (pixels) the footprint's cells other than the
/// silhouette's own are held.
pub const SIGHT_MARGIN_PX: f64 = 0.5;

impl Sight {
    fn bound(&self, col: i64, row: i64) -> f64 {
        self.get(&self.max_z, col, row)
    }

    fn cone(&self, col: i64, row: i64) -> f64 {
        self.get(&self.cone_z, col, row)
    }

    fn get(&self, v: &[f64], col: i64, row: i64) -> f64 {
        let w = self.window;
        if col < w.col || row < w.row {
            return f64::NAN;
        }
        let (c, r) = ((col - w.col) as usize, (row - w.row) as usize);
        if c >= w.width || r >= w.height {
            return f64::NAN;
        }
        v[r * w.width + c]
    }
}

/// The stroke's highest row (smallest y) at image column `x`, from its
/// densified pixels; `None` outside its columns.
fn stroke_row(pixels: &[[f64; 2]], x: f64) -> Option<f64> {
    let mut best: Option<f64> = None;
    for w in pixels.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (lo, hi) = (a[0].min(b[0]), a[0].max(b[0]));
        if x < lo || x > hi {
            continue;
        }
        let y = if hi > lo {
            a[1] + (x - a[0]) / (b[0] - a[0]) * (b[1] - a[1])
        } else {
            a[1].min(b[1])
        };
        best = Some(best.map_or(y, |v: f64| v.min(y)));
    }
    best
}

/// The sight bound (see [`Sight`]) over the window `win` (global cells).
fn sight_bound(dem: &Dem, proj: &SceneProjection, pixels: &[[f64; 2]], win: Window) -> Sight {
    Sight {
        window: win,
        max_z: sight_heights(dem, proj, pixels, win, SIGHT_MARGIN_PX, true),
        cone_z: sight_heights(dem, proj, pixels, win, 0.0, false),
    }
}

/// Per cell of `win`, the absolute height at which its centre appears
/// `margin_px` below the stroke (NaN outside the stroke's columns; with
/// `clamp`, beyond its ends, below the row of its nearest end: at 3 km a
/// 90 m cell is 16 px wide, and the bilinear patches of the stroke's end
/// columns reach cells whose centres lie beyond them).
fn sight_heights(
    dem: &Dem,
    proj: &SceneProjection,
    pixels: &[[f64; 2]],
    win: Window,
    margin_px: f64,
    clamp: bool,
) -> Vec<f64> {
    let gt = dem.geotransform;
    let x_range = pixels
        .iter()
        .map(|p| p[0])
        .fold(None, |acc: Option<(f64, f64)>, x| {
            Some(acc.map_or((x, x), |(lo, hi)| (lo.min(x), hi.max(x))))
        });
    let frame = proj.own_frame();
    let mut max_z = vec![f64::NAN; win.len()];
    for r in 0..win.height {
        for c in 0..win.width {
            let (x, y) = gt.pixel_to_crs(
                (win.col + c as i64) as f64 + 0.5,
                (win.row + r as i64) as f64 + 0.5,
            );
            let (e, n) = frame.crs_to_en(x, y);
            let horiz = e.hypot(n);
            if horiz < 1e-6 {
                continue;
            }
            // The cell's column (a vertical line is one column at pitch
            // 0; two rounds otherwise), the ray below the stroke there.
            let mut z = 0.0;
            let mut ok = false;
            for _ in 0..3 {
                let Some((px, _)) = proj.project([e, n, z]) else {
                    break;
                };
                // Beyond the stroke's ends (held cells only): its end's row.
                let x = match (clamp, x_range) {
                    (true, Some((lo, hi))) => px[0].clamp(lo, hi),
                    _ => px[0],
                };
                let Some(sy) = stroke_row(pixels, x) else {
                    ok = false;
                    break;
                };
                let d = CameraModel::unproject(&proj.camera, [px[0], sy + margin_px]);
                let h = d[0].hypot(d[1]);
                if h < 1e-9 {
                    break;
                }
                z = d[2] * horiz / h;
                ok = true;
            }
            if ok {
                max_z[r * win.width + c] = proj.local_to_dem([e, n, z])[2];
            }
        }
    }
    max_z
}

/// The view a landform's stroke is drawn on, set up on the DEM.
struct ViewSetup {
    before: RenderedView,
}

/// Maximum view distance of the placement renders, metres (the edit's
/// default).
const MAX_VIEW_M: f64 = 50_000.0;
/// Refraction coefficient of the placement renders (the edit's default).
const REFRACTION: f64 = 1.0 / 7.0;

fn set_up(dem: &Dem, v: &ViewSpec) -> Result<ViewSetup, String> {
    let vp = v.eye();
    let camera = v
        .pinhole()
        .map_err(|e| format!("view \"{}\": {e}", v.name))?;
    let scene = Scene::open_in_view(dem, &vp, Some(MAX_VIEW_M), REFRACTION, &camera)
        .map_err(|e| format!("view \"{}\": {e}", v.name))?;
    let before = RenderedView::from_terrain(scene.terrain, &camera)
        .map_err(|e| format!("view \"{}\": {e}", v.name))?;
    Ok(ViewSetup { before })
}

/// The stroke's vertices densified to at most one pixel apart.
fn densify(points: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        let n = (b[0] - a[0]).hypot(b[1] - a[1]).ceil().max(1.0) as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
        }
    }
    if let Some(&last) = points.last() {
        out.push(last);
    }
    out
}

/// Depth along the ray of `pixel` where it meets the vertical ruled
/// surface through `shadow` (own-frame `(east, north)`): the nearest
/// crossing in map view.
fn ruled_surface_depth(
    proj: &SceneProjection,
    pixel: [f64; 2],
    shadow: &[[f64; 2]],
) -> Option<f64> {
    let d = CameraModel::unproject(&proj.camera, pixel);
    let horiz = d[0].hypot(d[1]);
    if horiz < 1e-9 {
        return None;
    }
    let r = [d[0] / horiz, d[1] / horiz];
    let mut best: Option<f64> = None;
    for s in shadow.windows(2) {
        let (p, q) = (s[0], s[1]);
        let w = [q[0] - p[0], q[1] - p[1]];
        let den = r[0] * w[1] - r[1] * w[0];
        if den.abs() < 1e-12 {
            continue;
        }
        // origin + t r = p + u w
        let t = (p[0] * w[1] - p[1] * w[0]) / den;
        let u = (p[0] * r[1] - p[1] * r[0]) / den;
        if t > 0.0 && (-1e-3..=1.0 + 1e-3).contains(&u) && best.is_none_or(|b| t < b) {
            best = Some(t);
        }
    }
    // t is the horizontal distance: the depth along the unit ray.
    best.map(|t| t / horiz)
}

/// The stroke placed on the vertical plane through the terrain its two
/// end pixels show (own frame, one point per pixel), when both show
/// terrain beyond `observer_radius_m`. The fallback of
/// [`place_on_end_surface`], which also refuses an end within
/// [`crate::edit::stretch_placement::END_TOUCH_PX`] of any occlusion
/// boundary it sees (an end stopping on a nearer silhouette is a
/// T-junction there): its silhouettes count depth steps of 0.5%, so on
/// rough ground it refused ends drawn on ground the view plainly shows
/// (7 of the 60 strokes of `tools/fidelity/landform_real.py`). An end
/// pixel that shows terrain is a landform's foot (Gain et al. 2009,
/// section 3.1: the terrain under the end points). An end pixel that
/// shows sky stands on the terrain up to [`END_SNAP_PX`] pixels below it.
fn place_on_end_pixels(
    before: &RenderedView,
    proj: &SceneProjection,
    pixels: &[[f64; 2]],
    observer_radius_m: f64,
) -> Option<Vec<[f64; 3]>> {
    let foot = |px: [f64; 2]| -> Option<[f64; 2]> {
        if !(px[0] >= 0.0 && px[1] >= 0.0) {
            return None;
        }
        let (i, j) = (px[0] as usize, px[1] as usize);
        (0..=END_SNAP_PX).find_map(|k| {
            let hit = before.depth.hit(&before.terrain, i, j + k)?;
            (hit.distance > observer_radius_m).then_some([hit.local[0], hit.local[1]])
        })
    };
    let plane = [foot(*pixels.first()?)?, foot(*pixels.last()?)?];
    pixels
        .iter()
        .map(|&px| ruled_surface_depth(proj, px, &plane).map(|d| proj.unproject(px, d)))
        .collect()
}

/// How far below an end pixel that shows sky (image px) the terrain a
/// landform's foot stands on is looked for. A person adding a peak to a
/// ridge line ends the stroke on the crest; at its top row, the crest the
/// view shows and the terrain this renderer draws can differ by a pixel
/// (on Zion 83 m at 3 km, 2 of the 8 strokes whose feet stand on a crest,
/// `tools/fidelity/landform_real.py --feet crest` in a first version that
/// began them above the crest's row, were refused: "neither end stands on
/// terrain", although the independent judge sees ground under both ends;
/// with this the one 0.5 px above is placed, the one 4.4 px above is not).
pub const END_SNAP_PX: usize = 2;

/// A stroke placed in the DEM's CRS ([`place_stroke`]).
struct PlacedStroke {
    /// The silhouette curve, `[x, y, z]`.
    curve: Vec<[f64; 3]>,
    /// The terrain's height under each of its points.
    ground: Vec<f64>,
    /// Whether both ends stand on terrain (`None`: no shadow was given).
    both_ends: Option<bool>,
}

/// Places `stroke` of view `v` (see the module documentation); `shadow`
/// in the DEM's CRS.
fn place_stroke(
    dem: &Dem,
    setup: &ViewSetup,
    v: &ViewSpec,
    stroke_id: &str,
    shadow: Option<&[[f64; 2]]>,
) -> Result<PlacedStroke, String> {
    let stroke = v
        .strokes
        .iter()
        .find(|s| s.id == stroke_id)
        .ok_or_else(|| {
            let ids: Vec<&str> = v.strokes.iter().map(|s| s.id.as_str()).collect();
            format!(
                "view \"{}\" has no stroke \"{stroke_id}\" (its strokes: {})",
                v.name,
                if ids.is_empty() {
                    "none".to_string()
                } else {
                    ids.join(", ")
                }
            )
        })?;
    if stroke.points.len() < 2 {
        return Err(format!("stroke \"{stroke_id}\" needs at least two points"));
    }
    let before = &setup.before;
    let proj = SceneProjection::new(before.camera, &before.terrain);
    let pixels = densify(&stroke.points);
    let cell = dem_cell_m(dem);
    let observer = crate::edit::pipeline::OBSERVER_RADIUS_M.max(2.0 * cell);
    let (world, both): (Vec<[f64; 3]>, Option<bool>) = match shadow {
        Some(sh) => {
            let frame = &before.terrain.frame;
            let en: Vec<[f64; 2]> = sh
                .iter()
                .map(|p| {
                    let (e, n) = frame.crs_to_en(p[0], p[1]);
                    [e, n]
                })
                .collect();
            let pts = pixels
                .iter()
                .map(|&px| {
                    ruled_surface_depth(&proj, px, &en).map(|d| proj.unproject(px, d))
                })
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| {
                    format!("stroke \"{stroke_id}\": some of its rays do not meet the vertical surface through the shadow")
                })?;
            (pts, None)
        }
        None => match place_on_end_surface(before, &proj, &pixels, observer) {
            Some((placed, both)) => (placed.into_iter().map(|(w, _)| w).collect(), Some(both)),
            None => {
                let pts = place_on_end_pixels(before, &proj, &pixels, observer).ok_or_else(|| {
                        format!(
                            "stroke \"{stroke_id}\": neither end stands on terrain in view \"{}\" (a silhouette is placed on the vertical surface through the terrain under its end points)",
                            v.name
                        )
                    })?;
                (pts, Some(true))
            }
        },
    };
    let mut curve = Vec::with_capacity(world.len());
    let mut ground = Vec::with_capacity(world.len());
    for w in &world {
        let p = proj.local_to_dem(*w);
        let g = proj
            .terrain_height(w[0], w[1])
            .map(|h| proj.local_to_dem([w[0], w[1], h])[2])
            .ok_or_else(|| {
                format!(
                    "stroke \"{stroke_id}\": its placed curve leaves the DEM (or crosses nodata)"
                )
            })?;
        curve.push(p);
        ground.push(g);
    }
    Ok(PlacedStroke {
        curve,
        ground,
        both_ends: both,
    })
}

/// The larger cell side of `dem`, metres (at its centre).
fn dem_cell_m(dem: &Dem) -> f64 {
    let c = dem_cell(dem);
    c.hx.max(c.hy)
}

fn dem_cell(dem: &Dem) -> CellSize {
    let centre = dem
        .geotransform
        .pixel_to_crs(dem.width as f64 / 2.0, dem.height as f64 / 2.0);
    let lat = if dem.crs.geographic { centre.1 } else { 0.0 };
    crate::deform::locality::cell_size_m(
        &dem.geotransform,
        dem.crs.geographic,
        lat.clamp(-89.9, 89.9),
    )
}

/// A seed from the feature's index and stroke (stable across runs).
fn seed_for(index: usize, r: &StrokeRef) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ index as u64;
    for b in r.view.bytes().chain([0]).chain(r.stroke.bytes()) {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// Metres per CRS unit along x and y near the DEM's centre.
fn crs_to_m(dem: &Dem) -> [f64; 2] {
    let c = dem_cell(dem);
    let g = dem.geotransform.0;
    [c.hx / g[1].abs().max(1e-300), c.hy / g[5].abs().max(1e-300)]
}

/// Pixel-space points to the metric plane `(px hx, py hy)`.
fn metric(p: [f64; 2], cell: CellSize) -> [f64; 2] {
    [p[0] * cell.hx, p[1] * cell.hy]
}

/// The shoulders of the smoothed profile `h` (heights above the ground at
/// arc lengths `s`, one sample per stroke pixel): the base lengths from each end to where the profile
/// levels off, the first point reaching [`SHOULDER_TOP`] of the first local
/// maximum reached from that end (a peak's top, or a plateau's edge).
fn shoulders(s: &[f64], h: &[f64]) -> [f64; 2] {
    let n = h.len();
    if n < 3 {
        let l = s.last().copied().unwrap_or(0.0);
        return [l / 2.0, l / 2.0];
    }
    // Smoothed over the noise bands' scales (up to 1/16 of the length,
    // [`NOISE_SCALE_DIVISOR`]), so a jagged stroke's teeth are no maxima.
    let mut sm = h.to_vec();
    let half = ((n as f64 / (2.0 * NOISE_SCALE_DIVISOR)) as usize).max(1);
    for _ in 0..2 {
        sm = (0..n)
            .map(|i| {
                let (a, b) = (i.saturating_sub(half), (i + half + 1).min(n));
                sm[a..b].iter().sum::<f64>() / (b - a) as f64
            })
            .collect();
    }
    let is_max = |i: usize| sm[i] >= sm[i - 1] && sm[i] >= sm[i + 1] && sm[i] > 0.0;
    let first = (1..n - 1).find(|&i| is_max(i)).unwrap_or(n / 2);
    let last = (1..n - 1).rev().find(|&i| is_max(i)).unwrap_or(n / 2);
    let up = (0..=first)
        .find(|&i| sm[i] >= SHOULDER_TOP * sm[first])
        .unwrap_or(first);
    let down = (last..n)
        .rev()
        .find(|&i| sm[i] >= SHOULDER_TOP * sm[last])
        .unwrap_or(last);
    [s[up] - s[0], s[n - 1] - s[down.max(up)]]
}

/// Where a shoulder levels off, as a share of its top's height.
pub const SHOULDER_TOP: f64 = 0.95;

/// Distance from `p` to the polyline `line` (one point: to that point).
fn polyline_distance(p: [f64; 2], line: &[[f64; 2]]) -> f64 {
    if line.is_empty() {
        return f64::INFINITY;
    }
    let cum = vec![0.0; line.len()];
    closest_on(p, line, &cum).1
}

/// The default boundary: a capsule of radius the shoulders' mean around
/// the shadow between the shoulders (at least enclosing the whole shadow
/// with two cells to spare), as a polygon in pixel space.
fn capsule(
    shadow_px: &[[f64; 2]],
    heights: &[f64],
    cell: CellSize,
) -> (MultiPolygon<f64>, [f64; 2]) {
    let m: Vec<[f64; 2]> = shadow_px.iter().map(|&p| metric(p, cell)).collect();
    let mut s = vec![0.0];
    for w in m.windows(2) {
        s.push(s.last().copied().unwrap_or(0.0) + (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]));
    }
    let sh = shoulders(&s, heights);
    let (lo, hi) = (sh[0], s.last().copied().unwrap_or(0.0) - sh[1]);
    let spine: Vec<[f64; 2]> = m
        .iter()
        .zip(&s)
        .filter(|(_, &t)| t >= lo.min(hi) && t <= hi.max(lo))
        .map(|(p, _)| *p)
        .collect();
    let spine = if spine.is_empty() {
        vec![m[m.len() / 2]]
    } else {
        spine
    };
    let reach = m
        .iter()
        .map(|&p| polyline_distance(p, &spine))
        .fold(0.0, f64::max);
    let min_r = 3.0 * cell.hx.max(cell.hy);
    let r = (0.5 * (sh[0] + sh[1]))
        .max(reach + 2.0 * cell.hx.max(cell.hy))
        .max(min_r);
    let mut pts = Vec::new();
    let step = (r / 4.0).max(1e-9);
    let mut circle = |c: [f64; 2]| {
        for k in 0..48 {
            let a = k as f64 * std::f64::consts::TAU / 48.0;
            pts.push(Point::new(
                (c[0] + r * a.cos()) / cell.hx,
                (c[1] + r * a.sin()) / cell.hy,
            ));
        }
    };
    for w in spine.windows(2) {
        let d = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
        let n = (d / step).ceil().max(1.0) as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            circle([
                w[0][0] + t * (w[1][0] - w[0][0]),
                w[0][1] + t * (w[1][1] - w[0][1]),
            ]);
        }
    }
    if let Some(&l) = spine.last() {
        circle(l);
    }
    let hull: Polygon<f64> = MultiPoint::new(pts).convex_hull();
    (MultiPolygon::new(vec![hull]), sh)
}

/// Places the stroke of every landform and noise region of
/// `corrections` (see the module documentation). `sketch` is the sketch
/// file and its name, `None` when none was given: a landform is then an
/// error saying what to give (`hint`). Messages start with `name` and the
/// feature.
pub fn resolve(
    dem: &Dem,
    sketch: Option<(&SketchFile, &str)>,
    corrections: &mut [Correction],
    name: &str,
    hint: &str,
) -> Result<(), String> {
    let mut setups: HashMap<String, ViewSetup> = HashMap::new();
    let cell = dem_cell(dem);
    for c in corrections.iter_mut() {
        let label = c.label();
        let err = |m: String| format!("{name}: {label}: {m}");
        let (r, shadow, boundary) = match &c.kind {
            CorrectionKind::Landform {
                silhouette,
                shadow,
                boundary,
                ..
            } => (silhouette.clone(), shadow.clone(), boundary.clone()),
            CorrectionKind::NoiseRegion { stroke, area, .. } => {
                (stroke.clone(), None, Some(area.clone()))
            }
            _ => continue,
        };
        let Some((sk, sk_name)) = sketch else {
            return Err(err(format!("its stroke is drawn on a sketch view: {hint}")));
        };
        let v = sk.views.iter().find(|v| v.name == r.view).ok_or_else(|| {
            let names: Vec<&str> = sk.views.iter().map(|v| v.name.as_str()).collect();
            err(format!(
                "the sketch {sk_name} has no view \"{}\" (its views: {})",
                r.view,
                names.join(", ")
            ))
        })?;
        if !setups.contains_key(&v.name) {
            let s = set_up(dem, v).map_err(&err)?;
            setups.insert(v.name.clone(), s);
        }
        let setup = &setups[&v.name];
        let PlacedStroke {
            curve,
            ground,
            both_ends: both,
        } = place_stroke(dem, setup, v, &r.stroke, shadow.as_deref()).map_err(&err)?;
        let gt = dem.geotransform;
        let shadow_px: Vec<[f64; 2]> = curve
            .iter()
            .filter_map(|p| gt.crs_to_pixel(p[0], p[1]).map(|(x, y)| [x, y]))
            .collect();
        if shadow_px.len() != curve.len() {
            return Err(err("the DEM's geotransform is singular".into()));
        }
        let heights: Vec<f64> = curve.iter().zip(&ground).map(|(p, g)| p[2] - g).collect();
        let is_landform = matches!(c.kind, CorrectionKind::Landform { .. });
        let (boundary, default_boundary, shoulders_m) = match boundary {
            Some(b) => (b, false, [0.0, 0.0]),
            None => {
                let (b, sh) = capsule(&shadow_px, &heights, cell);
                (b, true, sh)
            }
        };
        if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
            use geo::BoundingRect;
            eprintln!(
                "landform: track {:?}..{:?}, boundary {:?}",
                shadow_px.first(),
                shadow_px.last(),
                boundary.bounding_rect()
            );
        }
        if is_landform {
            // The silhouette's ground track must lie in the boundary.
            if let Some(k) = shadow_px
                .iter()
                .position(|p| !boundary.intersects(&Point::new(p[0], p[1])))
            {
                return Err(err(format!(
                    "the silhouette's ground track leaves the boundary polygon (at stroke point {k} of {})",
                    shadow_px.len()
                )));
            }
            let w = dem.width as f64;
            let h = dem.height as f64;
            if shadow_px
                .iter()
                .any(|p| !(p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= w && p[1] <= h))
            {
                return Err(err("the placed silhouette lies outside the DEM".into()));
            }
        }
        let sight = if is_landform {
            let stroke = v.strokes.iter().find(|s| s.id == r.stroke);
            let pixels = stroke.map(|s| densify(&s.points)).unwrap_or_default();
            let before = &setup.before;
            let proj = SceneProjection::new(before.camera, &before.terrain);
            let full = Window::new(0, 0, dem.width, dem.height);
            bbox_window(&boundary)
                .and_then(|w| w.intersect(&full))
                .map(|w| sight_bound(dem, &proj, &pixels, w))
        } else {
            None
        };
        let new = Placed {
            curve,
            shadow_px,
            boundary,
            default_boundary,
            both_ends: both,
            shoulders_m,
            sight,
        };
        match &mut c.kind {
            CorrectionKind::Landform { placed, .. }
            | CorrectionKind::NoiseRegion { placed, .. } => *placed = Some(new),
            _ => {}
        }
    }
    Ok(())
}

impl LandformResult {
    fn new(
        (cells_changed, max_abs_dz_m): (usize, f64),
        max_curve_error_m: Option<f64>,
        field: &NoiseField,
        (sum2, count): (f64, usize),
        spectrum: Spectrum,
    ) -> LandformResult {
        LandformResult {
            cells_changed,
            max_abs_dz_m,
            max_curve_error_m,
            noise_sigma_m: field.sigma(),
            noise_rms_m: if count > 0 {
                (sum2 / count as f64).sqrt()
            } else {
                0.0
            },
            spectrum,
        }
    }
}

/// What a landform or a noise region did.
#[derive(Debug, Clone)]
pub struct LandformResult {
    pub cells_changed: usize,
    pub max_abs_dz_m: f64,
    /// Largest `|DEM - z|` along the placed silhouette afterwards
    /// (landforms).
    pub max_curve_error_m: Option<f64>,
    pub spectrum: Spectrum,
    /// Deviation of the noise field added (before the weights), metres.
    pub noise_sigma_m: f64,
    /// Root mean square of the noise added over the footprint, metres.
    pub noise_rms_m: f64,
}

/// Why a landform could not be applied.
#[derive(Debug, thiserror::Error)]
pub enum LandformError {
    #[error("the stroke was not placed (internal)")]
    NotPlaced,
    #[error("the boundary covers no cell of the DEM")]
    Empty,
    #[error("{0}")]
    Curve(#[from] super::control_curve::CurveError),
}

/// Per cell of the window `win` of `grid` (window-local cells): inside
/// the footprint, and the distance in metres to its edge.
fn footprint(grid: &Grid, win: Window, area: &MultiPolygon<f64>) -> (Vec<bool>, Vec<f64>) {
    let cell = grid.cell;
    let rings: Vec<LineString<f64>> = area
        .0
        .iter()
        .flat_map(|p| std::iter::once(p.exterior().clone()).chain(p.interiors().iter().cloned()))
        .map(|r| {
            LineString::new(
                r.coords()
                    .map(|q| Coord {
                        x: q.x * cell.hx,
                        y: q.y * cell.hy,
                    })
                    .collect(),
            )
        })
        .collect();
    let n = win.len();
    let mut inside = vec![false; n];
    let mut dist = vec![0.0; n];
    for r in 0..win.height {
        for c in 0..win.width {
            let (px, py) = (
                win.col as f64 + c as f64 + 0.5,
                win.row as f64 + r as f64 + 0.5,
            );
            let i = r * win.width + c;
            inside[i] = area.intersects(&Point::new(px, py));
            if inside[i] {
                let p = Point::new(px * cell.hx, py * cell.hy);
                dist[i] = rings
                    .iter()
                    .map(|l| Euclidean.distance(&p, l))
                    .fold(f64::INFINITY, f64::min);
            }
        }
    }
    (inside, dist)
}

/// The window of `grid` (DEM grid) covering `area`, with one cell to
/// spare.
fn area_window(grid: &Grid, area: &MultiPolygon<f64>) -> Option<Window> {
    bbox_window(area).and_then(|w| w.intersect(&grid.window))
}

/// The window (DEM cells) covering `area`'s bounding box, one cell to spare.
fn bbox_window(area: &MultiPolygon<f64>) -> Option<Window> {
    use geo::BoundingRect;
    let b = area.bounding_rect()?;
    let c0 = (b.min().x.floor() - 1.0) as i64;
    let r0 = (b.min().y.floor() - 1.0) as i64;
    let c1 = (b.max().x.ceil() + 1.0) as i64;
    let r1 = (b.max().y.ceil() + 1.0) as i64;
    Some(Window::new(
        c0,
        r0,
        (c1 - c0).max(0) as usize,
        (r1 - r0).max(0) as usize,
    ))
}

/// The silhouette's height above the ground along its shadow, split into
/// the bands of the à-trous pyramid (coarsest last): the profile of each
/// band on a uniform arc-length grid.
struct Profile {
    /// Arc-length spacing of the samples, metres.
    ds: f64,
    /// Per band, its values; their sum is the height above the ground.
    bands: Vec<Vec<f64>>,
    /// Per band, the boundary's scale (Gain et al.: `c_i / c_0`, the
    /// filter widths' ratio, here at least [`MIN_BOUNDARY_SCALE`]).
    scale: Vec<f64>,
}

/// The finest bands' boundaries are scaled in at most this far: a band
/// localised nearer its shadow would let the coarser ones in front of and
/// behind the silhouette hide its notches from the view.
pub const MIN_BOUNDARY_SCALE: f64 = 0.5;

impl Profile {
    fn new(s: &[f64], h: &[f64], ds: f64) -> Profile {
        let len = s.last().copied().unwrap_or(0.0);
        let n = (len / ds).floor() as usize + 1;
        let mut level: Vec<f64> = (0..n).map(|k| interp(s, h, k as f64 * ds)).collect();
        let mut bands = Vec::new();
        let mut widths = Vec::new();
        let mut step = 1usize;
        while n >= 8 && (4 * step) as f64 * ds <= len / 2.0 {
            let next = smooth(&level, step);
            bands.push(level.iter().zip(&next).map(|(a, b)| a - b).collect());
            widths.push(step as f64);
            level = next;
            step *= 2;
        }
        bands.push(level);
        widths.push(step as f64);
        let coarsest = widths.last().copied().unwrap_or(1.0);
        let scale = widths
            .iter()
            .map(|w| (w / coarsest).max(MIN_BOUNDARY_SCALE))
            .collect();
        Profile { ds, bands, scale }
    }

    /// Band `k` at arc length `t`.
    fn at(&self, k: usize, t: f64) -> f64 {
        let b = &self.bands[k];
        let x = (t / self.ds).clamp(0.0, (b.len() - 1) as f64);
        let i = (x.floor() as usize).min(b.len().saturating_sub(2));
        let f = x - i as f64;
        if b.len() == 1 {
            return b[0];
        }
        b[i] + f * (b[i + 1] - b[i])
    }
}

/// Linear interpolation of `(s, v)` at `t` (clamped to the ends).
fn interp(s: &[f64], v: &[f64], t: f64) -> f64 {
    let k = s.partition_point(|&x| x < t);
    if k == 0 {
        return v[0];
    }
    if k >= s.len() {
        return v[v.len() - 1];
    }
    let (a, b) = (s[k - 1], s[k]);
    let f = if b > a { (t - a) / (b - a) } else { 0.0 };
    v[k - 1] + f * (v[k] - v[k - 1])
}

/// How cells are attached to the shadow (Gain et al., "Parametrisation"):
/// by their projection on the base line through the shadow's end points,
/// which gives a shadow point and its arc length, when the shadow does not
/// fold back over that line; else by their closest shadow point (the
/// paper's "full curve search").
struct Attach<'a> {
    line: &'a [[f64; 2]],
    cum: &'a [f64],
    /// Base-line origin and direction, and the shadow's projections on it
    /// (increasing), when the shadow allows it.
    base: Option<([f64; 2], [f64; 2], Vec<f64>)>,
}

impl<'a> Attach<'a> {
    fn new(line: &'a [[f64; 2]], cum: &'a [f64]) -> Attach<'a> {
        let base = (|| {
            let (a, b) = (*line.first()?, *line.last()?);
            let len = (b[0] - a[0]).hypot(b[1] - a[1]);
            if len <= 0.0 {
                return None;
            }
            let u = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
            let proj: Vec<f64> = line
                .iter()
                .map(|p| (p[0] - a[0]) * u[0] + (p[1] - a[1]) * u[1])
                .collect();
            proj.windows(2).all(|w| w[1] > w[0]).then_some((a, u, proj))
        })();
        Attach { line, cum, base }
    }

    /// The arc length of the shadow point `p` is attached to, and the
    /// distance to it.
    fn at(&self, p: [f64; 2]) -> (f64, f64) {
        let Some((a, u, proj)) = &self.base else {
            return closest_on(p, self.line, self.cum);
        };
        let t = ((p[0] - a[0]) * u[0] + (p[1] - a[1]) * u[1]).clamp(proj[0], proj[proj.len() - 1]);
        let k = proj.partition_point(|&x| x < t).clamp(1, proj.len() - 1);
        let f = (t - proj[k - 1]) / (proj[k] - proj[k - 1]);
        let (q0, q1) = (self.line[k - 1], self.line[k]);
        let s = [q0[0] + f * (q1[0] - q0[0]), q0[1] + f * (q1[1] - q0[1])];
        (
            self.cum[k - 1] + f * (self.cum[k] - self.cum[k - 1]),
            (p[0] - s[0]).hypot(p[1] - s[1]),
        )
    }
}

/// The closest point of the polyline `line` to `p`: its arc length
/// (`cum` holds the vertices' arc lengths) and distance.
fn closest_on(p: [f64; 2], line: &[[f64; 2]], cum: &[f64]) -> (f64, f64) {
    if line.len() == 1 {
        return (0.0, (p[0] - line[0][0]).hypot(p[1] - line[0][1]));
    }
    let mut best = (0.0, f64::INFINITY);
    for (k, w) in line.windows(2).enumerate() {
        let (a, b) = (w[0], w[1]);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let l2 = dx * dx + dy * dy;
        let t = if l2 > 0.0 {
            (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / l2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy);
        if d < best.1 {
            best = (cum[k] + t * (cum[k + 1] - cum[k]), d);
        }
    }
    best
}

/// Gain et al.'s blending function `(a^2 - 1)^2` of the relative position
/// `a` between shadow (0) and boundary (1), 0 beyond.
fn blend(a: f64) -> f64 {
    if a >= 1.0 {
        0.0
    } else {
        (a * a - 1.0) * (a * a - 1.0)
    }
}

/// Cells next to the placed silhouette (within this many cells) take the
/// multigrid's harmonic correction that makes the bilinear surface pass
/// through it exactly.
pub const CORRECTION_CELLS: f64 = 3.0;

/// Applies a landform (see the module documentation) to `grid`: noise
/// (eqn 2), the multi-scale deformation (eqn 3), then the multigrid's
/// correction so the terrain interpolates the silhouette.
pub fn apply_landform(
    dem: &Dem,
    grid: &mut Grid,
    index: usize,
    silhouette: &StrokeRef,
    placed: Option<&Placed>,
) -> Result<LandformResult, LandformError> {
    let p = placed.ok_or(LandformError::NotPlaced)?;
    let cell = grid.cell;
    let win = area_window(grid, &p.boundary).ok_or(LandformError::Empty)?;
    let ds = 0.5 * cell.hx.min(cell.hy);
    let spec = spectrum(&p.curve, ds, crs_to_m(dem));
    let field = NoiseField::new(&spec, cell, 1.0, seed_for(index, silhouette));
    let (inside, edge) = footprint(grid, win, &p.boundary);
    let shadow: Vec<[f64; 2]> = p.shadow_px.iter().map(|&q| metric(q, cell)).collect();
    let mut cum = vec![0.0];
    for w in shadow.windows(2) {
        cum.push(cum.last().copied().unwrap_or(0.0) + (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]));
    }
    let fp = Footprint::new(grid, win, &inside, &edge, &Attach::new(&shadow, &cum));
    // The heights before this landform, window-local.
    let prior: Vec<f64> = (0..win.len())
        .map(|i| grid.values[fp.grid_index(i)])
        .collect();
    let noise = add_noise(grid, &fp, &field);
    // The silhouette's height above the (noisy) ground under it, band by
    // band, each blended in within its scaled boundary (eqn 3).
    let heights: Vec<f64> = p
        .curve
        .iter()
        .zip(&p.shadow_px)
        .map(|(q, s)| {
            let g = grid.bilinear(grid.local(*s)).unwrap_or(q[2]);
            q[2] - g
        })
        .collect();
    add_profile(grid, &fp, &Profile::new(&cum, &heights, ds));
    // Below the sight line through the silhouette (see [`Sight`]).
    if let Some(sight) = &p.sight {
        hold_under_sight(grid, &fp, sight, &prior, None);
    }
    // The multigrid's correction next to the silhouette: the bilinear
    // surface through the placed curve exactly.
    let curve = [CurveConstraint {
        points: p.curve.clone(),
    }];
    let reach = CORRECTION_CELLS * cell.hx.max(cell.hy);
    super::control_curve::solve_in(grid, &curve, win, false, |cons, _| {
        let near = crate::deform::locality::influence_mask(cons, cell, reach);
        near.iter().zip(&inside).map(|(&a, &b)| a && b).collect()
    })?;
    // Again after the correction, but for the cells of the bilinear
    // stencils the silhouette's points lie in: those are put on the sight
    // cone through the stroke (the surface that projects onto it, which
    // holds the placed curve), so that the bilinear surface between them
    // is seen on the stroke in every column, not only at the curve's
    // points (on Zion 30 m, smooth bump at 3 km: judge 0.56 -> 0.88).
    let stencil = stencil_cells(&p.shadow_px, win);
    if let Some(sight) = &p.sight {
        hold_under_sight(grid, &fp, sight, &prior, Some(&stencil));
        put_on_cone(grid, &fp, sight, &stencil);
    }
    ease_landform_spikes(grid, win, &fp.param, &stencil, p.sight.as_ref());
    let curve_error = super::control_curve::curve_error(grid, &p.curve);
    Ok(LandformResult::new(
        changes_in(grid, &fp),
        Some(curve_error),
        &field,
        noise,
        spec,
    ))
}

/// A landform's footprint in its window: per window cell, its arc length
/// on the shadow and its relative position between shadow (0) and
/// boundary (1) (Gain et al. eqn 1), `None` outside the footprint or on
/// nodata.
struct Footprint {
    win: Window,
    /// The window's offset in the grid (columns, rows) and the grid's width.
    offset: (usize, usize),
    grid_width: usize,
    param: Vec<Option<(f64, f64)>>,
}

impl Footprint {
    fn new(grid: &Grid, win: Window, inside: &[bool], edge: &[f64], attach: &Attach) -> Footprint {
        let cell = grid.cell;
        let offset = (
            (win.col - grid.window.col) as usize,
            (win.row - grid.window.row) as usize,
        );
        let mut fp = Footprint {
            win,
            offset,
            grid_width: grid.width(),
            param: vec![None; win.len()],
        };
        for r in 0..win.height {
            for c in 0..win.width {
                let i = r * win.width + c;
                if !inside[i] || grid.values[fp.grid_index(i)].is_nan() {
                    continue;
                }
                let pt = [
                    (win.col as f64 + c as f64 + 0.5) * cell.hx,
                    (win.row as f64 + r as f64 + 0.5) * cell.hy,
                ];
                let (t, d) = attach.at(pt);
                fp.param[i] = Some((t, d / (d + edge[i]).max(1e-12)));
            }
        }
        fp
    }

    /// The grid index of window cell `i`.
    fn grid_index(&self, i: usize) -> usize {
        let (r, c) = (i / self.win.width, i % self.win.width);
        (r + self.offset.1) * self.grid_width + c + self.offset.0
    }

    /// The footprint's cells, row by row: window index, grid column and
    /// row, arc length and relative position.
    fn cells(&self) -> impl Iterator<Item = (usize, usize, usize, f64, f64)> + '_ {
        self.param.iter().enumerate().filter_map(|(i, q)| {
            let (t, a) = (*q)?;
            let (r, c) = (i / self.win.width, i % self.win.width);
            Some((i, c + self.offset.0, r + self.offset.1, t, a))
        })
    }
}

/// Noise, blended in over the whole footprint (eqn 2); the sum of the
/// squared changes and their count.
fn add_noise(grid: &mut Grid, fp: &Footprint, field: &NoiseField) -> (f64, usize) {
    let (mut sum2, mut count) = (0.0, 0usize);
    if field.sigma() > 0.0 {
        for (i, gc, gr, _, a) in fp.cells() {
            let dz = blend(a) * field.at(grid, gc, gr);
            grid.values[fp.grid_index(i)] += dz;
            sum2 += dz * dz;
            count += 1;
        }
    }
    (sum2, count)
}

/// The silhouette's profile, band by band, each band blended in within its
/// scaled boundary (eqn 3).
fn add_profile(grid: &mut Grid, fp: &Footprint, profile: &Profile) {
    for (i, _, _, t, a) in fp.cells() {
        let dz: f64 = (0..profile.bands.len())
            .map(|k| blend(a / profile.scale[k]) * profile.at(k, t))
            .sum();
        grid.values[fp.grid_index(i)] += dz;
    }
}

/// Brings every footprint cell above its sight bound down to it (never
/// below its height before the landform), but for the cells `keep`
/// names.
fn hold_under_sight(
    grid: &mut Grid,
    fp: &Footprint,
    sight: &Sight,
    prior: &[f64],
    keep: Option<&[bool]>,
) {
    let win = fp.win;
    for (i, _, _, _, _) in fp.cells() {
        if keep.is_some_and(|k| k[i]) {
            continue;
        }
        let (r, c) = (i / win.width, i % win.width);
        let g = fp.grid_index(i);
        let bound = sight.bound(win.col + c as i64, win.row + r as i64);
        if bound.is_nan() || grid.values[g] <= bound {
            continue;
        }
        grid.values[g] = bound.max(prior[i]).min(grid.values[g]);
    }
}

/// Puts the footprint cells `cells` names on the sight cone through the
/// silhouette: the bilinear surface there is seen on the stroke.
fn put_on_cone(grid: &mut Grid, fp: &Footprint, sight: &Sight, cells: &[bool]) {
    let win = fp.win;
    for (i, _, _, _, _) in fp.cells() {
        if !cells[i] {
            continue;
        }
        let (r, c) = (i / win.width, i % win.width);
        let z = sight.cone(win.col + c as i64, win.row + r as i64);
        if z.is_finite() {
            grid.values[fp.grid_index(i)] = z;
        }
    }
}

/// The window cells of the bilinear stencils the shadow's points lie in.
fn stencil_cells(shadow_px: &[[f64; 2]], win: Window) -> Vec<bool> {
    let mut stencil = vec![false; win.len()];
    for q in shadow_px {
        let (c0, r0) = ((q[0] - 0.5).floor() as i64, (q[1] - 0.5).floor() as i64);
        for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let (c, r) = (c0 + dc - win.col, r0 + dr - win.row);
            if c >= 0 && r >= 0 && (c as usize) < win.width && (r as usize) < win.height {
                stencil[r as usize * win.width + c as usize] = true;
            }
        }
    }
    stencil
}

/// How many cells of the window the landform changed, and the largest
/// change.
fn changes_in(grid: &Grid, fp: &Footprint) -> (usize, f64) {
    let (mut changed, mut max_abs) = (0usize, 0f64);
    for i in 0..fp.win.len() {
        let g = fp.grid_index(i);
        let (v, b) = (grid.values[g], grid.base.data[g] as f64);
        if !v.is_nan() && v != b {
            changed += 1;
            max_abs = max_abs.max((v - b).abs());
        }
    }
    (changed, max_abs)
}

/// No spikes in the landform's change (see [`super::spike_easing`]): the
/// footprint's cells off the silhouette may rise towards a spike up to
/// their sight bound (they stay hidden under the stroke); the silhouette's
/// stencil cells give way only where no neighbour can.
fn ease_landform_spikes(
    grid: &mut Grid,
    win: Window,
    param: &[Option<(f64, f64)>],
    stencil: &[bool],
    sight: Option<&Sight>,
) {
    let (lc, lr) = (
        (win.col - grid.window.col) as usize,
        (win.row - grid.window.row) as usize,
    );
    let gw = grid.width();
    let at = move |i: usize| (i / win.width + lr) * gw + i % win.width + lc;
    let mut change: Vec<f64> = (0..win.len())
        .map(|i| grid.values[at(i)] - grid.base.data[at(i)] as f64)
        .collect();
    let own: Vec<bool> = param.iter().map(Option::is_some).collect();
    let movable: Vec<bool> = own.iter().zip(stencil).map(|(&o, &s)| o && !s).collect();
    let cap: Vec<f64> = (0..win.len())
        .map(|i| {
            let bound = sight.map_or(f64::INFINITY, |s| {
                s.bound(
                    win.col + (i % win.width) as i64,
                    win.row + (i / win.width) as i64,
                )
            });
            if bound.is_nan() {
                // Not projected: not raised.
                change[i]
            } else {
                bound - grid.base.data[at(i)] as f64
            }
        })
        .collect();
    let mut field = super::spike_easing::ChangeField {
        width: win.width,
        height: win.height,
        change: &mut change,
        movable: &movable,
        own: &own,
        cap: &cap,
    };
    if super::spike_easing::ease_spikes(&mut field, grid.cell) == 0 {
        return;
    }
    for (i, &d) in change.iter().enumerate() {
        if own[i] && !d.is_nan() {
            grid.values[at(i)] = grid.base.data[at(i)] as f64 + d;
        }
    }
}

/// Applies a noise region (region mode) to `grid`.
pub fn apply_noise_region(
    dem: &Dem,
    grid: &mut Grid,
    index: usize,
    stroke: &StrokeRef,
    amplitude_m: Option<f64>,
    placed: Option<&Placed>,
) -> Result<LandformResult, LandformError> {
    let p = placed.ok_or(LandformError::NotPlaced)?;
    let cell = grid.cell;
    let win = area_window(grid, &p.boundary).ok_or(LandformError::Empty)?;
    let spec = spectrum(&p.curve, 0.5 * cell.hx.min(cell.hy), crs_to_m(dem));
    let unit = NoiseField::new(&spec, cell, 1.0, seed_for(index, stroke));
    let gain = match amplitude_m {
        Some(a) if unit.sigma() > 0.0 => a / unit.sigma(),
        _ => 1.0,
    };
    let field = NoiseField::new(&spec, cell, gain, seed_for(index, stroke));
    let blend = field.coarsest_m().max(2.0 * cell.hx.max(cell.hy));
    let (inside, edge) = footprint(grid, win, &p.boundary);
    let (lc, lr) = (
        (win.col - grid.window.col) as usize,
        (win.row - grid.window.row) as usize,
    );
    let (mut sum2, mut count, mut changed, mut max_abs) = (0.0, 0usize, 0usize, 0f64);
    for r in 0..win.height {
        for c in 0..win.width {
            let i = r * win.width + c;
            let g = (r + lr) * grid.width() + c + lc;
            if !inside[i] || grid.values[g].is_nan() || field.sigma() == 0.0 {
                continue;
            }
            let t = (edge[i] / blend).min(1.0);
            let w = t * t * (3.0 - 2.0 * t);
            let dz = w * field.at(grid, c + lc, r + lr);
            if dz != 0.0 {
                grid.values[g] += dz;
                changed += 1;
                max_abs = max_abs.max(dz.abs());
            }
            sum2 += dz * dz;
            count += 1;
        }
    }
    Ok(LandformResult::new(
        (changed, max_abs),
        None,
        &field,
        (sum2, count),
        spec,
    ))
}

/// The footprint (boundary or region) and the shadow of a placed stroke
/// as GeoJSON geometries in the DEM's CRS, for the report: the defaults
/// to edit in a GIS and give back as the feature's Polygon and `shadow`.
pub fn geojson_of(dem: &Dem, p: &Placed) -> (serde_json::Value, serde_json::Value) {
    let gt = dem.geotransform;
    let ring = |r: &LineString<f64>| -> Vec<[f64; 2]> {
        r.coords()
            .map(|q| {
                let (x, y) = gt.pixel_to_crs(q.x, q.y);
                [x, y]
            })
            .collect()
    };
    let polys: Vec<Vec<Vec<[f64; 2]>>> = p
        .boundary
        .0
        .iter()
        .map(|poly| {
            std::iter::once(ring(poly.exterior()))
                .chain(poly.interiors().iter().map(ring))
                .collect()
        })
        .collect();
    let boundary = if polys.len() == 1 {
        serde_json::json!({"type": "Polygon", "coordinates": polys[0]})
    } else {
        serde_json::json!({"type": "MultiPolygon", "coordinates": polys})
    };
    // The shadow, thinned to every tenth point (and the last).
    let n = p.curve.len();
    let shadow: Vec<[f64; 2]> = p
        .curve
        .iter()
        .enumerate()
        .filter(|(k, _)| k % 10 == 0 || *k + 1 == n)
        .map(|(_, q)| [q[0], q[1]])
        .collect();
    (
        boundary,
        serde_json::json!({"type": "LineString", "coordinates": shadow}),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_single_peak_gets_a_round_capsule_and_a_ridge_an_elongated_one() {
        let cell = CellSize { hx: 10.0, hy: 10.0 };
        let track: Vec<[f64; 2]> = (0..=100).map(|k| [k as f64, 50.0]).collect();
        let peak: Vec<f64> = (0..=100).map(|k| 50.0 - (k as f64 - 50.0).abs()).collect();
        let ridge: Vec<f64> = (0..=100)
            .map(|k| (k as f64).min(100.0 - k as f64).min(10.0))
            .collect();
        let extent = |b: &MultiPolygon<f64>| {
            use geo::BoundingRect;
            let r = b.bounding_rect().unwrap();
            (r.width(), r.height())
        };
        let (pb, psh) = capsule(&track, &peak, cell);
        let (rb, rsh) = capsule(&track, &ridge, cell);
        let (pw, ph) = extent(&pb);
        let (rw, rh) = extent(&rb);
        assert!(
            (psh[0] - 500.0).abs() < 50.0 && (psh[1] - 500.0).abs() < 50.0,
            "{psh:?}"
        );
        assert!((pw / ph - 1.0).abs() < 0.1, "peak {pw} x {ph}");
        assert!(rw / rh > 3.0, "ridge {rw} x {rh} {rsh:?}");
        for p in &track {
            assert!(pb.intersects(&Point::new(p[0], p[1])));
            assert!(rb.intersects(&Point::new(p[0], p[1])));
        }
    }
}
