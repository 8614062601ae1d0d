//! Pictures of a correction run (`correct --renders DIR`): the corrected
//! window as a map, hillshaded, before and after, with every feature drawn
//! over it (water areas and river centrelines blue, control curves orange
//! and their cross-sections yellow, hard breaklines magenta, soft ones
//! violet), and the height change on the same grid with a diverging colour
//! scale and a labelled colour bar ([`crate::edit::renders::height_change_map`],
//! the picture `edit --renders` makes). Encoded in memory; the run writes
//! them only once the DEM is written.

use crate::edit::renders::{encode_png, height_change_map, Picture};
use crate::raster::Dem;
use crate::render::draw_polyline;

use super::grid::Grid;
use super::{Correction, CorrectionKind};

/// Grey hillshade of `heights` (`nx x ny`, cells of `cell_m` metres; light
/// from the north-west, 45 degrees up), each cell drawn `scale` pixels a
/// side; nodata drawn pale grey.
fn hillshade(heights: &[f64], nx: usize, ny: usize, cell_m: (f64, f64), scale: usize) -> Vec<u8> {
    let (w, h) = (nx * scale, ny * scale);
    let mut rgb = vec![0u8; w * h * 3];
    let at = |i: usize, j: usize| heights[j * nx + i];
    for j in 0..ny {
        for i in 0..nx {
            let c = if at(i, j).is_nan() {
                [200, 200, 200]
            } else {
                let (i0, i1) = (i.saturating_sub(1), (i + 1).min(nx - 1));
                let (j0, j1) = (j.saturating_sub(1), (j + 1).min(ny - 1));
                let gx = (at(i1, j) - at(i0, j)) / (cell_m.0 * (i1 - i0).max(1) as f64);
                // Rows run south: north-up gradient is minus the row one.
                let gy = -(at(i, j1) - at(i, j0)) / (cell_m.1 * (j1 - j0).max(1) as f64);
                let g = if gx.is_finite() && gy.is_finite() {
                    // Normal (-gx, -gy, 1); light from the NW at 45 degrees.
                    let n = (gx * gx + gy * gy + 1.0).sqrt();
                    let l = [-0.5, 0.5, std::f64::consts::FRAC_1_SQRT_2];
                    ((-gx * l[0] - gy * l[1] + l[2]) / n).clamp(0.0, 1.0)
                } else {
                    0.7
                };
                let v = (40.0 + 215.0 * g) as u8;
                [v, v, v]
            };
            for dj in 0..scale {
                for di in 0..scale {
                    let p = ((j * scale + dj) * w + i * scale + di) * 3;
                    rgb[p..p + 3].copy_from_slice(&c);
                }
            }
        }
    }
    rgb
}

/// Every feature's lines in window pixel space, with its colour.
fn feature_lines(dem: &Dem, grid: &Grid, c: &Correction) -> Vec<(Vec<[f64; 2]>, [u8; 3])> {
    let local = |p: [f64; 2]| grid.local(p);
    let from_crs = |pts: &[[f64; 3]]| -> Vec<[f64; 2]> {
        pts.iter()
            .filter_map(|p| dem.geotransform.crs_to_pixel(p[0], p[1]))
            .map(|(x, y)| local([x, y]))
            .collect()
    };
    const WATER: [u8; 3] = [30, 110, 230];
    match &c.kind {
        CorrectionKind::Lake { area, .. } | CorrectionKind::RiverArea { area, .. } => area
            .0
            .iter()
            .flat_map(|p| std::iter::once(p.exterior()).chain(p.interiors()))
            .map(|r| (r.coords().map(|q| local([q.x, q.y])).collect(), WATER))
            .collect(),
        CorrectionKind::River { centreline, .. } => {
            vec![(centreline.iter().map(|&p| local(p)).collect(), WATER)]
        }
        CorrectionKind::ControlCurve {
            points, sections, ..
        } => std::iter::once((from_crs(points), [240, 130, 20]))
            .chain(sections.iter().map(|s| (from_crs(s), [250, 215, 40])))
            .collect(),
        CorrectionKind::Landform { placed, .. } | CorrectionKind::NoiseRegion { placed, .. } => {
            let Some(p) = placed else { return Vec::new() };
            let mut out: Vec<(Vec<[f64; 2]>, [u8; 3])> = p
                .boundary
                .0
                .iter()
                .map(|poly| {
                    (
                        poly.exterior()
                            .coords()
                            .map(|q| local([q.x, q.y]))
                            .collect(),
                        [40, 170, 60],
                    )
                })
                .collect();
            if matches!(c.kind, CorrectionKind::Landform { .. }) {
                out.push((
                    p.shadow_px.iter().map(|&q| local(q)).collect(),
                    [200, 30, 30],
                ));
            }
            out
        }
        CorrectionKind::Breakline { points, hard, .. } => {
            let colour = if *hard {
                [220, 30, 190]
            } else {
                [140, 80, 220]
            };
            vec![(from_crs(points), colour)]
        }
    }
}

/// The pictures of a run: `map_before.png`, `map_after.png` and
/// `height_change.png`.
pub fn pictures(
    dem: &Dem,
    grid: &Grid,
    corrections: &[Correction],
) -> Result<Vec<Picture>, String> {
    let (nx, ny) = (grid.width(), grid.height());
    let cell = (grid.cell.hx, grid.cell.hy);
    let scale = (800 / nx.max(ny).max(1)).clamp(1, 8);
    let (w, h) = (nx * scale, ny * scale);
    let before: Vec<f64> = grid.base.data.iter().map(|&v| v as f64).collect();
    let lines: Vec<_> = corrections
        .iter()
        .flat_map(|c| feature_lines(dem, grid, c))
        .collect();
    let thick = (w.max(h) as f64 / 400.0).clamp(2.0, 4.0);
    let mut out = Vec::new();
    for (name, heights) in [("map_before.png", &before), ("map_after.png", &grid.values)] {
        let mut rgb = hillshade(heights, nx, ny, cell, scale);
        for (l, colour) in &lines {
            let px: Vec<[f64; 2]> = l
                .iter()
                .map(|p| [p[0] * scale as f64, p[1] * scale as f64])
                .collect();
            draw_polyline(&mut rgb, w, h, &px, *colour, thick);
        }
        out.push(Picture {
            name: name.into(),
            png: encode_png(w, h, &rgb)?,
        });
    }
    let change: Vec<f32> = grid
        .values
        .iter()
        .zip(&grid.base.data)
        .map(|(&v, &b)| {
            if b.is_nan() {
                0.0
            } else {
                (v - b as f64) as f32
            }
        })
        .collect();
    let (cw, ch, rgb) = height_change_map(nx, ny, cell, &grid.base.data, &change);
    out.push(Picture {
        name: "height_change.png".into(),
        png: encode_png(cw, ch, &rgb)?,
    });
    Ok(out)
}
