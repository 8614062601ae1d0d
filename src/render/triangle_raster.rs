//! Exact z-buffer rasterisation of the triangulated height field: for every
//! pixel centre, the nearest triangle of a [`LocalTerrain`] its ray passes
//! through, and the distance to it. The same answer as casting one exact ray
//! per pixel ([`LocalTerrain::cast`]), at a fraction of the cost, because the
//! work follows the triangles (most of which cover no pixel centre at all)
//! instead of the rays.
//!
//! How:
//! - **Exact coverage without clipping.** In camera coordinates (eye at the
//!   origin) the ray through pixel `(px, py)` is `d = (px - W/2, H/2 - py, f)`.
//!   It passes through triangle `P0 P1 P2` exactly when the three numbers
//!   `(Pj x Pk) . d` have the sign of `det = P0 . (P1 x P2)`; each is an
//!   affine function of `(px, py)` (the 2D homogeneous edge functions of
//!   Olano and Greer). The hit is `d * det / (n . d)` with `n` the
//!   triangle's normal. This needs no near-plane clipping, and because the
//!   cross product is exactly antisymmetric in floating point, the two
//!   triangles sharing an edge evaluate exactly opposite numbers on it:
//!   with inclusive tests no pixel centre falls through a crack.
//! - **Front to back by blocks.** The grid is cut into blocks of
//!   [`BLOCK`] x [`BLOCK`] cells and visited in rings of increasing
//!   Manhattan block distance from the eye's block. A ray's horizontal
//!   track moves monotonically away from the eye along both grid axes, so
//!   it meets the blocks of successive rings in order and never two blocks
//!   of one ring: a pixel filled by an earlier ring is final.
//! - **Screen boxes of blocks.** A block's box (its cells' extent times its
//!   height range) is projected after clipping away the depths nearer than
//!   any of its points can be seen at (its distance from the eye over the
//!   longest pixel ray's stretch), so that blocks reaching behind the
//!   camera, beside or below the view, still get a tight pixel box; only
//!   blocks next to the eye count as covering the whole image.
//! - **Occlusion culling.** Per image column the renderer keeps the
//!   topmost row from which every pixel down to the bottom is final. A
//!   block whose screen box lies entirely below those rows is hidden and
//!   skipped without looking at its triangles; most of the far terrain
//!   behind the first ridges goes this way.
//! - **Parallel by image strips.** Vertical strips of the image are
//!   rendered independently (rayon), each with its own buffers and its own
//!   culling state.

use super::depth_buffer::SKY;
use super::strip_columns::StripColumns;
use super::terrain::{fmax, fmin};
use super::terrain::{LocalTerrain, RANGE_BLOCK};
use crate::view::{cross, dot, Camera};
use rayon::prelude::*;

/// Block edge in cells for ordering and culling: the terrain's range blocks.
const BLOCK: usize = RANGE_BLOCK;

/// Blocks per superblock edge: a superblock whose screen box is empty is
/// skipped with one test instead of one per block.
const SUPER: usize = 4;

/// Pixel columns per strip rendered by one task.
const STRIP: usize = 128;

/// The camera in the terrain's vertex coordinates: camera coordinates
/// (right, up, forward) of vertex `(c, r)` with apparent height `z` are
/// `o + c * gc + r * gr + z * gz` per axis.
#[derive(Clone, Copy)]
struct VertexToCamera {
    o: [f64; 3],
    gc: [f64; 3],
    gr: [f64; 3],
    gz: [f64; 3],
}

impl VertexToCamera {
    fn new(terrain: &LocalTerrain, camera: &Camera) -> Self {
        let (e0, n0) = terrain.v_to_en(0.0, 0.0);
        let (e1, n1) = terrain.v_to_en(1.0, 0.0);
        let (e2, n2) = terrain.v_to_en(0.0, 1.0);
        let axes = [camera.right, camera.up, camera.forward];
        let mut m = VertexToCamera {
            o: [0.0; 3],
            gc: [0.0; 3],
            gr: [0.0; 3],
            gz: [0.0; 3],
        };
        for (k, a) in axes.iter().enumerate() {
            m.o[k] = a[0] * e0 + a[1] * n0;
            m.gc[k] = a[0] * (e1 - e0) + a[1] * (n1 - n0);
            m.gr[k] = a[0] * (e2 - e0) + a[1] * (n2 - n0);
            m.gz[k] = a[2];
        }
        m
    }

    #[inline]
    fn apply(&self, c: f64, r: f64, z: f64) -> [f64; 3] {
        [
            self.o[0] + c * self.gc[0] + r * self.gr[0] + z * self.gz[0],
            self.o[1] + c * self.gc[1] + r * self.gr[1] + z * self.gz[1],
            self.o[2] + c * self.gc[2] + r * self.gr[2] + z * self.gz[2],
        ]
    }
}

/// One block's screen footprint.
#[derive(Clone, Copy)]
struct BlockBox {
    /// Block index (column, row) in the block grid.
    bx: u32,
    by: u32,
    /// Pixel index ranges (inclusive) whose centres may show the block.
    x0: i32,
    x1: i32,
    y0: i32,
    y1: i32,
}

/// Render the depth (distance along the unit pixel-centre ray, infinite for
/// sky) and the triangle id of every pixel of `camera` over `terrain`.
///
/// With `last_row`, only rows `0..=last_row[x]` of each column `x` are
/// rendered (none where it is negative): the culling treats the rows below
/// as final from the start, so terrain seen only there is never drawn. The
/// other pixels get a NaN depth and [`SKY`].
pub(crate) fn rasterise(
    terrain: &LocalTerrain,
    camera: &Camera,
    last_row: Option<&[i32]>,
) -> (Vec<f32>, Vec<u32>) {
    let (mut depth, mut triangle) = pooled_buffers(camera);
    rasterise_into(terrain, camera, last_row, &mut depth, &mut triangle, true);
    (depth, triangle)
}

/// Depth and triangle buffers of `camera`'s image: buffers of an earlier
/// render where there are some (see `buffer_pool`), else fresh zeroed
/// ones; either way each strip clears its own columns in parallel, so no
/// page is touched serially.
fn pooled_buffers(camera: &Camera) -> (Vec<f32>, Vec<u32>) {
    let n = camera.width * camera.height;
    (
        crate::buffer_pool::overwritten_f32(n),
        crate::buffer_pool::overwritten_u32(n),
    )
}

/// True when `earlier`'s depths and triangles are of `camera`'s image.
fn of_image(earlier: (&[f32], &[u32]), camera: &Camera) -> bool {
    let n = camera.width * camera.height;
    earlier.0.len() == n && earlier.1.len() == n
}

