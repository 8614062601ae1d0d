//! Setting water cells to their surface and blending the shores into the
//! banks, shared by lakes and rivers. The blend is solved with the
//! project's multigrid ([`crate::deform::multigrid`]) on the displacement
//! `M = new - current`: water cells are held at `surface - current`, cells
//! farther than the blend width from every water cell (and nodata cells)
//! at 0, and `M` is harmonic on the band between them, so the shore has no
//! step and cells beyond the blend width keep their heights exactly. The
//! band is found with the deformation's exact Euclidean distance transform
//! ([`crate::deform::locality::squared_distance_to_constraints`]).

use crate::deform::locality::squared_distance_to_constraints;
use crate::deform::multigrid::{self, MultigridError, MultigridOptions};
use crate::deform::ConstraintRaster;

use super::grid::Grid;

/// What one water feature changed.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Change {
    /// Water cells set to their surface.
    pub water_cells: usize,
    /// Cells whose height changed (water and blend band).
    pub cells_changed: usize,
    /// Largest `|new - old|`, metres.
    pub max_abs_dz_m: f64,
}

/// Sets the cells `water` (window indices, surface heights) and blends the
/// band within `blend_m` metres of them (see the module documentation).
pub fn flatten_and_blend(
    grid: &mut Grid,
    water: &[(usize, f64)],
    blend_m: f64,
) -> Result<Change, MultigridError> {
    if water.is_empty() {
        return Ok(Change::default());
    }
    let (w, h) = (grid.width(), grid.height());
    let reach = (blend_m / grid.cell.hx.min(grid.cell.hy)).ceil() as usize + 1;
    let (mut c0, mut r0, mut c1, mut r1) = (usize::MAX, usize::MAX, 0, 0);
    for &(i, _) in water {
        let (c, r) = (i % w, i / w);
        c0 = c0.min(c);
        r0 = r0.min(r);
        c1 = c1.max(c);
        r1 = r1.max(r);
    }
    let (c0, r0) = (c0.saturating_sub(reach), r0.saturating_sub(reach));
    let (c1, r1) = ((c1 + reach).min(w - 1), (r1 + reach).min(h - 1));
    let (nx, ny) = (c1 - c0 + 1, r1 - r0 + 1);
    let sub = |i: usize| (i / w - r0) * nx + (i % w - c0);
    let full = |k: usize| (k / nx + r0) * w + (k % nx + c0);

    let mut is_water = vec![false; nx * ny];
    let mut values = vec![0f32; nx * ny];
    let mut target = vec![f64::NAN; nx * ny];
    for &(i, z) in water {
        let k = sub(i);
        is_water[k] = true;
        target[k] = z;
        values[k] = (z - grid.values[i]) as f32;
    }
    let cons = ConstraintRaster {
        width: nx,
        height: ny,
        constrained: is_water.clone(),
        delta: values.clone(),
        count: water.len(),
        max_abs_delta: 0.0,
    };
    let d2 = squared_distance_to_constraints(&cons, grid.cell);
    let mut fixed = vec![true; nx * ny];
    let mut any_free = false;
    for k in 0..nx * ny {
        let free = !is_water[k]
            && !grid.values[full(k)].is_nan()
            && (d2[k] as f64).sqrt() <= blend_m * (1.0 + 1e-9);
        fixed[k] = !free;
        any_free |= free;
    }
    if any_free {
        let opts = MultigridOptions {
            tolerance: 1e-6,
            max_cycles: 300,
            ..MultigridOptions::default()
        };
        multigrid::solve(
            nx,
            ny,
            grid.cell.hx,
            grid.cell.hy,
            &fixed,
            &mut values,
            &opts,
        )?;
    }
    let mut change = Change {
        water_cells: water.len(),
        ..Change::default()
    };
    for k in 0..nx * ny {
        let i = full(k);
        let old = grid.values[i];
        if old.is_nan() {
            continue;
        }
        let new = if is_water[k] {
            grid.water[i] = true;
            target[k]
        } else if !fixed[k] && values[k] != 0.0 {
            old + values[k] as f64
        } else {
            continue;
        };
        if new != old {
            change.cells_changed += 1;
            change.max_abs_dz_m = change.max_abs_dz_m.max((new - old).abs());
            grid.values[i] = new;
        }
    }
    Ok(change)
}

/// Default blend width: two cells of the larger cell side.
pub fn default_blend_m(grid: &Grid) -> f64 {
    2.0 * grid.cell.hx.max(grid.cell.hy)
}
