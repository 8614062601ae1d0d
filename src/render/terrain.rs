//! The triangulated height field in a viewpoint's local frame, ready for ray
//! casting: the part of a DEM within the maximum view distance, vertex
//! heights made apparent (relative to the eye, curvature and refraction
//! subtracted, see [`crate::view::LocalFrame`]), and a max-height mip pyramid
//! for empty-space skipping.
//!
//! Geometry: the vertices are the DEM's cell centres; vertex `(c, r)` of the
//! terrain is the centre of DEM cell `(col0 + c, row0 + r)`. Each quad of four
//! neighbouring vertices is split into two triangles along the diagonal from
//! `(c, r)` to `(c + 1, r + 1)`: triangle 0 is `(c,r) (c+1,r) (c+1,r+1)`
//! (the part where `fx >= fy`), triangle 1 is `(c,r) (c,r+1) (c+1,r+1)`.
//! Triangle ids are `2 * (r * cells_x + c) + t`. Triangles touching a nodata
//! vertex are holes. Between vertices the surface is the bilinear patch of
//! each cell (DESIGN.md's surface); the ids only name the half of the cell a
//! point lies in. [`LocalTerrain::cast`] intersects rays with the patches
//! exactly; the rasteriser draws each patch as triangles, finer where the
//! patch looks large (see `triangle_raster`).

use super::far_layers::{CastKind, FarLayer};
use super::horizon::{Block, HorizonIndex};
use super::vertex_heights::VertexHeights;
use crate::buffer_pool;
use crate::raster::HeightMap;
use crate::view::LocalFrame;
use rayon::prelude::*;

/// A ray-terrain intersection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Distance from the eye along the (unit) ray, metres.
    pub t: f64,
    /// Triangle id, `2 * (r * cells_x + c) + t` (see the module docs).
    pub triangle: u32,
}

/// The height field around a viewpoint in its local frame.
#[derive(Debug, Clone)]
pub struct LocalTerrain {
    /// The local frame (eye position, CRS mapping, curvature).
    pub frame: LocalFrame,
    /// Offset of vertex (0, 0) in cells of the DEM the terrain was built from.
    pub col0: usize,
    pub row0: usize,
    /// Number of vertices across and down (the DEM window's size).
    pub nx: usize,
    pub ny: usize,
    /// Apparent vertex heights relative to the eye (NaN = nodata), row-major
    /// (shared with the terrains patched from this one).
    pub z: VertexHeights,
    /// Maximum horizontal view distance in metres (infinite: the whole DEM).
    pub max_distance: f64,
    /// Eye position in vertex coordinates.
    eye_v: (f64, f64),
    /// Local (east, north) metres -> vertex coordinates.
    en_to_v: [[f64; 2]; 2],
    zmin: f64,
    zmax: f64,
    /// Acceleration structures of ray casting, built on first use
    /// (rasterised views need neither).
    index: std::sync::OnceLock<CastIndex>,
    horizon: std::sync::OnceLock<Option<HorizonIndex>>,
    ranges: std::sync::OnceLock<BlockRanges>,
    coarse_index: std::sync::OnceLock<CastIndex>,
    /// Coarser terrains beyond this one's reach (the level of detail of a
    /// long view, [`super::far_layers`]): rendered into the same depth
    /// buffer and cast against beside it, their triangle ids after this
    /// one's. Empty for a terrain at one resolution.
    pub(crate) far: Vec<FarLayer>,
}

/// Edge in cells of the blocks of [`BlockRanges`].
pub(crate) const RANGE_BLOCK: usize = 16;

/// Lowest and highest vertex (nodata skipped) of every block of
/// [`RANGE_BLOCK`] x [`RANGE_BLOCK`] cells, its boundary vertices included:
/// the renderer's block culling and the coarse cast index both read them.
#[derive(Debug, Clone)]
pub(crate) struct BlockRanges {
    /// Blocks across and down.
    pub bw: usize,
    pub bh: usize,
    /// Per block, row-major: `+inf` / `-inf` where every vertex is nodata.
    pub lo: Vec<f32>,
    pub hi: Vec<f32>,
}

/// A max-height pyramid for casts: level `l` holds the highest vertex of
/// each block of `2^(l + shift)` x `2^(l + shift)` cells. Casts test the
/// cells of a bottom-level block exactly.
#[derive(Debug, Clone)]
struct CastIndex {
    mip: Vec<Vec<f32>>,
    mip_dims: Vec<(usize, usize)>,
    shift: u32,
}

impl LocalTerrain {
    /// Build the terrain of `dem` around the viewpoint of `frame` (resolved on
    /// `dem`), keeping only the cells within `max_distance` metres (`None`:
    /// all of `dem`).
    pub fn new(dem: &HeightMap, frame: &LocalFrame, max_distance: Option<f64>) -> Self {
        Self::build(dem, frame, max_distance, None)
    }

    /// Like [`LocalTerrain::new`], keeping only the cells that `camera` can
    /// see horizontally: the bounding box of the wedge of the azimuths of
    /// its pixel rays (with a margin) within the maximum distance. What the
    /// camera sees, and every cast along its pixel rays, is the same as on
    /// the whole terrain, for a fraction of the set-up where the field of
    /// view is narrow. Falls back to [`LocalTerrain::new`]'s extent when the
    /// view's azimuths span more than a half-turn (or it looks straight up
    /// or down).
    pub fn in_view(
        dem: &HeightMap,
        frame: &LocalFrame,
        max_distance: Option<f64>,
        camera: &crate::view::Camera,
    ) -> Self {
        Self::build(dem, frame, max_distance, Some(camera))
    }

    /// The terrain of all of `dem` (no extent computed): `dem` is already
    /// the part the terrain covers, `extent_in` of the grid `frame` was
    /// resolved on ([`LocalTerrain::extent_in`]) read alone, and `frame`
    /// expressed for it ([`LocalFrame::shifted`]). Built so, the terrain
    /// has the same vertices, with the same bits, as
    /// [`LocalTerrain::in_view`] on the whole grid.
    pub fn over(dem: &HeightMap, frame: &LocalFrame, max_distance: Option<f64>) -> Self {
        let max_d = crate::view::distance_limit(max_distance).unwrap_or(f64::INFINITY);
        Self::build_over(dem, frame, max_d, (0, 0, dem.width, dem.height), 0.0)
    }

    /// [`LocalTerrain::over`] keeping only the vertices between `min_d`
    /// and `max_d` metres from the eye (the others nodata): one ring of a
    /// level-of-detail terrain ([`super::far_layers`]). The vertex heights
    /// are made in `dem`'s own buffer (each cell's height turned into its
    /// vertex's, the same operations as from a copy): a ring's heights are
    /// read for it alone, and a second buffer as large would be fresh
    /// pages.
    pub(crate) fn ring_from(dem: HeightMap, frame: &LocalFrame, min_d: f64, max_d: f64) -> Self {
        let (w, h) = (dem.width, dem.height);
        if w == 0 || h == 0 || dem.data.len() != w * h {
            return Self::build_over(&dem, frame, max_d, (0, 0, w, h), min_d);
        }
        let own = dem.data;
        let dem = HeightMap {
            data: Vec::new(),
            ..dem
        };
        Self::build_over_with::<true>(&dem, frame, max_d, (0, 0, w, h), min_d, own)
    }

    /// The cells `(c0, r0, c1, r1)` (end exclusive) of a grid of `size`
    /// cells that [`LocalTerrain::in_view`] (`camera` given) or
    /// [`LocalTerrain::new`] would keep around `frame`'s eye: within the
    /// maximum distance, and within the camera's horizontal wedge.
    pub fn extent_in(
        size: (usize, usize),
        frame: &LocalFrame,
        max_distance: Option<f64>,
        camera: Option<&crate::view::Camera>,
    ) -> (usize, usize, usize, usize) {
        let max_d = crate::view::distance_limit(max_distance).unwrap_or(f64::INFINITY);
        extent(size, frame, max_d, camera)
    }

    fn build(
        dem: &HeightMap,
        frame: &LocalFrame,
        max_distance: Option<f64>,
        camera: Option<&crate::view::Camera>,
    ) -> Self {
        let max_d = crate::view::distance_limit(max_distance).unwrap_or(f64::INFINITY);
        let cells = extent((dem.width, dem.height), frame, max_d, camera);
        Self::build_over(dem, frame, max_d, cells, 0.0)
    }

    /// The terrain of cells `(c0, r0, c1, r1)` of `dem`: vertices farther
    /// than `max_d` or nearer than `min_d` (0: none) are nodata.
    fn build_over(
        dem: &HeightMap,
        frame: &LocalFrame,
        max_d: f64,
        cells: (usize, usize, usize, usize),
        min_d: f64,
    ) -> Self {
        Self::build_over_with::<false>(dem, frame, max_d, cells, min_d, Vec::new())
    }

