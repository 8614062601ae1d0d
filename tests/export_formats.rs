//! `demsketch export`, each format checked with an independent reader:
//! Terrain-RGB and Terrarium tiles decode to within 0.1 m of what
//! `gdalwarp` makes of the same tile, and the tiles an edit changed
//! (`--changed`) are exactly those that differ; the COG passes GDAL's
//! `validate_cloud_optimized_geotiff.py`; the STAC item validates against
//! the core and extension schemas shipped in `fixtures/stac_schemas`
//! (Python `jsonschema`, `.venv` made by `tools/setup.sh`); the GeoJSON
//! of an edit has its placed curves and footprint; the glTF loads in the
//! `gltf` crate with the right vertex count and bounds. Bad input: exit 1,
//! one line naming the file, nothing written.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{demsketch, fixture, gdal_values, gdalinfo, run, snapshot};
use serde_json::Value;

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn ok(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "failed ({:?}): {}",
        out.status.code(),
        String::from_utf8_lossy(&out.stderr)
    );
}

fn one_line_error(out: &std::process::Output, names: &str) {
    assert_eq!(
        out.status.code(),
        Some(1),
        "exit 1: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(err.contains(names), "names {names}: {err}");
    assert!(!err.contains("ERROR "), "no GDAL ERROR line: {err}");
}

/// Every `z/x/y.png` under `root`.
fn tiles_in(root: &Path) -> Vec<(u8, u32, u32)> {
    let mut v = Vec::new();
    for (p, _) in snapshot(root) {
        let rel = p.strip_prefix(root).expect("under root");
        let parts: Vec<String> = rel
            .iter()
            .map(|c| c.to_string_lossy().into_owned())
            .collect();
        if parts.len() == 3 && parts[2].ends_with(".png") {
            v.push((
                parts[0].parse().expect("z"),
                parts[1].parse().expect("x"),
                parts[2].trim_end_matches(".png").parse().expect("y"),
            ));
        }
    }
    v.sort();
    v
}

/// RGBA pixels of a PNG tile (png crate, 256 x 256).
fn read_png(path: &Path) -> Vec<u8> {
    let dec = png::Decoder::new(std::io::BufReader::new(
        std::fs::File::open(path).expect("tile opens"),
    ));
    let mut reader = dec.read_info().expect("PNG header");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("PNG data");
    assert_eq!((info.width, info.height), (256, 256));
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    buf
}

/// EPSG:3857 bounds of an XYZ tile (the slippy-map formula, written out
/// here rather than taken from the library).
fn tile_bounds(z: u8, x: u32, y: u32) -> [f64; 4] {
    let half = std::f64::consts::PI * 6_378_137.0;
    let span = 2.0 * half / f64::from(1u32 << z);
    let x0 = -half + x as f64 * span;
    let y1 = half - y as f64 * span;
    [x0, y1 - span, x0 + span, y1]
}

fn decode(encoding: &str, p: &[u8]) -> f64 {
    let (r, g, b) = (p[0] as f64, p[1] as f64, p[2] as f64);
    match encoding {
        "terrain-rgb" => -10_000.0 + (r * 65_536.0 + g * 256.0 + b) * 0.1,
        _ => r * 256.0 + g + b / 256.0 - 32_768.0,
    }
}

/// Compare every tile of `tree` with `gdalwarp` of `dem` into that tile:
/// the largest height difference, and the pixels whose validity differs.
fn compare_with_gdalwarp(
    dem: &Path,
    tree: &Path,
    encoding: &str,
    work: &Path,
) -> (f64, usize, usize) {
    let mut worst: f64 = 0.0;
    let (mut compared, mut mismatched) = (0usize, 0usize);
    for (z, x, y) in tiles_in(tree) {
        let b = tile_bounds(z, x, y);
        let reference = work.join(format!("ref_{z}_{x}_{y}.tif"));
        let bs: Vec<String> = b.iter().map(|v| format!("{v:.10}")).collect();
        run(
            "gdalwarp",
            &[
                "-q",
                "-overwrite",
                "-t_srs",
                "EPSG:3857",
                "-te",
                &bs[0],
                &bs[1],
                &bs[2],
                &bs[3],
                "-ts",
                "256",
                "256",
                "-r",
                "bilinear",
                "-ot",
                "Float32",
                &s(dem),
                &s(&reference),
            ],
        );
        let (w, h, vals, nodata) = gdal_values(&reference);
        assert_eq!((w, h), (256, 256));
        let px = read_png(&tree.join(format!("{z}/{x}/{y}.png")));
        for (k, &v) in vals.iter().enumerate() {
            let valid_ref = !(v.is_nan() || nodata.is_some_and(|n| v == n));
            let p = &px[4 * k..4 * k + 4];
            let valid_tile = p[3] == 255;
            if valid_ref != valid_tile {
                mismatched += 1;
                continue;
            }
            if valid_ref {
                worst = worst.max((decode(encoding, p) - v).abs());
                compared += 1;
            }
        }
        let _ = std::fs::remove_file(&reference);
    }
    (worst, compared, mismatched)
}

#[test]
fn tiles_decode_to_gdalwarp_heights_within_a_decimetre() {
    let dir = tempfile::tempdir().expect("tempdir");
    // UTM DEM with nodata: reprojection, nodata and partial tiles.
    let dem = fixture("zion_srtm_utm12n.tif");
    for encoding in ["terrain-rgb", "terrarium"] {
        let tree = dir.path().join(encoding);
        ok(&demsketch(&[
            "export",
            "tiles",
            &s(&dem),
            "--encoding",
            encoding,
            "--zoom",
            "9-12",
            "--out",
            &s(&tree),
        ]));
        let tiles = tiles_in(&tree);
        assert!(tiles.len() >= 20, "{} tiles", tiles.len());
        assert!(tiles.iter().any(|t| t.0 == 9) && tiles.iter().any(|t| t.0 == 12));
        let (worst, compared, mismatched) =
            compare_with_gdalwarp(&dem, &tree, encoding, dir.path());
        eprintln!("{encoding}: {} tiles, {compared} pixels, worst {worst:.4} m, {mismatched} validity mismatches", tiles.len());
        assert!(compared > 100_000, "{compared} pixels compared");
        assert!(worst <= 0.1, "{encoding}: worst difference {worst} m");
        assert_eq!(
            mismatched, 0,
            "{encoding}: nodata where gdalwarp has heights or the reverse"
        );
        let tj: Value =
            serde_json::from_slice(&std::fs::read(tree.join("tiles.json")).expect("tiles.json"))
                .expect("TileJSON");
        assert_eq!(tj["minzoom"], 9);
        assert_eq!(tj["maxzoom"], 12);
        assert_eq!(
            tj["encoding"],
            if encoding == "terrarium" {
                "terrarium"
            } else {
                "mapbox"
            }
        );
    }
    // Nothing left behind beside the trees.
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .expect("dir")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        !names.iter().any(|n| n.contains(".demsketch-")),
        "{names:?}"
    );
}

