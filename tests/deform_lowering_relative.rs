//! A lowering curve only lowers (section 6.2 of Tassé et al. 2014: the
//! protruding silhouette `s` is lowered by `h`), cell by cell: a curve found
//! on the terrain `H + M_ref` at `z = H'(q) - h` decides the cells within a
//! cell of it at `M_ref(c) - h`, never above `M_ref(c)`
//! (`demsketch::deform::constraints::Reference`). Without the reference the
//! band rule copies `delta(q*)` to every cell centre near the curve, and on
//! a coarse grid where `M_ref` falls steeply across the band (a lowered
//! line on the front of a raised landform, 250 m cells) that raises the
//! centres in front of the curve, and the solve carries the rise to the
//! landform's front.

mod deform_support;

use deform_support::write_f32_geotiff;
use demsketch::deform::constraints::{bilinear_valid, rasterise, rasterise_relative};
use demsketch::deform::{
    deform, deform_bounded, deform_relative, CellSize, CurveConstraint, DeformOptions, Deformation,
    Displacement,
};
use demsketch::raster::{Dem, HeightMap};

const N: usize = 40;
const CELL: f64 = 250.0;
/// The lowering `h`, metres.
const H_LOWER: f64 = 5.0;

fn plane_dem(dir: &std::path::Path) -> Dem {
    let mut data = vec![0f32; N * N];
    for r in 0..N {
        for c in 0..N {
            data[r * N + c] = (1500.0 + 2.0 * c as f64 - 1.5 * r as f64) as f32;
        }
    }
    let path = dir.join("plane.tif");
    let gt = [600_000.0, CELL, 0.0, 5_200_000.0, 0.0, -CELL];
    write_f32_geotiff(&path, N, N, gt, 32632, &data, Some(-9999.0));
    Dem::open(&path).expect("open the plane DEM")
}

fn opts() -> DeformOptions {
    DeformOptions {
        // The whole DEM within the influence in every solve: the window
        // and the free cells are the same for both solves.
        influence_m: Some(100.0 * CELL),
        ..DeformOptions::default()
    }
}

/// CRS point of window pixel `(px, py)` on `m`'s grid.
fn crs(m: &HeightMap, px: f64, py: f64) -> (f64, f64) {
    m.geotransform.pixel_to_crs(px, py)
}

/// A short raised ridge along row 20 (through the cell centres): its `M`
/// falls off steeply across the rows in front of it.
fn ridge(m: &HeightMap) -> CurveConstraint {
    let points = (16..=24)
        .map(|c| {
            let (px, py) = (c as f64 + 0.5, 20.5);
            let (x, y) = crs(m, px, py);
            [x, y, bilinear_valid(m, px, py).unwrap() + 300.0]
        })
        .collect();
    CurveConstraint { points }
}

/// A lowering curve half a row in front of the ridge (pixel row 21.0),
/// found on the terrain `H + M0`: its points at `H'(q) - h`.
fn lowering(m: &HeightMap, d0: &Deformation) -> CurveConstraint {
    let m0 = HeightMap {
        data: d0.displacement.clone(),
        ..m.clone()
    };
    let points = (0..=16)
        .map(|k| {
            let (px, py) = (16.5 + 0.5 * k as f64, 21.0);
            let (x, y) = crs(m, px, py);
            let z = bilinear_valid(m, px, py).unwrap() + bilinear_valid(&m0, px, py).unwrap();
            [x, y, z - H_LOWER]
        })
        .collect();
    CurveConstraint { points }
}