    /// [`LocalTerrain::build_over`]; with `IN_PLACE`, the heights are
    /// `own`'s (`dem` is then its grid, its data not read, and the cells
    /// `(0, 0, width, height)`), each turned into its vertex's in place.
    fn build_over_with<const IN_PLACE: bool>(
        dem: &HeightMap,
        frame: &LocalFrame,
        max_d: f64,
        (c0, r0, c1, r1): (usize, usize, usize, usize),
        min_d: f64,
        own: Vec<f32>,
    ) -> Self {
        // (0 for a whole terrain: no squared distance is under it)
        let min_d2 = min_d * min_d;
        let p = frame.p;
        let pinv = inverse_2x2(p);
        let (ex, ey) = frame.eye_pixel;
        let nx = c1.saturating_sub(c0).max(1);
        let ny = r1.saturating_sub(r0).max(1);
        let coef = frame.curvature.coefficient();
        let eye_alt = frame.eye_alt;
        // A recycled buffer (see `buffer_pool`) or a zeroed allocation whose
        // pages are mapped by the parallel fill below, which writes every
        // element.
        let mut z = if IN_PLACE {
            own
        } else {
            buffer_pool::overwritten_f32(nx * ny)
        };
        let max_d2 = max_d * max_d * 1.0001 + 1.0;
        // Each column's offset from the eye, once for all rows (the same
        // value per cell as computing it in the row: the loop below is then
        // straight arithmetic, which vectorises).
        let dx0 = c0 as f64 + 0.5 - ex;
        let dxs: Vec<f64> = (0..nx).map(|c| dx0 + c as f64).collect();
        z.par_chunks_mut(nx).enumerate().for_each(|(r, row)| {
            let src_r = r0 + r;
            if src_r >= dem.height {
                row.fill(f32::NAN);
                return;
            }
            let dy = src_r as f64 + 0.5 - ey;
            // columns inside the DEM, then any beyond its edge
            let inside = dem.width.saturating_sub(c0).min(nx);
            let src = if IN_PLACE {
                &[][..]
            } else {
                &dem.data[src_r * dem.width + c0..src_r * dem.width + c0 + inside]
            };
            let (e0, n0) = (p[0][1] * dy, p[1][1] * dy);
            let row_frame = RowFrame {
                p0: (p[0][0], e0),
                p1: (p[1][0], n0),
                eye_alt,
                coef,
                d2_range: (min_d2, max_d2),
            };
            // (a ring's vertices surely nearer than its inner radius are
            // nodata whatever their height: not computed)
            let (a, b) = surely_inside(&dxs[..inside], &row_frame);
            if IN_PLACE {
                vertex_row_in_place(&mut row[..a], &dxs[..a], row_frame);
                row[a..b].fill(f32::NAN);
                vertex_row_in_place(&mut row[b..inside], &dxs[b..inside], row_frame);
            } else {
                vertex_row(&mut row[..a], &src[..a], &dxs[..a], row_frame);
                row[a..b].fill(f32::NAN);
                vertex_row(
                    &mut row[b..inside],
                    &src[b..inside],
                    &dxs[b..inside],
                    row_frame,
                );
            }
            row[inside..].fill(f32::NAN);
        });
        let eye_v = (ex - 0.5 - c0 as f64, ey - 0.5 - r0 as f64);
        let (zmin, zmax) = z
            .par_chunks(1 << 16)
            .map(|ch| {
                ch.iter()
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                        // comparisons skip NaN and vectorise
                        (if v < a { v } else { a }, if v > b { v } else { b })
                    })
            })
            .reduce(
                || (f32::INFINITY, f32::NEG_INFINITY),
                |x, y| (x.0.min(y.0), x.1.max(y.1)),
            );
        LocalTerrain {
            frame: *frame,
            col0: c0,
            row0: r0,
            nx,
            ny,
            z: VertexHeights::new(z, nx),
            max_distance: max_d,
            eye_v,
            en_to_v: pinv,
            zmin: zmin as f64,
            zmax: zmax as f64,
            index: std::sync::OnceLock::new(),
            horizon: std::sync::OnceLock::new(),
            ranges: std::sync::OnceLock::new(),
            coarse_index: std::sync::OnceLock::new(),
            far: Vec::new(),
        }
    }

    /// This terrain with the heights of some cells replaced: `height(col,
    /// row)` (cells of the grid the terrain was built from, within the
    /// rectangle `(c0, r0, c1, r1)`, end exclusive) gives a cell's new
    /// height, `None` to keep it. The changed vertices are computed as
    /// [`LocalTerrain::new`] computes them, so the result has the same bits
    /// as building the terrain again over a copy of the grid with those
    /// heights swapped in, without the copy and for the cost of a copy of
    /// the vertex heights plus the changed cells. The acceleration
    /// structures are built again on use.
    pub fn with_heights(
        &self,
        (c0, r0, c1, r1): (usize, usize, usize, usize),
        height: &(dyn Fn(usize, usize) -> Option<f32> + Sync),
    ) -> LocalTerrain {
        let frame = &self.frame;
        let p = frame.p;
        let (ex, ey) = frame.eye_pixel;
        let coef = frame.curvature.coefficient();
        let eye_alt = frame.eye_alt;
        let max_d = self.max_distance;
        let max_d2 = max_d * max_d * 1.0001 + 1.0;
        let (tc0, tr0) = (self.col0, self.row0);
        // The rectangle within the terrain's vertices, patched over the
        // shared heights (see `vertex_heights`).
        let (a0, b0) = (c0.max(tc0), r0.max(tr0));
        let (a1, b1) = (c1.min(tc0 + self.nx), r1.min(tr0 + self.ny));
        let changed = (a0 < a1 && b0 < b1).then(|| (a0 - tc0, b0 - tr0, a1 - tc0, b1 - tr0));
        let z = match changed {
            None => self.z.clone(),
            Some(rect) => self.z.patched(rect, &|c, r, old| {
                let src_r = tr0 + r;
                let Some(h) = height(tc0 + c, src_r) else {
                    return old;
                };
                // As in `build_over`, term by term.
                let dy = src_r as f64 + 0.5 - ey;
                let (e0, n0) = (p[0][1] * dy, p[1][1] * dy);
                let dx0 = tc0 as f64 + 0.5 - ex;
                let dx = dx0 + c as f64;
                let e = p[0][0] * dx + e0;
                let n = p[1][0] * dx + n0;
                let d2 = e * e + n * n;
                let v = (h as f64 - eye_alt - coef * d2) as f32;
                if d2 > max_d2 {
                    f32::NAN
                } else {
                    v
                }
            }),
        };
        // The block ranges of this terrain's parent with the changed
        // rectangle's blocks computed again (when the parent has them):
        // the height range then follows from them, with no scan of the
        // vertices.
        let ranges = self
            .ranges
            .get()
            .filter(|r| r.bw > 0 && r.bh > 0)
            .map(|r| patched_ranges(r, &z, self.nx, self.ny, changed));
        let (zmin, zmax) = match &ranges {
            Some(r) => r.height_range(),
            None => (0..self.ny)
                .into_par_iter()
                .map(|r| {
                    z.row(r)
                        .iter()
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                            (if v < a { v } else { a }, if v > b { v } else { b })
                        })
                })
                .reduce(
                    || (f32::INFINITY, f32::NEG_INFINITY),
                    |x, y| (x.0.min(y.0), x.1.max(y.1)),
                ),
        };
        let ranges_lock = std::sync::OnceLock::new();
        if let Some(r) = ranges {
            let _ = ranges_lock.set(r);
        }
        // Likewise the full cast index, when the parent built it (each
        // round's re-render builds it beside the render).
        let index_lock = std::sync::OnceLock::new();
        if let Some(old) = self.index.get() {
            let _ = index_lock.set(patched_index(old, &z, self.nx, self.ny, changed));
        }
        LocalTerrain {
            frame: self.frame,
            col0: self.col0,
            row0: self.row0,
            nx: self.nx,
            ny: self.ny,
            z,
            max_distance: self.max_distance,
            eye_v: self.eye_v,
            en_to_v: self.en_to_v,
            zmin: zmin as f64,
            zmax: zmax as f64,
            index: index_lock,
            horizon: std::sync::OnceLock::new(),
            ranges: ranges_lock,
            coarse_index: std::sync::OnceLock::new(),
            // The far layers lie beyond the deformations (they are not
            // patched): shared.
            far: self.far.clone(),
        }
    }

    /// The max-height pyramid, built on first use.
    fn index(&self) -> &CastIndex {
        self.index.get_or_init(|| {
            let (mip, mip_dims) = self.build_mip();
            CastIndex {
                mip,
                mip_dims,
                shift: 1,
            }
        })
    }

    /// The coarse cast index: blocks of [`RANGE_BLOCK`] cells at the
    /// bottom, built from the block ranges (which the renderer computes
    /// anyway) at almost no cost. Casts through it test more cells than
    /// through [`LocalTerrain::index`]: for a few thousand casts per view.
    fn coarse_index(&self) -> &CastIndex {
        self.coarse_index.get_or_init(|| {
            let r = self.block_ranges();
            let (mip, mip_dims) = max_pyramid(r.hi.clone(), r.bw, r.bh);
            CastIndex {
                mip,
                mip_dims,
                shift: RANGE_BLOCK.trailing_zeros(),
            }
        })
    }

    /// The lowest and highest vertex of every block (computed on first use).
    pub(crate) fn block_ranges(&self) -> &BlockRanges {
        self.ranges.get_or_init(|| {
            let (nx, cx, cy) = (self.nx, self.cells_x(), self.ny.saturating_sub(1));
            let (bw, bh) = (cx.div_ceil(RANGE_BLOCK), cy.div_ceil(RANGE_BLOCK));
            let z = &self.z;
            let rows: Vec<(Vec<f32>, Vec<f32>)> = (0..bh)
                .into_par_iter()
                .map_init(
                    || (vec![0f32; nx], vec![0f32; nx]),
                    |(col_lo, col_hi), by| {
                        column_ranges(z, cy, by, col_lo, col_hi);
                        (0..bw)
                            .map(|bx| block_of_columns(col_lo, col_hi, cx, bx))
                            .unzip()
                    },
                )
                .collect();
            let (mut lo, mut hi) = (Vec::with_capacity(bw * bh), Vec::with_capacity(bw * bh));
            for (l, h) in rows {
                lo.extend(l);
                hi.extend(h);
            }
            BlockRanges { bw, bh, lo, hi }
        })
    }

    /// The horizon index, built on first use.
    fn horizon(&self) -> Option<&HorizonIndex> {
        self.horizon
            .get_or_init(|| {
                let idx = self.index();
                self.build_horizon(&idx.mip, &idx.mip_dims)
            })
            .as_ref()
    }

    /// Mean size of a cell in metres.
    fn cell_m(&self) -> f64 {
        let p = self.frame.p;
        (p[0][0].hypot(p[1][0]) * p[0][1].hypot(p[1][1])).sqrt()
    }

    /// Build the [`HorizonIndex`] from a pyramid level with at most ~300k
    /// blocks.
    fn build_horizon(&self, mips: &[Vec<f32>], dims: &[(usize, usize)]) -> Option<HorizonIndex> {
        if self.nx < 2 || self.ny < 2 || !self.zmax.is_finite() {
            return None;
        }
        let cells = self.cells_x() * (self.ny - 1);
        let mut level = 0;
        while level + 1 < mips.len() && (cells >> (2 * (level + 1))) > 300_000 {
            level += 1;
        }
        let (mw, mh) = dims[level];
        // level l: blocks of 2^(l + 1) cells (see `build_mip`)
        let s = 2usize << level;
        let cell_m = self.cell_m();
        let (wx, wy) = ((self.nx - 1) as f64, (self.ny - 1) as f64);
        let mut max_dh = 0f64;
        for (vx, vy) in [(0.0, 0.0), (wx, 0.0), (0.0, wy), (wx, wy)] {
            let (e, n) = self.v_to_en(vx, vy);
            max_dh = max_dh.max(e.hypot(n));
        }
        max_dh = max_dh.min(self.max_distance) + cell_m;
        let mip = &mips[level];
        let this = self;
        let index = HorizonIndex::build(
            mh,
            |by, out: &mut Vec<Block>| {
                let y0 = (by * s) as f64;
                let y1 = (((by + 1) * s) as f64).min(wy);
                for bx in 0..mw {
                    let x0 = (bx * s) as f64;
                    let x1 = (((bx + 1) * s) as f64).min(wx);
                    let centre = this.v_to_en(0.5 * (x0 + x1), 0.5 * (y0 + y1));
                    let mut radius = 0f64;
                    for (vx, vy) in [(x0, y0), (x1, y0), (x0, y1), (x1, y1)] {
                        let (e, n) = this.v_to_en(vx, vy);
                        radius =
                            radius.max(((e - centre.0).powi(2) + (n - centre.1).powi(2)).sqrt());
                    }
                    out.push(Block {
                        centre,
                        radius: radius * 1.000_001 + 1e-6,
                        zmax: mip[by * mw + bx],
                    });
                }
            },
            cell_m * s as f64,
            max_dh,
            3.0 * cell_m,
        );
        Some(index)
    }

    /// Eye position in vertex coordinates.
    pub(crate) fn eye_vertex(&self) -> (f64, f64) {
        self.eye_v
    }

    /// The max-height pyramid: level 0 holds the highest vertex of each
    /// block of 2 x 2 cells (its 3 x 3 vertices, nodata skipped, `-inf`
    /// when all are nodata), level `l` that of blocks of `2^(l+1)` cells.
    /// There is no per-cell level: a cast tests the cells of a 2 x 2 block
    /// exactly instead, and the pyramid costs a quarter of the memory.
    #[allow(clippy::type_complexity)]
    fn build_mip(&self) -> (Vec<Vec<f32>>, Vec<(usize, usize)>) {
        let (cx, cy) = (
            self.nx.saturating_sub(1).max(1),
            self.ny.saturating_sub(1).max(1),
        );
        let (nx, ny) = (self.nx, self.ny);
        let z = &self.z;
        let (w0, h0) = (cx.div_ceil(2), cy.div_ceil(2));
        let mut l0 = vec![f32::NEG_INFINITY; w0 * h0];
        l0.par_chunks_mut(w0).enumerate().for_each_init(
            || vec![f32::NAN; nx + 2],
            |colmax, (by, out)| {
                // column maxima of vertex rows 2 by ..= 2 by + 2
                let rows = 2 * by..(2 * by + 3).min(ny);
                colmax[..nx].copy_from_slice(&z.row(rows.start));
                for r in rows.start + 1..rows.end {
                    for (m, &v) in colmax[..nx].iter_mut().zip(z.row(r).iter()) {
                        // f32::max skips NaN and vectorises
                        *m = m.max(v);
                    }
                }
                // padding past the last vertex column
                colmax[nx] = f32::NAN;
                colmax[nx + 1] = f32::NAN;
                for (bx, o) in out.iter_mut().enumerate() {
                    let m = colmax[2 * bx]
                        .max(colmax[2 * bx + 1])
                        .max(colmax[2 * bx + 2]);
                    *o = if m.is_nan() { f32::NEG_INFINITY } else { m };
                }
            },
        );
        max_pyramid(l0, w0, h0)
    }

    /// Lowest and highest apparent vertex height (relative to the eye);
    /// infinite when every vertex is nodata.
    pub fn height_range(&self) -> (f64, f64) {
        (self.zmin, self.zmax)
    }

    /// Where this terrain's vertices differ from `earlier`'s, both patched
    /// from one terrain ([`LocalTerrain::with_heights`]: the same grid and
    /// frame) and with the same height range (which bounds every cast):
    /// `Some(None)` when none differs (to the bit), `Some(Some((c0, r0,
    /// c1, r1)))` the box of those that do (vertex indices, end
    /// exclusive), `None` when the two cannot be compared so.
    pub fn changed_since(
        &self,
        earlier: &LocalTerrain,
    ) -> Option<Option<(usize, usize, usize, usize)>> {
        let same_grid = (self.col0, self.row0, self.nx, self.ny)
            == (earlier.col0, earlier.row0, earlier.nx, earlier.ny)
            && self.eye_v == earlier.eye_v
            && self.en_to_v == earlier.en_to_v
            && self.max_distance.to_bits() == earlier.max_distance.to_bits();
        let same_range = self.zmin.to_bits() == earlier.zmin.to_bits()
            && self.zmax.to_bits() == earlier.zmax.to_bits();
        if !(same_grid && same_range) {
            return None;
        }
        self.z.changed_box(&earlier.z)
    }

    /// Whether this terrain is `other`'s surface to the bit, however each
    /// was built (from a grid, or patched from another terrain): the same
    /// frame, grid, reach and height range, every vertex height the same,
    /// and no far layers (which are not compared). Everything a render or
    /// a cast reads then is the same: the acceleration structures follow
    /// from the heights.
    pub fn same_surface(&self, other: &LocalTerrain) -> bool {
        let same_grid = self.frame == other.frame
            && (self.col0, self.row0, self.nx, self.ny)
                == (other.col0, other.row0, other.nx, other.ny)
            && self.eye_v == other.eye_v
            && self.en_to_v == other.en_to_v
            && self.max_distance.to_bits() == other.max_distance.to_bits();
        let same_range = self.zmin.to_bits() == other.zmin.to_bits()
            && self.zmax.to_bits() == other.zmax.to_bits();
        same_grid
            && same_range
            && self.far.is_empty()
            && other.far.is_empty()
            && self.z.len() == other.z.len()
            && (0..self.ny).all(|r| {
                let (a, b) = (self.z.row(r), other.z.row(r));
                a.len() == b.len()
                    && a.iter()
                        .zip(b.iter())
                        .all(|(p, q)| p.to_bits() == q.to_bits())
            })
    }

    /// Number of cells across (`nx - 1`).
    pub fn cells_x(&self) -> usize {
        self.nx.saturating_sub(1)
    }

    /// Apparent height (local frame) of vertex `(c, r)`, `None` for nodata.
    #[inline]
    pub fn vertex_z(&self, c: usize, r: usize) -> Option<f64> {
        if c >= self.nx || r >= self.ny {
            return None;
        }
        let v = self.z.at_cr(c, r);
        (!v.is_nan()).then_some(v as f64)
    }

    /// The largest twist `|z00 + z11 - z10 - z01|` (metres) of the cell of
    /// triangle `id` and its eight neighbours (nodata cells skipped): two
    /// planar triangles depart from a cell's bilinear patch by up to a
    /// quarter of its twist.
    pub fn twist_around(&self, id: u32) -> f64 {
        if let Some((l, id)) = self.far_of(id) {
            return l.terrain.twist_around(id);
        }
        let (nx, ny) = (self.nx, self.ny);
        if nx < 2 || ny < 2 {
            return 0.0;
        }
        let cx = self.cells_x().max(1);
        let cell = (id / 2) as usize;
        let (c, r) = (cell % cx, cell / cx);
        // the cells around whose four vertices lie in the grid
        let (c_lo, c_hi) = (c.saturating_sub(1), (c + 1).min(nx - 2));
        let (r_lo, r_hi) = (r.saturating_sub(1), (r + 1).min(ny - 2));
        if c_hi < c_lo || r_hi < r_lo {
            return 0.0;
        }
        // The (at most) 4 x 4 vertices, read once each (a row of a patched
        // terrain would be a copy).
        let v = self.z.rect4(c_lo, r_lo, c_hi + 2 - c_lo, r_hi + 2 - r_lo);
        let mut twist = 0.0f64;
        for rr in r_lo..=r_hi {
            let (row0, row1) = (&v[rr - r_lo], &v[rr + 1 - r_lo]);
            for cc in c_lo..=c_hi {
                let i = cc - c_lo;
                let (a, b) = (row0[i], row0[i + 1]);
                let (e, d) = (row1[i], row1[i + 1]);
                if a.is_nan() || b.is_nan() || e.is_nan() || d.is_nan() {
                    continue;
                }
                let (a, b, e, d) = (a as f64, b as f64, e as f64, d as f64);
                // (a number, never NaN: `fmax` is `max` here)
                twist = fmax(twist, (a + d - b - e).abs());
            }
        }
        twist
    }

    /// Local point (ENU metres, apparent z) of vertex `(c, r)`, `None` for nodata.
    #[inline]
    pub fn vertex_local(&self, c: usize, r: usize) -> Option<[f64; 3]> {
        let z = self.vertex_z(c, r)?;
        let (e, n) = self.v_to_en(c as f64, r as f64);
        Some([e, n, z])
    }

    /// The vertex columns of row `r` that may lie within `radius` metres
    /// (horizontally) of the eye: a superset of those that do, for scans
    /// that test each vertex's distance anyway. A vertex's offset from the
    /// eye in cells is at most the Frobenius norm of the local-to-vertex
    /// map times its distance in metres, so the columns outside the disc of
    /// that radius (plus a cell) are beyond `radius`.
    pub fn columns_within(&self, r: usize, radius: f64) -> std::ops::Range<usize> {
        let m = self.en_to_v;
        let norm =
            (m[0][0] * m[0][0] + m[0][1] * m[0][1] + m[1][0] * m[1][0] + m[1][1] * m[1][1]).sqrt();
        let reach = radius * norm * (1.0 + 1e-6) + 2.0;
        if !reach.is_finite() {
            return 0..self.nx;
        }
        let dy = r as f64 - self.eye_v.1;
        if !(dy.abs() <= reach) {
            return 0..0;
        }
        let half = (reach * reach - dy * dy).max(0.0).sqrt();
        let c0 = (self.eye_v.0 - half).floor().max(0.0) as usize;
        let c1 = ((self.eye_v.0 + half).ceil() + 1.0).max(0.0) as usize;
        c0.min(self.nx)..c1.min(self.nx)
    }

    /// Local (east, north) of vertex coordinates `(vx, vy)`.
    #[inline]
    pub fn v_to_en(&self, vx: f64, vy: f64) -> (f64, f64) {
        self.frame
            .pixel_to_en(vx + 0.5 + self.col0 as f64, vy + 0.5 + self.row0 as f64)
    }

    /// Vertex coordinates of local (east, north).
    #[inline]
    pub fn en_to_v(&self, e: f64, n: f64) -> (f64, f64) {
        let m = self.en_to_v;
        (
            self.eye_v.0 + m[0][0] * e + m[0][1] * n,
            self.eye_v.1 + m[1][0] * e + m[1][1] * n,
        )
    }

    /// The three local vertices of triangle `id`, `None` when it is a hole.
    pub fn triangle_vertices(&self, id: u32) -> Option<[[f64; 3]; 3]> {
        if let Some((l, id)) = self.far_of(id) {
            return l.terrain.triangle_vertices(id);
        }
        let cx = self.cells_x().max(1);
        let cell = (id / 2) as usize;
        let (c, r) = (cell % cx, cell / cx);
        let a = self.vertex_local(c, r)?;
        let d = self.vertex_local(c + 1, r + 1)?;
        if id % 2 == 0 {
            Some([a, self.vertex_local(c + 1, r)?, d])
        } else {
            Some([a, self.vertex_local(c, r + 1)?, d])
        }
    }

    /// Cell `(col, row)` of the source DEM (pixel space of the `HeightMap`
    /// the terrain was built from) of triangle `id`, and which half (0 or 1).
    pub fn triangle_cell(&self, id: u32) -> (usize, usize, u8) {
        if let Some((l, id)) = self.far_of(id) {
            return Self::far_triangle_cell(l, id);
        }
        let cx = self.cells_x().max(1);
        let cell = (id / 2) as usize;
        (self.col0 + cell % cx, self.row0 + cell / cx, (id % 2) as u8)
    }

    /// Smooth upward unit normal of the surface at local point `p` on
    /// triangle `id`, for shading: the central-difference gradients of the
    /// cell's four vertices, interpolated bilinearly (like a hillshade's
    /// gradient, without the facets of the triangles). Falls back to the
    /// triangle's own normal next to nodata.
    pub fn shading_normal(&self, p: [f64; 3], id: u32) -> Option<[f64; 3]> {
        if let Some((l, id)) = self.far_of(id) {
            return l.terrain.shading_normal(p, id);
        }
        let cx = self.cells_x().max(1);
        let cell = (id / 2) as usize;
        let (c, r) = (cell % cx, cell / cx);
        let (vx, vy) = self.en_to_v(p[0], p[1]);
        let (fx, fy) = (
            (vx - c as f64).clamp(0.0, 1.0),
            (vy - r as f64).clamp(0.0, 1.0),
        );
        let grad = |c: usize, r: usize| -> Option<(f64, f64)> {
            let z = |c: usize, r: usize| self.vertex_z(c, r);
            let (c0, c1) = (c.saturating_sub(1), (c + 1).min(self.nx - 1));
            let (r0, r1) = (r.saturating_sub(1), (r + 1).min(self.ny - 1));
            let gx = (z(c1, r)? - z(c0, r)?) / (c1 - c0).max(1) as f64;
            let gy = (z(c, r1)? - z(c, r0)?) / (r1 - r0).max(1) as f64;
            Some((gx, gy))
        };
        let g = (|| {
            let g00 = grad(c, r)?;
            let g10 = grad(c + 1, r)?;
            let g01 = grad(c, r + 1)?;
            let g11 = grad(c + 1, r + 1)?;
            let l = |a: f64, b: f64, t: f64| a + (b - a) * t;
            Some((
                l(l(g00.0, g10.0, fx), l(g01.0, g11.0, fx), fy),
                l(l(g00.1, g10.1, fx), l(g01.1, g11.1, fx), fy),
            ))
        })();
        let Some((gx, gy)) = g else {
            return self.triangle_normal(id);
        };
        let m = self.en_to_v;
        let de = gx * m[0][0] + gy * m[1][0];
        let dn = gx * m[0][1] + gy * m[1][1];
        let l = (de * de + dn * dn + 1.0).sqrt();
        Some([-de / l, -dn / l, 1.0 / l])
    }

    /// Upward unit normal of triangle `id` in the local frame.
    pub fn triangle_normal(&self, id: u32) -> Option<[f64; 3]> {
        if let Some((l, id)) = self.far_of(id) {
            return l.terrain.triangle_normal(id);
        }
        let [a, b, c] = self.triangle_vertices(id)?;
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let mut n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        if n[2] < 0.0 {
            n = [-n[0], -n[1], -n[2]];
        }
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        (l > 0.0).then(|| [n[0] / l, n[1] / l, n[2] / l])
    }

    /// As [`LocalTerrain::cast`], for a few short rays: uses the horizon
    /// index when it exists but does not build it (building it costs more
    /// than a few hundred casts of bounded length gain from it).
    pub fn cast_within(&self, d: [f64; 3], t_limit: f64) -> Option<RayHit> {
        let hit = if self.horizon.get().is_some() {
            self.cast_own(d, t_limit)
        } else {
            self.traverse(d, 0.0, t_limit)
        };
        self.with_far_hit(hit, d, 0.0, t_limit, CastKind::Within)
    }

    /// The first intersection with the terrain of the segment
    /// `[t_start, t_limit]` of the ray from the eye along unit direction `d`
    /// (distances in metres): through the full cast index when it has been
    /// built ([`LocalTerrain::build_cast_index`]), else through the coarse
    /// one (built on first use from the block ranges, at almost no cost).
    /// The answer is the same; the full index tests about a quarter as many
    /// cells per cast (grazing casts from silhouettes descend into the block
    /// of the crest they start at), which pays for its build when the
    /// terrain serves many casts.
    pub fn cast_segment(&self, d: [f64; 3], t_start: f64, t_limit: f64) -> Option<RayHit> {
        let hit = self.cast_segment_own(d, t_start, t_limit);
        self.with_far_hit(hit, d, t_start, t_limit, CastKind::Segment)
    }

    /// [`LocalTerrain::cast_segment`] on this terrain's own grid (no far
    /// layer).
    pub(crate) fn cast_segment_own(
        &self,
        d: [f64; 3],
        t_start: f64,
        t_limit: f64,
    ) -> Option<RayHit> {
        let index = match self.index.get() {
            Some(full) => full,
            None => self.coarse_index(),
        };
        self.traverse_with(index, d, t_start, t_limit)
    }

    /// The horizontal part of direction `d` (east, north, up) in vertex
    /// units of the grid (columns, rows per metre along the ray).
    fn grid_direction(&self, d: [f64; 3]) -> (f64, f64) {
        let m = self.en_to_v;
        (
            m[0][0] * d[0] + m[0][1] * d[1],
            m[1][0] * d[0] + m[1][1] * d[1],
        )
    }

    /// The distance at which the ray from the eye along unit direction `d`
    /// enters the cell it crosses at distance `t`, as the traversal of
    /// [`LocalTerrain::cast_segment`] computes it (the exit of the cell
    /// before, along the axis crossed last): a start there gives that
    /// traversal's answer bit for bit. `None` where the cell is at the
    /// grid's edge the ray enters by, the point is off the grid, or a
    /// component of the ray is zero.
    pub fn cell_entry(&self, d: [f64; 3], t: f64) -> Option<f64> {
        if self.nx < 2 || self.ny < 2 || !t.is_finite() {
            return None;
        }
        let (gx, gy) = self.grid_direction(d);
        let (ox, oy) = self.eye_v;
        let (wx, wy) = ((self.nx - 1) as f64, (self.ny - 1) as f64);
        let (px, py) = (ox + gx * t, oy + gy * t);
        if !(px > 0.0 && px < wx && py > 0.0 && py < wy) {
            return None;
        }
        let c = floor_index(px).min(self.nx - 2);
        let r = floor_index(py).min(self.ny - 2);
        let entry = self.cell_entry_at(d, c, r)?;
        (entry <= t).then_some(entry)
    }

    /// The distance at which the ray from the eye along unit direction `d`
    /// enters cell `(c, r)`, as the traversal of
    /// [`LocalTerrain::cast_segment`] computes it (the exit of the cell
    /// before it along each axis; the later of the two). `None` where the
    /// cell is at the grid's edge the ray enters by or a component of the
    /// ray is zero.
    pub fn cell_entry_at(&self, d: [f64; 3], c: usize, r: usize) -> Option<f64> {
        if self.nx < 2 || self.ny < 2 || c + 1 >= self.nx || r + 1 >= self.ny {
            return None;
        }
        let (gx, gy) = self.grid_direction(d);
        let (ox, oy) = self.eye_v;
        let (wx, wy) = ((self.nx - 1) as f64, (self.ny - 1) as f64);
        let mut entry = f64::NEG_INFINITY;
        for (o, g, w, i) in [(ox, gx, wx, c), (oy, gy, wy, r)] {
            if g == 0.0 {
                return None;
            }
            let a = RayAxis::new(o, g, w);
            let n = w as usize;
            // the exit of the cell before, as `axis_block` computes it
            // (its block size, a power of two, multiplies exactly)
            let e = if g > 0.0 {
                if i == 0 {
                    return None;
                }
                (index_f64(i).min(a.w) - a.o) * a.inv_g
            } else {
                if i + 1 >= n {
                    return None;
                }
                (index_f64(i + 1) - a.o) * a.inv_g
            };
            entry = entry.max(e);
        }
        Some(entry)
    }

    /// Build the full cast index now (it is otherwise built by the first
    /// [`LocalTerrain::cast`]), e.g. beside other work, so that
    /// [`LocalTerrain::cast_segment`] uses it.
    pub fn build_cast_index(&self) {
        self.index();
    }

    /// The first intersection of the ray from the eye along unit direction
    /// `d` (local frame) with the triangulated terrain, within distance
    /// `t_limit` and the maximum view distance. `None`: the ray escapes (sky).
    pub fn cast(&self, d: [f64; 3], t_limit: f64) -> Option<RayHit> {
        let hit = self.cast_own(d, t_limit);
        self.with_far_hit(hit, d, 0.0, t_limit, CastKind::Full)
    }

    /// [`LocalTerrain::cast`] on this terrain's own grid (no far layer).
    fn cast_own(&self, d: [f64; 3], t_limit: f64) -> Option<RayHit> {
        let dh = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let Some(hz) = self.horizon().filter(|_| dh > 1e-9) else {
            return self.traverse(d, 0.0, t_limit);
        };
        // Exactly through the disc around the eye, then from the first
        // distance where the horizon index allows a hit.
        let t_near = hz.near_m / dh;
        if let Some(hit) = self.traverse(d, 0.0, t_near.min(t_limit)) {
            return Some(hit);
        }
        if t_near >= t_limit {
            return None;
        }
        let s0 = hz.start_distance(d[0], d[1], d[2] / dh)?;
        self.traverse(d, (s0 / dh).max(t_near), t_limit)
    }

    /// Exact first intersection of the ray segment `[t_start, t_limit]`
    /// (clipped to the grid, the height range and the maximum distance),
    /// by hierarchical traversal of the max-height pyramid.
    fn traverse(&self, d: [f64; 3], t_start: f64, t_limit: f64) -> Option<RayHit> {
        self.traverse_with(self.index(), d, t_start, t_limit)
    }

    /// [`LocalTerrain::traverse`] through `index`.
    fn traverse_with(
        &self,
        index: &CastIndex,
        d: [f64; 3],
        t_start: f64,
        t_limit: f64,
    ) -> Option<RayHit> {
        let (gx, gy) = self.grid_direction(d);
        let dz = d[2];
        let (ox, oy) = self.eye_v;
        if self.nx < 2 || self.ny < 2 || !self.zmax.is_finite() {
            return None;
        }
        let (wx, wy) = ((self.nx - 1) as f64, (self.ny - 1) as f64);
        let mut t0 = t_start.max(0.0);
        let mut t1 = t_limit;
        let dh = (d[0] * d[0] + d[1] * d[1]).sqrt();
        if self.max_distance.is_finite() && dh > 0.0 {
            t1 = t1.min(self.max_distance / dh);
        }
        for (o, g, w) in [(ox, gx, wx), (oy, gy, wy)] {
            if g == 0.0 {
                if o < 0.0 || o > w {
                    return None;
                }
            } else {
                let (a, b) = ((0.0 - o) / g, (w - o) / g);
                t0 = t0.max(a.min(b));
                t1 = t1.min(a.max(b));
            }
        }
        if dz > 0.0 {
            t1 = t1.min(self.zmax / dz + 1e-6);
        } else if dz < 0.0 {
            t1 = t1.min(self.zmin / dz + 1e-6);
        }
        if !(t1 > t0) {
            return None;
        }
        let CastIndex {
            mip,
            mip_dims,
            shift,
        } = index;
        let top = mip.len() - 1;
        // level l: blocks of 2^(l + shift) cells; start at blocks of 8 or
        // the bottom level
        let mut level = top.min(3usize.saturating_sub(*shift as usize));
        let mut t = t0;
        let eps = 1e-7 * (1.0 + t1.min(1e7));
        let ray = (ox, oy, gx, gy, dz);
        let (cells_x, cells_y) = (self.nx - 1, self.ny - 1);
        let (ax, ay) = (RayAxis::new(ox, gx, wx), RayAxis::new(oy, gy, wy));
        while t < t1 {
            let tp = t + eps;
            let (px, py) = (ox + gx * tp, oy + gy * tp);
            let sh = level as u32 + shift;
            // 2^sh and its reciprocal, exactly, without a division
            let (s, inv_s) = (pow2(sh as i32), pow2(-(sh as i32)));
            let (mw, mh) = mip_dims[level];
            let (Some((bx, tx)), Some((by, ty))) = (
                axis_block(&ax, px, s, inv_s, mw, tp),
                axis_block(&ay, py, s, inv_s, mh, tp),
            ) else {
                break;
            };
            let te = fmax(fmin(fmin(tx, ty), t1), tp);
            let ray_min = dz * if dz < 0.0 { te } else { t };
            if ray_min > mip[level][by * mw + bx] as f64 {
                t = te;
                // Ascend when leaving the parent block (within it, the
                // parent was just found too high).
                if level < top {
                    let tq = t + eps;
                    let (qx, qy) = (ox + gx * tq, oy + gy * tq);
                    let ps = sh + 1;
                    if floor_index(qx) >> ps != bx >> 1 || floor_index(qy) >> ps != by >> 1 {
                        level += 1;
                    }
                }
                continue;
            }
            if level > 0 {
                level -= 1;
                continue;
            }
            // The cells of the bottom block, in the order the ray crosses them.
            while t < te {
                let tq = t + eps;
                let (qx, qy) = (ox + gx * tq, oy + gy * tq);
                let (Some((c, cx_exit)), Some((r, cy_exit))) = (
                    axis_block(&ax, qx, 1.0, 1.0, cells_x, tq),
                    axis_block(&ay, qy, 1.0, 1.0, cells_y, tq),
                ) else {
                    return None;
                };
                let tc = fmax(fmin(fmin(cx_exit, cy_exit), te), tq);
                if let Some(hit) = self.cell_hit(c, r, t, tc, ray) {
                    return Some(hit);
                }
                t = tc;
            }
            // Ascend when leaving the parent block.
            if level < top {
                let tq = t + eps;
                let (qx, qy) = (ox + gx * tq, oy + gy * tq);
                let ps = shift + 1;
                // (truncation is floor for the non-negative values kept by max)
                if floor_index(qx) >> ps != bx >> 1 || floor_index(qy) >> ps != by >> 1 {
                    level += 1;
                }
            }
        }
        None
    }

    /// Exact first intersection of the ray segment `[ta, tb]` with the
    /// bilinear patch of cell `(c, r)`; the triangle id says which side of
    /// the cell's diagonal the hit lies on.
    #[inline]
    fn cell_hit(
        &self,
        c: usize,
        r: usize,
        ta: f64,
        tb: f64,
        ray: (f64, f64, f64, f64, f64),
    ) -> Option<RayHit> {
        let (ox, oy, gx, gy, dz) = ray;
        let nx = self.nx;
        let corners = self.corners(c, r)?;
        if ray_clears(&corners, dz, ta, tb) {
            return None;
        }
        let patch = BilinearPatch::new(corners)?;
        let (bx, by) = (ox - index_f64(c), oy - index_f64(r));
        let t = patch.first_crossing((bx, by, gx, gy, dz), ta, tb)?;
        let half = u32::from((bx + gx * t) - (by + gy * t) < 0.0);
        Some(RayHit {
            t,
            triangle: (r * (nx - 1) + c) as u32 * 2 + half,
        })
    }

    /// The bilinear patch of cell `(c, r)` (`c + 1 < nx`, `r + 1 < ny`),
    /// `None` next to nodata.
    #[inline]
    fn patch(&self, c: usize, r: usize) -> Option<BilinearPatch> {
        BilinearPatch::new(self.corners(c, r)?)
    }

    /// The corner heights `[h00, h10, h01, h11]` of cell `(c, r)`, `None`
    /// next to nodata (where [`LocalTerrain::patch`] is `None`).
    #[inline]
    fn corners(&self, c: usize, r: usize) -> Option<[f64; 4]> {
        let h = self.z.quad(c, r).map(f64::from);
        (!h.iter().any(|v| v.is_nan())).then_some(h)
    }

    /// The first intersection of the ray from the eye along unit direction
    /// `d` with the terrain, found by walking the cells the ray crosses
    /// from the cell of triangle `id` on, at most `max_cells` of them, past
    /// `t_start` and within the maximum view distance: what
    /// [`LocalTerrain::cast_segment`] finds when nothing before that cell
    /// is hit, for a few patches' work instead of a traversal of the block
    /// index. For rays known to meet the terrain first at or a little
    /// beyond that cell (the silhouettes' bisection between two rays of one
    /// column), with a check of that: `None` when the ray enters the cell
    /// after `latest_entry`, is already under the patch where it enters (it
    /// met the terrain before), meets no terrain within `max_cells` cells,
    /// or reaches nodata or the grid's edge: the caller then casts.
    pub fn cast_from_cell(
        &self,
        d: [f64; 3],
        id: u32,
        t_start: f64,
        latest_entry: f64,
        max_cells: usize,
    ) -> Option<RayHit> {
        self.cast_from_cell_walk(d, id, t_start, latest_entry, max_cells)
            .ok()
    }

    /// [`LocalTerrain::cast_from_cell`], telling where a walk that met no
    /// terrain in its `max_cells` cells stopped: `Err(Some(cell))`, the
    /// first cell it did not test (a traversal may start at that cell's
    /// entry, [`LocalTerrain::cell_entry_at`]); `Err(None)` for the other
    /// refusals. From a far layer's triangle the walk is over that layer's
    /// cells ([`LocalTerrain::far_walk`]), and any refusal is `Err(None)`.
    pub fn cast_from_cell_walk(
        &self,
        d: [f64; 3],
        id: u32,
        t_start: f64,
        latest_entry: f64,
        max_cells: usize,
    ) -> Result<RayHit, Option<(usize, usize)>> {
        if self.is_far_triangle(id) {
            // The far layer's own cells are walked, and the terrain and
            // the other layers asked for a nearer hit; a walk that meets
            // nothing leaves the cast to the caller (from the start: its
            // cells are not this grid's).
            return self
                .far_walk(d, id, t_start, latest_entry, max_cells)
                .ok_or(None);
        }
        let hit = self.walk_cells(d, id, t_start, latest_entry, max_cells)?;
        match self.with_far_hit(Some(hit), d, t_start, hit.t, CastKind::Segment) {
            Some(h) => Ok(h),
            None => Ok(hit),
        }
    }

    /// The walk of [`LocalTerrain::cast_from_cell_walk`] over this
    /// terrain's own cells.
    pub(crate) fn walk_cells(
        &self,
        d: [f64; 3],
        id: u32,
        t_start: f64,
        latest_entry: f64,
        max_cells: usize,
    ) -> Result<RayHit, Option<(usize, usize)>> {
        let cx = self.cells_x();
        if cx == 0 || self.ny < 2 {
            return Err(None);
        }
        let cell = (id / 2) as usize;
        let (mut c, mut r) = (cell % cx, cell / cx);
        if c + 1 >= self.nx || r + 1 >= self.ny {
            return Err(None);
        }
        let (gx, gy) = self.grid_direction(d);
        let (ox, oy) = self.eye_v;
        let dh = (d[0] * d[0] + d[1] * d[1]).sqrt();
        let t_max = if self.max_distance.is_finite() && dh > 0.0 {
            self.max_distance / dh
        } else {
            f64::INFINITY
        };
        let mut t_lo = t_start.max(0.0);
        for k in 0..max_cells {
            // The ray's stretch over cell (c, r), and where it leaves it.
            let (mut ta, mut tb) = (t_lo, t_max);
            let (mut exit_x, mut exit_y) = (f64::INFINITY, f64::INFINITY);
            for (o, g, exit) in [
                (ox - index_f64(c), gx, &mut exit_x),
                (oy - index_f64(r), gy, &mut exit_y),
            ] {
                if g == 0.0 {
                    if !(0.0..=1.0).contains(&o) {
                        return Err(None);
                    }
                } else {
                    let (a, b) = (-o / g, (1.0 - o) / g);
                    ta = fmax(ta, fmin(a, b));
                    *exit = fmax(a, b);
                    tb = fmin(tb, *exit);
                }
            }
            if !(tb > ta) || (k == 0 && ta > latest_entry) {
                return Err(None);
            }
            let corners = self.corners(c, r).ok_or(None)?;
            // Above the whole cell: no crossing in it (and, at the first
            // cell, not under the patch where it enters).
            if !ray_clears(&corners, d[2], ta, tb) {
                let patch = BilinearPatch::new(corners).ok_or(None)?;
                let ray = (ox - index_f64(c), oy - index_f64(r), gx, gy, d[2]);
                if k == 0 && patch.clearance(ray, ta)[2] <= 0.0 {
                    return Err(None);
                }
                if let Some(t) = patch.first_crossing(ray, ta, tb) {
                    let half = u32::from((ray.0 + gx * t) - (ray.1 + gy * t) < 0.0);
                    return Ok(RayHit {
                        t,
                        triangle: (r * cx + c) as u32 * 2 + half,
                    });
                }
            }
            if tb >= t_max {
                return Err(None);
            }
            // On to the cell beyond the edge the ray leaves by (both at a
            // corner).
            if exit_x <= exit_y {
                c = if gx > 0.0 {
                    c + 1
                } else {
                    c.checked_sub(1).ok_or(None)?
                };
            }
            if exit_y <= exit_x {
                r = if gy > 0.0 {
                    r + 1
                } else {
                    r.checked_sub(1).ok_or(None)?
                };
            }
            if c + 1 >= self.nx || r + 1 >= self.ny {
                return Err(None);
            }
            t_lo = tb;
        }
        // none of `max_cells` cells met: (c, r) is the next one
        Err(Some((c, r)))
    }

    /// Distance along unit ray `d` from the eye to the bilinear patch of the
    /// cell of triangle `id`, where the ray crosses that cell: the crossing
    /// nearest `t_near` (the rasteriser's depth, which follows the patch to
    /// a fraction of a pixel). `None` when the ray misses the patch.
    pub fn patch_distance(&self, d: [f64; 3], id: u32, t_near: f64) -> Option<f64> {
        if let Some((l, id)) = self.far_of(id) {
            return l.terrain.patch_distance(d, id, t_near);
        }
        let cx = self.cells_x().max(1);
        let cell = (id / 2) as usize;
        let (c, r) = (cell % cx, cell / cx);
        if c + 1 >= self.nx || r + 1 >= self.ny {
            return None;
        }
        let patch = self.patch(c, r)?;
        let (gx, gy) = self.grid_direction(d);
        let (bx, by) = (self.eye_v.0 - c as f64, self.eye_v.1 - r as f64);
        // The ray's stretch over the cell.
        let (mut ta, mut tb) = (0.0f64, f64::INFINITY);
        for (o, g) in [(bx, gx), (by, gy)] {
            if g == 0.0 {
                if !(0.0..=1.0).contains(&o) {
                    return None;
                }
            } else {
                let (a, b) = (-o / g, (1.0 - o) / g);
                ta = ta.max(a.min(b));
                tb = tb.min(a.max(b));
            }
        }
        if !(tb >= ta) {
            return None;
        }
        patch
            .crossings((bx, by, gx, gy, d[2]), ta, tb)
            .into_iter()
            .flatten()
            .min_by(|a, b| (a - t_near).abs().total_cmp(&(b - t_near).abs()))
    }
}

