//! Viewshed: demsketch against `gdal_viewshed` (GDAL on this machine) in one
//! run, on the same DEM, observer and curvature coefficient (0.85714, i.e.
//! refraction k = 1/7). For each case prints the share of valid cells on
//! which the two agree and the wall-clock time of each: ours covers reading
//! the DEM, resolving the viewpoint, building the terrain and computing the
//! viewshed (best of 3, in-process); GDAL's is the `gdal_viewshed` process
//! (best of 3). It also times the exact reference (one cast per cell,
//! `viewshed_exact`, once; skipped above 20 M cells) and gives the sweep's
//! agreement with it.
//!
//!     cargo run --release --example viewshed_vs_gdal
//!
//! The cases are the three fixtures of `tests/view_viewshed.rs` (Zion UTM,
//! Arenal in EPSG:4326, Vinschgau) and, for timings on larger grids, Zion
//! resampled with `gdal_translate -outsize` to 1688 x 2060 (4x), 4096 x 4096
//! and 8192 x 8192 cells.

use demsketch::raster::read_height_map;
use demsketch::render::{viewshed, viewshed_exact, LocalTerrain};
use demsketch::view::{Georef, Viewpoint};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

struct Case {
    name: String,
    path: PathBuf,
    col: usize,
    row: usize,
    eye: f64,
}

fn best_of<T>(n: usize, mut f: impl FnMut() -> T) -> (T, f64) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..n {
        let t = Instant::now();
        let v = f();
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(v);
    }
    (out.expect("n > 0"), best)
}

fn run(case: &Case, tmp: &Path) -> anyhow::Result<()> {
    let map = read_height_map(&case.path)?;
    let (x, y) = map
        .geotransform
        .pixel_to_crs(case.col as f64 + 0.5, case.row as f64 + 0.5);
    let georef = Georef::new(&map, &case.name)?;
    let (lon, lat) = georef.crs_to_lonlat(x, y)?;
    let (ours, ours_s) = best_of(3, || -> anyhow::Result<_> {
        let map = read_height_map(&case.path)?;
        let georef = Georef::new(&map, &case.name)?;
        let frame = georef.local_frame(
            &Viewpoint::above_surface(lon, lat, case.eye),
            &map,
            1.0 / 7.0,
        )?;
        let terrain = LocalTerrain::new(&map, &frame, None);
        Ok(viewshed(&terrain, &map, 0.0))
    });
    let ours = ours?;
    let cells = map.width * map.height;
    let exact = if cells <= 20_000_000 {
        let (e, s) = best_of(1, || -> anyhow::Result<_> {
            let frame = georef.local_frame(
                &Viewpoint::above_surface(lon, lat, case.eye),
                &map,
                1.0 / 7.0,
            )?;
            let terrain = LocalTerrain::new(&map, &frame, None);
            Ok(viewshed_exact(&terrain, &map, 0.0))
        });
        Some((e?, s))
    } else {
        None
    };
    let out = tmp.join(format!("{}.gdal.tif", case.name));
    let (st, gdal_s) = best_of(3, || {
        Command::new("gdal_viewshed")
            .args(["-q", "-ox", &format!("{x:.6}"), "-oy", &format!("{y:.6}")])
            .args(["-oz", &case.eye.to_string(), "-cc", "0.85714"])
            .args(["-vv", "255", "-iv", "0"])
            .arg(&case.path)
            .arg(&out)
            .status()
    });
    anyhow::ensure!(st?.success(), "gdal_viewshed failed on {}", case.name);
    let ds = gdal::Dataset::open(&out)?;
    let band = ds.rasterband(1)?;
    let (w, h) = band.size();
    anyhow::ensure!((w, h) == (map.width, map.height), "size mismatch");
    let g = band.read_as::<u8>((0, 0), (w, h), (w, h), None)?;
    let (mut agree, mut total) = (0usize, 0usize);
    for (i, (&a, &b)) in ours.data.iter().zip(g.data().iter()).enumerate() {
        if map.data[i].is_nan() {
            continue;
        }
        total += 1;
        agree += ((a == 255) == (b == 255)) as usize;
    }
    let (vs_exact, exact_ms) = match &exact {
        Some((e, s)) => {
            let same = ours
                .data
                .iter()
                .zip(&e.data)
                .zip(&map.data)
                .filter(|((a, b), h)| !h.is_nan() && a == b)
                .count();
            (
                format!("{:.2} %", 100.0 * same as f64 / total as f64),
                format!("{:.0} ms", s * 1e3),
            )
        }
        None => ("-".into(), "-".into()),
    };
    println!(
        "| {} | {} x {} | cell ({}, {}), {} m | {:.2} % | {} | {:.1} ms | {} | {:.1} ms | {:.2} |",
        case.name,
        map.width,
        map.height,
        case.col,
        case.row,
        case.eye,
        100.0 * agree as f64 / total as f64,
        vs_exact,
        ours_s * 1e3,
        exact_ms,
        gdal_s * 1e3,
        ours_s / gdal_s
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let tmp = tempfile::tempdir()?;
    let resampled = |name: &str, w: &str, h: &str| -> anyhow::Result<PathBuf> {
        let p = tmp.path().join(name);
        let st = Command::new("gdal_translate")
            .args(["-q", "-outsize", w, h, "-r", "cubic"])
            .args(["-co", "TILED=YES"])
            .arg(fixtures.join("zion_srtm_utm12n.tif"))
            .arg(&p)
            .status()?;
        anyhow::ensure!(st.success(), "gdal_translate failed");
        Ok(p)
    };
    let big = resampled("zion_x4.tif", "400%", "400%")?;
    let big4k = resampled("zion_4096.tif", "4096", "4096")?;
    let big8k = resampled("zion_8192.tif", "8192", "8192")?;
    let case = |name: &str, path: PathBuf, col, row, eye| Case {
        name: name.into(),
        path,
        col,
        row,
        eye,
    };
    let cases = [
        case(
            "zion_srtm_utm12n",
            fixtures.join("zion_srtm_utm12n.tif"),
            210,
            103,
            1.7,
        ),
        case(
            "arenal_aster30m_epsg4326",
            fixtures.join("arenal_aster30m_epsg4326.tif"),
            35,
            30,
            1.7,
        ),
        case(
            "vinschgau_250m_utm32n",
            fixtures.join("vinschgau_250m_utm32n.tif"),
            101,
            110,
            25.0,
        ),
        case("zion_x4 (resampled)", big.clone(), 842, 414, 1.7),
        case("zion 4096^2 (resampled)", big4k, 2048, 820, 1.7),
        case("zion 8192^2 (resampled)", big8k, 4096, 1640, 1.7),
    ];
    println!(
        "| DEM | cells | observer | agreement with GDAL | agreement with exact | demsketch (sweep) | exact | gdal_viewshed | sweep / GDAL |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for c in &cases {
        run(c, tmp.path())?;
    }
    Ok(())
}
