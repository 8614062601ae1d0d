//! Vertical strips of a row-major image pair, each owned by one task: the
//! z-buffer rasteriser ([`super::triangle_raster`]) renders every strip of
//! columns in place, in parallel, instead of into per-strip buffers that are
//! copied into the image afterwards.

use std::marker::PhantomData;

/// Columns `x0..x0 + width` of two row-major images of the same shape (ray
/// parameters and triangle ids): the only access to them while it lives.
pub(super) struct StripColumns<'a> {
    t: *mut f32,
    id: *mut u32,
    stride: usize,
    rows: usize,
    x0: usize,
    width: usize,
    _owns: PhantomData<(&'a mut [f32], &'a mut [u32])>,
}

// SAFETY: a strip is the only access to its columns of the two images while
// it lives (see `split`), so it may move to another thread with them.
unsafe impl Send for StripColumns<'_> {}

impl<'a> StripColumns<'a> {
    /// Cut two images `stride` pixels wide into strips of `strip` columns
    /// (the last one narrower when `strip` does not divide `stride`).
    ///
    /// # Panics
    /// When the images differ in length, or their length is not a multiple
    /// of `stride`, or `stride` or `strip` is 0.
    pub(super) fn split(
        t: &'a mut [f32],
        id: &'a mut [u32],
        stride: usize,
        strip: usize,
    ) -> Vec<Self> {
        assert!(stride > 0 && strip > 0, "empty strips");
        assert!(
            t.len() == id.len() && t.len() % stride == 0,
            "two images of whole rows"
        );
        let rows = t.len() / stride;
        let (tp, ip) = (t.as_mut_ptr(), id.as_mut_ptr());
        (0..stride.div_ceil(strip))
            .map(|s| StripColumns {
                t: tp,
                id: ip,
                stride,
                rows,
                x0: s * strip,
                width: strip.min(stride - s * strip),
                _owns: PhantomData,
            })
            .collect()
    }

    /// First image column of the strip.
    pub(super) fn x0(&self) -> usize {
        self.x0
    }

    /// Number of columns.
    pub(super) fn width(&self) -> usize {
        self.width
    }

    /// Number of rows.
    pub(super) fn rows(&self) -> usize {
        self.rows
    }

    /// The strip's part of row `j` of both images.
    ///
    /// # Panics
    /// When `j` is not a row.
    #[inline]
    pub(super) fn row_mut(&mut self, j: usize) -> (&mut [f32], &mut [u32]) {
        assert!(j < self.rows, "row out of range");
        let at = j * self.stride + self.x0;
        // SAFETY: `at + width <= rows * stride`, the images' length; the
        // columns are this strip's alone (`split` hands out disjoint column
        // ranges of images borrowed mutably for 'a), and `&mut self` lets
        // one row borrow live at a time.
        unsafe {
            (
                std::slice::from_raw_parts_mut(self.t.add(at), self.width),
                std::slice::from_raw_parts_mut(self.id.add(at), self.width),
            )
        }
    }

    /// Triangle id at strip column `k` of row `j`.
    ///
    /// # Panics
    /// When `(k, j)` is outside the strip.
    #[inline]
    pub(super) fn id(&self, k: usize, j: usize) -> u32 {
        assert!(j < self.rows && k < self.width, "pixel out of range");
        // SAFETY: in bounds as above; no row borrow is live while `&self` is.
        unsafe { *self.id.add(j * self.stride + self.x0 + k) }
    }
}

#[cfg(test)]
mod tests {
    use super::StripColumns;

    #[test]
    fn strips_cover_every_pixel_once() {
        let (w, h) = (10, 3);
        let mut t = vec![0f32; w * h];
        let mut id = vec![0u32; w * h];
        let strips = StripColumns::split(&mut t, &mut id, w, 4);
        assert_eq!(
            strips
                .iter()
                .map(|s| (s.x0(), s.width()))
                .collect::<Vec<_>>(),
            [(0, 4), (4, 4), (8, 2)]
        );
        std::thread::scope(|scope| {
            for mut s in strips {
                scope.spawn(move || {
                    for j in 0..s.rows() {
                        let x0 = s.x0();
                        let (tr, ir) = s.row_mut(j);
                        for (k, (tv, iv)) in tr.iter_mut().zip(ir.iter_mut()).enumerate() {
                            *tv += 1.0;
                            *iv = (j * w + x0 + k) as u32;
                        }
                    }
                });
            }
        });
        assert!(t.iter().all(|&v| v == 1.0));
        assert!(id.iter().enumerate().all(|(k, &v)| v as usize == k));
    }
}