/// The bilinear height field of one cell, `h(x, y) = h00 + a x + b y + q x
/// y` over `0 <= x, y <= 1` (cell coordinates), and where rays cross it.
#[derive(Debug, Clone, Copy)]
struct BilinearPatch {
    h00: f64,
    a: f64,
    b: f64,
    q: f64,
}

impl BilinearPatch {
    /// The patch through corner heights `[h00, h10, h01, h11]` (`hXY`),
    /// `None` when one is nodata.
    #[inline]
    fn new([h00, h10, h01, h11]: [f64; 4]) -> Option<Self> {
        if h00.is_nan() || h10.is_nan() || h01.is_nan() || h11.is_nan() {
            return None;
        }
        Some(BilinearPatch {
            h00,
            a: h10 - h00,
            b: h01 - h00,
            q: h00 - h10 - h01 + h11,
        })
    }

    /// How far the ray `(bx + gx t, by + gy t, dz t)` is above the patch
    /// at `t`, as `A s^2 + B s + C` in `s = t - t0`.
    #[inline]
    fn clearance(&self, (bx, by, gx, gy, dz): (f64, f64, f64, f64, f64), t0: f64) -> [f64; 3] {
        let (x, y) = (bx + gx * t0, by + gy * t0);
        let c = dz * t0 - (self.h00 + self.a * x + self.b * y + self.q * x * y);
        let b = dz - self.a * gx - self.b * gy - self.q * (x * gy + y * gx);
        [-self.q * gx * gy, b, c]
    }

