//! Lakes on a real DEM: Reschensee (Lago di Resia), the reservoir at the
//! head of the Vinschgau valley, in `fixtures/vinschgau_250m_utm32n.tif`
//! (250 m cells, Float32), drawn as a lon/lat polygon in
//! `fixtures/corrections/vinschgau_reschensee.geojson`. Checked with GDAL:
//! every cell whose centre is inside the polygon equals the level within
//! 1 cm, no shore cell differs from its outside neighbour by more than the
//! DEM's own 99th percentile of neighbour differences, cells beyond the
//! blend width bit-identical.

mod common;
mod correct_support;

use std::path::Path;

use common::fixture;
use correct_support::{collection, correct_ok, inside, lonlat_to, Raster};
use serde_json::{json, Value};

const DEM: &str = "vinschgau_250m_utm32n.tif";

fn lake_ring() -> Vec<[f64; 2]> {
    let text =
        std::fs::read_to_string(fixture("corrections/vinschgau_reschensee.geojson")).unwrap();
    let v: Value = serde_json::from_str(&text).unwrap();
    v["features"][0]["geometry"]["coordinates"][0]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()])
        .collect()
}

fn run(features: &Path, out: &Path, rep: &Path) -> Value {
    correct_ok(&fixture(DEM), features, out, rep)
}

/// Checks the three acceptance lines for a lake with outer ring `ring`
/// and island `hole` (pixel space), level `level`, blend `blend_m`.
#[allow(clippy::too_many_arguments)]
fn check_lake(
    input: &Raster,
    output: &Raster,
    ring: &[[f64; 2]],
    hole: Option<&[[f64; 2]]>,
    level: f64,
    blend_m: f64,
    check_step: bool,
    cell: f64,
) {
    let is_lake = |c: usize, r: usize| {
        let p = [c as f64 + 0.5, r as f64 + 0.5];
        inside(ring, p) && !hole.is_some_and(|h| inside(h, p))
    };
    let mut lake = Vec::new();
    for r in 0..input.h {
        for c in 0..input.w {
            if is_lake(c, r) {
                lake.push((c, r));
            }
        }
    }
    assert!(lake.len() > 50, "{} lake cells", lake.len());
    let mut worst_level = 0f64;
    for &(c, r) in &lake {
        worst_level = worst_level.max((output.at(c, r) - level).abs());
    }
    assert!(
        worst_level <= 0.01,
        "lake cell off the level by {worst_level} m"
    );

    let p99 = input.neighbour_diff_p99();
    let mut worst_step = 0f64;
    for &(c, r) in &lake {
        for (dc, dr) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
            let (cc, rr) = ((c as i64 + dc) as usize, (r as i64 + dr) as usize);
            if !is_lake(cc, rr) {
                worst_step = worst_step.max((output.at(c, r) - output.at(cc, rr)).abs());
            }
        }
    }
    println!("shore step max {worst_step:.2} m, DEM neighbour p99 {p99:.2} m");
    assert!(
        !check_step || worst_step <= p99,
        "shore step {worst_step} m > p99 {p99} m"
    );

    let mut outside = 0;
    for r in 0..input.h {
        for c in 0..input.w {
            let near = lake.iter().any(|&(lc, lr)| {
                let d = ((lc as f64 - c as f64).hypot(lr as f64 - r as f64)) * cell;
                d <= blend_m + 1e-6
            });
            if !near {
                outside += 1;
                let (a, b) = (input.at(c, r), output.at(c, r));
                assert!(
                    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                    "cell ({c}, {r}) beyond the blend width changed: {a} -> {b}"
                );
            }
        }
    }
    assert!(outside > input.w * input.h / 2);
}