/// One edit of the Zion fixture (the sketch of tests/cli_outputs.rs), with
/// its report and dz raster.
struct Edited {
    dir: tempfile::TempDir,
    dem: PathBuf,
    fixed: PathBuf,
    report: PathBuf,
    dz: PathBuf,
}

fn edit_zion() -> Edited {
    edit_fixture(
        "zion_srtm_utm12n.tif",
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/sketches/zion_dome.json"),
    )
}

/// The fixture `dem` edited with `sketch` (written whatever its fit), with
/// its report and dz raster, in a temporary directory.
fn edit_fixture(dem: &str, sketch: &Path) -> Edited {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture(dem);
    let fixed = dir.path().join("fixed.tif");
    let report = dir.path().join("report.json");
    let dz = dir.path().join("dz.tif");
    ok(&demsketch(&[
        "edit",
        &s(&dem),
        "--sketch",
        &s(sketch),
        "--out",
        &s(&fixed),
        "--report",
        &s(&report),
        "--dz",
        &s(&dz),
        "--allow-partial",
        "-q",
    ]));
    Edited {
        dir,
        dem,
        fixed,
        report,
        dz,
    }
}

#[test]
fn after_an_edit_changed_tiles_geojson_and_stac() {
    let e = edit_zion();
    let d = e.dir.path();
    // --changed: the tiles over the change, renamed into the old tree,
    // give exactly the tree of the edited DEM.
    let before = d.join("before");
    let after = d.join("after");
    let args = |dem: &Path, out: &Path| {
        vec![
            "export".to_string(),
            "tiles".into(),
            s(dem),
            "--encoding".into(),
            "terrarium".into(),
            "--zoom".into(),
            "8-12".into(),
            "--out".into(),
            s(out),
        ]
    };
    let run_args = |v: Vec<String>| {
        let r: Vec<&str> = v.iter().map(String::as_str).collect();
        demsketch(&r)
    };
    ok(&run_args(args(&e.dem, &before)));
    ok(&run_args(args(&e.fixed, &after)));
    let mut upd = args(&e.fixed, &before);
    upd.extend(["--changed".to_string(), s(&e.dz), "--json".into()]);
    let out = run_args(upd);
    ok(&out);
    let r: Value = serde_json::from_slice(&out.stdout).expect("--json");
    let rewritten = r["tiles_written"].as_u64().expect("tiles_written");
    let all = tiles_in(&after).len() as u64;
    assert!(
        rewritten > 0 && rewritten < all,
        "{rewritten} of {all} tiles rewritten"
    );
    // The tiles (tiles.json names the DEM it was made from).
    let png = |v: Vec<(PathBuf, Vec<u8>)>| -> Vec<(PathBuf, Vec<u8>)> {
        v.into_iter()
            .filter(|(p, _)| p.extension().is_some_and(|e| e == "png"))
            .map(|(p, b)| (p.components().rev().take(3).collect::<PathBuf>(), b))
            .collect()
    };
    let (a, b) = (png(snapshot(&after)), png(snapshot(&before)));
    let differing: Vec<_> = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x.1 != y.1)
        .map(|(x, _)| x.0.clone())
        .collect();
    assert_eq!(a.len(), b.len());
    assert!(
        differing.is_empty(),
        "tiles not updated by --changed: {differing:?}"
    );
    // The report's window also works (a superset of the dz cells).
    let via_report = d.join("via_report");
    let mut v = args(&e.fixed, &via_report);
    v.extend(["--changed".to_string(), s(&e.report), "--json".into()]);
    let out = run_args(v);
    ok(&out);
    let r2: Value = serde_json::from_slice(&out.stdout).expect("--json");
    assert!(r2["tiles_written"].as_u64().expect("n") >= rewritten);

    // GeoJSON: a LineString Z per placed stroke, and the footprint.
    let gj = d.join("edit.geojson");
    ok(&demsketch(&[
        "export",
        "geojson",
        &s(&e.fixed),
        "--report",
        &s(&e.report),
        "--dz",
        &s(&e.dz),
        "--out",
        &s(&gj),
        "-q",
    ]));
    let fc: Value = serde_json::from_slice(&std::fs::read(&gj).expect("geojson")).expect("JSON");
    let feats = fc["features"].as_array().expect("features");
    let curves: Vec<&Value> = feats
        .iter()
        .filter(|f| f["properties"]["kind"] == "placed_curve")
        .collect();
    let report: Value =
        serde_json::from_slice(&std::fs::read(&e.report).expect("report")).expect("JSON");
    let strokes = report["views"][0]["strokes"]
        .as_array()
        .expect("strokes")
        .len();
    assert_eq!(curves.len(), strokes, "one curve per stroke");
    let bounds = &gdalinfo(&e.dem)["wgs84Extent"]["coordinates"][0];
    let (mut w, mut so, mut ea, mut n) = (180.0f64, 90.0f64, -180.0f64, -90.0f64);
    for c in bounds.as_array().expect("ring") {
        let (x, y) = (c[0].as_f64().expect("x"), c[1].as_f64().expect("y"));
        (w, so, ea, n) = (w.min(x), so.min(y), ea.max(x), n.max(y));
    }
    for c in &curves {
        let coords = c["geometry"]["coordinates"].as_array().expect("coords");
        assert!(coords.len() >= 2);
        for p in coords {
            let (x, y, z) = (
                p[0].as_f64().unwrap(),
                p[1].as_f64().unwrap(),
                p[2].as_f64().unwrap(),
            );
            assert!(
                x > w - 0.01 && x < ea + 0.01 && y > so - 0.01 && y < n + 0.01,
                "{p} on the DEM"
            );
            assert!((1000.0..3500.0).contains(&z), "height {z} of Zion");
        }
    }
    let fp: Vec<&Value> = feats
        .iter()
        .filter(|f| f["properties"]["kind"] == "change_footprint")
        .collect();
    assert_eq!(fp.len(), 1);
    assert_eq!(fp[0]["geometry"]["type"], "MultiPolygon");
    // The footprint's cells are the dz cells that changed.
    let (_, _, vz, nd) = gdal_values(&e.dz);
    let changed = vz.iter().filter(|&&v| Some(v) != nd && v != 0.0).count();
    assert_eq!(
        fp[0]["properties"]["changed_cells"].as_u64(),
        Some(changed as u64)
    );
    // GDAL reads the file as a vector layer with the features.
    let info = run("ogrinfo", &["-ro", "-al", "-so", &s(&gj)]);
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        text.contains(&format!("Feature Count: {}", strokes + 1)),
        "{text}"
    );

    // STAC: of a COG of the edited DEM, with the report.
    let cog = d.join("fixed_cog.tif");
    ok(&demsketch(&[
        "export",
        "cog",
        &s(&e.fixed),
        "--out",
        &s(&cog),
        "-q",
    ]));
    let item = d.join("item.json");
    ok(&demsketch(&[
        "export",
        "stac",
        &s(&cog),
        "--report",
        &s(&e.report),
        "--out",
        &s(&item),
        "-q",
    ]));
    let v: Value = serde_json::from_slice(&std::fs::read(&item).expect("item")).expect("JSON");
    assert_eq!(v["properties"]["proj:epsg"], 32612);
    assert_eq!(v["properties"]["proj:shape"], serde_json::json!([515, 422]));
    assert_eq!(v["assets"]["dem"]["href"], "./fixed_cog.tif");
    assert_eq!(
        v["assets"]["dem"]["type"],
        "image/tiff; application=geotiff; profile=cloud-optimized"
    );
    assert_eq!(v["assets"]["dem"]["raster:bands"][0]["data_type"], "uint16");
    assert_eq!(v["assets"]["dem"]["raster:bands"][0]["nodata"], 65535.0);
    let prov = v["properties"]["demsketch:provenance"]
        .as_array()
        .expect("provenance");
    assert!(!prov.is_empty(), "the edit's provenance entry: {v}");
    assert!(prov[0]["sketch_sha256"]
        .as_str()
        .is_some_and(|h| h.len() == 64));
    assert_eq!(
        v["properties"]["demsketch:edit"]["changed_cells"],
        report["changed_cells"]
    );
    validate_stac(&item);
}