    /// The first `t` in `[ta, tb]` where the ray is not above the patch.
    #[inline]
    fn first_crossing(&self, ray: (f64, f64, f64, f64, f64), ta: f64, tb: f64) -> Option<f64> {
        let [qa, qb, qc] = self.clearance(ray, ta);
        if qc <= 0.0 {
            return Some(ta);
        }
        let span = tb - ta;
        let roots = quadratic_roots(qa, qb, qc);
        // The least root in (0, span] (compared as written: the roots kept
        // are positive numbers, where that is `f64::min`).
        let kept = |s: Option<f64>| match s {
            Some(s) if s > 0.0 && s <= span => s,
            _ => f64::INFINITY,
        };
        let first = fmin(kept(roots[0]), kept(roots[1]));
        if first.is_finite() {
            return Some(ta + first);
        }
        // Rounding can lose a root at the segment's end.
        let end = (qa * span + qb) * span + qc;
        (end <= 0.0).then(|| ta + span * qc / (qc - end))
    }

    /// Every `t` in `[ta, tb]` where the ray meets the patch.
    fn crossings(&self, ray: (f64, f64, f64, f64, f64), ta: f64, tb: f64) -> [Option<f64>; 2] {
        let [qa, qb, qc] = self.clearance(ray, ta);
        let span = tb - ta;
        let slack = 1e-9 * (1.0 + span);
        quadratic_roots(qa, qb, qc).map(|s| {
            s.filter(|&s| s >= -slack && s <= span + slack)
                .map(|s| ta + s.clamp(0.0, span))
        })
    }
}