/// [`rasterise`], taking the strips of pixel columns `x0..=x1` for which
/// `keep(x0, x1)` holds from `earlier` (the depths and triangles of an
/// earlier render of the same camera and rows, on a terrain whose changed
/// triangles none of those columns can show: see [`box_columns`]). Each
/// strip is rendered on its own, with its own culling, so a strip no
/// changed triangle reaches comes out as it did.
pub(crate) fn rasterise_keeping(
    terrain: &LocalTerrain,
    camera: &Camera,
    last_row: Option<&[i32]>,
    earlier: (&[f32], &[u32]),
    keep: &(dyn Fn(usize, usize) -> bool + Sync),
) -> (Vec<f32>, Vec<u32>) {
    if !of_image(earlier, camera) {
        return rasterise(terrain, camera, last_row);
    }
    let (mut depth, mut triangle) = pooled_buffers(camera);
    rasterise_strips(
        terrain,
        camera,
        last_row,
        (&mut depth, &mut triangle, true),
        Some((earlier, keep)),
        None,
    );
    // Kept strips hold the far layers already; drawing them again changes
    // nothing there (a pixel takes a layer's hit only when it is nearer).
    draw_far_layers(terrain, camera, &mut depth, &mut triangle);
    (depth, triangle)
}

/// The pixel columns (inclusive range) whose centres may show a point of
/// the box of the vertices `c` x `r` (index ranges, end inclusive, of the
/// terrain's vertices) times the apparent heights `lo..=hi`, as the
/// renderer's block culling projects boxes (with its margin); `None` when
/// no pixel may show it.
pub(crate) fn box_columns(
    terrain: &LocalTerrain,
    camera: &Camera,
    c: [usize; 2],
    r: [usize; 2],
    (lo, hi): (f32, f32),
) -> Option<(usize, usize)> {
    let m = VertexToCamera::new(terrain, camera);
    let (x0, x1, _, _) = BoxProjector::new(&m, camera).pixels(c, r, lo, hi)?;
    Some((x0.max(0) as usize, x1.max(0) as usize))
}

/// [`rasterise`] into `depth` and `triangle`, resized to the image; with
/// `reused`, buffers of an earlier view (whatever they hold), which each
/// strip clears in parallel before drawing: a caller rendering view after
/// view (the browser app) then neither allocates nor touches fresh pages.
/// Without it, buffers already cleared (`f32::INFINITY`, [`SKY`]).
pub(crate) fn rasterise_into(
    terrain: &LocalTerrain,
    camera: &Camera,
    last_row: Option<&[i32]>,
    depth: &mut Vec<f32>,
    triangle: &mut Vec<u32>,
    reused: bool,
) {
    rasterise_strips(
        terrain,
        camera,
        last_row,
        (depth, triangle, reused),
        None,
        None,
    );
    draw_far_layers(terrain, camera, depth, triangle);
}

/// [`rasterise`] of the whole image, with rows `0..first_row[x]` of each
/// column `x` taken from `earlier` (a render of the same camera and
/// terrain whose pixels there are the whole render's, as a render of
/// rows `0..=first_row[x] - 1` gives them: [`rasterise`] with
/// `last_row`). The rows from `first_row[x]` down are rendered with the
/// culling of a whole render plus that of the blocks and cells whose
/// pixels all lie in the rows taken: every triangle that may show one of
/// those rows' pixels is drawn in the whole render's order, so they are
/// the whole render's. Terrains with far layers render whole.
pub(crate) fn rasterise_below(
    terrain: &LocalTerrain,
    camera: &Camera,
    first_row: &[i32],
    earlier: (&[f32], &[u32]),
) -> (Vec<f32>, Vec<u32>) {
    if !of_image(earlier, camera) || first_row.len() != camera.width || !terrain.far.is_empty() {
        return rasterise(terrain, camera, None);
    }
    let (mut depth, mut triangle) = pooled_buffers(camera);
    rasterise_strips(
        terrain,
        camera,
        None,
        (&mut depth, &mut triangle, true),
        None,
        Some((first_row, earlier)),
    );
    (depth, triangle)
}

/// Each far layer of `terrain` ([`super::far_layers`]) drawn into a render
/// of its own grid.
fn draw_far_layers(
    terrain: &LocalTerrain,
    camera: &Camera,
    depth: &mut [f32],
    triangle: &mut [u32],
) {
    for layer in &terrain.far {
        draw_far_layer(layer, camera, depth, triangle);
    }
}

/// Draw a far layer of a terrain ([`super::far_layers`]) into `depth` and
/// `triangle` (the terrain's, already drawn, and the layers inside this
/// one): the layer's render (kept by the layer for the next render with
/// this camera), taken where it is nearer, its ids moved to the layer's.
/// The layer is rendered only in the rows the image does not already show
/// nearer than any of its points ([`super::far_layers::FarLayer::rows_shown`]):
/// the nearer hit wins there whatever the layer holds, so the image is the
/// one a whole render of the layer gives, and the far terrain behind the
/// nearer ridges is culled by the layer's own culling instead of drawn
/// (a ring's inner hole otherwise leaves its bottom rows open, and with
/// them every triangle in view). The pixels not drawn here
/// (NaN outside `last_row`) and those the layer does not reach keep what
/// they show: a render of some rows gets the whole render's values in
/// them, as for the terrain's own triangles.
fn draw_far_layer(
    layer: &super::far_layers::FarLayer,
    camera: &Camera,
    depth: &mut [f32],
    triangle: &mut [u32],
) {
    // Only the rows the image so far does not already show nearer (the
    // layer's own culling then skips what lies behind the nearer ridges).
    let needed = layer.rows_shown(depth, camera.width);
    let r = layer.render_with(camera, &needed, |t, rows, kept| match kept {
        Some((old, keep)) => rasterise_keeping(t, camera, rows, (&old.depth, &old.triangle), keep),
        None => rasterise(t, camera, rows),
    });
    let (id0, w) = (layer.id0, camera.width.max(1));
    // Only the rows some column needs: below them every pixel is nearer
    // than any point of the layer (or NaN), where the composite keeps it.
    // Nor the rows above the layer's first finite depth (sky or not drawn:
    // never nearer).
    let rows = needed.iter().max().map_or(0, |&m| (m + 1).max(0) as usize);
    let n = (rows * w).min(depth.len()).min(r.depth.len());
    let a = (r.first_row * w).min(n);
    depth[a..n]
        .par_chunks_mut(w)
        .zip(triangle[a..n].par_chunks_mut(w))
        .zip(
            r.depth[a..n]
                .par_chunks(w)
                .zip(r.triangle[a..n].par_chunks(w)),
        )
        .for_each(|((d, t), (fd, ft))| take_nearer(d, t, fd, ft, id0));
}

