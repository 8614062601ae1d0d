//! Makes the fit cases of issue 5 (`fixtures/fit_cases/`): for each case a
//! *target* DEM is made from a fixture by a known change (a peak raised, a
//! ridge raised or cut), the target is rendered from a chosen viewpoint, and
//! the silhouettes the change produced are traced into a sketch file. Editing
//! the original fixture with that sketch must bring it close to the target
//! (`tests/edit_fit_cases.rs` checks fit, visibility and the height error).
//!
//!     cargo run --release --example make_fit_cases -- [OUT_DIR]
//!
//! (`tools/make_fit_cases.sh` runs it; OUT_DIR defaults to
//! `fixtures/fit_cases`.) For every case it writes
//!
//! - `<case>.json`: the sketch (DESIGN.md's sketch file format), one view,
//!   the traced strokes;
//! - `<case>_target.tif`: the target heights (Float32, NaN nodata) on the
//!   part of the fixture's grid the change touches (plus a margin);
//!
//! and `cases.json` lists the cases: fixture, sketch, target, the change
//! (centre, width, amplitude in metres) and the changed region's threshold.
//! With `MAKE_FIT_CASES_KEEP_FULL=DIR` the whole target GeoTIFFs are kept in
//! `DIR` too (to look at them with `demsketch view DIR/<case>_full.tif
//! --sketch <case>.json`).
//!
//! The change is anchored on the terrain: the point that forms the topmost
//! silhouette of the original view in a chosen image column (so the change
//! is seen from the viewpoint). It is a Gaussian `a exp(-d^2 / 2 s^2)` of
//! the horizontal distance `d` to that point: a peak or knob raised with
//! `a > 0`, a notch cut into a ridge with `a < 0`; beyond `3 s` it is
//! exactly 0. The target is written in the fixture's own sample type, so
//! integer DEMs hold the rounded heights the edit is compared with.
//!
//! Strokes trace the *outline of the change* in the rendered target: per
//! image column the topmost silhouette sample whose terrain point lies
//! where the change is at least [`TRACE_FRACTION`] of its amplitude. The
//! outline is cut where a column has none, where it jumps by more than
//! [`MAX_STROKE_JUMP_PX`] or its depth by more than [`MAX_STROKE_DEPTH_STEP`]
//! (it passes onto another ridge); each piece is kept over the columns where
//! it leaves every boundary of the original view by more than
//! [`MIN_VISIBLE_CHANGE_PX`] (where the change shows), plus
//! [`STROKE_MARGIN_COLUMNS`] on each side, if that is at least
//! [`MIN_STROKE_COLUMNS`] long; one point every [`STROKE_STEP`] columns.

use demsketch::deform::locality::cell_size_m;
use demsketch::features::{extract_silhouettes, SilhouetteParams, Silhouettes};
use demsketch::raster::{Dem, Destination, HeightMap, Provenance, Window};
use demsketch::render::{DepthBuffer, Scene, SKY};
use demsketch::view::{Camera, Viewpoint};
use serde_json::json;
use std::path::{Path, PathBuf};

/// Strokes follow silhouette samples where the change is at least this
/// fraction of its amplitude.
const TRACE_FRACTION: f64 = 0.05;
/// Shortest stroke, image columns.
const MIN_STROKE_COLUMNS: usize = 24;
/// Strokes cover the outline where it leaves the original view's
/// boundaries by more than this (pixels) ...
const MIN_VISIBLE_CHANGE_PX: f64 = 1.0;
/// ... and this many columns more on each side.
const STROKE_MARGIN_COLUMNS: usize = 6;
/// The outline is cut into two strokes where it jumps by more than this
/// between neighbouring columns, pixels.
const MAX_STROKE_JUMP_PX: f64 = 1.5;
/// ... or its depth changes by more than this fraction (it passes onto
/// another ridge: a person draws two strokes meeting at a T-junction).
const MAX_STROKE_DEPTH_STEP: f64 = 0.06;
/// One stroke point every this many silhouette samples (columns).
const STROKE_STEP: usize = 3;
/// The changed region of the RMSE check: `|target - original|` at least
/// this fraction of its largest value.
const REGION_FRACTION: f64 = 0.1;
/// Maximum view distance and refraction, as `demsketch edit` uses them.
const MAX_DISTANCE_M: f64 = 50_000.0;
const REFRACTION: f64 = 1.0 / 7.0;

