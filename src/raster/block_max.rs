//! Reading a DEM at a coarser resolution: each cell of a grid `k` times
//! coarser (aligned to the DEM's origin) holds the highest valid height of
//! the `k x k` cells it covers. For the far rings of a level-of-detail
//! terrain ([`crate::render::Scene::open_wedge`]): the maximum, not the
//! mean, so that a coarse surface's vertices are never below a cell they
//! stand for (a far ridge is not lowered below the sky line it draws).
//!
//! The window is read in chunks of [`CHUNK`] x [`CHUNK`] cells, one band
//! of chunks per task, each reduced at once: the full-resolution heights
//! never exist for more than a chunk per thread. A chunk the caller does
//! not want (outside the camera's wedge, inside the exact terrain) is not
//! read at all.

use rayon::prelude::*;

use super::{Dem, HeightMap, RasterError, Window};

/// Edge in DEM cells of the chunks read at once (a multiple of every
/// power-of-two coarseness up to it; a common TIFF block).
pub const CHUNK: usize = 256;

impl Dem {
    /// The heights of coarse window `cwin` (cells of the grid `k` times
    /// coarser than the DEM's, cell `(c, r)` covering DEM cells `c k ..
    /// (c + 1) k` and `r k .. (r + 1) k`): the highest valid height of each
    /// coarse cell's DEM cells (NaN where none is valid, or the cell lies
    /// off the DEM), on the coarse grid. The DEM is read in chunks of
    /// [`CHUNK`] cells (aligned to the DEM's origin); a chunk for which
    /// `wanted` (its window in DEM cells) is false is not read and its
    /// coarse cells are NaN. Reads through [`Dem::read_height_map_once`]
    /// (an overlay is seen; no block is kept in the cache).
    pub fn read_block_max(
        &self,
        cwin: Window,
        k: usize,
        wanted: &(dyn Fn(Window) -> bool + Sync),
    ) -> Result<HeightMap, RasterError> {
        let k = k.max(1);
        // coarse cells per chunk edge (a chunk a whole number of coarse cells)
        let cc = (CHUNK / k).max(1);
        let (w, h) = (cwin.width, cwin.height);
        // (a recycled buffer where there is one: each band sets its rows
        // to NaN before its chunks are reduced into them)
        let mut data = crate::buffer_pool::overwritten_f32(w * h);
        if w > 0 && h > 0 {
            // Bands of coarse rows aligned to the chunk grid.
            let first_band = cwin.row.div_euclid(cc as i64);
            let bands = band_rows(cwin, cc, first_band);
            let mut slices = Vec::with_capacity(bands.len());
            let mut rest = &mut data[..];
            for &(r0, r1) in &bands {
                let (band, tail) = rest.split_at_mut((r1 - r0) * w);
                slices.push((r0, r1, band));
                rest = tail;
            }
            slices
                .into_par_iter()
                .map(|(r0, r1, band)| self.band_max(cwin, k, cc, (r0, r1), band, wanted))
                .collect::<Result<Vec<()>, RasterError>>()?;
        }
        let g = self
            .geotransform
            .offset((cwin.col * k as i64) as f64, (cwin.row * k as i64) as f64)
            .0;
        let kf = k as f64;
        Ok(HeightMap {
            width: w,
            height: h,
            data,
            geotransform: super::GeoTransform([
                g[0],
                g[1] * kf,
                g[2] * kf,
                g[3],
                g[4] * kf,
                g[5] * kf,
            ]),
            crs: self.crs.clone(),
        })
    }

    /// One band of [`Dem::read_block_max`]: coarse rows `r0..r1` of
    /// `cwin` (relative to it) into `out`, chunk by chunk.
    fn band_max(
        &self,
        cwin: Window,
        k: usize,
        cc: usize,
        (r0, r1): (usize, usize),
        out: &mut [f32],
        wanted: &(dyn Fn(Window) -> bool + Sync),
    ) -> Result<(), RasterError> {
        let w = cwin.width;
        out.fill(f32::NAN);
        for ((c, c1), _, full) in chunks_of_band(cwin, k, cc, (r0, r1)) {
            if let Some(read) = full.intersect(&self.full_window()).filter(|f| wanted(*f)) {
                let cells = self.read_height_map_once(read)?;
                ChunkMax {
                    cells: &cells,
                    read,
                    full,
                    k,
                    cols: (c, c1),
                    w,
                }
                .reduce_max(out);
            }
        }
        Ok(())
    }
}