#[test]
fn reschensee_flattened_to_the_lowest_shoreline_height() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, rep) = (tmp.path().join("out.tif"), tmp.path().join("r.json"));
    let r = run(
        &fixture("corrections/vinschgau_reschensee.geojson"),
        &out,
        &rep,
    );
    let f = &r["corrections"][0];
    assert_eq!(f["kind"], "lake");
    assert_eq!(f["id"], "reschensee");
    assert_eq!(f["level_from_shoreline"], true);
    let level = f["level_m"].as_f64().unwrap();
    let input = Raster::read(&fixture(DEM));
    let output = Raster::read(&out);
    // The ring in pixel space, through GDAL's own transform.
    let ring: Vec<[f64; 2]> = lonlat_to(32632, &lake_ring())
        .into_iter()
        .map(|p| input.pixel(p[0], p[1]))
        .collect();
    // The level is the lowest bilinear height along the shoreline.
    let mut lowest = f64::INFINITY;
    for s in ring.windows(2) {
        for k in 0..40 {
            let t = k as f64 / 40.0;
            let p = [
                s[0][0] + t * (s[1][0] - s[0][0]),
                s[0][1] + t * (s[1][1] - s[0][1]),
            ];
            if let Some(v) = input.bilinear(p) {
                lowest = lowest.min(v);
            }
        }
    }
    assert!(
        (level - lowest).abs() < 0.5,
        "level {level}, lowest shore {lowest}"
    );
    check_lake(&input, &output, &ring, None, level, 500.0, true, 250.0);
    assert_eq!(r["changed_cells"], f["cells_changed"]);
    assert!(f["cells_changed"].as_u64().unwrap() > f["water_cells"].as_u64().unwrap());
}

#[test]
fn lake_with_an_island_at_a_given_level_in_the_dem_crs() {
    // The same lake written in the DEM's CRS (legacy "crs" member, as QGIS
    // writes it), raised to the reservoir's full supply level 1498 m, with
    // an (illustrative) island of one cell as a hole, and a blend width
    // under one cell, so the shore cells next to the water keep their
    // heights (the island among them).
    let tmp = tempfile::tempdir().unwrap();
    let input = Raster::read(&fixture(DEM));
    let utm = lonlat_to(32632, &lake_ring());
    let centre = input.crs([74.5, 36.5]);
    let hole_utm: Vec<[f64; 2]> = [
        [-150.0, -150.0],
        [150.0, -150.0],
        [150.0, 150.0],
        [-150.0, 150.0],
        [-150.0, -150.0],
    ]
    .iter()
    .map(|d| [centre[0] + d[0], centre[1] + d[1]])
    .collect();
    let fc = collection(
        vec![json!({"type": "Feature", "id": "resia",
            "properties": {"kind": "lake", "level_m": 1498.0, "blend_m": 100.0},
            "geometry": {"type": "Polygon", "coordinates": [utm, hole_utm]}})],
        Some(32632),
    );
    let features = tmp.path().join("lake.geojson");
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (tmp.path().join("out.tif"), tmp.path().join("r.json"));
    let r = run(&features, &out, &rep);
    let f = &r["corrections"][0];
    assert_eq!(f["level_m"], 1498.0);
    assert_eq!(f["level_from_shoreline"], false);
    assert_eq!(f["blend_m"], 100.0);
    let output = Raster::read(&out);
    let px =
        |v: &[[f64; 2]]| -> Vec<[f64; 2]> { v.iter().map(|p| input.pixel(p[0], p[1])).collect() };
    let (ring, hole) = (px(&utm), px(&hole_utm));
    check_lake(
        &input,
        &output,
        &ring,
        Some(&hole),
        1498.0,
        100.0,
        true,
        250.0,
    );
    // The island is not water: it keeps its height.
    assert_eq!(output.at(74, 36).to_bits(), input.at(74, 36).to_bits());
    assert!(f["water_cells"].as_u64().unwrap() == f["cells_changed"].as_u64().unwrap());
}

