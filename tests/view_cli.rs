//! `demsketch view` and `demsketch locate` from the command line: the help
//! teaches the options, every output (PNG with overlays, depth TIFF,
//! viewshed GeoTIFF, features GeoJSON) is written and readable, a sketch
//! file's view is used, and user errors (viewpoint off the DEM, unknown
//! view, bad camera, missing viewpoint) give one line and exit code 1
//! without creating the outputs.

mod common;

use common::{demsketch, fixture};
use std::path::Path;

const ZION: &str = "zion_srtm_utm12n.tif";

fn stderr_line(out: &std::process::Output) -> String {
    let s = String::from_utf8_lossy(&out.stderr).trim_end().to_string();
    assert_eq!(s.lines().count(), 1, "expected one line, got: {s}");
    s
}

fn png_size(path: &Path) -> (u32, u32) {
    let dec = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(path).expect("png exists"),
    ));
    let r = dec.read_info().expect("png header");
    (r.info().width, r.info().height)
}

#[test]
fn help_lists_the_options() {
    let out = demsketch(&["view", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for opt in [
        "--sketch",
        "--view",
        "--lon",
        "--lat",
        "--eye-height",
        "--alt",
        "--heading",
        "--pitch",
        "--roll",
        "--hfov",
        "--size",
        "--out",
        "--overlay",
        "--depth",
        "--viewshed",
        "--features",
        "silhouettes",
        "ridges",
        "strokes",
        "Examples:",
    ] {
        assert!(help.contains(opt), "view --help does not mention {opt}");
    }
    let out = demsketch(&["locate", "--help"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("--pixel"));
}

#[test]
fn view_writes_picture_depth_viewshed_and_features() {
    let dir = tempfile::tempdir().unwrap();
    let d = |n: &str| dir.path().join(n);
    let sketch = d("sketch.json");
    std::fs::write(
        &sketch,
        r#"{"views": [
            {"name": "other", "viewpoint": {"lon": -113.0, "lat": 37.3},
             "camera": {"heading_deg": 0.0, "width": 64, "height": 32}, "strokes": []},
            {"name": "canyon", "viewpoint": {"lon": -113.0463, "lat": 37.3225, "eye_height_m": 1.7},
             "camera": {"heading_deg": 30.0, "pitch_deg": 2.0, "roll_deg": 0.0,
                        "hfov_deg": 60.0, "width": 400, "height": 225},
             "strokes": [{"id": "a", "points": [[10.0, 100.0], [200.0, 80.0], [390.0, 95.0]]}]}
        ]}"#,
    )
    .unwrap();
    let out = demsketch(&[
        "view",
        &fixture(ZION).to_string_lossy(),
        "--sketch",
        &sketch.to_string_lossy(),
        "--view",
        "canyon",
        "--out",
        &d("v.png").to_string_lossy(),
        "--overlay",
        "silhouettes,ridges,strokes,junctions",
        "--depth",
        &d("depth.tif").to_string_lossy(),
        "--viewshed",
        &d("vis.tif").to_string_lossy(),
        "--features",
        &d("f.geojson").to_string_lossy(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(png_size(&d("v.png")), (400, 225));

    // Depth buffer: image-sized, sky nodata (-9999) at the top, terrain at
    // the bottom.
    let (w, h, depth, nodata) = common::gdal_values(&d("depth.tif"));
    assert_eq!((w, h), (400, 225));
    assert_eq!(nodata, Some(-9999.0));
    assert_eq!(depth[0], -9999.0);
    assert!(depth[(h - 1) * w + w / 2] > 0.0);

    // Viewshed on the DEM grid, 0/255, the eye's own cell visible.
    let vis = gdal::Dataset::open(d("vis.tif")).unwrap();
    let dem = gdal::Dataset::open(fixture(ZION)).unwrap();
    assert_eq!(vis.raster_size(), dem.raster_size());
    assert_eq!(vis.geo_transform().unwrap(), dem.geo_transform().unwrap());
    let (_, _, v, _) = common::gdal_values(&d("vis.tif"));
    assert!(v.iter().all(|&x| x == 0.0 || x == 255.0));
    let visible = v.iter().filter(|&&x| x == 255.0).count();
    assert!(visible > 100 && visible < v.len() / 2, "{visible} visible");

    // Features: silhouettes with pixels, ridges, lon/lat near the viewpoint.
    let fc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d("f.geojson")).unwrap()).unwrap();
    let feats = fc["features"].as_array().unwrap();
    let kinds = |k: &str| {
        feats
            .iter()
            .filter(|f| f["properties"]["kind"] == k)
            .count()
    };
    assert!(
        kinds("silhouette") > 3,
        "{} silhouettes",
        kinds("silhouette")
    );
    assert!(kinds("ridge") > 50, "{} ridges", kinds("ridge"));
    for f in feats
        .iter()
        .filter(|f| f["properties"]["kind"] == "silhouette")
    {
        let px = f["properties"]["pixels"].as_array().unwrap();
        for p in px {
            let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
            assert!((0.0..=400.0).contains(&x) && (0.0..=225.0).contains(&y));
        }
        let c = &f["geometry"]["coordinates"][0];
        assert!((c[0].as_f64().unwrap() + 113.0).abs() < 0.5);
        assert!((c[1].as_f64().unwrap() - 37.3).abs() < 0.5);
    }
    // Nothing else left in the output directory (no temporaries).
    let mut names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["depth.tif", "f.geojson", "sketch.json", "v.png", "vis.tif"]
    );
}

#[test]
fn overlays_change_the_picture_where_features_are() {
    let dir = tempfile::tempdir().unwrap();
    let base = [
        "view",
        &fixture("vinschgau_250m_utm32n.tif").to_string_lossy(),
        "--lon",
        "10.6959",
        "--lat",
        "46.6597",
        "--heading",
        "200",
        "--pitch",
        "2",
        "--size",
        "320x180",
    ]
    .map(|s| s.to_string())
    .to_vec();
    let render = |name: &str, extra: &[&str]| {
        let p = dir.path().join(name);
        let mut a: Vec<String> = base.clone();
        a.extend(["--out".into(), p.to_string_lossy().into_owned()]);
        a.extend(extra.iter().map(|s| s.to_string()));
        let args: Vec<&str> = a.iter().map(|s| s.as_str()).collect();
        let out = demsketch(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&p).unwrap()));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        r.next_frame(&mut buf).unwrap();
        buf
    };
    let plain = render("plain.png", &[]);
    let sil = render("sil.png", &["--overlay", "silhouettes"]);
    let ridges = render("ridges.png", &["--overlay", "ridges"]);
    let count = |img: &[u8], c: [u8; 3]| {
        let changed = img
            .chunks(3)
            .zip(plain.chunks(3))
            .filter(|(a, b)| a != b)
            .count();
        let exact = img.chunks(3).filter(|p| *p == c).count();
        (changed, exact)
    };
    let (ch, red) = count(&sil, [225, 30, 30]);
    assert!(
        red > 320 && ch == red,
        "silhouettes: {ch} changed, {red} red"
    );
    let (ch, yellow) = count(&ridges, [255, 214, 0]);
    assert!(
        yellow > 50 && ch == yellow,
        "ridges: {ch} changed, {yellow} yellow"
    );
}

