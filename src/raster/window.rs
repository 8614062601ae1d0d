//! Pixel windows of a DEM and the arrays read from them.

use serde::Serialize;

/// A rectangle of pixels: columns `col .. col + width`, rows `row .. row + height`
/// of the whole DEM (tile mosaic) grid. May extend past the DEM's edges; the
/// outside reads as nodata.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Window {
    pub col: i64,
    pub row: i64,
    pub width: usize,
    pub height: usize,
}

impl Window {
    pub fn new(col: i64, row: i64, width: usize, height: usize) -> Self {
        Window {
            col,
            row,
            width,
            height,
        }
    }

    pub fn len(&self) -> usize {
        self.width * self.height
    }

    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }

    pub fn col_end(&self) -> i64 {
        self.col + self.width as i64
    }

    pub fn row_end(&self) -> i64 {
        self.row + self.height as i64
    }

    /// The overlap of two windows, if any.
    pub fn intersect(&self, o: &Window) -> Option<Window> {
        let c0 = self.col.max(o.col);
        let r0 = self.row.max(o.row);
        let c1 = self.col_end().min(o.col_end());
        let r1 = self.row_end().min(o.row_end());
        (c1 > c0 && r1 > r0).then(|| Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize))
    }
}

/// Values read from a window, row-major, with a validity mask (false =
/// nodata, or outside every tile).
#[derive(Debug, Clone)]
pub struct WindowData<T> {
    pub window: Window,
    pub data: Vec<T>,
    pub valid: Vec<bool>,
}