/// Margin of [`ray_clears`], relative to the cell's highest corner (plus
/// one, metres): a million times the rounding of a patch's crossing, so
/// that a cell it skips is one where the crossing finds no root either.
const CLEAR_MARGIN: f64 = 1e-6;

/// Is the ray `(.., dz t)` over `[ta, tb]` above the highest of a cell's
/// `corners` by more than [`CLEAR_MARGIN`]? Then it is above the cell's
/// bilinear patch (which lies within its corners' range) and crosses
/// nothing there: the casts skip the patch's quadratic, the same answer
/// for a fraction of its cost.
#[inline]
fn ray_clears(corners: &[f64; 4], dz: f64, ta: f64, tb: f64) -> bool {
    let hi = fmax(fmax(corners[0], corners[1]), fmax(corners[2], corners[3]));
    let lowest = dz * if dz < 0.0 { tb } else { ta };
    lowest > hi + CLEAR_MARGIN * (1.0 + hi.abs())
}

/// The real roots of `a s^2 + b s + c`, by the cancellation-free formula
/// (a linear equation where `a` is negligible).
#[inline]
fn quadratic_roots(a: f64, b: f64, c: f64) -> [Option<f64>; 2] {
    if a == 0.0 || a.abs() * 1e12 < b.abs() {
        return [(b != 0.0).then(|| -c / b), None];
    }
    let disc = b * b - 4.0 * a * c;
    if disc < 0.0 {
        return [None, None];
    }
    let q = -0.5 * (b + b.signum() * disc.sqrt());
    if q == 0.0 {
        return [Some(0.0), None];
    }
    [Some(q / a), Some(c / q)]
}