/// One row of [`draw_far_layer`]'s composite: where the layer's depth `fd`
/// is nearer than the image's `d`, its depth and its triangle (moved by
/// `id0`) are taken. Selects, not branches, with `id0` by value: the loop
/// vectorises. (`wrapping_add`: the sum is computed for every pixel but
/// kept only where the layer is nearer, where it is the old `ft + id0`.)
/// Compiled for AVX2 where the CPU has it (selects: the same result).
#[inline(never)]
fn take_nearer(d: &mut [f32], t: &mut [u32], fd: &[f32], ft: &[u32], id0: u32) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { take_nearer_avx2(d, t, fd, ft, id0) };
        return;
    }
    take_nearer_body(d, t, fd, ft, id0);
}

/// [`take_nearer`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn take_nearer_avx2(d: &mut [f32], t: &mut [u32], fd: &[f32], ft: &[u32], id0: u32) {
    take_nearer_body(d, t, fd, ft, id0);
}

/// The loop of [`take_nearer`].
#[inline(always)]
fn take_nearer_body(d: &mut [f32], t: &mut [u32], fd: &[f32], ft: &[u32], id0: u32) {
    for (((dv, tv), &f), &fi) in d.iter_mut().zip(t.iter_mut()).zip(fd).zip(ft) {
        let nearer = f < *dv;
        *tv = if nearer { fi.wrapping_add(id0) } else { *tv };
        *dv = if nearer { f } else { *dv };
    }
}

/// A render's strips kept from an earlier one: its depths and triangles,
/// and which strips (pixel columns `x0..=x1`) to take from them.
type KeptStrips<'a> = (
    (&'a [f32], &'a [u32]),
    &'a (dyn Fn(usize, usize) -> bool + Sync),
);

/// [`rasterise_into`], each strip either rendered or, where `kept` says
/// so, copied from the earlier render.
fn rasterise_strips(
    terrain: &LocalTerrain,
    camera: &Camera,
    last_row: Option<&[i32]>,
    (depth, triangle, reused): (&mut Vec<f32>, &mut Vec<u32>, bool),
    kept: Option<KeptStrips>,
    below: Option<RowsAbove>,
) {
    let (w, h) = (camera.width, camera.height);
    debug_assert!(last_row.is_none_or(|l| l.len() == w));
    let mut reused = reused;
    if depth.len() != w * h || triangle.len() != w * h {
        depth.clear();
        depth.resize(w * h, f32::INFINITY);
        triangle.clear();
        triangle.resize(w * h, SKY);
        reused = false;
    }
    let clear = |cols: &mut StripColumns| {
        if reused {
            for j in 0..cols.rows() {
                let (t, id) = cols.row_mut(j);
                t.fill(f32::INFINITY);
                id.fill(SKY);
            }
        }
    };
    let empty = terrain.nx < 2 || terrain.ny < 2;
    let m = VertexToCamera::new(terrain, camera);
    let blocks = if empty {
        None
    } else {
        Some(block_boxes(terrain, camera, &m)).filter(|b| !b.is_empty())
    };
    let Some(blocks) = blocks else {
        StripColumns::split(depth, triangle, w, STRIP)
            .into_par_iter()
            .for_each(|mut cols| clear(&mut cols));
        return;
    };
    // Each strip renders ray parameters in place, then turns them into
    // distances (sky: an infinite parameter gives an infinite distance).
    StripColumns::split(depth, triangle, w, STRIP)
        .into_par_iter()
        .for_each(|mut cols| {
            if let Some((earlier, keep)) = kept {
                if keep(cols.x0(), cols.x0() + cols.width() - 1) {
                    copy_strip(earlier, w, &mut cols);
                    return;
                }
            }
            clear(&mut cols);
            let first = below.map(|(first, _)| first);
            render_strip(terrain, camera, &m, &blocks, &mut cols, last_row, first);
            parameters_to_distances(camera, &mut cols);
            if let Some((first, earlier)) = below {
                copy_rows_above(earlier, first, w, &mut cols);
            }
        });
}

/// The rows above a render's first rows: per image column the first row
/// rendered, and the depths and triangles of the rows above it, taken
/// from an earlier render ([`rasterise_below`]).
type RowsAbove<'a> = (&'a [i32], (&'a [f32], &'a [u32]));

/// Rows `0..first[x]` of each of the strip's columns `x` copied from an
/// earlier render's `(depths, triangles)` (of an image `w` wide).
fn copy_rows_above(
    (depth, triangle): (&[f32], &[u32]),
    first: &[i32],
    w: usize,
    cols: &mut StripColumns,
) {
    let (x0, sw) = (cols.x0(), cols.width());
    let first = &first[x0..x0 + sw];
    let deepest = first
        .iter()
        .copied()
        .max()
        .unwrap_or(0)
        .clamp(0, cols.rows() as i32);
    for j in 0..deepest as usize {
        let k = j * w + x0;
        let (t, id) = cols.row_mut(j);
        for (i, &f) in first.iter().enumerate() {
            if (j as i32) < f {
                t[i] = depth[k + i];
                id[i] = triangle[k + i];
            }
        }
    }
}

/// The strip's columns of an earlier render's `(depths, triangles)` (of
/// an image `w` wide), copied into it.
fn copy_strip((depth, triangle): (&[f32], &[u32]), w: usize, cols: &mut StripColumns) {
    let (x0, sw) = (cols.x0(), cols.width());
    for j in 0..cols.rows() {
        let k = j * w + x0;
        let (t, id) = cols.row_mut(j);
        t.copy_from_slice(&depth[k..k + sw]);
        id.copy_from_slice(&triangle[k..k + sw]);
    }
}

/// Turn the ray parameters of a strip (distance over `|d|`, with the
/// unnormalised pixel-centre ray `d = (u, v, f)`) into distances, in `f32`.
fn parameters_to_distances(camera: &Camera, cols: &mut StripColumns) {
    let (w, h) = (camera.width as f32, camera.height as f32);
    let f = camera.focal_px as f32;
    let uu: Vec<f32> = (cols.x0()..cols.x0() + cols.width())
        .map(|i| {
            let u = i as f32 + 0.5 - w / 2.0;
            u * u
        })
        .collect();
    for j in 0..cols.rows() {
        let v = h / 2.0 - (j as f32 + 0.5);
        let vf = v * v + f * f;
        let (t, _) = cols.row_mut(j);
        for (t, &uu) in t.iter_mut().zip(&uu) {
            *t *= (uu + vf).sqrt();
        }
    }
}

/// The blocks that may be seen, with their screen boxes, ordered by ring
/// (Manhattan block distance from the eye's block), and the ring starts.
struct Blocks {
    boxes: Vec<BlockBox>,
    /// `boxes[ring_start[k]..ring_start[k + 1]]` is ring `k`.
    ring_start: Vec<usize>,
}

