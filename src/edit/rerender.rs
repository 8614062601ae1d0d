//! Rendering a view again after a small change of its terrain, taking
//! from the earlier render what the change cannot reach.
//!
//! The edit's rounds render each view's region again on every new
//! terrain; a round that asks for little (a stalled round, the final
//! spike flattening) changes a few cells, and most of the image with them
//! stays as it was. Both terrains are patched from the view's terrain
//! before the edit ([`LocalTerrain::with_heights`]), so the vertices that
//! differ are found by comparing the two patches alone
//! ([`LocalTerrain::changed_since`]). From their box:
//!
//! - **Depth buffer.** The renderer draws vertical strips of the image
//!   independently, each with its own culling; a strip that no changed
//!   triangle (before or after the change) can show draws the same
//!   triangles in the same order, so it is copied
//!   ([`DepthBuffer::render_rows_keeping`]). Which strips: the pixel
//!   columns of the changed cells' box times their heights before and
//!   after, projected as the renderer projects its blocks
//!   ([`DepthBuffer::box_columns`]).
//! - **Silhouettes.** A column's refinement reads the terrain only under
//!   rays of its own column plane, within the rows of
//!   [`reach_rows`] (the extraction records where its walks went beyond:
//!   [`crate::features::ColumnSamples::confined`]), and the cells next to
//!   a pixel's hit ([`LocalTerrain::twist_around`]). Where the vertical
//!   prism over the changed cells, widened by a cell, does not meet those
//!   rows of the column plane, and the column's depths and triangles are
//!   those of the earlier render, the column's samples are the earlier
//!   ones ([`crate::features::extract_silhouettes_reusing`]); the curves
//!   are linked again from all columns. The casts' max pyramid changes
//!   over whole blocks around the changed cells, so a kept column's ray
//!   may descend a block it skipped before: its hit is the same, as a
//!   traversal's hit does not depend on the level it crosses a block at
//!   (the premise of the casts' later starts in `features::silhouettes`),
//!   but for a crossing shorter than the traversal's epsilon at a block's
//!   last cell; the fidelity suite and `tests/edit_rerender.rs` check it.
//!
//! Anything out of the ordinary (another camera or region, terrains not
//! patched from one, a change of the height range, a change the geometry
//! cannot bound) renders the region afresh, as before. Where the change
//! from the rounds' latest render reaches every column but that from the
//! unedited terrain does not (a pass's terrain as the write stores it,
//! rounded to a few changed cells), the edit re-renders from the
//! unedited view's region instead, cut from the pass's whole render
//! ([`RenderedView::region_of`], [`RenderedView::rerender_keeps_some`]).

use super::rendered_view::{RenderedView, StrokeRegion};
use crate::features::{reach_rows, FeatureError};
use crate::render::{DepthBuffer, LocalTerrain};
use crate::view::{dot, Camera};

/// Pixels added on each side of the columns the change's prism reaches.
const PRISM_MARGIN_PX: f64 = 1.0;

impl RenderedView {
    /// [`RenderedView::render_terrain_region`] of `terrain`, taking from
    /// `earlier` (a render of the same region with the same camera, on a
    /// terrain patched from the same one) the strips of the depth buffer
    /// and the silhouette columns its change cannot reach. The result is
    /// that of a fresh render, to the bit.
    pub fn rerender_terrain_region(
        terrain: LocalTerrain,
        camera: &Camera,
        region: &StrokeRegion,
        earlier: &RenderedView,
    ) -> Result<RenderedView, FeatureError> {
        let comparable = earlier.camera == *camera && earlier.region.as_ref() == Some(region);
        let change = comparable
            .then(|| terrain.changed_since(&earlier.terrain))
            .flatten();
        let Some(change) = change else {
            return Self::render_terrain_region(terrain, camera, region);
        };
        let Some(reach) = change_reach(&terrain, &earlier.terrain, camera, change) else {
            return Self::render_terrain_region(terrain, camera, region);
        };
        let (depth, ()) = rayon::join(
            || {
                DepthBuffer::render_rows_keeping(
                    &terrain,
                    camera,
                    &region.last_row,
                    &earlier.depth,
                    &|x0, x1| reach.raster.is_none_or(|(a, b)| x1 < a || x0 > b),
                )
            },
            || terrain.build_cast_index(),
        );
        let same = same_columns(&depth, &earlier.depth);
        let kept: Vec<bool> = (0..camera.width)
            .map(|x| {
                reach.columns.is_none_or(|(a, b)| x < a || x > b)
                    && same.get(x).copied().unwrap_or(false)
            })
            .collect();
        if std::env::var_os("DEMSKETCH_DEBUG").is_some() {
            eprintln!(
                "re-render after a change of vertices {change:?}: raster columns {:?}, silhouette columns {:?}, {} of {} columns kept",
                reach.raster,
                reach.columns,
                kept.iter().filter(|k| **k).count(),
                kept.len()
            );
        }
        let keep = |x: usize| kept.get(x).copied().unwrap_or(false);
        Self::from_depth_reusing(terrain, depth, Some(region), Some((earlier, &keep)))
    }
}