/// The inverse of the 2 x 2 matrix `p` (a frame's local metres -> pixel
/// map, inverted: pixel -> local metres, or the reverse).
fn inverse_2x2(p: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let det = p[0][0] * p[1][1] - p[0][1] * p[1][0];
    [
        [p[1][1] / det, -p[0][1] / det],
        [-p[1][0] / det, p[0][0] / det],
    ]
}

impl Drop for LocalTerrain {
    fn drop(&mut self) {
        if let Some(z) = self.z.take_unshared() {
            buffer_pool::recycle_f32(z);
        }
    }
}

/// The cells a terrain keeps of a grid of `(width, height)` cells: those
/// within `max_d` of `frame`'s eye, and within `camera`'s wedge if given
/// (see [`LocalTerrain::in_view`]).
fn extent(
    (width, height): (usize, usize),
    frame: &LocalFrame,
    max_d: f64,
    camera: Option<&crate::view::Camera>,
) -> (usize, usize, usize, usize) {
    let p = frame.p;
    let pinv = inverse_2x2(p);
    let (ex, ey) = frame.eye_pixel;
    let (mut c0, mut r0, mut c1, mut r1) = (0usize, 0usize, width, height);
    if max_d.is_finite() {
        // Pixel half-extents of a circle of radius max_d.
        let rx = max_d * pinv[0][0].hypot(pinv[0][1]) + 2.0;
        let ry = max_d * pinv[1][0].hypot(pinv[1][1]) + 2.0;
        c0 = (ex - rx).floor().max(0.0) as usize;
        r0 = (ey - ry).floor().max(0.0) as usize;
        c1 = ((ex + rx).ceil().max(0.0) as usize).min(width);
        r1 = ((ey + ry).ceil().max(0.0) as usize).min(height);
    }
    if let Some((a, b, c, d)) =
        camera.and_then(|cam| view_wedge_box((width, height), frame, max_d, cam))
    {
        (c0, r0, c1, r1) = (c0.max(a), r0.max(b), c1.min(c), r1.min(d));
        if c1 <= c0 || r1 <= r0 {
            // the wedge misses the DEM: keep the eye's cell
            c0 = (ex.floor().max(0.0) as usize).min(width.saturating_sub(1));
            r0 = (ey.floor().max(0.0) as usize).min(height.saturating_sub(1));
            (c1, r1) = (c0 + 1, r0 + 1);
        }
    }
    (c0, r0, c1, r1)
}

/// The horizontal wedge of `camera`'s pixel rays: the centre ray's azimuth
/// (radians clockwise from north) and the least and greatest azimuths of
/// the rays relative to it (with a degree's margin); `None` when they span
/// more than a half-turn or a ray is nearly vertical.
pub(crate) fn wedge_azimuths(camera: &crate::view::Camera) -> Option<(f64, f64, f64)> {
    use crate::view::CameraModel;
    use std::f64::consts::{PI, TAU};
    // Azimuths of the rays around the image border (the rays through a
    // rectangle form a convex cone, whose horizontal extremes lie on its
    // border), relative to the centre ray's.
    let centre = camera.unproject([camera.width as f64 / 2.0, camera.height as f64 / 2.0]);
    let azimuth = |d: [f64; 3]| {
        let h = d[0].hypot(d[1]);
        (h > 1e-3 * (h + d[2].abs())).then(|| d[0].atan2(d[1]))
    };
    let a_centre = azimuth(centre)?;
    let (w, h) = (camera.width as f64, camera.height as f64);
    let (mut lo, mut hi) = (0.0f64, 0.0f64);
    let steps = 64;
    for k in 0..=steps {
        let f = k as f64 / steps as f64;
        for px in [[f * w, 0.0], [f * w, h], [0.0, f * h], [w, f * h]] {
            let a = azimuth(camera.unproject(px))?;
            // relative to the centre, in (-pi, pi]
            let mut r = (a - a_centre) % TAU;
            if r > PI {
                r -= TAU;
            } else if r <= -PI {
                r += TAU;
            }
            lo = lo.min(r);
            hi = hi.max(r);
        }
    }
    let margin = 1f64.to_radians();
    let (lo, hi) = (lo - margin, hi + margin);
    if hi - lo > PI {
        return None;
    }
    Some((a_centre, lo, hi))
}

#[allow(clippy::type_complexity)]
/// The pixel box `(c0, r0, c1, r1)` (end exclusive, clipped to `dem`) of
/// the horizontal wedge `camera` sees from `frame`'s eye out to `max_d`
/// (the far corner of `dem` when infinite), or `None` when the azimuths of
/// its pixel rays span more than a half-turn or a ray is nearly vertical.
fn view_wedge_box(
    (width, height): (usize, usize),
    frame: &LocalFrame,
    max_d: f64,
    camera: &crate::view::Camera,
) -> Option<(usize, usize, usize, usize)> {
    let (a_centre, lo, hi) = wedge_azimuths(camera)?;
    // Radius: the maximum distance, or the farthest corner of the DEM.
    let p = frame.p;
    let to_en = |px: f64, py: f64| {
        let (dx, dy) = (px - frame.eye_pixel.0, py - frame.eye_pixel.1);
        (p[0][0] * dx + p[0][1] * dy, p[1][0] * dx + p[1][1] * dy)
    };
    let radius = if max_d.is_finite() {
        max_d
    } else {
        let (wd, hd) = (width as f64, height as f64);
        [(0.0, 0.0), (wd, 0.0), (0.0, hd), (wd, hd)]
            .iter()
            .map(|&(x, y)| {
                let (e, n) = to_en(x, y);
                e.hypot(n)
            })
            .fold(0.0, f64::max)
            * 1.01
    };
    let det = p[0][0] * p[1][1] - p[0][1] * p[1][0];
    let to_px = |e: f64, n: f64| {
        (
            frame.eye_pixel.0 + (p[1][1] * e - p[0][1] * n) / det,
            frame.eye_pixel.1 + (-p[1][0] * e + p[0][0] * n) / det,
        )
    };
    // The eye and the arc, sampled every degree (its chords fall short of
    // the arc by under 2e-5 of the radius; the padding covers that).
    let (mut x0, mut y0, mut x1, mut y1) = (
        frame.eye_pixel.0,
        frame.eye_pixel.1,
        frame.eye_pixel.0,
        frame.eye_pixel.1,
    );
    let n = ((hi - lo).to_degrees().ceil() as usize).max(1);
    for k in 0..=n {
        let a = a_centre + lo + (hi - lo) * k as f64 / n as f64;
        let (x, y) = to_px(radius * a.sin(), radius * a.cos());
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    let pad = 3.0;
    let clip = |v: f64, n: usize| (v.max(0.0) as usize).min(n);
    Some((
        clip((x0 - pad).floor(), width),
        clip((y0 - pad).floor(), height),
        clip((x1 + pad).ceil(), width),
        clip((y1 + pad).ceil(), height),
    ))
}

/// Lowest and highest vertex of each column of `z` (`nx` across) over the
/// vertex rows of block row `by` (rows `by * RANGE_BLOCK ..=` the next
/// block's first, within `cy` cells): comparisons skip NaN and vectorise.
fn column_ranges(z: &VertexHeights, cy: usize, by: usize, lo: &mut [f32], hi: &mut [f32]) {
    let r0 = by * RANGE_BLOCK;
    let r1 = ((by + 1) * RANGE_BLOCK).min(cy);
    lo.fill(f32::INFINITY);
    hi.fill(f32::NEG_INFINITY);
    for r in r0..=r1 {
        range_row(lo, hi, &z.row(r));
    }
}

/// One row of [`column_ranges`]: each column's lowest and highest so far
/// lowered and raised by `row`'s vertex (NaN skipped). Compiled for AVX2
/// where the CPU has it (compares and selects: the same result).
fn range_row(lo: &mut [f32], hi: &mut [f32], row: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { range_row_avx2(lo, hi, row) };
        return;
    }
    range_row_body(lo, hi, row);
}