/// The item passes the core Item schema and the raster, projection and
/// processing extension schemas (offline, shipped as test data).
fn validate_stac(item: &Path) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let py = root.join(".venv/bin/python");
    assert!(
        py.exists(),
        "{} is missing: run bash tools/setup.sh (it creates the venv with jsonschema)",
        py.display()
    );
    let out = Command::new(&py)
        .arg(root.join("tools/validate_stac.py"))
        .arg(item)
        .arg(root.join("fixtures/stac_schemas"))
        .output()
        .expect("run the validator");
    assert!(
        out.status.success(),
        "STAC validation: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// GDAL's COG validator (python3-gdal's samples), where installed.
/// On a DEM in degrees (the Texas fixture, EPSG:4326) the GeoJSON's change
/// footprint is in longitude, latitude order like its placed curves (RFC
/// 7946): GDAL 3 reads EPSG:4326 latitude first unless told otherwise, and
/// the footprint used to come out swapped (latitude 32.7 as x). Its box is
/// the box of the dz raster's changed cells, read with GDAL.
#[test]
fn geojson_of_an_edit_in_degrees_is_lon_lat() {
    let e = edit_fixture(
        "texas_srtm90m_tiled_int16.tif",
        &Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/holdout1_texas_peak_raised_dense.json"),
    );
    let (fixed, report, dz) = (&e.fixed, &e.report, &e.dz);
    let gj = e.dir.path().join("edit.geojson");
    ok(&demsketch(&[
        "export",
        "geojson",
        &s(fixed),
        "--report",
        &s(report),
        "--dz",
        &s(dz),
        "--out",
        &s(&gj),
        "-q",
    ]));
    let fc: Value = serde_json::from_slice(&std::fs::read(&gj).expect("geojson")).expect("JSON");
    let fp = fc["features"]
        .as_array()
        .expect("features")
        .iter()
        .find(|f| f["properties"]["kind"] == "change_footprint")
        .expect("a footprint");
    let (mut w, mut so, mut ea, mut n) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for poly in fp["geometry"]["coordinates"].as_array().expect("polygons") {
        for ring in poly.as_array().expect("rings") {
            for c in ring.as_array().expect("ring") {
                let (x, y) = (c[0].as_f64().expect("x"), c[1].as_f64().expect("y"));
                (w, so, ea, n) = (w.min(x), so.min(y), ea.max(x), n.max(y));
            }
        }
    }
    // The changed cells' box from the dz raster (cell edges, degrees).
    let info = gdalinfo(dz);
    let gt: Vec<f64> = info["geoTransform"]
        .as_array()
        .expect("geotransform")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect();
    let (width, _, v, nd) = gdal_values(dz);
    let (mut cw, mut cs, mut ce, mut cn) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for (k, &z) in v.iter().enumerate() {
        if Some(z) == nd || z == 0.0 {
            continue;
        }
        let (i, j) = ((k % width) as f64, (k / width) as f64);
        cw = cw.min(gt[0] + i * gt[1]);
        ce = ce.max(gt[0] + (i + 1.0) * gt[1]);
        cn = cn.max(gt[3] + j * gt[5]);
        cs = cs.min(gt[3] + (j + 1.0) * gt[5]);
    }
    assert!(cw < ce, "the edit changed cells");
    for (got, want, what) in [
        (w, cw, "west"),
        (ea, ce, "east"),
        (so, cs, "south"),
        (n, cn, "north"),
    ] {
        assert!(
            (got - want).abs() < 1e-6,
            "footprint {what} {got} against the changed cells' {want}"
        );
    }
}

fn cog_validator() -> Option<PathBuf> {
    [
        "/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_cloud_optimized_geotiff.py",
        "/usr/share/doc/python3-gdal/examples/validate_cloud_optimized_geotiff.py",
    ]
    .iter()
    .map(PathBuf::from)
    .find(|p| p.exists())
}

#[test]
fn cog_passes_gdal_validation() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (name, extra) in [
        ("nz_1km_nan_nodata.tif", vec![]),
        (
            "zion_srtm_utm12n.tif",
            vec!["-co", "COMPRESS=ZSTD", "-co", "BLOCKSIZE=256"],
        ),
    ] {
        let src = fixture(name);
        let out = dir.path().join(format!("{name}.cog.tif"));
        let (a, b) = (s(&src), s(&out));
        let mut args = vec!["export", "cog", &a, "--out", &b, "-q"];
        args.extend(extra.iter().copied());
        ok(&demsketch(&args));
        let info = gdalinfo(&out);
        assert_eq!(
            info["metadata"]["IMAGE_STRUCTURE"]["LAYOUT"], "COG",
            "{name}"
        );
        let band = &info["bands"][0];
        assert!(
            band["overviews"].as_array().is_some_and(|o| !o.is_empty()),
            "{name}: overviews"
        );
        assert!(
            band["block"][0].as_u64() < info["size"][0].as_u64(),
            "{name}: tiled"
        );
        // Same heights as the source (GDAL's checksums).
        let sum = |p: &Path| {
            let o = run("gdalinfo", &["-checksum", "-json", &s(p)]);
            let v: Value = serde_json::from_slice(&o.stdout).expect("json");
            v["bands"][0]["checksum"].clone()
        };
        assert_eq!(sum(&src), sum(&out), "{name}: heights");
        match cog_validator() {
            Some(script) => {
                let o = Command::new("/usr/bin/python3")
                    .arg(&script)
                    .arg(&out)
                    .output()
                    .expect("run the COG validator");
                let text = String::from_utf8_lossy(&o.stdout);
                assert!(o.status.success() && text.contains("is a valid cloud optimized GeoTIFF"), "{name}: {text}{}", String::from_utf8_lossy(&o.stderr));
            }
            None => eprintln!("validate_cloud_optimized_geotiff.py not installed: layout checked with gdalinfo only"),
        }
    }
}