impl Blocks {
    fn is_empty(&self) -> bool {
        self.boxes.is_empty()
    }
}

fn block_boxes(terrain: &LocalTerrain, camera: &Camera, m: &VertexToCamera) -> Blocks {
    let (cx, cy) = (terrain.nx - 1, terrain.ny - 1);
    let (bw, bh) = (cx.div_ceil(BLOCK), cy.div_ceil(BLOCK));
    let eye = terrain.eye_vertex();
    let ebx = (eye.0 / BLOCK as f64).floor() as i64;
    let eby = (eye.1 / BLOCK as f64).floor() as i64;
    let ranges = terrain.block_ranges();
    debug_assert_eq!((ranges.bw, ranges.bh), (bw, bh));
    let projector = BoxProjector::new(m, camera);
    // Cell range of blocks bx0..bx1 (or rows).
    let cells = |b0: usize, b1: usize, n: usize| [b0 * BLOCK, (b1 * BLOCK).min(n)];
    let rows: Vec<Vec<(u32, BlockBox)>> = (0..bh.div_ceil(SUPER))
        .into_par_iter()
        .map(|sy| {
            let mut out = Vec::new();
            let (by0, by1) = (sy * SUPER, ((sy + 1) * SUPER).min(bh));
            for sx in 0..bw.div_ceil(SUPER) {
                let (bx0, bx1) = (sx * SUPER, ((sx + 1) * SUPER).min(bw));
                // A superblock off the image: none of its blocks is seen.
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for by in by0..by1 {
                    for k in by * bw + bx0..by * bw + bx1 {
                        lo = lo.min(ranges.lo[k]);
                        hi = hi.max(ranges.hi[k]);
                    }
                }
                if !(hi >= lo)
                    || projector
                        .pixels(cells(bx0, bx1, cx), cells(by0, by1, cy), lo, hi)
                        .is_none()
                {
                    continue;
                }
                for by in by0..by1 {
                    for bx in bx0..bx1 {
                        let (lo, hi) = (ranges.lo[by * bw + bx], ranges.hi[by * bw + bx]);
                        if !(hi >= lo) {
                            continue;
                        }
                        let Some((x0, x1, y0, y1)) =
                            projector.pixels(cells(bx, bx + 1, cx), cells(by, by + 1, cy), lo, hi)
                        else {
                            continue;
                        };
                        let ring =
                            (bx as i64 - ebx).unsigned_abs() + (by as i64 - eby).unsigned_abs();
                        let bb = BlockBox {
                            bx: bx as u32,
                            by: by as u32,
                            x0,
                            x1,
                            y0,
                            y1,
                        };
                        out.push((ring as u32, bb));
                    }
                }
            }
            out
        })
        .collect();
    // Counting sort by ring.
    let max_ring = rows
        .iter()
        .flat_map(|r| r.iter().map(|(k, _)| *k as usize))
        .max()
        .unwrap_or(0);
    let mut ring_start = vec![0usize; max_ring + 2];
    for (k, _) in rows.iter().flatten() {
        ring_start[*k as usize + 1] += 1;
    }
    for k in 0..=max_ring {
        ring_start[k + 1] += ring_start[k];
    }
    let mut fill = ring_start.clone();
    let total = ring_start[max_ring + 1];
    let mut boxes = vec![
        BlockBox {
            bx: 0,
            by: 0,
            x0: 0,
            x1: -1,
            y0: 0,
            y1: -1,
        };
        total
    ];
    for (k, b) in rows.into_iter().flatten() {
        boxes[fill[k as usize]] = b;
        fill[k as usize] += 1;
    }
    Blocks { boxes, ring_start }
}

/// Projects boxes of the grid (a cell range times a height range) to the
/// pixels that may show them.
///
/// A hit seen through a pixel centre at camera depth `z` lies within
/// `z * ray_stretch` of the eye (`ray_stretch`: the longest pixel ray
/// `(u, v, f)` over its depth `f`, with a margin), so a box farther than `L`
/// from the eye shows nothing nearer than depth `L / ray_stretch`: its part
/// nearer than that (which projects far out, or not at all) is clipped away
/// before projecting.
struct BoxProjector<'a> {
    m: &'a VertexToCamera,
    w: f64,
    h: f64,
    f: f64,
    ray_stretch: f64,
}

/// Boxes that may be seen nearer than this depth (the eye is in or next to
/// them) count as covering the whole image.
const MIN_NEAR: f64 = 1e-6;

impl<'a> BoxProjector<'a> {
    fn new(m: &'a VertexToCamera, camera: &Camera) -> Self {
        let (w, h, f) = (camera.width as f64, camera.height as f64, camera.focal_px);
        BoxProjector {
            m,
            w,
            h,
            f,
            ray_stretch: 2.0 * ((w * w + h * h) / (4.0 * f * f) + 1.0).sqrt(),
        }
    }

    /// Inclusive pixel column and row ranges (`x0, x1, y0, y1`) that may
    /// show box `c` x `r` (cell ranges) x `lo..=hi` (heights), `None` for
    /// none.
    fn pixels(
        &self,
        c: [usize; 2],
        r: [usize; 2],
        lo: f32,
        hi: f32,
    ) -> Option<(i32, i32, i32, i32)> {
        let m = self.m;
        // corner j + 4 l: column c[j & 1], row r[j >> 1], height [lo, hi][l]
        let mut corners = [[0.0; 3]; 8];
        // (k is the axis: it indexes the corners' coordinates and the
        // matrix's rows in step)
        #[allow(clippy::needless_range_loop)]
        for k in 0..3 {
            let zg = [lo as f64 * m.gz[k], hi as f64 * m.gz[k]];
            for j in 0..4 {
                let xy = m.o[k] + c[j & 1] as f64 * m.gc[k] + r[j >> 1] as f64 * m.gr[k];
                corners[j][k] = xy + zg[0];
                corners[j + 4][k] = xy + zg[1];
            }
        }
        // Least distance from the eye, bounded below along the direction
        // of the centre (`sum` is 8 times the centre).
        let mut sum = [0.0; 3];
        for p in &corners {
            for k in 0..3 {
                sum[k] += p[k];
            }
        }
        let least = corners
            .iter()
            .map(|&p| dot(sum, p))
            .fold(f64::INFINITY, fmin)
            / dot(sum, sum).sqrt();
        let near = least / self.ray_stretch;
        if !(near >= MIN_NEAR) {
            return Some((0, self.w as i32 - 1, 0, self.h as i32 - 1));
        }
        let (mut sx0, mut sx1, mut sy0, mut sy1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        let mut add = |p: [f64; 3]| {
            let q = self.f / p[2];
            let (sx, sy) = (p[0] * q, -p[1] * q);
            sx0 = fmin(sx0, sx);
            sx1 = fmax(sx1, sx);
            sy0 = fmin(sy0, sy);
            sy1 = fmax(sy1, sy);
        };
        if corners.iter().all(|p| p[2] >= near) {
            corners.iter().for_each(|&p| add(p));
        } else {
            // The box clipped to depths >= near: its corners there and the
            // crossings of its 12 edges.
            for (k, &p) in corners.iter().enumerate() {
                if p[2] >= near {
                    add(p);
                }
                for bit in [1, 2, 4] {
                    let q = corners[k | bit];
                    if k & bit == 0 && (p[2] >= near) != (q[2] >= near) {
                        let s = (near - p[2]) / (q[2] - p[2]);
                        add([p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]), near]);
                    }
                }
            }
        }
        // Pixel i's centre is i + 0.5; a margin of one pixel absorbs
        // rounding. (No point at or beyond `near`: no pixel.)
        let (hw, hh) = (self.w / 2.0, self.h / 2.0);
        let x0 = (sx0 + hw - 1.5).ceil().max(0.0);
        let x1 = (sx1 + hw + 0.5).floor().min(self.w - 1.0);
        let y0 = (sy0 + hh - 1.5).ceil().max(0.0);
        let y1 = (sy1 + hh + 0.5).floor().min(self.h - 1.0);
        (x0 <= x1 && y0 <= y1).then_some((x0 as i32, x1 as i32, y0 as i32, y1 as i32))
    }
}