/// [`range_row`] compiled for AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn range_row_avx2(lo: &mut [f32], hi: &mut [f32], row: &[f32]) {
    range_row_body(lo, hi, row);
}

/// The loop of [`range_row`].
#[inline(always)]
fn range_row_body(lo: &mut [f32], hi: &mut [f32], row: &[f32]) {
    for ((l, h), &v) in lo.iter_mut().zip(hi.iter_mut()).zip(row.iter()) {
        *l = if v < *l { v } else { *l };
        *h = if v > *h { v } else { *h };
    }
}

/// The range of block column `bx` (its vertex columns, boundary included,
/// within `cx` cells) from the column ranges of its block row.
fn block_of_columns(lo: &[f32], hi: &[f32], cx: usize, bx: usize) -> (f32, f32) {
    let c0 = bx * RANGE_BLOCK;
    let c1 = ((bx + 1) * RANGE_BLOCK).min(cx);
    (
        lo[c0..=c1].iter().fold(f32::INFINITY, |a, &v| a.min(v)),
        hi[c0..=c1].iter().fold(f32::NEG_INFINITY, |a, &v| a.max(v)),
    )
}

/// `old` (the block ranges of a terrain of `nx` x `ny` vertices) with the
/// blocks holding a vertex of `changed` (vertex rectangle `(c0, r0, c1, r1)`,
/// end exclusive) computed again from `z`: the ranges
/// [`LocalTerrain::block_ranges`] gives on `z`, for the cost of the changed
/// blocks.
fn patched_ranges(
    old: &BlockRanges,
    z: &VertexHeights,
    nx: usize,
    ny: usize,
    changed: Option<(usize, usize, usize, usize)>,
) -> BlockRanges {
    let mut r = old.clone();
    let Some((c0, r0, c1, r1)) = changed else {
        return r;
    };
    let (cx, cy) = (nx.saturating_sub(1), ny.saturating_sub(1));
    // A vertex on a block edge belongs to the blocks on both sides.
    let bx0 = c0.saturating_sub(1) / RANGE_BLOCK;
    let by0 = r0.saturating_sub(1) / RANGE_BLOCK;
    let bx1 = ((c1 - 1) / RANGE_BLOCK).min(r.bw - 1);
    let by1 = ((r1 - 1) / RANGE_BLOCK).min(r.bh - 1);
    let (mut lo, mut hi) = (vec![0f32; nx], vec![0f32; nx]);
    for by in by0..=by1 {
        column_ranges(z, cy, by, &mut lo, &mut hi);
        for bx in bx0..=bx1 {
            let (l, h) = block_of_columns(&lo, &hi, cx, bx);
            r.lo[by * r.bw + bx] = l;
            r.hi[by * r.bw + bx] = h;
        }
    }
    r
}

impl BlockRanges {
    /// Lowest and highest vertex over all blocks (every vertex lies in
    /// one): the terrain's height range.
    fn height_range(&self) -> (f32, f32) {
        (
            self.lo.iter().fold(f32::INFINITY, |a, &v| a.min(v)),
            self.hi.iter().fold(f32::NEG_INFINITY, |a, &v| a.max(v)),
        )
    }
}

/// `old` (the full cast index of a terrain of `nx` x `ny` vertices) for
/// the vertex heights `z`, which differ from those it was built on only in
/// the vertices `changed` (`(c0, r0, c1, r1)`, end exclusive): the level-0
/// blocks holding them computed again as [`LocalTerrain::build_mip`] does,
/// then every level above over their parents as [`max_pyramid`] does, the
/// rest copied. The same values as a build over `z`.
fn patched_index(
    old: &CastIndex,
    z: &VertexHeights,
    nx: usize,
    ny: usize,
    changed: Option<(usize, usize, usize, usize)>,
) -> CastIndex {
    let mut mip = old.mip.clone();
    let out = |mip| CastIndex {
        mip,
        mip_dims: old.mip_dims.clone(),
        shift: old.shift,
    };
    let Some((c0, r0, c1, r1)) = changed.filter(|_| old.shift == 1) else {
        return out(mip);
    };
    // Level 0: block b holds vertices 2 b ..= 2 b + 2.
    let span = |a: usize, b: usize, n: usize| (a.saturating_sub(1) / 2, ((b - 1) / 2).min(n - 1));
    let (w0, h0) = old.mip_dims[0];
    let (mut x0, mut x1) = span(c0, c1, w0);
    let (mut y0, mut y1) = span(r0, r1, h0);
    for by in y0..=y1 {
        let rows: Vec<_> = (2 * by..(2 * by + 3).min(ny)).map(|r| z.row(r)).collect();
        for bx in x0..=x1 {
            let mut m = f32::NAN;
            for row in &rows {
                for &v in &row[2 * bx..(2 * bx + 3).min(nx)] {
                    m = m.max(v);
                }
            }
            mip[0][by * w0 + bx] = if m.is_nan() { f32::NEG_INFINITY } else { m };
        }
    }
    // Each level up: block b is the max of blocks 2 b, 2 b + 1 below.
    for l in 1..mip.len() {
        let (w, h) = old.mip_dims[l - 1];
        let w2 = old.mip_dims[l].0;
        (x0, x1, y0, y1) = (x0 / 2, x1 / 2, y0 / 2, y1 / 2);
        let (below, above) = mip.split_at_mut(l);
        let (prev, next) = (&below[l - 1], &mut above[0]);
        for r in y0..=y1 {
            let a = &prev[2 * r * w..(2 * r + 1) * w];
            let b = if 2 * r + 1 < h {
                &prev[(2 * r + 1) * w..(2 * r + 2) * w]
            } else {
                a
            };
            for c in x0..=x1 {
                let cc = (2 * c + 1).min(w - 1);
                next[r * w2 + c] = a[2 * c].max(a[cc]).max(b[2 * c]).max(b[cc]);
            }
        }
    }
    out(mip)
}

/// The cast index and block ranges of `t` as bits (built on demand): for
/// tests that a patched terrain's equal a fresh build's.
#[doc(hidden)]
pub fn acceleration_bits(t: &LocalTerrain) -> (Vec<u32>, Vec<u32>) {
    let idx = t.index();
    let r = t.block_ranges();
    let mip = idx.mip.iter().flatten().map(|v| v.to_bits()).collect();
    let ranges = r.lo.iter().chain(&r.hi).map(|v| v.to_bits()).collect();
    (mip, ranges)
}

/// The pyramid over `base` (`w` x `h` block maxima): each level the max of
/// 2 x 2 blocks of the one below, up to a single block.
fn max_pyramid(base: Vec<f32>, w: usize, h: usize) -> (Vec<Vec<f32>>, Vec<(usize, usize)>) {
    let mut mip = vec![base];
    let mut dims = vec![(w.max(1), h.max(1))];
    while {
        let (w, h) = dims[dims.len() - 1];
        w > 1 || h > 1
    } {
        let (w, h) = dims[dims.len() - 1];
        let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
        let prev = &mip[mip.len() - 1];
        let mut next = vec![f32::NEG_INFINITY; w2 * h2];
        next.par_chunks_mut(w2).enumerate().for_each(|(r, out)| {
            let a = &prev[2 * r * w..(2 * r + 1) * w];
            let b = if 2 * r + 1 < h {
                &prev[(2 * r + 1) * w..(2 * r + 2) * w]
            } else {
                a
            };
            for (c, o) in out.iter_mut().enumerate() {
                let c1 = (2 * c + 1).min(w - 1);
                *o = a[2 * c].max(a[c1]).max(b[2 * c]).max(b[c1]);
            }
        });
        mip.push(next);
        dims.push((w2, h2));
    }
    (mip, dims)
}

/// `2^e` exactly (`|e| < 1023`), built from its bits: the traversal's
/// block sizes and their reciprocals without a conversion or a division.
#[inline]
fn pow2(e: i32) -> f64 {
    f64::from_bits(((1023 + e) as u64) << 52)
}