#[test]
fn gltf_loads_with_the_right_vertices_and_bounds() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("vinschgau_250m_utm32n.tif");
    let out = dir.path().join("vinschgau.glb");
    let o = demsketch(&[
        "export",
        "gltf",
        &s(&dem),
        "--bounds",
        "10.5,46.55,10.8,46.75",
        "--step",
        "2",
        "--out",
        &s(&out),
        "--json",
    ]);
    ok(&o);
    let r: Value = serde_json::from_slice(&o.stdout).expect("--json");
    let win: Vec<usize> = r["window"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    // The expected vertices: valid cells of the window, every second one.
    let (w, _, vals, nodata) = gdal_values(&dem);
    let mut expected = 0usize;
    let (mut hmin, mut hmax) = (f64::INFINITY, f64::NEG_INFINITY);
    for row in (win[1]..win[1] + win[3]).step_by(2) {
        for col in (win[0]..win[0] + win[2]).step_by(2) {
            let v = vals[row * w + col];
            if !(v.is_nan() || nodata.is_some_and(|n| v as f32 == n as f32)) {
                expected += 1;
                hmin = hmin.min(v);
                hmax = hmax.max(v);
            }
        }
    }
    let bytes = std::fs::read(&out).expect("glb");
    let gltf = gltf::Gltf::from_slice(&bytes).expect("a valid glTF 2.0 binary");
    let blob = gltf.blob.clone().expect("binary chunk");
    let mesh = gltf.meshes().next().expect("a mesh");
    let prim = mesh.primitives().next().expect("a primitive");
    let reader = prim.reader(|_| Some(&blob[..]));
    let positions: Vec<[f32; 3]> = reader.read_positions().expect("POSITION").collect();
    let normals: Vec<[f32; 3]> = reader.read_normals().expect("NORMAL").collect();
    let indices: Vec<u32> = reader.read_indices().expect("indices").into_u32().collect();
    assert_eq!(
        positions.len(),
        expected,
        "one vertex per valid sampled cell"
    );
    assert_eq!(normals.len(), expected);
    assert!(indices.len() % 3 == 0 && !indices.is_empty());
    assert!(indices.iter().all(|&i| (i as usize) < expected));
    // Accessor bounds are the positions' bounds.
    let acc = prim.get(&gltf::Semantic::Positions).expect("accessor");
    let (min, max) = (acc.min().expect("min"), acc.max().expect("max"));
    for d in 0..3 {
        let lo = positions.iter().map(|p| p[d]).fold(f32::INFINITY, f32::min);
        let hi = positions
            .iter()
            .map(|p| p[d])
            .fold(f32::NEG_INFINITY, f32::max);
        assert_eq!(min[d].as_f64().unwrap() as f32, lo);
        assert_eq!(max[d].as_f64().unwrap() as f32, hi);
    }
    // East-west and north-south extents: the window's size in metres
    // (250 m cells, UTM scale within 0.1 %), less a sampled cell.
    let ex = max[0].as_f64().unwrap() - min[0].as_f64().unwrap();
    let ez = max[2].as_f64().unwrap() - min[2].as_f64().unwrap();
    let (wx, wz) = (250.0 * (win[2] - 1) as f64, 250.0 * (win[3] - 1) as f64);
    assert!(
        (ex - wx).abs() < 0.01 * wx + 500.0,
        "east extent {ex} for {wx}"
    );
    assert!(
        (ez - wz).abs() < 0.01 * wz + 500.0,
        "north extent {ez} for {wz}"
    );
    // Up: the heights less the earth's curvature away from the origin
    // (under 15 km: under 20 m).
    let (ymin, ymax) = (min[1].as_f64().unwrap(), max[1].as_f64().unwrap());
    assert!(
        ymax <= hmax + 0.5 && ymax > hmax - 30.0,
        "top {ymax} for {hmax}"
    );
    assert!(
        ymin <= hmin + 0.5 && ymin > hmin - 30.0,
        "bottom {ymin} for {hmin}"
    );
    assert!(normals.iter().all(|n| n[1] > 0.0), "normals point up");
}