impl RenderedView {
    /// Whether [`RenderedView::rerender_terrain_region`] of `terrain`
    /// from `earlier` can take any column of it: the same camera and
    /// region, terrains patched from one, and a change whose reach is
    /// bounded short of the whole image (through the depth buffer or the
    /// silhouettes).
    pub fn rerender_keeps_some(
        terrain: &LocalTerrain,
        camera: &Camera,
        region: &StrokeRegion,
        earlier: &RenderedView,
    ) -> bool {
        earlier.camera == *camera
            && earlier.region.as_ref() == Some(region)
            && Self::change_keeps_some(terrain, camera, &earlier.terrain)
    }

    /// Whether the change from `earlier` to `terrain` (patched from one)
    /// has a reach bounded short of the whole image of `camera`, through
    /// the depth buffer or the silhouettes (see
    /// [`RenderedView::rerender_keeps_some`]).
    pub fn change_keeps_some(
        terrain: &LocalTerrain,
        camera: &Camera,
        earlier: &LocalTerrain,
    ) -> bool {
        let Some(change) = terrain.changed_since(earlier) else {
            return false;
        };
        let all = Some((0, camera.width.saturating_sub(1)));
        change_reach(terrain, earlier, camera, change)
            .is_some_and(|r| r.raster != all || r.columns != all)
    }
}

/// The pixel columns a change of terrain can reach: through the depth
/// buffer (`raster`) and through the silhouettes' refinement (`columns`);
/// `None` in either: no column.
#[derive(Debug, Clone, Copy)]
struct Reach {
    raster: Option<(usize, usize)>,
    columns: Option<(usize, usize)>,
}

/// The columns the change `change` (a box of changed vertices, end
/// exclusive, or none) of `terrain` from `earlier` can reach; `None` where
/// they cannot be bounded (all of them).
fn change_reach(
    terrain: &LocalTerrain,
    earlier: &LocalTerrain,
    camera: &Camera,
    change: Option<(usize, usize, usize, usize)>,
) -> Option<Reach> {
    let Some((c0, r0, c1, r1)) = change else {
        return Some(Reach {
            raster: None,
            columns: None,
        });
    };
    let (nx, ny) = (terrain.nx, terrain.ny);
    if nx < 2 || ny < 2 || c1 == 0 || r1 == 0 {
        return None;
    }
    // The cells with a changed corner (vertices c0 - 1 ..= c1 across).
    let cells = [c0.saturating_sub(1), c1.min(nx - 1)];
    let rows = [r0.saturating_sub(1), r1.min(ny - 1)];
    let heights = height_span([terrain, earlier], cells, rows);
    let raster = match heights {
        Some(h) => DepthBuffer::box_columns(terrain, camera, cells, rows, h),
        None => None,
    };
    // One cell more for the neighbours of a pixel's hit cell.
    let wide_cells = [cells[0].saturating_sub(1), (cells[1] + 1).min(nx - 1)];
    let wide_rows = [rows[0].saturating_sub(1), (rows[1] + 1).min(ny - 1)];
    let columns = prism_columns(terrain, camera, wide_cells, wide_rows)?;
    Some(Reach { raster, columns })
}

/// Lowest and highest apparent height of the vertices `cells` x `rows`
/// (inclusive ranges) of either terrain, nodata skipped; `None` when all
/// are nodata.
fn height_span(
    terrains: [&LocalTerrain; 2],
    cells: [usize; 2],
    rows: [usize; 2],
) -> Option<(f32, f32)> {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for t in terrains {
        for r in rows[0]..=rows[1] {
            for c in cells[0]..=cells[1] {
                let z = t.z.at_cr(c, r);
                if !z.is_nan() {
                    lo = lo.min(z);
                    hi = hi.max(z);
                }
            }
        }
    }
    (lo <= hi).then_some((lo, hi))
}

