//! The footprint of an edit: a window of the DEM grid that holds every cell
//! the edit may read or write, known before the edit runs, from its sketch
//! alone (viewpoints, view distance, influence distance).
//!
//! What an edit reads ([`crate::edit::run`]): around each viewpoint the
//! square window within the view distance ([`crate::render::Scene`], the
//! same computation as here, grown by two cells), the ridges within the
//! union of those windows, and the deformation window. What it writes: the
//! tiles with a changed cell, all inside the deformation window. The
//! deformation window is the curves' bounding box grown by the influence
//! distance plus the constraint reach and a cell
//! ([`crate::deform::locality::affected_window`]); the curves are the
//! strokes placed on the terrain the views show, inside the union `U` of
//! the view windows. So the footprint is `U` grown by the influence
//! distance (the sketch's `influence_m`, else the default, at most half the
//! diagonal of `U` and at least 8 cells), the reach and three cells.
//!
//! The bound on the curves is a property of the placement, not a proof:
//! after an edit the batch checks that its deformation window lies inside
//! its footprint ([`contains`]) and stops its group if not, rather than let
//! two groups touch the same tile.

use crate::deform::locality::{cell_size_m, DEFAULT_INFLUENCE_FRACTION, MIN_INFLUENCE_CELLS};
use crate::deform::CellSize;
use crate::raster::{Dem, Window};
use crate::render::Scene;
use crate::sketch::SketchFile;
use crate::view::Georef;

/// Extra cells around the view windows and the grown window, beyond what
/// the edit's own computation gives.
pub const SLACK_CELLS: i64 = 3;

/// The window around the viewpoint `(lon, lat)` that an edit reads within
/// `max_d` metres (the whole DEM without a limit), [`Scene::window_of`],
/// grown by [`SLACK_CELLS`]. `Err` (one line) when the
/// viewpoint is off the DEM or cannot be converted to its CRS.
pub fn view_window(
    dem: &Dem,
    georef: &Georef,
    lon: f64,
    lat: f64,
    max_d: Option<f64>,
) -> Result<Window, String> {
    let win = Scene::window_of(dem, georef, lon, lat, max_d).map_err(|e| e.to_string())?;
    Ok(grow(win, SLACK_CELLS, SLACK_CELLS))
}

/// The conversions between lon/lat and the DEM's CRS (one per batch: PROJ
/// is set up once).
pub fn dem_georef(dem: &Dem) -> Result<Georef, String> {
    Georef::for_crs(&dem.crs, &dem.path.display().to_string()).map_err(|e| e.to_string())
}

/// `w` grown by `gc` columns and `gr` rows on every side.
fn grow(w: Window, gc: i64, gr: i64) -> Window {
    Window::new(
        w.col - gc,
        w.row - gr,
        (w.width as i64 + 2 * gc).max(0) as usize,
        (w.height as i64 + 2 * gr).max(0) as usize,
    )
}

/// The smallest window holding both.
pub fn union(a: Window, b: Window) -> Window {
    let (c0, r0) = (a.col.min(b.col), a.row.min(b.row));
    let (c1, r1) = (a.col_end().max(b.col_end()), a.row_end().max(b.row_end()));
    Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize)
}

/// True when `inner` lies inside `outer` (an empty `inner` always does).
pub fn contains(outer: &Window, inner: &Window) -> bool {
    inner.is_empty()
        || (inner.col >= outer.col
            && inner.row >= outer.row
            && inner.col_end() <= outer.col_end()
            && inner.row_end() <= outer.row_end())
}

/// The cell sizes in metres over the rows of `w`: the smallest and the
/// largest (they differ with latitude on a geographic CRS).
fn cell_sizes(dem: &Dem, w: &Window) -> (CellSize, CellSize) {
    let gt = &dem.geotransform;
    let rows = [w.row, w.row + w.height as i64 / 2, w.row_end()];
    let sizes: Vec<CellSize> = rows
        .iter()
        .map(|&r| {
            let (_, lat) = gt.pixel_to_crs(w.col as f64, r as f64);
            cell_size_m(gt, dem.crs.geographic, lat.clamp(-89.9, 89.9))
        })
        .collect();
    let min = CellSize {
        hx: sizes.iter().map(|c| c.hx).fold(f64::INFINITY, f64::min),
        hy: sizes.iter().map(|c| c.hy).fold(f64::INFINITY, f64::min),
    };
    let max = CellSize {
        hx: sizes.iter().map(|c| c.hx).fold(0.0, f64::max),
        hy: sizes.iter().map(|c| c.hy).fold(0.0, f64::max),
    };
    (min, max)
}

/// The footprint of the edit of `sketch` on `dem` with view distance
/// `max_d` (see the module documentation), clipped to the DEM. `Err` (one
/// line naming the view) when a viewpoint is unusable. `georef`: the
/// DEM's ([`dem_georef`]).
pub fn footprint(
    dem: &Dem,
    georef: &Georef,
    sketch: &SketchFile,
    max_d: Option<f64>,
) -> Result<Window, String> {
    let mut u: Option<Window> = None;
    for v in &sketch.views {
        let w = view_window(dem, georef, v.viewpoint.lon, v.viewpoint.lat, max_d)
            .map_err(|m| format!("view \"{}\": {m}", v.name))?;
        u = Some(u.map_or(w, |a| union(a, w)));
    }
    let u = u.ok_or("the sketch has no view")?;
    let (small, large) = cell_sizes(dem, &u);
    if !(small.hx > 0.0 && small.hy > 0.0 && large.hx.is_finite() && large.hy.is_finite()) {
        return Err("the DEM's cell size is not usable".into());
    }
    let floor = MIN_INFLUENCE_CELLS * large.hx.max(large.hy);
    let influence = match sketch.options.influence_m {
        Some(d) if d.is_finite() && d > 0.0 => d,
        _ => {
            let diag = (u.width as f64 * large.hx).hypot(u.height as f64 * large.hy);
            (DEFAULT_INFLUENCE_FRACTION * diag).max(floor)
        }
    };
    let reach = large.hx.hypot(large.hy);
    let gc = ((influence + reach) / small.hx + 1.0).ceil() as i64 + SLACK_CELLS;
    let gr = ((influence + reach) / small.hy + 1.0).ceil() as i64 + SLACK_CELLS;
    grow(u, gc, gr)
        .intersect(&dem.full_window())
        .ok_or_else(|| "the edit's footprint misses the DEM".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_and_containment() {
        let a = Window::new(0, 0, 10, 10);
        let b = Window::new(5, -2, 10, 4);
        let u = union(a, b);
        assert_eq!(u, Window::new(0, -2, 15, 12));
        assert!(contains(&u, &a) && contains(&u, &b));
        assert!(!contains(&a, &b));
        assert!(contains(&a, &Window::new(3, 3, 0, 0)));
        assert_eq!(grow(a, 2, 1), Window::new(-2, -1, 14, 12));
    }
}
