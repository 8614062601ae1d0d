//! Map-view corrections inside a sketch file (its `corrections` member, a
//! GeoJSON FeatureCollection exactly as `correct --features` reads it),
//! applied in the same edit as the first-person strokes and written in the
//! same write-back.
//!
//! The two are solved in turn, not in one system: the strokes' deformation
//! first (with its refinement rounds, which re-render the views), then the
//! corrections on the terrain it gave, in file order, on the union of the
//! two windows. One joint solve is not feasible because most corrections
//! are not displacement constraints of the edit's harmonic solve: a lake
//! or a river sets cells to a level and must stay exactly flat (and
//! monotonic downstream), a hard breakline re-interpolates its band from a
//! triangulation; rounds that moved those cells again (the lowering of
//! protruding silhouettes) would undo them. Applying the corrections last
//! makes each of them hold on the written DEM exactly as `correct` alone
//! would make it hold (landforms too: their silhouette strokes, drawn in
//! the sketch's views and taken out of the first-person strokes, are placed
//! on the unedited DEM's views as `correct --features F --sketch S` places
//! them, and the landform is built on the edited terrain); the strokes' fit is then measured on the final
//! terrain (the edit re-renders its views after the corrections), so a
//! correction that changes what a view shows is seen in the report.

use crate::deform::Deformation;
use crate::raster::Dem;
use crate::sketch::SketchFile;

use super::grid::Grid;
use super::{geojson_input, plan, union, CorrectError, FeatureReport};

/// Applies the corrections of `collection` (named `name` in messages) on
/// top of the edit's deformation `d`; its landforms and noise regions
/// place their strokes on the views of `sketch` (the file as given, and its
/// name), on the unedited DEM as `correct --sketch` does: returns the deformation of both
/// together (over the union of the windows) and what each feature did.
/// Cells the edit moved and no correction reached keep exactly the edit's
/// displacement.
pub fn apply_after_edit(
    dem: &Dem,
    collection: &serde_json::Value,
    name: &str,
    sketch: (&SketchFile, &str),
    d: &Deformation,
    max_window_cells: usize,
) -> Result<(Deformation, Vec<FeatureReport>), CorrectError> {
    let mut corrections =
        geojson_input::from_value(collection, name, dem).map_err(CorrectError::Input)?;
    super::landform::resolve(
        dem,
        Some(sketch),
        &mut corrections,
        name,
        super::LANDFORM_HINT_CORRECT,
    )
    .map_err(CorrectError::Input)?;
    let plan = plan(dem, corrections, name, max_window_cells)?;
    let window = union(plan.window, d.window);
    let mut grid = Grid::new(window, plan.cell, dem.read_height_map(window)?);
    // The edited heights where the edit moved a cell.
    let (oc, or) = (
        (d.window.col - window.col) as usize,
        (d.window.row - window.row) as usize,
    );
    for r in 0..d.window.height {
        for c in 0..d.window.width {
            let k = r * d.window.width + c;
            let (h, m) = (d.base.data[k], d.displacement[k]);
            if !h.is_nan() && !m.is_nan() && m != 0.0 {
                grid.values[(r + or) * window.width + c + oc] = h as f64 + m as f64;
            }
        }
    }
    let reports = plan.apply(dem, &mut grid, name)?;
    Ok((to_deformation(dem, grid, d), reports))
}

/// The grid's heights as a deformation over its window: `M = current -
/// input` (exactly the edit's `M` where no correction changed the cell),
/// the edit's constrained cells carried over.
fn to_deformation(dem: &Dem, grid: Grid, d: &Deformation) -> Deformation {
    let window = grid.window;
    let displacement: Vec<f32> = grid
        .values
        .iter()
        .zip(&grid.base.data)
        .map(|(&v, &h)| {
            if h.is_nan() || v.is_nan() {
                f32::NAN
            } else if v == h as f64 {
                0.0
            } else {
                (v - h as f64) as f32
            }
        })
        .collect();
    let mut constrained = vec![false; window.len()];
    let (oc, or) = (
        (d.window.col - window.col) as usize,
        (d.window.row - window.row) as usize,
    );
    for r in 0..d.window.height {
        for c in 0..d.window.width {
            constrained[(r + or) * window.width + c + oc] = d.constrained[r * d.window.width + c];
        }
    }
    let mut stats = d.stats.clone();
    stats.recount(&displacement);
    Deformation {
        window,
        displacement,
        affected_tiles: dem.tiles_touching(&window),
        constrained,
        stats,
        base: grid.base,
    }
}