/// The pixel columns (inclusive, clipped to the image; `Some(None)`: none
/// of the image) whose column plane meets, within the rows of
/// [`reach_rows`], the vertical prism over the vertices `cells` x `rows`
/// (inclusive index ranges) of `terrain`; `None` when that cannot be
/// bounded (a prism edge crossing those rows' planes at or behind the
/// camera, the eye within the prism).
///
/// The plane of an image row (through the eye) cuts the prism in a
/// quadrilateral with its corners on the prism's four vertical edges; the
/// image of a vertical edge is a straight line, so over a range of rows
/// the prism's columns lie between the least and greatest column of the
/// edges at the range's two ends.
fn prism_columns(
    terrain: &LocalTerrain,
    camera: &Camera,
    cells: [usize; 2],
    rows: [usize; 2],
) -> Option<Option<(usize, usize)>> {
    let (rows_lo, rows_hi) = reach_rows(camera.height);
    let (mut x_lo, mut x_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (c, r) in [
        (cells[0], rows[0]),
        (cells[1], rows[0]),
        (cells[0], rows[1]),
        (cells[1], rows[1]),
    ] {
        let (e, n) = terrain.v_to_en(c as f64, r as f64);
        for row in [rows_lo, rows_hi] {
            let x = edge_column(camera, (e, n), row)?;
            x_lo = x_lo.min(x);
            x_hi = x_hi.max(x);
        }
    }
    // Pixel i's centre is i + 0.5.
    let first = (x_lo - 0.5 - PRISM_MARGIN_PX).floor();
    let last = (x_hi - 0.5 + PRISM_MARGIN_PX).ceil();
    let w = camera.width as f64;
    if !(first.is_finite() && last.is_finite()) {
        return None;
    }
    if last < 0.0 || first > w - 1.0 {
        return Some(None);
    }
    Some(Some((first.max(0.0) as usize, last.min(w - 1.0) as usize)))
}

/// The image column coordinate at which the vertical line through local
/// ground point `(e, n)` crosses image row coordinate `row`; `None` where
/// it crosses that row's plane at or behind the camera (or never).
fn edge_column(camera: &Camera, (e, n): (f64, f64), row: f64) -> Option<f64> {
    let (rt, up, fw) = (camera.right, camera.up, camera.forward);
    let f = camera.focal_px;
    let p0 = [e, n, 0.0];
    // Camera coordinates of (e, n, z): p + z * dz per axis.
    let (x0, y0, z0) = (dot(p0, rt), dot(p0, up), dot(p0, fw));
    let (dx, dy, dz) = (rt[2], up[2], fw[2]);
    // row = H/2 - f y / depth  <=>  k depth = f y, with k = H/2 - row.
    let k = camera.height as f64 / 2.0 - row;
    let denom = k * dz - f * dy;
    if denom == 0.0 || !denom.is_finite() {
        return None;
    }
    let z = (f * y0 - k * z0) / denom;
    let depth = z0 + z * dz;
    if !(depth > 0.0) {
        return None;
    }
    let x = camera.width as f64 / 2.0 + f * (x0 + z * dx) / depth;
    x.is_finite().then_some(x)
}

/// Per column `x` of `a`: whether it holds the same depths and triangles
/// as that of `b` (to the bit; the two of one image size, else no column
/// is). One pass over the rows, in the buffers' order (a column at a time
/// would read a cache line per pixel).
fn same_columns(a: &DepthBuffer, b: &DepthBuffer) -> Vec<bool> {
    let w = a.width;
    let n = w * a.height;
    let sized = |d: &DepthBuffer| d.depth.len() >= n && d.triangle.len() >= n;
    if b.width != w || a.depth.len() != b.depth.len() || !sized(a) || !sized(b) {
        return vec![false; w];
    }
    let mut same = vec![true; w];
    for j in 0..a.height {
        let k = j * w;
        let rows = (&a.depth[k..k + w], &b.depth[k..k + w]);
        let ids = (&a.triangle[k..k + w], &b.triangle[k..k + w]);
        // (zipped slices and a non-short-circuit `&`: no bounds checks
        // and no branch, so the loop vectorises)
        for ((s, (da, db)), (ta, tb)) in same
            .iter_mut()
            .zip(rows.0.iter().zip(rows.1))
            .zip(ids.0.iter().zip(ids.1))
        {
            *s &= (da.to_bits() == db.to_bits()) & (ta == tb);
        }
    }
    same
}
