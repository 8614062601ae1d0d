//! Lakes (hydro-flattening, Maquettier section IV): every cell whose centre
//! lies inside the lake polygon (and not in an island hole) is set to one
//! level, the given `level_m` or, as the USGS lidar base specification asks,
//! the lowest height on the shoreline (the DEM sampled bilinearly along the
//! outer rings every half cell); the shores are blended into the banks
//! within the blend width by [`super::water::flatten_and_blend`].

use geo::{BoundingRect, Contains, LineString, MultiPolygon, Point};

use super::grid::Grid;
use super::water::{self, Change};

/// What a lake did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LakeResult {
    /// The level used, metres.
    pub level_m: f64,
    /// True when the level is the lowest shoreline height.
    pub level_from_shore: bool,
    pub change: Change,
}

/// Why a lake could not be applied (a user error).
#[derive(Debug, thiserror::Error)]
pub enum LakeError {
    #[error("no valid DEM height on the shoreline to take the level from; give level_m")]
    NoShoreHeight,
    #[error("no cell centre lies inside the lake over valid DEM cells")]
    NoCells,
    #[error("blend solver: {0}")]
    Solver(#[from] crate::deform::multigrid::MultigridError),
}

/// Window indices of the valid cells whose centre lies inside `area` (DEM
/// pixel space).
pub fn cells_inside(grid: &Grid, area: &MultiPolygon<f64>) -> Vec<usize> {
    let Some(b) = area.bounding_rect() else {
        return Vec::new();
    };
    let (w, h) = (grid.width() as i64, grid.height() as i64);
    let (col0, row0) = (grid.window.col, grid.window.row);
    let c0 = ((b.min().x - 0.5).floor() as i64 - col0).clamp(0, w);
    let c1 = ((b.max().x + 0.5).ceil() as i64 - col0).clamp(0, w);
    let r0 = ((b.min().y - 0.5).floor() as i64 - row0).clamp(0, h);
    let r1 = ((b.max().y + 0.5).ceil() as i64 - row0).clamp(0, h);
    let mut out = Vec::new();
    for r in r0..r1 {
        for c in c0..c1 {
            let centre = Point::new((c + col0) as f64 + 0.5, (r + row0) as f64 + 0.5);
            let i = (r * w + c) as usize;
            if !grid.values[i].is_nan() && area.contains(&centre) {
                out.push(i);
            }
        }
    }
    out
}

/// Points every half cell along a ring (DEM pixel space).
fn densify(ring: &LineString<f64>) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    for seg in ring.lines() {
        let (a, b) = (seg.start, seg.end);
        let n = ((b.x - a.x).hypot(b.y - a.y) / 0.5).ceil().max(1.0) as usize;
        for k in 0..n {
            let t = k as f64 / n as f64;
            out.push([a.x + t * (b.x - a.x), a.y + t * (b.y - a.y)]);
        }
    }
    out
}

/// The lowest current height along the outer rings, sampled bilinearly.
pub fn lowest_shore(grid: &Grid, area: &MultiPolygon<f64>) -> Option<f64> {
    area.0
        .iter()
        .flat_map(|p| densify(p.exterior()))
        .filter_map(|p| grid.bilinear(grid.local(p)))
        .reduce(f64::min)
}

/// Flattens the lake and blends its shores.
pub fn apply(
    grid: &mut Grid,
    area: &MultiPolygon<f64>,
    level_m: Option<f64>,
    blend_m: f64,
) -> Result<LakeResult, LakeError> {
    let (level, from_shore) = match level_m {
        Some(l) => (l, false),
        None => (
            lowest_shore(grid, area).ok_or(LakeError::NoShoreHeight)?,
            true,
        ),
    };
    let cells = cells_inside(grid, area);
    if cells.is_empty() {
        return Err(LakeError::NoCells);
    }
    let water: Vec<(usize, f64)> = cells.into_iter().map(|i| (i, level)).collect();
    let change = water::flatten_and_blend(grid, &water, blend_m)?;
    Ok(LakeResult {
        level_m: level,
        level_from_shore: from_shore,
        change,
    })
}