/// A projected vertex: camera coordinates and the pixel columns and rows
/// whose centres a box reaching it may hold.
#[derive(Clone, Copy, Default)]
struct PVertex {
    p: [f64; 3],
    /// For screen position `(sx, sy)`: `ceil(sx - 0.5 - 1e-7)` and
    /// `floor(sx - 0.5 + 1e-7)` (as [`ceil_i32`], [`floor_i32`]), so that a
    /// box's pixel range is the least first and greatest second entry of
    /// its vertices (both roundings are monotonic).
    ix: [i32; 2],
    /// The same for `sy`.
    iy: [i32; 2],
    /// 0: in front of the camera (`ix`, `iy` valid), 1: nodata, 2: at or
    /// behind the camera plane.
    state: u8,
}

/// Pixel indices `i` whose centre `i + 0.5` may be at screen coordinate
/// `s` or beyond, and at `s` or before (with a rounding margin).
#[inline]
fn pixel_bounds(s: f64) -> [i32; 2] {
    [ceil_i32(s - 0.5 - 1e-7), floor_i32(s - 0.5 + 1e-7)]
}

/// Project camera-space point `p` for an image `w` x `h` with focal length
/// `f` (pixels).
#[inline]
fn project(p: [f64; 3], w: f64, h: f64, f: f64) -> PVertex {
    if p[2] > 0.0 {
        let q = f / p[2];
        PVertex {
            p,
            ix: pixel_bounds(w / 2.0 + p[0] * q),
            iy: pixel_bounds(h / 2.0 - p[1] * q),
            state: 0,
        }
    } else {
        PVertex {
            p,
            state: 2,
            ..PVertex::default()
        }
    }
}

/// Two triangles stand in for a cell's bilinear patch where they cannot put
/// a boundary farther than this from the patch's, in pixels.
pub const PATCH_TOLERANCE_PX: f64 = 0.05;

/// The most sub-cells along a cell's side.
const MAX_SUBDIVISIONS: usize = 16;

/// Sub-cells along each side with which the bilinear patch of a cell
/// (projected corners `v`, apparent heights `z` in the order `00, 10, 01,
/// 11`) is drawn within [`PATCH_TOLERANCE_PX`]: two triangles depart from
/// the patch by at most a quarter of its twist `|z00 + z11 - z10 - z01|`,
/// `n x n` sub-cells by `1 / n^2` of that, seen at the depth of the nearest
/// corner. 1 (two triangles) for far cells and holes; at most
/// [`MAX_SUBDIVISIONS`], for cells at the eye.
#[inline]
fn subdivisions(v: [&PVertex; 4], z: [f32; 4], f: f64) -> usize {
    let twist = (z[0] as f64 + z[3] as f64 - z[1] as f64 - z[2] as f64).abs();
    if !(twist > 0.0) {
        return 1;
    }
    if v.iter().any(|v| v.state != 0) {
        return if v.iter().any(|v| v.state == 1) {
            1
        } else {
            MAX_SUBDIVISIONS
        };
    }
    let near = v.iter().map(|v| v.p[2]).fold(f64::INFINITY, fmin);
    let px = 0.25 * twist * f / near;
    if !(px > PATCH_TOLERANCE_PX) {
        return 1;
    }
    ((px / PATCH_TOLERANCE_PX).sqrt().ceil() as usize).min(MAX_SUBDIVISIONS)
}