#[test]
fn a_lowering_curve_never_raises_a_cell_above_the_terrain_it_lowers() {
    let dir = tempfile::tempdir().unwrap();
    let dem = plane_dem(dir.path());
    let d0 = deform(&dem, &[ridge(&dem_map(&dem))], &opts()).unwrap();
    let m = d0.base.clone();
    assert_eq!((d0.window.width, d0.window.height), (N, N));
    let low = lowering(&m, &d0);
    let reference = Displacement {
        window: d0.window,
        values: d0.displacement.clone(),
    };
    let cell = CellSize { hx: CELL, hy: CELL };

    // The lowering curve alone, rasterised: with its reference no cell it
    // decides is above M0; by the band rule alone some centre in front of
    // it is raised.
    let rel = rasterise_relative(
        &m,
        d0.window,
        std::slice::from_ref(&low),
        &[Some(&reference)],
        cell,
    );
    let plain = rasterise(&m, std::slice::from_ref(&low), cell);
    assert!(rel.count > 0 && rel.count == plain.count);
    let mut raised = 0f64;
    for k in 0..N * N {
        if !rel.constrained[k] {
            continue;
        }
        let m0 = d0.displacement[k] as f64;
        let d = rel.delta[k] as f64;
        assert!(d <= m0 + 1e-3, "cell {k}: {d} above M0 {m0}");
        raised = raised.max(plain.delta[k] as f64 - m0);
    }
    assert!(
        raised > 5.0,
        "the band rule alone raises a cell by {raised:.1} m: the case shows no defect"
    );

    // Solved with the ridge: with the reference no cell rises above M0
    // (every constraint at most M0, the free cells the same: the maximum
    // principle); without it the cells in front of the ridge rise.
    let curves = [ridge(&m), low];
    let with = deform_relative(
        &dem,
        (&curves, &[None, Some(&reference)]),
        &[],
        &[],
        &opts(),
    )
    .unwrap();
    let without = deform_bounded(&dem, &curves, &[], &[], &opts()).unwrap();
    let rise = |d: &Deformation| {
        d.displacement
            .iter()
            .zip(&d0.displacement)
            .map(|(a, b)| (*a - *b) as f64)
            .fold(f64::NEG_INFINITY, f64::max)
    };
    assert!(rise(&with) < 0.05, "a cell rose by {:.2} m", rise(&with));
    assert!(rise(&without) > 1.0, "without: {:.2}", rise(&without));
}

/// Two lowered points far apart joined by one polyline (the depth-buffer
/// points of two columns): the lowering is interpolated between them, so
/// the cells under the segment come down by `h`, not to the straight
/// line between the two heights (a trench across the landform).
#[test]
fn a_lowering_segment_between_far_points_lowers_by_h_not_to_the_chord() {
    let dir = tempfile::tempdir().unwrap();
    let dem = plane_dem(dir.path());
    let d0 = deform(&dem, &[ridge(&dem_map(&dem))], &opts()).unwrap();
    let m = d0.base.clone();
    let m0 = HeightMap {
        data: d0.displacement.clone(),
        ..m.clone()
    };
    let ends: Vec<[f64; 3]> = [12.5, 20.5]
        .iter()
        .map(|&px| {
            let py = 21.0;
            let (x, y) = crs(&m, px, py);
            let z = bilinear_valid(&m, px, py).unwrap() + bilinear_valid(&m0, px, py).unwrap();
            [x, y, z - H_LOWER]
        })
        .collect();
    let chord = CurveConstraint { points: ends };
    let reference = Displacement {
        window: d0.window,
        values: d0.displacement.clone(),
    };
    let cell = CellSize { hx: CELL, hy: CELL };
    let rel = rasterise_relative(
        &m,
        d0.window,
        std::slice::from_ref(&chord),
        &[Some(&reference)],
        cell,
    );
    let plain = rasterise(&m, &[chord], cell);
    let (mut deepest_rel, mut deepest_plain) = (0f64, 0f64);
    for k in 0..N * N {
        if rel.constrained[k] {
            let m0 = d0.displacement[k] as f64;
            deepest_rel = deepest_rel.max(m0 - rel.delta[k] as f64);
            deepest_plain = deepest_plain.max(m0 - plain.delta[k] as f64);
        }
    }
    assert!(
        deepest_rel < 0.5 * deepest_plain,
        "lowered by {deepest_rel:.2}, the chord {deepest_plain:.1}"
    );
    assert!(
        deepest_plain > 4.0 * H_LOWER,
        "the chord: {deepest_plain:.1}"
    );
}

/// The whole DEM as a height map (the window `deform` reads).
fn dem_map(dem: &Dem) -> HeightMap {
    dem.read_height_map(demsketch::raster::Window::new(0, 0, N, N))
        .unwrap()
}