#[test]
fn coastal_lake_keeps_nodata_sea_on_a_dem_without_epsg_code() {
    // New Zealand 1 km DEM (NZTM as WKT, NaN sea): a square lake drawn in
    // lon/lat across the coast at level 5 m. Sea cells stay nodata; the
    // valid cells inside are at the level.
    use gdal::spatial_ref::{AxisMappingStrategy, CoordTransform, SpatialRef};
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("nz_1km_nan_nodata.tif");
    let input = Raster::read(&dem);
    let ds = gdal::Dataset::open(&dem).unwrap();
    let mut src = SpatialRef::from_wkt(&ds.projection()).unwrap();
    src.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let mut dst = SpatialRef::from_epsg(4326).unwrap();
    dst.set_axis_mapping_strategy(AxisMappingStrategy::TraditionalGisOrder);
    let t = CoordTransform::new(&src, &dst).unwrap();
    let px = [
        [540.0, 698.0],
        [552.0, 698.0],
        [552.0, 710.0],
        [540.0, 710.0],
        [540.0, 698.0],
    ];
    let ring: Vec<[f64; 2]> = px
        .iter()
        .map(|&p| {
            let c = input.crs(p);
            let (mut x, mut y, mut z) = ([c[0]], [c[1]], [0.0]);
            t.transform_coords(&mut x, &mut y, &mut z).unwrap();
            [x[0], y[0]]
        })
        .collect();
    let fc = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "lake", "name": "coast", "level_m": 5.0},
            "geometry": {"type": "Polygon", "coordinates": [ring]}}),
        ],
        None,
    );
    let features = tmp.path().join("coast.geojson");
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (tmp.path().join("out.tif"), tmp.path().join("r.json"));
    correct_ok(&dem, &features, &out, &rep);
    let output = Raster::read(&out);
    let (mut sea, mut land) = (0, 0);
    for r in 698..710 {
        for c in 540..552 {
            let (a, b) = (input.at(c, r), output.at(c, r));
            if a.is_nan() {
                assert!(b.is_nan(), "sea cell ({c}, {r}) became {b}");
                sea += 1;
            } else {
                assert!((b - 5.0).abs() <= 0.01, "cell ({c}, {r}) at {b}");
                land += 1;
            }
        }
    }
    assert!(sea > 5 && land > 5, "{sea} sea, {land} land cells");
    let nan_in = input.v.iter().filter(|v| v.is_nan()).count();
    let nan_out = output.v.iter().filter(|v| v.is_nan()).count();
    assert_eq!(nan_in, nan_out);
}

#[test]
fn lake_on_a_geographic_int16_dem() {
    // Arenal (ASTER, EPSG:4326, Int16): lon/lat needs no transform, cell
    // sizes in metres come from the latitude; an integer level is stored
    // exactly in Int16. The square lies on the volcano's flank, not in a
    // basin, so a flat lake there must have a step at its uphill shore:
    // only the level and the untouched cells beyond the blend are checked.
    let tmp = tempfile::tempdir().unwrap();
    let dem = fixture("arenal_aster30m_epsg4326.tif");
    let input = Raster::read(&dem);
    let px = [
        [20.0, 100.0],
        [40.0, 100.0],
        [40.0, 120.0],
        [20.0, 120.0],
        [20.0, 100.0],
    ];
    let ring: Vec<[f64; 2]> = px.iter().map(|&p| input.crs(p)).collect();
    let fc = collection(
        vec![
            json!({"type": "Feature", "properties": {"kind": "lake", "name": "arenal", "level_m": 600.0, "blend_m": 90.0},
            "geometry": {"type": "Polygon", "coordinates": [ring]}}),
        ],
        None,
    );
    let features = tmp.path().join("arenal.geojson");
    std::fs::write(&features, fc).unwrap();
    let (out, rep) = (tmp.path().join("out.tif"), tmp.path().join("r.json"));
    let r = correct_ok(&dem, &features, &out, &rep);
    let cell = r["cell_size_m"][0].as_f64().unwrap();
    assert!((cell - 30.4).abs() < 0.5, "cell {cell} m");
    let output = Raster::read(&out);
    let ring_px: Vec<[f64; 2]> = px.to_vec();
    check_lake(
        &input,
        &output,
        &ring_px,
        None,
        600.0,
        90.0,
        false,
        // The smaller cell side: distances are underestimated, so only
        // cells surely beyond the blend width are checked.
        cell.min(r["cell_size_m"][1].as_f64().unwrap()),
    );
}