/// Render the ray parameters (distance / |d|, with the unnormalised ray
/// `d`) and triangle ids of the strip's columns; with `last_row`, only those
/// rows (see [`rasterise`]); with `first_row`, the blocks and cells all of
/// whose pixels lie above the first row of their columns are not drawn
/// (the rows there are taken from elsewhere, see [`rasterise_below`]).
fn render_strip(
    terrain: &LocalTerrain,
    camera: &Camera,
    m: &VertexToCamera,
    blocks: &Blocks,
    cols: &mut StripColumns,
    last_row: Option<&[i32]>,
    first_row: Option<&[i32]>,
) {
    let h = camera.height;
    let (x0, sw) = (cols.x0(), cols.width());
    // ytop[k]: every pixel of strip column k from this row down is final
    // (rows not asked for count as final from the start).
    let mut ytop: Vec<i32> = match last_row {
        Some(l) => l[x0..x0 + sw]
            .iter()
            .map(|&r| (r + 1).clamp(0, h as i32))
            .collect(),
        None => vec![h as i32; sw],
    };
    let skipped = ytop.clone();
    if ytop.iter().all(|&t| t == 0) {
        for j in 0..h {
            cols.row_mut(j).0.fill(f32::NAN);
        }
        return;
    }
    let mut verts = vec![PVertex::default(); (BLOCK + 1) * (BLOCK + 1)];
    let mut sub = Vec::with_capacity((MAX_SUBDIVISIONS + 1) * (MAX_SUBDIVISIONS + 1));
    let first = first_row.map(|f| &f[x0..x0 + sw]);
    let ctx = Raster {
        terrain,
        camera,
        x0: x0 as i32,
        x1: (x0 + sw) as i32 - 1,
        h: h as i32,
        first,
    };
    let rings = blocks.ring_start.len() - 1;
    for ring in 0..rings {
        // strip columns of the blocks drawn in this ring
        let (mut drawn0, mut drawn1) = (sw, 0);
        for b in &blocks.boxes[blocks.ring_start[ring]..blocks.ring_start[ring + 1]] {
            let bx0 = b.x0.max(ctx.x0);
            let bx1 = b.x1.min(ctx.x1);
            if bx0 > bx1 {
                continue;
            }
            // Hidden when every column of its box is final below its top
            // (or, with first rows, not wanted above its bottom).
            let hidden = match first {
                None => (bx0..=bx1).all(|x| ytop[(x - ctx.x0) as usize] <= b.y0),
                Some(f) => (bx0..=bx1).all(|x| {
                    let k = (x - ctx.x0) as usize;
                    ytop[k] <= b.y0 || b.y1 < f[k]
                }),
            };
            if hidden {
                continue;
            }
            ctx.draw_block(m, b, &mut verts, &mut sub, &ytop, cols);
            drawn0 = drawn0.min((bx0 - ctx.x0) as usize);
            drawn1 = drawn1.max((bx1 - ctx.x0) as usize + 1);
        }
        // Only those columns can have changed (a block draws inside its box).
        for (k, yt) in ytop.iter_mut().enumerate().take(drawn1).skip(drawn0) {
            while *yt > 0 && cols.id(k, *yt as usize - 1) != SKY {
                *yt -= 1;
            }
        }
    }
    if last_row.is_some() {
        for j in 0..h {
            let (t, id) = cols.row_mut(j);
            for ((t, id), &y) in t.iter_mut().zip(id.iter_mut()).zip(&skipped) {
                if j as i32 >= y {
                    *t = f32::NAN;
                    *id = SKY;
                }
            }
        }
    }
}

/// What one strip task draws into.
struct Raster<'a> {
    terrain: &'a LocalTerrain,
    camera: &'a Camera,
    /// Inclusive pixel column range of the strip.
    x0: i32,
    x1: i32,
    h: i32,
    /// Per strip column, the first row wanted ([`render_strip`]'s
    /// `first_row`); `None`: every row.
    first: Option<&'a [i32]>,
}