#[test]
fn bad_input_exits_1_in_one_line_and_writes_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let dem = s(&fixture("zion_srtm_utm12n.tif"));
    let not_report = d.join("not_report.json");
    std::fs::write(&not_report, "{\"type\": \"FeatureCollection\"}").expect("write");
    let a_file = d.join("a_file");
    std::fs::write(&a_file, "x").expect("write");
    let missing = s(&d.join("missing.tif"));
    let before = snapshot(d);
    let tiles = s(&d.join("tiles"));
    let nr = s(&not_report);
    let (c_tif, i_json, g_json, m_glb) = (
        s(&d.join("c.tif")),
        s(&d.join("i.json")),
        s(&d.join("g.geojson")),
        s(&d.join("m.glb")),
    );
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "export",
                "tiles",
                &missing,
                "--encoding",
                "terrarium",
                "--zoom",
                "8",
                "--out",
                &tiles,
            ],
            "missing.tif",
        ),
        (
            vec![
                "export",
                "tiles",
                &dem,
                "--encoding",
                "terrarium",
                "--zoom",
                "8",
                "--out",
                &tiles,
                "--changed",
                &nr,
            ],
            "not_report.json",
        ),
        (
            vec![
                "export",
                "tiles",
                &dem,
                "--encoding",
                "terrarium",
                "--zoom",
                "8-20",
                "--out",
                &tiles,
                "--max-tiles",
                "1000",
            ],
            "--max-tiles",
        ),
        (
            vec![
                "export",
                "tiles",
                &dem,
                "--encoding",
                "terrarium",
                "--zoom",
                "8",
                "--out",
                a_file.to_str().unwrap(),
            ],
            "a_file",
        ),
        (
            vec!["export", "cog", &dem, "--out", "/nonexistent-dir/x.tif"],
            "x.tif",
        ),
        (
            vec![
                "export",
                "cog",
                &dem,
                "--out",
                &c_tif,
                "-co",
                "NOT_AN_OPTION",
            ],
            "NOT_AN_OPTION",
        ),
        (
            vec!["export", "stac", &dem, "--report", &nr, "--out", &i_json],
            "not_report.json",
        ),
        (
            vec!["export", "geojson", &dem, "--report", &nr, "--out", &g_json],
            "not_report.json",
        ),
        (
            vec![
                "export", "gltf", &dem, "--bounds", "0,0,1,1", "--out", &m_glb,
            ],
            "does not overlap",
        ),
        (
            vec!["export", "gltf", &missing, "--out", &m_glb],
            "missing.tif",
        ),
    ];
    for (args, names) in cases {
        let out = demsketch(&args);
        one_line_error(&out, names);
        assert_eq!(snapshot(d), before, "{args:?} wrote something");
    }
    // A whole tree never goes into an existing directory, and --changed
    // never mixes encodings.
    let tree = d.join("tree");
    ok(&demsketch(&[
        "export",
        "tiles",
        &dem,
        "--encoding",
        "terrarium",
        "--zoom",
        "8",
        "--out",
        &s(&tree),
        "-q",
    ]));
    let t = s(&tree);
    let dz = d.join("dz.tif");
    common::gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &dz,
        &["-ot", "Float32", "-scale", "0", "65535", "1", "1"],
    );
    let before = snapshot(d);
    let dzs = s(&dz);
    for (args, names) in [
        (
            vec![
                "export",
                "tiles",
                &dem,
                "--encoding",
                "terrarium",
                "--zoom",
                "8",
                "--out",
                &t,
            ],
            "exists",
        ),
        (
            vec![
                "export",
                "tiles",
                &dem,
                "--encoding",
                "terrain-rgb",
                "--zoom",
                "8",
                "--out",
                &t,
                "--changed",
                &dzs,
            ],
            "tiles.json",
        ),
    ] {
        one_line_error(&demsketch(&args), names);
        assert_eq!(snapshot(d), before, "{args:?} wrote something");
    }
    // Flags clap refuses are user errors too (exit 1).
    for args in [
        vec![
            "export",
            "tiles",
            &dem,
            "--encoding",
            "jpeg",
            "--zoom",
            "8",
            "--out",
            &tiles,
        ],
        vec![
            "export",
            "tiles",
            &dem,
            "--encoding",
            "terrarium",
            "--zoom",
            "12-8",
            "--out",
            &tiles,
        ],
        vec!["export", "gltf", &dem, "--bounds", "1,2,3", "--out", &tiles],
    ] {
        assert_eq!(demsketch(&args).status.code(), Some(1), "{args:?}");
        assert_eq!(snapshot(d), before);
    }
}