/// The box of the chunks of [`CHUNK`] x [`CHUNK`] cells of a grid (its
/// cells `grid`, chunks aligned to its origin) that reach window `cwin` of
/// it and for which `wanted` holds (asked of the chunk clipped to `cwin`
/// and `grid`, as [`Dem::read_block_max`] with `k` = 1 asks), clipped to
/// `cwin`; `None` when there is none. What reading `cwin` that way
/// reads, and, for a grid `k` times coarser than a DEM's and `wanted` of
/// the DEM cells under a window, a box holding every chunk that reading
/// the DEM's block maxima (chunks `k` times finer, each within one of
/// these) reads: outside it every coarse cell comes out NaN.
pub fn block_max_extent(
    cwin: Window,
    grid: Window,
    wanted: &(dyn Fn(Window) -> bool + Sync),
) -> Option<Window> {
    let first_band = cwin.row.div_euclid(CHUNK as i64);
    let mut extent: Option<(i64, i64, i64, i64)> = None;
    for (r0, r1) in band_rows(cwin, CHUNK, first_band) {
        for (_, coarse, _) in chunks_of_band(cwin, 1, CHUNK, (r0, r1)) {
            if coarse.intersect(&grid).is_some_and(wanted) {
                let (c0, rr0) = (coarse.col, coarse.row);
                let (c1, rr1) = (coarse.col_end(), coarse.row_end());
                extent = Some(match extent {
                    None => (c0, rr0, c1, rr1),
                    Some((a, b, c, d)) => (a.min(c0), b.min(rr0), c.max(c1), d.max(rr1)),
                });
            }
        }
    }
    let (c0, r0, c1, r1) = extent?;
    Some(Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize))
}

/// The chunks of the band of coarse rows `r0..r1` of `cwin` (relative to
/// it), left to right: the coarse columns of `cwin` each covers (relative,
/// end exclusive), its coarse window (clipped to `cwin`) and that window
/// in DEM cells (`k` a coarse cell).
fn chunks_of_band(
    cwin: Window,
    k: usize,
    cc: usize,
    (r0, r1): (usize, usize),
) -> impl Iterator<Item = ((usize, usize), Window, Window)> {
    let w = cwin.width;
    let mut c = 0usize;
    std::iter::from_fn(move || {
        if c >= w {
            return None;
        }
        // the chunk column holding coarse column c, clipped to cwin
        let abs = cwin.col + c as i64;
        let next = (abs.div_euclid(cc as i64) + 1) * cc as i64;
        let c1 = ((next - cwin.col) as usize).min(w);
        let coarse = Window::new(abs, cwin.row + r0 as i64, c1 - c, r1 - r0);
        let full = Window::new(
            coarse.col * k as i64,
            coarse.row * k as i64,
            coarse.width * k,
            coarse.height * k,
        );
        let cols = (c, c1);
        c = c1;
        Some((cols, coarse, full))
    })
}

/// The bands of coarse rows of `cwin` (relative to it, end exclusive) cut
/// at the chunk grid's rows (every `cc` coarse rows from the origin).
fn band_rows(cwin: Window, cc: usize, first_band: i64) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut r = 0usize;
    let mut band = first_band;
    while r < cwin.height {
        let end = ((band + 1) * cc as i64 - cwin.row) as usize;
        let r1 = end.min(cwin.height);
        out.push((r, r1));
        r = r1;
        band += 1;
    }
    out
}

/// One chunk's share of a band: its heights `cells` (DEM window `read`,
/// within the chunk's full extent `full`, `k x k` DEM cells a coarse cell),
/// and where its coarse cells go: the coarse columns `cols` of a band of
/// rows `w` coarse cells wide, starting at the chunk's first coarse row.
struct ChunkMax<'a> {
    cells: &'a HeightMap,
    read: Window,
    full: Window,
    k: usize,
    cols: (usize, usize),
    w: usize,
}