/// Where the eye is and the camera.
#[derive(Clone, Copy)]
struct ViewSpec {
    lon: f64,
    lat: f64,
    heading_deg: f64,
    pitch_deg: f64,
    hfov_deg: f64,
    width: usize,
    height: usize,
}

struct CaseSpec {
    name: &'static str,
    fixture: &'static str,
    what: &'static str,
    view: ViewSpec,
    /// The change is centred on the terrain point forming the topmost
    /// silhouette in this image column.
    column: f64,
    sigma_m: f64,
    amplitude_m: f64,
    influence_m: f64,
}

fn cases() -> Vec<CaseSpec> {
    let zion_view = ViewSpec {
        lon: -112.90,
        lat: 37.40,
        heading_deg: 200.0,
        pitch_deg: -1.0,
        hfov_deg: 35.0,
        width: 1200,
        height: 600,
    };
    vec![
        CaseSpec {
            name: "zion_peak_raised",
            fixture: "zion_srtm_utm12n.tif",
            what: "the peak on the skyline at column 352 raised by 120 m",
            view: zion_view,
            column: 352.0,
            sigma_m: 350.0,
            amplitude_m: 120.0,
            influence_m: 1200.0,
        },
        CaseSpec {
            name: "zion_ridge_cut",
            fixture: "zion_srtm_utm12n.tif",
            what: "a notch 60 m deep cut into the dome on the skyline at column 830",
            view: zion_view,
            column: 830.0,
            sigma_m: 300.0,
            amplitude_m: -60.0,
            influence_m: 1000.0,
        },
        CaseSpec {
            name: "vinschgau_ridge_cut",
            fixture: "vinschgau_250m_utm32n.tif",
            what: "a notch 150 m deep cut into the skyline ridge at column 410, 27 km away",
            view: ViewSpec {
                lon: 11.05,
                lat: 46.66,
                heading_deg: 260.0,
                pitch_deg: 1.0,
                hfov_deg: 60.0,
                width: 1200,
                height: 600,
            },
            column: 410.0,
            sigma_m: 500.0,
            amplitude_m: -150.0,
            influence_m: 1500.0,
        },
        CaseSpec {
            name: "arenal_flank_raised",
            fixture: "arenal_aster30m_epsg4326.tif",
            what:
                "a knob 15 m high raised on the volcano's east flank, on the skyline at column 823",
            view: ViewSpec {
                lon: -84.684,
                lat: 10.451,
                heading_deg: 305.0,
                pitch_deg: 9.0,
                hfov_deg: 55.0,
                width: 1200,
                height: 600,
            },
            column: 823.0,
            sigma_m: 40.0,
            amplitude_m: 15.0,
            influence_m: 150.0,
        },
    ]
}

