//! The vertex heights of a [`super::LocalTerrain`], shared between a terrain
//! and the terrains patched from it: a base grid (reference counted) and at
//! most one patched rectangle over it. An edit's rounds re-render the same
//! view with a few thousand cells changed out of tens of millions; with
//! the base shared, each round's terrain costs its changed rectangle, not a
//! copy of the whole grid (time, and the fresh pages the kernel must zero).

use std::borrow::Cow;
use std::sync::Arc;

/// Row-major vertex heights, `nx` across: `base` with `patch` over it.
#[derive(Debug, Clone)]
pub struct VertexHeights {
    base: Arc<Vec<f32>>,
    patch: Option<Patch>,
    nx: usize,
}

/// A rectangle of vertices `(c0, r0)` of `w` x `h` whose heights replace
/// the base's; `k_lo..k_hi` the linear indices it spans (a quick test).
#[derive(Debug, Clone)]
struct Patch {
    c0: usize,
    r0: usize,
    w: usize,
    h: usize,
    k_lo: usize,
    k_hi: usize,
    data: Vec<f32>,
}

impl Patch {
    /// Whether vertex `(c, r)` lies in the patch.
    #[inline]
    fn holds(&self, c: usize, r: usize) -> bool {
        c >= self.c0 && c < self.c0 + self.w && r >= self.r0 && r < self.r0 + self.h
    }

    /// Whether any corner of cell `(c, r)` lies in the patch (`c + 1 -
    /// c0` within `0..=w`, wrapping below `c0`; rows alike).
    #[inline]
    fn touches_quad(&self, c: usize, r: usize) -> bool {
        (c + 1).wrapping_sub(self.c0) <= self.w && (r + 1).wrapping_sub(self.r0) <= self.h
    }

    /// Whether all four corners of cell `(c, r)` lie in the patch (`c -
    /// c0` within `0..w - 1`, wrapping below `c0`; rows alike).
    #[inline]
    fn holds_quad(&self, c: usize, r: usize) -> bool {
        c.wrapping_sub(self.c0) < self.w.wrapping_sub(1)
            && r.wrapping_sub(self.r0) < self.h.wrapping_sub(1)
    }
}

/// The heights at `k`, `k + 1`, `k + stride` and `k + stride + 1` of
/// `data`: a cell's four corners in a row-major grid `stride` across.
#[inline]
fn quad_from(data: &[f32], k: usize, stride: usize) -> [f32; 4] {
    [data[k], data[k + 1], data[k + stride], data[k + stride + 1]]
}

impl VertexHeights {
    /// Heights `z` of a grid `nx` across, with no patch.
    pub(crate) fn new(z: Vec<f32>, nx: usize) -> Self {
        VertexHeights {
            base: Arc::new(z),
            patch: None,
            nx: nx.max(1),
        }
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.base.len()
    }

    /// Whether there is no vertex.
    pub fn is_empty(&self) -> bool {
        self.base.is_empty()
    }

    /// The height of vertex `k` (row-major index).
    #[inline]
    pub fn at(&self, k: usize) -> f32 {
        *self.at_ref(k)
    }

    /// The height of vertex `(c, r)` (`c < nx`): [`VertexHeights::at`]
    /// without the division that turns a linear index back into a column
    /// and a row, for callers that hold them (the renderer, the casts).
    #[inline]
    pub fn at_cr(&self, c: usize, r: usize) -> f32 {
        if let Some(p) = &self.patch {
            if p.holds(c, r) {
                return p.data[(r - p.r0) * p.w + (c - p.c0)];
            }
        }
        self.base[r * self.nx + c]
    }

    /// The heights `[z(c, r), z(c + 1, r), z(c, r + 1), z(c + 1, r + 1)]`
    /// of the corners of cell `(c, r)` (`c + 1 < nx`): one test of the
    /// patch for the four where they all lie on one side of its border.
    #[inline]
    pub fn quad(&self, c: usize, r: usize) -> [f32; 4] {
        match &self.patch {
            Some(p) if p.touches_quad(c, r) => {
                if p.holds_quad(c, r) {
                    quad_from(&p.data, (r - p.r0) * p.w + (c - p.c0), p.w)
                } else {
                    self.quad_straddling(c, r)
                }
            }
            _ => quad_from(&self.base, r * self.nx + c, self.nx),
        }
    }

    /// [`VertexHeights::quad`] of a cell across the patch's border: out of
    /// line, so that the common cases (all four corners in the base, or
    /// all in the patch) are a few instructions wherever they are inlined.
    #[inline(never)]
    fn quad_straddling(&self, c: usize, r: usize) -> [f32; 4] {
        [
            self.at_cr(c, r),
            self.at_cr(c + 1, r),
            self.at_cr(c, r + 1),
            self.at_cr(c + 1, r + 1),
        ]
    }

    /// The heights of the vertices `c0..c0 + w` x `r0..r0 + h` (within
    /// the grid, `w` and `h` at most 4), as [`VertexHeights::at_cr`] gives
    /// them, at `[row - r0][column - c0]` (the rest zero): rows read as
    /// slices where the rectangle lies wholly outside or inside the patch.
    #[inline]
    pub fn rect4(&self, c0: usize, r0: usize, w: usize, h: usize) -> [[f32; 4]; 4] {
        let (w, h) = (w.min(4), h.min(4));
        let mut v = [[0f32; 4]; 4];
        let (data, k, stride) = match &self.patch {
            Some(p) if c0 < p.c0 + p.w && p.c0 < c0 + w && r0 < p.r0 + p.h && p.r0 < r0 + h => {
                let inside =
                    c0 >= p.c0 && c0 + w <= p.c0 + p.w && r0 >= p.r0 && r0 + h <= p.r0 + p.h;
                if !inside {
                    for (j, row) in v.iter_mut().enumerate().take(h) {
                        for (i, z) in row.iter_mut().enumerate().take(w) {
                            *z = self.at_cr(c0 + i, r0 + j);
                        }
                    }
                    return v;
                }
                (&p.data[..], (r0 - p.r0) * p.w + (c0 - p.c0), p.w)
            }
            _ => (&self.base[..], r0 * self.nx + c0, self.nx),
        };
        for (j, row) in v.iter_mut().enumerate().take(h) {
            let k = k + j * stride;
            row[..w].copy_from_slice(&data[k..k + w]);
        }
        v
    }