impl ChunkMax<'_> {
    /// The highest valid height of each `k x k` block of the chunk, into
    /// its coarse columns of the band `out`. Each coarse row is reduced
    /// down the columns first (whole rows at a time, which vectorises),
    /// then across each block's columns: the same maximum as cell by cell.
    fn reduce_max(&self, out: &mut [f32]) {
        let (c0, c1) = self.cols;
        let single = self.k == 1
            && self.read == self.full
            && c1 - c0 == self.read.width
            && self.rows(out) <= self.read.height;
        if single {
            self.single_cells(out);
        } else {
            self.reduce_general(out);
        }
    }

    /// The coarse rows of the band `out`.
    fn rows(&self, out: &[f32]) -> usize {
        out.len() / self.w.max(1)
    }

    /// [`ChunkMax::reduce_max`] with one cell per coarse cell and the chunk
    /// read whole (a ring read from an overview of its own coarseness): the
    /// general path's two reductions of a single cell, row by row, without
    /// its per-cell slicing.
    fn single_cells(&self, out: &mut [f32]) {
        let ((c0, c1), w) = (self.cols, self.w);
        let rw = self.cells.width;
        for cr in 0..self.rows(out) {
            let src = &self.cells.data[cr * rw..(cr + 1) * rw];
            let row = &mut out[cr * w + c0..cr * w + c1];
            for (o, &v) in row.iter_mut().zip(src) {
                *o = f32::NAN.max(f32::NAN.max(v));
            }
        }
    }

    /// [`ChunkMax::reduce_max`] for any `k`: down the columns, then across
    /// each block.
    fn reduce_general(&self, out: &mut [f32]) {
        let Self {
            cells,
            read,
            full,
            k,
            cols: (c0, c1),
            w,
        } = *self;
        let mut column_max = vec![f32::NAN; read.width];
        for cr in 0..self.rows(out) {
            // the block row's cells within what was read
            let br0 = full.row + (cr * k) as i64;
            let y0 = (br0.max(read.row) - read.row) as usize;
            let y1 = ((br0 + k as i64).min(read.row_end()) - read.row).max(0) as usize;
            column_max.fill(f32::NAN);
            for y in y0..y1 {
                let src = &cells.data[y * read.width..(y + 1) * read.width];
                for (m, &v) in column_max.iter_mut().zip(src) {
                    // f32::max skips NaN
                    *m = m.max(v);
                }
            }
            let row = &mut out[cr * w + c0..cr * w + c1];
            for (i, o) in row.iter_mut().enumerate() {
                let bc0 = full.col + (i * k) as i64;
                let x0 = (bc0.max(read.col) - read.col) as usize;
                let x1 = ((bc0 + k as i64).min(read.col_end()) - read.col).max(0) as usize;
                *o = column_max[x0.min(x1)..x1]
                    .iter()
                    .fold(f32::NAN, |m, &v| m.max(v));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The heights `data` of DEM window `read`, as read.
    fn cells_of(read: Window, data: Vec<f32>) -> HeightMap {
        HeightMap {
            width: read.width,
            height: read.height,
            data,
            geotransform: crate::raster::GeoTransform([0.0, 1.0, 0.0, 0.0, 0.0, -1.0]),
            crs: crate::raster::Crs {
                epsg: None,
                wkt: String::new(),
                proj: None,
                geographic: false,
            },
        }
    }

    /// The reduction of chunk `cells` (DEM window `read` within `full`)
    /// into the coarse columns `cols` of a band `w` wide.
    fn chunk(
        cells: &HeightMap,
        read: Window,
        full: Window,
        k: usize,
        cols: (usize, usize),
        w: usize,
    ) -> ChunkMax<'_> {
        ChunkMax {
            cells,
            read,
            full,
            k,
            cols,
            w,
        }
    }

    #[test]
    fn bands_follow_the_chunk_grid() {
        let w = Window::new(0, 5, 10, 20);
        assert_eq!(
            band_rows(w, 8, 0),
            vec![(0, 3), (3, 11), (11, 19), (19, 20)]
        );
    }

    /// With one cell per coarse cell the fast path gives the general
    /// path's values, bit for bit (NaN cells too).
    #[test]
    fn single_cell_blocks_are_the_cells() {
        let read = Window::new(4, 8, 5, 3);
        let mut data: Vec<f32> = (0..read.len()).map(|i| (i as f32) * 1.5 - 3.0).collect();
        data[2] = f32::NAN;
        data[7] = -0.0;
        let cells = cells_of(read, data.clone());
        // (a band 7 wide with the chunk at columns 1..6)
        let mut fast = vec![7.0f32; 7 * 3];
        chunk(&cells, read, read, 1, (1, 6), 7).reduce_max(&mut fast);
        let mut general = vec![7.0f32; 7 * 3];
        chunk(&cells, read, read, 1, (1, 6), 7).reduce_general(&mut general);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&fast), bits(&general));
        assert!(fast[1 + 2].is_nan());
        assert_eq!(fast[0], 7.0);
        assert_eq!(fast[6], 7.0);
    }

    /// The block maxima are those of the cells, block by block, NaN
    /// skipped, a block of no valid cell NaN, a read window clipped at the
    /// chunk's edges.
    #[test]
    fn block_maxima_are_the_cells_maxima() {
        let read = Window::new(1, 2, 7, 5);
        let full = Window::new(0, 0, 8, 8);
        let k = 4;
        let mut data: Vec<f32> = (0..read.len()).map(|i| ((i * 37) % 11) as f32).collect();
        data[3] = f32::NAN;
        let cells = cells_of(read, data);
        let mut out = vec![0.0f32; 4];
        chunk(&cells, read, full, k, (0, 2), 2).reduce_max(&mut out);
        for (o, (bc, br)) in out.iter().zip([(0, 0), (1, 0), (0, 1), (1, 1)]) {
            let mut m = f32::NAN;
            for y in 0..read.height {
                for x in 0..read.width {
                    let (c, r) = (read.col as usize + x, read.row as usize + y);
                    if c / k == bc && r / k == br {
                        m = m.max(cells.data[y * read.width + x]);
                    }
                }
            }
            assert_eq!(o.to_bits(), m.to_bits(), "block ({bc}, {br})");
        }
    }
}
