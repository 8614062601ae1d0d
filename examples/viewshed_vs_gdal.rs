//! Viewshed: demsketch against `gdal_viewshed` (GDAL on this machine) in one
//! run, on the same DEM, observer and curvature coefficient (0.85714, i.e.
//! refraction k = 1/7). For each case prints the share of valid cells on
//! which the two agree and the wall-clock time of each, the median of
//! several runs alternating between them: ours covers opening the DEM,
//! resolving the viewpoint and computing the viewshed while the DEM is read
//! in bands of rows (`viewshed_from_file`, in-process), and, in its own
//! columns, also writing it as a GeoTIFF (`write_viewshed_tiff`: PackBits
//! tiles; and, "as GDAL", striped and uncompressed as gdal_viewshed
//! writes); "read whole + sweep" is the
//! previous way (the DEM read whole, then `viewshed_from_dem`; checked to
//! give the same bytes); GDAL's is the `gdal_viewshed` process (read,
//! compute, write). It also times the
//! exact reference (one cast per cell, `viewshed_exact`, once; skipped
//! above 20 M cells) and gives our agreement with it.
//!
//!     cargo run --release --example viewshed_vs_gdal [-- RUNS [WORD...]]
//!
//! (with WORDs, only the cases whose name contains one, e.g. `5 4096 8192`)
//!
//! The cases are the three fixtures of `tests/view_viewshed.rs` (Zion UTM,
//! Arenal in EPSG:4326, Vinschgau) and, for timings on larger grids, Zion
//! resampled with `gdal_translate -outsize` to 1688 x 2060 (4x), 4096 x 4096
//! and 8192 x 8192 cells.

use demsketch::raster::{read_height_map, Dem};
use demsketch::render::{
    eye_frame, viewshed_exact, viewshed_from_dem, viewshed_from_file, write_viewshed_tiff,
    write_viewshed_tiff_with, LocalTerrain,
};
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

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn run(case: &Case, tmp: &Path, runs: usize) -> anyhow::Result<()> {
    let map = read_height_map(&case.path)?;
    let (x, y) = map
        .geotransform
        .pixel_to_crs(case.col as f64 + 0.5, case.row as f64 + 0.5);
    let georef = Georef::new(&map, &case.name)?;
    let (lon, lat) = georef.crs_to_lonlat(x, y)?;
    // the previous way: the DEM read whole, then swept
    let whole_once = || -> anyhow::Result<_> {
        let map = read_height_map(&case.path)?;
        let georef = Georef::new(&map, &case.name)?;
        let frame = georef.local_frame(
            &Viewpoint::above_surface(lon, lat, case.eye),
            &map,
            1.0 / 7.0,
        )?;
        Ok(viewshed_from_dem(&map, &frame, None, 0.0))
    };
    // streamed: bands of rows read as the sweep reaches them
    let ours_once = || -> anyhow::Result<_> {
        let dem = Dem::open(&case.path)?.without_block_cache();
        let georef = Georef::for_crs(&dem.crs, &case.name)?;
        let frame = eye_frame(
            &dem,
            &georef,
            &Viewpoint::above_surface(lon, lat, case.eye),
            1.0 / 7.0,
        )?;
        Ok(viewshed_from_file(&dem, &frame, None, 0.0)?)
    };
    let out = tmp.join(format!("{}.gdal.tif", case.name));
    let ours_tif = tmp.join(format!("{}.ours.tif", case.name));
    let gdal_once = || -> anyhow::Result<()> {
        let st = Command::new("gdal_viewshed")
            .args(["-q", "-ox", &format!("{x:.6}"), "-oy", &format!("{y:.6}")])
            .args(["-oz", &case.eye.to_string(), "-cc", "0.85714"])
            .args(["-vv", "255", "-iv", "0"])
            .arg(&case.path)
            .arg(&out)
            .status()?;
        anyhow::ensure!(st.success(), "gdal_viewshed failed on {}", case.name);
        Ok(())
    };
    // alternate: read whole, ours, ours + write, GDAL; medians
    let (mut t_ours, mut t_write, mut t_gdal) = (Vec::new(), Vec::new(), Vec::new());
    let (mut t_whole, mut t_raw) = (Vec::new(), Vec::new());
    let mut ours = None;
    for _ in 0..runs {
        let t = Instant::now();
        let whole = whole_once()?;
        t_whole.push(t.elapsed().as_secs_f64());
        if let Some(prev) = &ours {
            let prev: &demsketch::render::Viewshed = prev;
            anyhow::ensure!(prev.data == whole.data, "streamed and whole differ");
        }
        drop(whole);
        let t = Instant::now();
        let vs = ours_once()?;
        t_ours.push(t.elapsed().as_secs_f64());
        drop(vs);
        let t = Instant::now();
        let vs = ours_once()?;
        write_viewshed_tiff(&vs, &ours_tif)?;
        t_write.push(t.elapsed().as_secs_f64());
        drop(vs);
        // the same, written as gdal_viewshed writes (striped, uncompressed)
        let t = Instant::now();
        let vs = ours_once()?;
        write_viewshed_tiff_with(&vs, &ours_tif, &[])?;
        t_raw.push(t.elapsed().as_secs_f64());
        ours = Some(vs);
        let t = Instant::now();
        gdal_once()?;
        t_gdal.push(t.elapsed().as_secs_f64());
    }
    let ours = ours.expect("runs > 0");
    let (ours_s, write_s, gdal_s) = (median(t_ours), median(t_write), median(t_gdal));
    let (whole_s, raw_s) = (median(t_whole), median(t_raw));
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
        "| {} | {} x {} | cell ({}, {}), {} m | {:.2} % | {} | {:.1} ms | {:.1} ms | {:.1} ms | {:.1} ms | {} | {:.1} ms | {:.2} | {:.2} | {:.2} |",
        case.name,
        map.width,
        map.height,
        case.col,
        case.row,
        case.eye,
        100.0 * agree as f64 / total as f64,
        vs_exact,
        whole_s * 1e3,
        ours_s * 1e3,
        write_s * 1e3,
        raw_s * 1e3,
        exact_ms,
        gdal_s * 1e3,
        ours_s / gdal_s,
        write_s / gdal_s,
        raw_s / gdal_s
    );
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let runs: usize = match std::env::args().nth(1) {
        Some(a) => a.parse()?,
        None => 5,
    };
    anyhow::ensure!(runs > 0, "RUNS must be at least 1");
    // optional: only the cases whose name contains one of these words
    let only: Vec<String> = std::env::args().skip(2).collect();
    let wanted = |name: &str| only.is_empty() || only.iter().any(|w| name.contains(w.as_str()));
    let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
    let tmp = tempfile::tempdir()?;
    let resampled = |name: &str, w: &str, h: &str| -> anyhow::Result<PathBuf> {
        let p = tmp.path().join(name);
        if !wanted(name) {
            return Ok(p);
        }
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
        "| DEM | cells | observer | agreement with GDAL | agreement with exact | read whole + sweep | demsketch | + write | + write as GDAL | exact | gdal_viewshed | demsketch / GDAL | + write / GDAL | + write as GDAL / GDAL |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for c in cases.iter().filter(|c| wanted(&c.name)) {
        run(c, tmp.path(), runs)?;
    }
    Ok(())
}