fn main() {
    if let Err(e) = run() {
        eprintln!("make_fit_cases: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out_dir = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("fixtures/fit_cases"));
    std::fs::create_dir_all(&out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let tmp = tempfile::tempdir().map_err(|e| e.to_string())?;
    let mut manifest = Vec::new();
    for case in cases() {
        eprintln!("{}: {}", case.name, case.what);
        manifest.push(make_case(&case, root, &out_dir, tmp.path())?);
    }
    let text =
        serde_json::to_string_pretty(&json!({ "cases": manifest })).map_err(|e| e.to_string())?;
    let path = out_dir.join("cases.json");
    std::fs::write(&path, text + "\n").map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(())
}

/// A rendered view and its silhouettes.
struct Rendered {
    depth: DepthBuffer,
    sil: Silhouettes,
}

fn render(dem: &Dem, v: &ViewSpec) -> Result<Rendered, String> {
    let camera = Camera::new(
        v.width,
        v.height,
        v.heading_deg,
        v.pitch_deg,
        0.0,
        v.hfov_deg,
    )
    .map_err(|e| e.to_string())?;
    let scene = Scene::open(
        dem,
        &Viewpoint::above_surface(v.lon, v.lat, 1.7),
        Some(MAX_DISTANCE_M),
        REFRACTION,
    )
    .map_err(|e| e.to_string())?;
    let depth = DepthBuffer::render(&scene.terrain, &camera);
    let sil = extract_silhouettes(&scene.terrain, &depth, &SilhouetteParams::default())
        .map_err(|e| e.to_string())?;
    Ok(Rendered { depth, sil })
}

/// The topmost silhouette sample of image column `x`: (curve, sample).
fn topmost(sil: &Silhouettes, x: f64) -> Option<(usize, usize)> {
    let col = x.floor();
    let mut best: Option<(usize, usize, f64)> = None;
    for (ci, c) in sil.curves.iter().enumerate() {
        for (si, s) in c.samples.iter().enumerate() {
            if s.pixel[0].floor() == col && best.is_none_or(|b| s.pixel[1] < b.2) {
                best = Some((ci, si, s.pixel[1]));
            }
        }
    }
    best.map(|b| (b.0, b.1))
}

fn make_case(
    case: &CaseSpec,
    root: &Path,
    out_dir: &Path,
    tmp: &Path,
) -> Result<serde_json::Value, String> {
    let fixture = root.join("fixtures").join(case.fixture);
    let dem = Dem::open(&fixture).map_err(|e| e.to_string())?;
    let full = dem
        .read_height_map(dem.full_window())
        .map_err(|e| e.to_string())?;
    let before = render(&dem, &case.view)?;

    // The anchor in DEM pixel coordinates.
    let gt = &dem.geotransform;
    let to_px = |p: [f64; 3]| gt.crs_to_pixel(p[0], p[1]);
    let column = case.column;
    let (c, s) = topmost(&before.sil, column)
        .ok_or_else(|| format!("{}: no silhouette in column {column}", case.name))?;
    let centre = to_px(before.sil.curves[c].samples[s].world)
        .ok_or_else(|| format!("{}: bad geotransform", case.name))?;

    // The change on the whole grid.
    let lat = case.view.lat;
    let cell = cell_size_m(gt, dem.crs.geographic, lat);
    let (w, h) = (full.width, full.height);
    let reach = 3.0 * case.sigma_m;
    let mut change = vec![0f64; w * h];
    for r in 0..h {
        for c in 0..w {
            let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
            let d = distance_m(centre, x, y, cell.hx, cell.hy);
            if d < reach && !full.data[r * w + c].is_nan() {
                change[r * w + c] =
                    case.amplitude_m * (-(d * d) / (2.0 * case.sigma_m * case.sigma_m)).exp();
            }
        }
    }
    let values: Vec<f64> = full
        .data
        .iter()
        .zip(&change)
        .map(|(&z, &d)| if d != 0.0 { z as f64 + d } else { f64::NAN })
        .collect();
    let full_target = tmp.join(format!("{}_full.tif", case.name));
    dem.write_back(
        dem.full_window(),
        &values,
        &Destination::Path(full_target.clone()),
        &Provenance {
            edit_id: format!("make_fit_cases:{}", case.name),
        },
    )
    .map_err(|e| e.to_string())?;
    if let Some(keep) = std::env::var_os("MAKE_FIT_CASES_KEEP_FULL") {
        let to = Path::new(&keep).join(format!("{}_full.tif", case.name));
        std::fs::copy(&full_target, &to).map_err(|e| format!("{}: {e}", to.display()))?;
    }
    let target_dem = Dem::open(&full_target).map_err(|e| e.to_string())?;
    let target = target_dem
        .read_height_map(target_dem.full_window())
        .map_err(|e| e.to_string())?;
    let after = render(&target_dem, &case.view)?;

    // Strokes: the target's silhouettes formed by changed terrain.
    let change_at = |p: [f64; 3]| -> f64 {
        let Some((x, y)) = to_px(p) else { return 0.0 };
        let d = distance_m(centre, x, y, cell.hx, cell.hy);
        if d < reach {
            case.amplitude_m * (-(d * d) / (2.0 * case.sigma_m * case.sigma_m)).exp()
        } else {
            0.0
        }
    };
    let strokes = trace_strokes(&after.sil, &before, |p| {
        change_at(p).abs() >= TRACE_FRACTION * case.amplitude_m.abs()
    });
    if strokes.is_empty() {
        return Err(format!("{}: the change shows no silhouette", case.name));
    }
    let stroke_json: Vec<serde_json::Value> = strokes
        .iter()
        .enumerate()
        .map(|(k, pts)| {
            let pts: Vec<[f64; 2]> = pts.iter().map(|p| [round2(p[0]), round2(p[1])]).collect();
            json!({"id": format!("s{k}"), "points": pts})
        })
        .collect();
    for (k, s) in strokes.iter().enumerate() {
        eprintln!(
            "  stroke s{k}: {} points, x {:.1}..{:.1}",
            s.len(),
            s[0][0],
            s[s.len() - 1][0]
        );
    }
    let v = &case.view;
    let sketch = json!({
        "views": [{
            "name": case.name,
            "viewpoint": {"lon": v.lon, "lat": v.lat, "eye_height_m": 1.7},
            "camera": {"heading_deg": v.heading_deg, "pitch_deg": v.pitch_deg, "roll_deg": 0.0,
                       "hfov_deg": v.hfov_deg, "width": v.width, "height": v.height},
            "strokes": stroke_json
        }],
        "options": {"influence_m": case.influence_m}
    });
    let sketch_name = format!("{}.json", case.name);
    let text = serde_json::to_string_pretty(&sketch).map_err(|e| e.to_string())? + "\n";
    let sp = out_dir.join(&sketch_name);
    std::fs::write(&sp, text).map_err(|e| format!("{}: {e}", sp.display()))?;

    // The target on the changed part of the grid (plus a margin).
    let (mut c0, mut r0, mut c1, mut r1) = (w, h, 0, 0);
    let mut max_change = 0f64;
    for r in 0..h {
        for c in 0..w {
            let (a, b) = (full.data[r * w + c], target.data[r * w + c]);
            if !a.is_nan() && a != b {
                c0 = c0.min(c);
                r0 = r0.min(r);
                c1 = c1.max(c + 1);
                r1 = r1.max(r + 1);
                max_change = max_change.max((a as f64 - b as f64).abs());
            }
        }
    }
    if c1 <= c0 {
        return Err(format!("{}: the change is empty", case.name));
    }
    let m = 2;
    let win = Window::new(
        c0.saturating_sub(m) as i64,
        r0.saturating_sub(m) as i64,
        (c1 + m).min(w) - c0.saturating_sub(m),
        (r1 + m).min(h) - r0.saturating_sub(m),
    );
    let crop = target_dem.read_height_map(win).map_err(|e| e.to_string())?;
    let target_name = format!("{}_target.tif", case.name);
    write_f32_tiff(&crop, &out_dir.join(&target_name))?;

    let (cx, cy) = gt.pixel_to_crs(centre.0, centre.1);
    Ok(json!({
        "name": case.name,
        "fixture": case.fixture,
        "change": case.what,
        "anchor_column": column,
        "centre_crs": [round2(cx), round2(cy)],
        "sigma_m": case.sigma_m,
        "amplitude_m": case.amplitude_m,
        "influence_m": case.influence_m,
        "sketch": sketch_name,
        "target": target_name,
        "target_window": [win.col, win.row, win.width, win.height],
        "max_change_m": max_change,
        "region_min_change_m": REGION_FRACTION * max_change,
    }))
}

fn round2(v: f64) -> f64 {
    (v * 100.0).round() / 100.0
}

/// Distance in metres from pixel `(x, y)` to pixel point `c`, with cells
/// `hx` x `hy` metres.
fn distance_m(c: (f64, f64), x: f64, y: f64, hx: f64, hy: f64) -> f64 {
    ((x - c.0) * hx).hypot((y - c.1) * hy)
}

/// Rows of the occlusion boundaries of column `i` of a rendered view:
/// silhouette samples and the skyline.
fn boundaries(r: &Rendered, i: usize) -> Vec<f64> {
    let mut out: Vec<f64> = r
        .sil
        .curves
        .iter()
        .flat_map(|c| c.samples.iter())
        .filter(|s| s.pixel[0].floor() as usize == i)
        .map(|s| s.pixel[1])
        .collect();
    let w = r.depth.width;
    if let Some(j) = (0..r.depth.height).find(|&j| r.depth.triangle[j * w + i] != SKY) {
        if j > 0 {
            out.push(j as f64);
        }
    }
    out
}

/// The outline of the change: per image column the topmost silhouette
/// sample of `sil` whose terrain point is `changed`, cut into strokes where
/// a column has none, the outline jumps by more than [`MAX_STROKE_JUMP_PX`]
/// or its depth by more than [`MAX_STROKE_DEPTH_STEP`] (see the module
/// documentation).
fn trace_strokes(
    sil: &Silhouettes,
    before: &Rendered,
    changed: impl Fn([f64; 3]) -> bool,
) -> Vec<Vec<[f64; 2]>> {
    let mut top: std::collections::BTreeMap<i64, [f64; 2]> = Default::default();
    let mut depth: std::collections::BTreeMap<i64, f64> = Default::default();
    for c in &sil.curves {
        for s in &c.samples {
            if changed(s.world) {
                let col = s.pixel[0].floor() as i64;
                let e = top.entry(col).or_insert(s.pixel);
                if s.pixel[1] <= e[1] {
                    *e = s.pixel;
                    depth.insert(col, s.depth);
                }
            }
        }
    }
    let (dlo, dhi) = depth
        .values()
        .fold((f64::INFINITY, 0.0f64), |a, d| (a.0.min(*d), a.1.max(*d)));
    eprintln!("  outline depth {dlo:.0}-{dhi:.0} m");
    let mut runs: Vec<Vec<[f64; 2]>> = Vec::new();
    let mut prev: Option<(i64, [f64; 2], f64)> = None;
    for (&col, &p) in &top {
        let d = depth.get(&col).copied().unwrap_or(f64::NAN);
        let joins = prev.is_some_and(|(c, q, e)| {
            c + 1 == col
                && (q[1] - p[1]).abs() <= MAX_STROKE_JUMP_PX
                && (d - e).abs() <= MAX_STROKE_DEPTH_STEP * d.min(e)
        });
        if !joins {
            runs.push(Vec::new());
        }
        if let Some(r) = runs.last_mut() {
            r.push(p);
        }
        prev = Some((col, p, d));
    }
    let mut out = Vec::new();
    for r in runs {
        // Where the outline leaves the original view's boundaries, widened
        // by a few columns on each side.
        let moved: Vec<bool> = r
            .iter()
            .map(|p| {
                boundaries(before, p[0].floor() as usize)
                    .iter()
                    .all(|b| (b - p[1]).abs() > MIN_VISIBLE_CHANGE_PX)
            })
            .collect();
        let (Some(first), Some(last)) = (
            moved.iter().position(|m| *m),
            moved.iter().rposition(|m| *m),
        ) else {
            continue;
        };
        let a = first.saturating_sub(STROKE_MARGIN_COLUMNS);
        let b = (last + STROKE_MARGIN_COLUMNS).min(r.len() - 1);
        let r = &r[a..=b];
        if r.len() < MIN_STROKE_COLUMNS {
            continue;
        }
        let mut pts: Vec<[f64; 2]> = r.iter().step_by(STROKE_STEP).copied().collect();
        if let (Some(last), Some(end)) = (pts.last(), r.last()) {
            if last != end {
                pts.push(*end);
            }
        }
        out.push(pts);
    }
    out
}

/// Write `map` as a single-band Float32 GeoTIFF (DEFLATE, NaN nodata).
fn write_f32_tiff(map: &HeightMap, path: &Path) -> Result<(), String> {
    let err = |e: gdal::errors::GdalError| format!("{}: {e}", path.display());
    let driver = gdal::DriverManager::get_driver_by_name("GTiff").map_err(err)?;
    let opts = gdal::raster::RasterCreationOptions::from_iter(["COMPRESS=DEFLATE", "PREDICTOR=3"]);
    let mut ds = driver
        .create_with_band_type_with_options::<f32, _>(path, map.width, map.height, 1, &opts)
        .map_err(err)?;
    ds.set_geo_transform(&map.geotransform.0).map_err(err)?;
    let srs = map.crs.gdal_definition();
    if let Ok(sr) = gdal::spatial_ref::SpatialRef::from_definition(&srs) {
        ds.set_spatial_ref(&sr).map_err(err)?;
    }
    let mut band = ds.rasterband(1).map_err(err)?;
    band.set_no_data_value(Some(f64::NAN)).map_err(err)?;
    let mut buf = gdal::raster::Buffer::new((map.width, map.height), map.data.clone());
    band.write((0, 0), (map.width, map.height), &mut buf)
        .map_err(err)?;
    ds.close().map_err(err)?;
    Ok(())
}