impl Raster<'_> {
    fn draw_block(
        &self,
        m: &VertexToCamera,
        b: &BlockBox,
        verts: &mut [PVertex],
        sub: &mut Vec<PVertex>,
        ytop: &[i32],
        cols: &mut StripColumns,
    ) {
        let t = self.terrain;
        let (cx, cy) = (t.nx - 1, t.ny - 1);
        let c0 = b.bx as usize * BLOCK;
        let r0 = b.by as usize * BLOCK;
        let c1 = ((b.bx as usize + 1) * BLOCK).min(cx);
        let r1 = ((b.by as usize + 1) * BLOCK).min(cy);
        let vw = c1 - c0 + 1;
        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
        let f = self.camera.focal_px;
        for r in r0..=r1 {
            for c in c0..=c1 {
                let z = t.z.at_cr(c, r);
                let v = &mut verts[(r - r0) * vw + (c - c0)];
                if z.is_nan() {
                    v.state = 1;
                    continue;
                }
                *v = project(m.apply(c as f64, r as f64, z as f64), w, h, f);
            }
        }
        let cells_x = cx as u32;
        for r in r0..r1 {
            for c in c0..c1 {
                let k = (r - r0) * vw + (c - c0);
                let (a, bq, cq, d) = (&verts[k], &verts[k + 1], &verts[k + vw], &verts[k + vw + 1]);
                // Most far cells cover no pixel centre or lie behind what is
                // drawn: one test of the cell's box rejects both triangles
                // (whose boxes lie inside it).
                if a.state | bq.state | cq.state | d.state == 0
                    && self.box_hidden_or_empty([a, bq, cq, d], ytop)
                {
                    continue;
                }
                let id = 2 * (r as u32 * cells_x + c as u32);
                let z = t.z.quad(c, r);
                let n = subdivisions([a, bq, cq, d], z, f);
                if n > 1 {
                    self.draw_patch(m, (c, r), n, id, ytop, cols, sub);
                    continue;
                }
                // triangle 0: (c,r) (c+1,r) (c+1,r+1); 1: (c,r) (c,r+1) (c+1,r+1)
                self.draw_triangle(a, bq, d, id, ytop, cols);
                self.draw_triangle(a, cq, d, id + 1, ytop, cols);
            }
        }
    }

    /// Draw the bilinear patch of cell `(c, r)` as `n` x `n` sub-cells of
    /// two triangles each, their vertices on the patch; every triangle
    /// keeps the id of the half of the cell it lies in (`id`: half 0).
    #[allow(clippy::too_many_arguments)]
    fn draw_patch(
        &self,
        m: &VertexToCamera,
        (c, r): (usize, usize),
        n: usize,
        id: u32,
        ytop: &[i32],
        cols: &mut StripColumns,
        sub: &mut Vec<PVertex>,
    ) {
        let t = self.terrain;
        let [h00, h10, h01, h11] = t.z.quad(c, r).map(f64::from);
        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
        let f = self.camera.focal_px;
        let vn = n + 1;
        sub.clear();
        for j in 0..=n {
            let fy = j as f64 / n as f64;
            let (left, right) = (h00 + (h01 - h00) * fy, h10 + (h11 - h10) * fy);
            for i in 0..=n {
                let fx = i as f64 / n as f64;
                let z = left + (right - left) * fx;
                sub.push(project(m.apply(c as f64 + fx, r as f64 + fy, z), w, h, f));
            }
        }
        for j in 0..n {
            for i in 0..n {
                let q = j * vn + i;
                let (a, b, cc, d) = (&sub[q], &sub[q + 1], &sub[q + vn], &sub[q + vn + 1]);
                if a.state | b.state | cc.state | d.state == 0
                    && self.box_hidden_or_empty([a, b, cc, d], ytop)
                {
                    continue;
                }
                // The cell's diagonal runs through the sub-cells i == j.
                let (h0, h1) = match i.cmp(&j) {
                    std::cmp::Ordering::Greater => (0, 0),
                    std::cmp::Ordering::Less => (1, 1),
                    std::cmp::Ordering::Equal => (0, 1),
                };
                self.draw_triangle(a, b, d, id + h0, ytop, cols);
                self.draw_triangle(a, cc, d, id + h1, ytop, cols);
            }
        }
    }

    /// Whether the screen box of projected vertices (all in front of the
    /// camera) holds no pixel centre of the strip, or only pixels that are
    /// final already.
    #[inline]
    fn box_hidden_or_empty(&self, v: [&PVertex; 4], ytop: &[i32]) -> bool {
        let px0 = v[0].ix[0].min(v[1].ix[0]).min(v[2].ix[0].min(v[3].ix[0]));
        let px1 = v[0].ix[1].max(v[1].ix[1]).max(v[2].ix[1].max(v[3].ix[1]));
        let (px0, px1) = (px0.max(self.x0), px1.min(self.x1));
        if px0 > px1 {
            return true;
        }
        let py0 = v[0].iy[0].min(v[1].iy[0]).min(v[2].iy[0].min(v[3].iy[0]));
        let py1 = v[0].iy[1].max(v[1].iy[1]).max(v[2].iy[1].max(v[3].iy[1]));
        let (py0, py1) = (py0.max(0), py1.min(self.h - 1));
        let cols = (px0 - self.x0) as usize..=(px1 - self.x0) as usize;
        py0 > py1
            || match self.first {
                None => ytop[cols].iter().all(|&t| t <= py0),
                Some(f) => ytop[cols.clone()]
                    .iter()
                    .zip(&f[cols])
                    .all(|(&t, &f)| t <= py0 || py1 < f),
            }
    }

    #[inline]
    #[allow(clippy::too_many_arguments)]
    fn draw_triangle(
        &self,
        a: &PVertex,
        b: &PVertex,
        c: &PVertex,
        id: u32,
        ytop: &[i32],
        cols: &mut StripColumns,
    ) {
        if (a.state | b.state | c.state) & 1 != 0 {
            return; // hole
        }
        let (px0, px1, py0, py1);
        if a.state | b.state | c.state == 0 {
            // pixel centres within the screen box, with a rounding margin
            px0 = a.ix[0].min(b.ix[0]).min(c.ix[0]).max(self.x0);
            px1 = a.ix[1].max(b.ix[1]).max(c.ix[1]).min(self.x1);
            if px0 > px1 {
                return;
            }
            py0 = a.iy[0].min(b.iy[0]).min(c.iy[0]).max(0);
            py1 = a.iy[1].max(b.iy[1]).max(c.iy[1]).min(self.h - 1);
            if py0 > py1 {
                return;
            }
            // hidden behind what earlier rings drew
            if ytop[(px0 - self.x0) as usize..=(px1 - self.x0) as usize]
                .iter()
                .all(|&t| t <= py0)
            {
                return;
            }
        } else {
            if a.state & b.state & c.state == 2 {
                return; // wholly behind the camera
            }
            match self.clipped_box(a, b, c) {
                Some((x0, x1, y0, y1)) => {
                    px0 = x0;
                    px1 = x1;
                    py0 = y0;
                    py1 = y1;
                }
                None => return,
            }
        }
        let (p0, p1, p2) = (a.p, b.p, c.p);
        let e0 = cross(p1, p2);
        let e1 = cross(p2, p0);
        let e2 = cross(p0, p1);
        let det = dot(p0, e0);
        if det == 0.0 || !det.is_finite() {
            return; // edge-on: seen as a line, covers no pixel centre
        }
        let s = det.signum();
        let (w2, h2, f) = (
            self.camera.width as f64 / 2.0,
            self.camera.height as f64 / 2.0,
            self.camera.focal_px,
        );
        // E . d with d = (px - w2, h2 - py, f) as  ax * px + ay * py + k
        let edge = |e: [f64; 3]| {
            let e = [e[0] * s, e[1] * s, e[2] * s];
            (e[0], -e[1], e[2] * f - e[0] * w2 + e[1] * h2)
        };
        let (a0, b0, k0) = edge(e0);
        let (a1, b1, k1) = edge(e1);
        let (a2, b2, k2) = edge(e2);
        // n . d, n = e0 + e1 + e2 (the normal scaled by 2 * area)
        let n = [
            e0[0] + e1[0] + e2[0],
            e0[1] + e1[1] + e2[1],
            e0[2] + e1[2] + e2[2],
        ];
        let (na, nb, nk) = (n[0], -n[1], n[2] * f - n[0] * w2 + n[1] * h2);
        let edges = [(a0, b0, k0), (a1, b1, k1), (a2, b2, k2)];
        let depth = (det, na, nb, nk);
        let margin = span_margin(&edges, px1, py1);
        if !(margin < 0.25) {
            // Degenerate (nearly edge-on in a row): widened spans, every
            // pixel tested.
            self.fill_rows_tested(&edges, depth, (px0, px1, py0, py1), id, cols);
            return;
        }
        // Spans of more than 4 pixels skip rows whose computed bounds cross.
        let wide = px1 - px0 > 3;
        for py in py0..=py1 {
            let y = py as f64 + 0.5;
            // The span of the row inside all three edges: a pixel centre x
            // passes edge (a, b, k) (a != 0) when a * x + b * y + k >= 0 as
            // computed, so near -(b * y + k) / a up to `margin`.
            let mut by = [0.0; 3];
            let (mut xl, mut xh) = (f64::NEG_INFINITY, f64::INFINITY);
            for (&(a, b, k), by) in edges.iter().zip(&mut by) {
                *by = b * y;
                let c = *by + k;
                // (`-c / a` is a number here, never NaN: a finite margin
                // bounds it; its zeros' signs do not matter below)
                if a > 0.0 {
                    xl = fmax(xl, -c / a);
                } else if a < 0.0 {
                    xh = fmin(xh, -c / a);
                } else if c < 0.0 {
                    // a = 0: the test is c >= 0 exactly
                    xh = f64::NEG_INFINITY;
                }
            }
            if wide && !(xh >= xl) {
                continue;
            }
            let lo = px0.max(ceil_i32(xl - 0.5 - margin));
            let hi = px1.min(floor_i32(xh - 0.5 + margin));
            if lo > hi {
                continue;
            }
            // Pixels farther inside than the margin pass every test (the
            // extra 1e-9 covers the rounding of `floor_i32`).
            let inner = margin + 1e-9;
            let ilo = ceil_i32(xl - 0.5 + inner).clamp(lo, hi + 1);
            let ihi = floor_i32(xh - 0.5 - inner).clamp(ilo - 1, hi);
            let nby = nb * y;
            let (trow, irow) = cols.row_mut(py as usize);
            let mut tested = |px: i32| {
                let x = px as f64 + 0.5;
                let covered = edges
                    .iter()
                    .zip(&by)
                    .all(|(&(a, _, k), &by)| a * x + by + k >= 0.0);
                if covered {
                    let tt = (det / (na * x + nby + nk)) as f32;
                    let k = (px - self.x0) as usize;
                    if tt > 0.0 && tt < trow[k] {
                        trow[k] = tt;
                        irow[k] = id;
                    }
                }
            };
            (lo..ilo).for_each(&mut tested);
            (ihi + 1..=hi).for_each(&mut tested);
            if ilo <= ihi {
                // Branch-free, so that occlusion mispredicts nothing.
                let k = (ilo - self.x0) as usize..=(ihi - self.x0) as usize;
                let (ts, is) = (&mut trow[k.clone()], &mut irow[k]);
                for ((t, i), px) in ts.iter_mut().zip(is.iter_mut()).zip(ilo..) {
                    let x = px as f64 + 0.5;
                    let tt = (det / (na * x + nby + nk)) as f32;
                    let nearer = (tt > 0.0) & (tt < *t);
                    *t = if nearer { tt } else { *t };
                    *i = if nearer { id } else { *i };
                }
            }
        }
    }

    /// Rows `py0..=py1` of a triangle with edge functions `edges` and depth
    /// `(det, na, nb, nk)` (ray parameter `det / (na x + nb y + nk)`) over
    /// columns `px0..=px1`: each row's span widened by a pixel on each side,
    /// every pixel in it tested.
    #[allow(clippy::too_many_arguments)]
    fn fill_rows_tested(
        &self,
        edges: &[(f64, f64, f64); 3],
        (det, na, nb, nk): (f64, f64, f64, f64),
        (px0, px1, py0, py1): (i32, i32, i32, i32),
        id: u32,
        cols: &mut StripColumns,
    ) {
        let [(a0, b0, k0), (a1, b1, k1), (a2, b2, k2)] = *edges;
        for py in py0..=py1 {
            let y = py as f64 + 0.5;
            let (mut lo, mut hi) = (px0, px1);
            if px1 - px0 > 3 {
                let (mut xl, mut xh) = (f64::NEG_INFINITY, f64::INFINITY);
                for &(a, b, k) in edges {
                    let c = b * y + k;
                    if a > 0.0 {
                        xl = xl.max(-c / a);
                    } else if a < 0.0 {
                        xh = xh.min(-c / a);
                    } else if c < 0.0 {
                        xh = f64::NEG_INFINITY;
                    }
                }
                if !(xh >= xl) {
                    continue;
                }
                // pixel centres px + 0.5 in [xl, xh], one pixel of margin
                lo = lo.max(floor_i32(xl - 1.5));
                hi = hi.min(floor_i32(xh + 0.5));
            }
            for px in lo..=hi {
                let x = px as f64 + 0.5;
                let w0 = a0 * x + b0 * y + k0;
                let w1 = a1 * x + b1 * y + k1;
                let w2v = a2 * x + b2 * y + k2;
                if w0 < 0.0 || w1 < 0.0 || w2v < 0.0 {
                    continue;
                }
                let nd = na * x + nb * y + nk;
                let tt = (det / nd) as f32;
                let k = (px - self.x0) as usize;
                let (trow, irow) = cols.row_mut(py as usize);
                if tt > 0.0 && tt < trow[k] {
                    trow[k] = tt;
                    irow[k] = id;
                }
            }
        }
    }

    /// Pixel box of a triangle that reaches the camera plane: the part in
    /// front of a near plane, projected.
    fn clipped_box(&self, a: &PVertex, b: &PVertex, c: &PVertex) -> Option<(i32, i32, i32, i32)> {
        let near = 1e-6;
        let pts = [a.p, b.p, c.p];
        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
        let f = self.camera.focal_px;
        let (mut sx0, mut sx1, mut sy0, mut sy1) = (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        );
        let mut add = |p: [f64; 3]| {
            let sx = w / 2.0 + f * p[0] / p[2];
            let sy = h / 2.0 - f * p[1] / p[2];
            sx0 = sx0.min(sx);
            sx1 = sx1.max(sx);
            sy0 = sy0.min(sy);
            sy1 = sy1.max(sy);
        };
        for i in 0..3 {
            let (p, q) = (pts[i], pts[(i + 1) % 3]);
            if p[2] >= near {
                add(p);
            }
            if (p[2] >= near) != (q[2] >= near) {
                let s = (near - p[2]) / (q[2] - p[2]);
                add([p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1]), near]);
            }
        }
        if !(sx1 >= sx0) {
            return None;
        }
        let x0 = ((sx0 - 1.5).max(-1.0).ceil() as i32).max(self.x0);
        let x1 = ((sx1 + 0.5).min(w + 1.0).floor() as i32).min(self.x1);
        let y0 = ((sy0 - 1.5).max(-1.0).ceil() as i32).max(0);
        let y1 = ((sy1 + 0.5).min(h + 1.0).floor() as i32).min(self.h - 1);
        (x0 <= x1 && y0 <= y1).then_some((x0, x1, y0, y1))
    }
}