#[test]
fn viewpoint_outside_the_dem_is_one_line_exit_1_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("v.png");
    let out = demsketch(&[
        "view",
        &fixture(ZION).to_string_lossy(),
        "--lon",
        "-100.0",
        "--lat",
        "37.3",
        "--out",
        &png.to_string_lossy(),
        "--viewshed",
        &dir.path().join("vis.tif").to_string_lossy(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(
        line.contains(ZION) && line.contains("outside"),
        "message: {line}"
    );
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

#[test]
fn user_errors_are_one_line_with_exit_1() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("v.png");
    let png = png.to_string_lossy().into_owned();
    let dem = fixture(ZION).to_string_lossy().into_owned();
    let sketch = dir.path().join("s.json");
    std::fs::write(
        &sketch,
        r#"{"views": [{"name": "a", "viewpoint": {"lon": -113.0463, "lat": 37.3225}, "camera": {}}]}"#,
    )
    .unwrap();
    let sketch = sketch.to_string_lossy().into_owned();
    let bad_json = dir.path().join("bad.json");
    std::fs::write(&bad_json, "{ not json").unwrap();
    let bad_json = bad_json.to_string_lossy().into_owned();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["view", &dem, "--out", &png], "--lon"),
        (
            vec![
                "view", &dem, "--sketch", &sketch, "--view", "nope", "--out", &png,
            ],
            "nope",
        ),
        (
            vec!["view", &dem, "--sketch", &bad_json, "--out", &png],
            "bad.json",
        ),
        (
            vec![
                "view",
                &dem,
                "--lon",
                "-113.0463",
                "--lat",
                "37.3225",
                "--hfov",
                "200",
                "--out",
                &png,
            ],
            "hfov",
        ),
        (
            vec![
                "view",
                "/nonexistent/dem.tif",
                "--lon",
                "-113.0463",
                "--lat",
                "37.3225",
                "--out",
                &png,
            ],
            "/nonexistent/dem.tif",
        ),
        (
            vec![
                "locate",
                &dem,
                "--lon",
                "-113.0463",
                "--lat",
                "37.3225",
                "--pitch",
                "30",
                "--pixel",
                "800,10",
            ],
            "sky",
        ),
    ];
    for (args, needle) in cases {
        let out = demsketch(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        let line = stderr_line(&out);
        assert!(line.contains(needle), "{args:?}: {line}");
    }
    assert!(!Path::new(&png).exists());
}

#[test]
fn locate_prints_the_terrain_point_as_json() {
    let out = demsketch(&[
        "locate",
        &fixture(ZION).to_string_lossy(),
        "--lon",
        "-113.0463",
        "--lat",
        "37.3225",
        "--heading",
        "30",
        "--pitch",
        "-10",
        "--pixel",
        "800,600",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let (lon, lat) = (v["lon"].as_f64().unwrap(), v["lat"].as_f64().unwrap());
    assert!((lon + 113.0463).abs() < 0.1 && (lat - 37.3225).abs() < 0.1);
    let (h, dist) = (
        v["height"].as_f64().unwrap(),
        v["distance"].as_f64().unwrap(),
    );
    assert!(h > 1000.0 && h < 3000.0 && dist > 0.0 && dist < 20_000.0);
}

/// `--viewshed-exact` writes the exact reference; the default sweep agrees
/// with it on at least 99 % of the cells; both are Byte GeoTIFFs on the
/// DEM's grid, read with GDAL.
#[test]
fn viewshed_exact_flag_and_the_sweep_agree() {
    let dir = tempfile::tempdir().unwrap();
    let read = |extra: &[&str], name: &str| -> Vec<u8> {
        let p = dir.path().join(name);
        let png = dir.path().join(format!("{name}.png"));
        let mut args = vec![
            "view".to_string(),
            fixture(ZION).to_string_lossy().into_owned(),
            "--lon".into(),
            "-113.0463".into(),
            "--lat".into(),
            "37.3225".into(),
            "--size".into(),
            "64x32".into(),
            "--out".into(),
            png.to_string_lossy().into_owned(),
            "--viewshed".into(),
            p.to_string_lossy().into_owned(),
        ];
        args.extend(extra.iter().map(|s| s.to_string()));
        let refs: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
        let out = demsketch(&refs);
        assert!(out.status.success(), "{}", stderr_line(&out));
        let ds = gdal::Dataset::open(&p).unwrap();
        let band = ds.rasterband(1).unwrap();
        assert_eq!(band.band_type(), gdal::raster::GdalDataType::UInt8);
        let (w, h) = band.size();
        band.read_as::<u8>((0, 0), (w, h), (w, h), None)
            .unwrap()
            .data()
            .to_vec()
    };
    let sweep = read(&[], "sweep.tif");
    let exact = read(&["--viewshed-exact"], "exact.tif");
    assert_eq!(sweep.len(), exact.len());
    let same = sweep.iter().zip(&exact).filter(|(a, b)| a == b).count();
    let frac = same as f64 / sweep.len() as f64;
    assert!(frac >= 0.99, "agreement {frac}");
    assert!(exact.contains(&255));
}