    #[inline]
    fn at_ref(&self, k: usize) -> &f32 {
        if let Some(p) = &self.patch {
            if k >= p.k_lo && k < p.k_hi {
                let r = k / self.nx;
                let c = k - r * self.nx;
                if c >= p.c0 && c < p.c0 + p.w {
                    return &p.data[(r - p.r0) * p.w + (c - p.c0)];
                }
            }
        }
        &self.base[k]
    }

    /// Vertex row `r`: borrowed where no patch crosses it.
    pub fn row(&self, r: usize) -> Cow<'_, [f32]> {
        let nx = self.nx;
        let base = &self.base[r * nx..(r + 1) * nx];
        match &self.patch {
            Some(p) if r >= p.r0 && r < p.r0 + p.h => {
                let mut row = base.to_vec();
                let src = &p.data[(r - p.r0) * p.w..(r - p.r0 + 1) * p.w];
                row[p.c0..p.c0 + p.w].copy_from_slice(src);
                Cow::Owned(row)
            }
            _ => Cow::Borrowed(base),
        }
    }

    /// All heights as one slice: borrowed without a patch (a terrain built
    /// from a grid), else a copy.
    pub fn slice(&self) -> Cow<'_, [f32]> {
        match &self.patch {
            None => Cow::Borrowed(&self.base[..]),
            Some(_) => Cow::Owned(self.iter().copied().collect()),
        }
    }

    /// Every height, row-major.
    pub fn iter(&self) -> impl Iterator<Item = &f32> + '_ {
        (0..self.len()).map(move |k| self.at_ref(k))
    }

    /// These heights with the vertices of `(c0, r0, c1, r1)` (end
    /// exclusive, within the grid) set by `set(c, r, old)` (their new
    /// height, or `old` to keep it): the base is shared, the patch covers
    /// the rectangle (and any earlier patch).
    pub(crate) fn patched(
        &self,
        (c0, r0, c1, r1): (usize, usize, usize, usize),
        set: &(dyn Fn(usize, usize, f32) -> f32 + Sync),
    ) -> VertexHeights {
        let (mut a0, mut b0, mut a1, mut b1) = (c0, r0, c1, r1);
        if let Some(p) = &self.patch {
            a0 = a0.min(p.c0);
            b0 = b0.min(p.r0);
            a1 = a1.max(p.c0 + p.w);
            b1 = b1.max(p.r0 + p.h);
        }
        let (w, h) = (a1 - a0, b1 - b0);
        let nx = self.nx;
        let mut data = Vec::with_capacity(w * h);
        for r in b0..b1 {
            for c in a0..a1 {
                let old = self.at(r * nx + c);
                let inside = c >= c0 && c < c1 && r >= r0 && r < r1;
                data.push(if inside { set(c, r, old) } else { old });
            }
        }
        VertexHeights {
            base: Arc::clone(&self.base),
            patch: Some(Patch {
                c0: a0,
                r0: b0,
                w,
                h,
                k_lo: b0 * nx + a0,
                k_hi: (b1 - 1) * nx + a1,
                data,
            }),
            nx,
        }
    }

    /// Where these heights and `other` differ, when both are patched from
    /// one base grid (the same shared grid, not merely equal heights):
    /// `Some(None)` where they are the same to the bit, `Some(Some((c0,
    /// r0, c1, r1)))` the box of the vertices that differ (end exclusive);
    /// `None` for heights of different grids.
    pub(crate) fn changed_box(
        &self,
        other: &VertexHeights,
    ) -> Option<Option<(usize, usize, usize, usize)>> {
        if !Arc::ptr_eq(&self.base, &other.base) || self.nx != other.nx {
            return None;
        }
        // Only the patches' rectangles can differ.
        let rects = [&self.patch, &other.patch]
            .map(|p| p.as_ref().map(|p| (p.c0, p.r0, p.c0 + p.w, p.r0 + p.h)));
        let (c0, r0, c1, r1) = match rects {
            [None, None] => return Some(None),
            [Some(a), None] | [None, Some(a)] => a,
            [Some(a), Some(b)] => (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3)),
        };
        let mut changed: Option<(usize, usize, usize, usize)> = None;
        for r in r0..r1 {
            for c in c0..c1 {
                if self.at_cr(c, r).to_bits() != other.at_cr(c, r).to_bits() {
                    changed = Some(match changed {
                        None => (c, r, c + 1, r + 1),
                        Some((a0, b0, a1, b1)) => {
                            (a0.min(c), b0.min(r), a1.max(c + 1), b1.max(r + 1))
                        }
                    });
                }
            }
        }
        Some(changed)
    }

    /// The base grid when no other terrain shares it (for recycling).
    pub(crate) fn take_unshared(&mut self) -> Option<Vec<f32>> {
        let base = std::mem::take(&mut self.base);
        Arc::try_unwrap(base).ok()
    }
}

impl<'a> IntoIterator for &'a VertexHeights {
    type Item = &'a f32;
    type IntoIter = Box<dyn Iterator<Item = &'a f32> + 'a>;
    fn into_iter(self) -> Self::IntoIter {
        Box::new(self.iter())
    }
}