/// A bound, in pixels along a row, on where the computed edge tests
/// `a * x + b * y + k >= 0` of a triangle can disagree with the computed
/// row bounds `x = -(b * y + k) / a` (`a != 0`), for pixel centres
/// `0 <= x <= px1 + 1`, `0 <= y <= py1 + 1`: the tests' rounding is below
/// `3u (|a x| + |b y| + |k|)` and the bound's below `3u (|b y| + |k|) / |a|`
/// (`u` = 2^-53), so `4e-15 (x + (|b y| + |k|) / |a|)` holds with room.
/// (`a = 0` edges are exact: their test is the row's `b * y + k >= 0`.)
fn span_margin(edges: &[(f64, f64, f64); 3], px1: i32, py1: i32) -> f64 {
    let (xmax, ymax) = (px1 as f64 + 1.0, py1 as f64 + 1.0);
    let mut g = 0.0;
    for &(a, b, k) in edges {
        if a != 0.0 {
            // a sum, so that a NaN or infinity is kept
            g += (b.abs() * ymax + k.abs()) / a.abs();
        }
    }
    4e-15 * (xmax + g)
}

/// `floor` to i32 without a libm call or a branch, saturating far outside
/// the image (truncation is floor for the shifted value, kept
/// non-negative and at most `i32::MAX`, where `as` would saturate; NaN
/// gives `-SHIFT`).
#[inline]
fn floor_i32(v: f64) -> i32 {
    const SHIFT: f64 = 4_194_304.0;
    let t = v + SHIFT;
    // one `maxsd` (NaN gives 0), one `minsd`
    let t = fmin(if t > 0.0 { t } else { 0.0 }, i32::MAX as f64);
    // SAFETY: `t` is a number within `0..=i32::MAX` (both exact in f64),
    // where the conversion is defined (it truncates, as `as` does); the
    // unchecked one is a single instruction, without `as`'s saturation.
    (unsafe { t.to_int_unchecked::<i32>() }) - SHIFT as i32
}

/// `ceil` to i32, as [`floor_i32`].
#[inline]
fn ceil_i32(v: f64) -> i32 {
    -floor_i32(-v)
}