/// The lesser of `a` and `b`, compared as written (one `minsd`): for the
/// casts' inner loops, whose values are never NaN (there, `f64::min`
/// would give the same, with a NaN check each time). On a tie the result
/// is `b`, the same number (the loops' ties are never zeros of opposite
/// signs, where the two could differ: they are distances past a positive
/// start, or heights compared with a margin).
#[inline]
pub(super) fn fmin(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

/// The greater of `a` and `b`, as [`fmin`]; a NaN `a` gives `b`.
#[inline]
pub(super) fn fmax(a: f64, b: f64) -> f64 {
    if a > b {
        a
    } else {
        b
    }
}

/// A grid index as `f64`, the value `i as f64` gives (indices are far below
/// 2^53), by the signed conversion, a single instruction on x86-64.
#[inline]
fn index_f64(i: usize) -> f64 {
    i as i64 as f64
}

/// `v.max(0.0) as usize` (NaN and negative values give 0: `fmax` gives 0
/// for a NaN `v`, as `max` does), by the signed conversion: the two agree
/// for every value below 2^53, and the callers clamp the index to the
/// grid (or compare it with one), far below it, so that above (where
/// this gives 2^53) the outcome is theirs too.
#[inline]
fn floor_index(v: f64) -> usize {
    let x = fmin(fmax(v, 0.0), 9_007_199_254_740_992.0);
    // SAFETY: `x` is a number within `0..=2^53`, where the conversion is
    // defined (it truncates, as `as` does); the unchecked one is a single
    // instruction, without `as`'s saturation.
    (unsafe { x.to_int_unchecked::<i64>() }) as usize
}

/// One axis of a ray's horizontal track in vertex coordinates: `o + g t`,
/// with `1 / g` precomputed (the traversal's block exits are products, not
/// quotients) and `w` the extent of the cells along the axis.
#[derive(Clone, Copy)]
struct RayAxis {
    o: f64,
    g: f64,
    inv_g: f64,
    w: f64,
}

impl RayAxis {
    fn new(o: f64, g: f64, w: f64) -> RayAxis {
        RayAxis {
            o,
            g,
            inv_g: if g != 0.0 { 1.0 / g } else { 0.0 },
            w,
        }
    }
}

/// Block index along one axis of the point `p = o + g * tp` at block size `s`
/// (a power of two, `inv_s = 1 / s`; `n`: number of blocks) and the ray
/// parameter at which the ray leaves that block. Robust to points lying
/// numerically on a block boundary: the block is the one the ray is
/// entering, so the exit lies beyond `tp`. `None` when the ray has left the
/// grid along this axis.
#[inline]
fn axis_block(a: &RayAxis, p: f64, s: f64, inv_s: f64, n: usize, tp: f64) -> Option<(usize, f64)> {
    let exit = |b: usize| {
        if a.g > 0.0 {
            (fmin(index_f64(b + 1) * s, a.w) - a.o) * a.inv_g
        } else if a.g < 0.0 {
            (index_f64(b) * s - a.o) * a.inv_g
        } else {
            f64::INFINITY
        }
    };
    // truncation is floor for the non-negative values kept by max (and
    // multiplying by a power of two's reciprocal is exact)
    let mut b = floor_index(p * inv_s).min(n - 1);
    let mut te = exit(b);
    if te <= tp {
        if a.g > 0.0 {
            if b + 1 >= n {
                return None;
            }
            b += 1;
        } else {
            if b == 0 {
                return None;
            }
            b -= 1;
        }
        te = exit(b);
    }
    Some((b, te))
}

/// What [`vertex_row`] needs of a terrain's frame for one row: `e = p0.0
/// dx + p0.1`, `n = p1.0 dx + p1.1` (the row's terms folded in), the eye's
/// altitude, the curvature coefficient and the squared distances kept.
#[derive(Clone, Copy)]
struct RowFrame {
    p0: (f64, f64),
    p1: (f64, f64),
    eye_alt: f64,
    coef: f64,
    d2_range: (f64, f64),
}

/// The columns `[a, b)` of a row (column offsets `dxs` from the eye, in
/// increasing order; the row's frame `f`) whose squared distance, as
/// [`vertex_row`] computes it, is surely under the row's least kept one:
/// [`vertex_row`] writes NaN there whatever the height. `(0, 0)` where no
/// column is sure (or nothing is cut). The interval comes from the roots of
/// the squared distance (a quadratic in the offset) at a slightly smaller
/// radius, and is kept only where its two end columns, computed as
/// [`vertex_row`] does, lie under `1 - 1e-9` times the least squared
/// distance: the exact squared distance is convex along the row, so every
/// column between lies at most that far, and the rounding of
/// [`vertex_row`]'s few operations (relative 1e-14 for any ring whose box
/// is within a million times its inner radius) cannot lift it to the bound.
fn surely_inside(dxs: &[f64], f: &RowFrame) -> (usize, usize) {
    const MARGIN: f64 = 1.0 - 1e-9;
    let min_d2 = f.d2_range.0;
    let (Some(&first), true) = (dxs.first(), min_d2 > 0.0) else {
        return (0, 0);
    };
    let d2_at = |dx: f64| {
        let e = f.p0.0 * dx + f.p0.1;
        let n = f.p1.0 * dx + f.p1.1;
        e * e + n * n
    };
    let (a2, b2) = (
        f.p0.0 * f.p0.0 + f.p1.0 * f.p1.0,
        f.p0.0 * f.p0.1 + f.p1.0 * f.p1.1,
    );
    // (the roots a little inside, so that the end columns pass the check)
    let c = f.p0.1 * f.p0.1 + f.p1.1 * f.p1.1 - min_d2 * (1.0 - 4e-9);
    // a2 s^2 + 2 b2 s + c < 0 between the roots
    let disc = b2 * b2 - a2 * c;
    if !(a2 > 0.0 && disc > 0.0) {
        return (0, 0);
    }
    let root = disc.sqrt();
    let (lo, hi) = ((-b2 - root) / a2, (-b2 + root) / a2);
    let n = dxs.len() as f64;
    let a = (lo - first).ceil().clamp(0.0, n) as usize;
    let b = ((hi - first).floor() + 1.0).clamp(0.0, n) as usize;
    let sure = |i: usize| d2_at(dxs[i]) < min_d2 * MARGIN;
    if a < b && sure(a) && sure(b - 1) {
        (a, b)
    } else {
        (0, 0)
    }
}

/// One row of [`LocalTerrain::build_over`]'s vertex heights: the height of
/// each cell `h` at column offset `dx` from the eye, less the eye's altitude
/// and the curvature drop at its squared distance, NaN outside the kept
/// distances (NaN heights stay NaN). A function of its own, with every
/// constant passed by value, so that the loop vectorises (in the row's
/// closure the constants were read through references that the compiler
/// could not tell apart from the row written).
#[inline(never)]
fn vertex_row(out: &mut [f32], src: &[f32], dxs: &[f64], f: RowFrame) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { vertex_row_avx2(out, src, dxs, f) };
        return;
    }
    vertex_row_body(out, src, dxs, f);
}

/// [`vertex_row`] compiled for AVX2 (four `f64` lanes; the same IEEE
/// operations per cell, no fused multiply-add: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn vertex_row_avx2(out: &mut [f32], src: &[f32], dxs: &[f64], f: RowFrame) {
    vertex_row_body(out, src, dxs, f);
}

/// The loop of [`vertex_row`].
#[inline(always)]
fn vertex_row_body(out: &mut [f32], src: &[f32], dxs: &[f64], f: RowFrame) {
    for ((out, &h), &dx) in out.iter_mut().zip(src).zip(dxs) {
        *out = vertex_height(h, dx, &f);
    }
}

/// [`vertex_row`] with each cell's height in `out` itself, turned into
/// its vertex's height in place.
#[inline(never)]
fn vertex_row_in_place(out: &mut [f32], dxs: &[f64], f: RowFrame) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked just above).
        unsafe { vertex_row_in_place_avx2(out, dxs, f) };
        return;
    }
    vertex_row_in_place_body(out, dxs, f);
}

/// [`vertex_row_in_place`] compiled for AVX2 (as [`vertex_row_avx2`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn vertex_row_in_place_avx2(out: &mut [f32], dxs: &[f64], f: RowFrame) {
    vertex_row_in_place_body(out, dxs, f);
}

/// The loop of [`vertex_row_in_place`].
#[inline(always)]
fn vertex_row_in_place_body(out: &mut [f32], dxs: &[f64], f: RowFrame) {
    for (out, &dx) in out.iter_mut().zip(dxs) {
        *out = vertex_height(*out, dx, &f);
    }
}

/// The vertex height of a cell of height `h` at column offset `dx` from
/// the eye, in a row of frame `f` (see [`vertex_row`]).
#[inline(always)]
fn vertex_height(h: f32, dx: f64, f: &RowFrame) -> f32 {
    let (min_d2, max_d2) = f.d2_range;
    let e = f.p0.0 * dx + f.p0.1;
    let n = f.p1.0 * dx + f.p1.1;
    let d2 = e * e + n * n;
    let v = (h as f64 - f.eye_alt - f.coef * d2) as f32;
    if (d2 > max_d2) | (d2 < min_d2) {
        f32::NAN
    } else {
        v
    }
}

#[cfg(test)]
mod ring_tests {
    use super::*;

    /// The columns a ring's row skips are columns whose squared distance,
    /// as the vertex loop computes it, is under the inner radius's (where
    /// it writes NaN whatever the height): on rows through, beside and
    /// tangent to the inner disc, for rotated grids of several cell sizes;
    /// and the skipped interval is most of the inside.
    #[test]
    fn the_columns_a_ring_skips_are_nodata_in_the_vertex_loop() {
        let mut skipped = 0usize;
        let mut inside = 0usize;
        for (cell, turn) in [(15.0, 0.0), (30.0, 0.3), (83.5, 1.1), (1.0, 2.0)] {
            let (s, c) = (f64::sin(turn), f64::cos(turn));
            let p = [[cell * c, -cell * s], [cell * s, cell * c]];
            let min_d = 1000.0 * cell;
            let min_d2 = min_d * min_d;
            let dx0 = -1500.37;
            let dxs: Vec<f64> = (0..3000).map(|i| dx0 + i as f64).collect();
            for dy in (-1100..1100).map(|r| r as f64 + 0.5) {
                let f = RowFrame {
                    p0: (p[0][0], p[0][1] * dy),
                    p1: (p[1][0], p[1][1] * dy),
                    eye_alt: 0.0,
                    coef: 0.0,
                    d2_range: (min_d2, f64::INFINITY),
                };
                let (a, b) = surely_inside(&dxs, &f);
                let mut src = vec![100.0f32; dxs.len()];
                src[0] = f32::NAN;
                let mut whole = vec![0f32; dxs.len()];
                vertex_row_body(&mut whole, &src, &dxs, f);
                for (i, v) in whole.iter().enumerate() {
                    if (a..b).contains(&i) {
                        assert_eq!(v.to_bits(), f32::NAN.to_bits(), "column {i} of row {dy}");
                        skipped += 1;
                    }
                    if v.is_nan() && i > 0 {
                        inside += 1;
                    }
                }
            }
        }
        assert!(
            skipped > 0 && skipped + skipped / 50 >= inside,
            "{skipped} of {inside}"
        );
    }
    /// A ring's heights made in place are those made from a copy, bit
    /// for bit (NaN heights, the inner hole and the outer edge included).
    #[test]
    fn heights_made_in_place_are_those_made_from_a_copy() {
        let p = [[30.0, 0.4], [-0.2, -30.0]];
        let dxs: Vec<f64> = (0..500).map(|i| -250.37 + i as f64).collect();
        for dy in [-200.5, -3.5, 0.5, 77.5] {
            let f = RowFrame {
                p0: (p[0][0], p[0][1] * dy),
                p1: (p[1][0], p[1][1] * dy),
                eye_alt: 1234.5,
                coef: 6.7e-8,
                d2_range: (3000.0f64.powi(2), 7000.0f64.powi(2)),
            };
            let src: Vec<f32> = (0..dxs.len())
                .map(|i| {
                    if i % 17 == 3 {
                        f32::NAN
                    } else {
                        900.0 + (i * 37 % 101) as f32 * 1.25
                    }
                })
                .collect();
            let mut copied = vec![0f32; dxs.len()];
            vertex_row(&mut copied, &src, &dxs, f);
            let mut own = src.clone();
            vertex_row_in_place(&mut own, &dxs, f);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&own), bits(&copied), "row {dy}");
        }
    }
}
