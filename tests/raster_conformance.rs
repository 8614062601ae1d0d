//! The native GeoTIFF reader and `demsketch info` against GDAL: every
//! fixture, and variants made here with `gdal_translate` in the encodings
//! real DEM products use, must agree with `gdalinfo -json` on size,
//! geotransform, EPSG code and nodata, and decode to GDAL's exact values.

mod common;

use std::path::Path;

use common::*;
use demsketch::raster::{Dem, SampleType};

fn check_against_gdal(path: &Path) {
    let g = gdalinfo(path);
    let out = demsketch(&["info", "--json", &path.to_string_lossy()]);
    assert!(
        out.status.success(),
        "info failed on {}: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let a: serde_json::Value = serde_json::from_slice(&out.stdout).expect("info --json is JSON");
    let name = path.display();
    assert_eq!(a["width"], g["size"][0], "{name}: width");
    assert_eq!(a["height"], g["size"][1], "{name}: height");
    for i in 0..6 {
        let (x, y) = (
            a["geotransform"][i].as_f64().expect("number"),
            g["geoTransform"][i].as_f64().expect("number"),
        );
        assert!(
            (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1e-300),
            "{name}: geotransform[{i}] {x} vs GDAL {y}"
        );
    }
    let gdal_epsg = g["stac"]["proj:epsg"].as_u64();
    assert_eq!(a["epsg"].as_u64(), gdal_epsg, "{name}: EPSG");
    let gnd = &g["bands"][0]["noDataValue"];
    match (&a["nodata"], gnd) {
        (serde_json::Value::Null, serde_json::Value::Null) => {}
        (serde_json::Value::String(s), serde_json::Value::String(t)) => {
            assert_eq!(s.to_lowercase(), t.to_lowercase(), "{name}: nodata")
        }
        (x, y) => assert_eq!(x.as_f64(), y.as_f64(), "{name}: nodata"),
    }
    assert_eq!(
        a["sample_type"].as_str(),
        g["bands"][0]["type"].as_str(),
        "{name}: sample type"
    );

    // Values: exactly GDAL's, nodata where GDAL has the nodata value.
    let (w, h, gv, gnodata) = gdal_values(path);
    let dem = Dem::open(path).expect("open");
    let ours = dem.read_window::<f64>(dem.full_window()).expect("read");
    assert_eq!(ours.data.len(), w * h);
    let nd = gnodata.map(|n| dem.sample_type.quantize(n));
    let mut mismatches = 0;
    for (i, &g) in gv.iter().enumerate().take(w * h) {
        let gdal_nodata = g.is_nan() || nd.is_some_and(|n| g == n);
        if gdal_nodata {
            if ours.valid[i] {
                mismatches += 1;
            }
        } else if !ours.valid[i] || ours.data[i].to_bits() != g.to_bits() {
            mismatches += 1;
        }
    }
    assert_eq!(
        mismatches, 0,
        "{name}: {mismatches} values differ from GDAL"
    );
}

#[test]
fn fixtures_agree_with_gdal() {
    for f in FIXTURES {
        check_against_gdal(&fixture(f));
    }
}

#[test]
fn encoding_variants_agree_with_gdal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let zion = fixture("zion_srtm_utm12n.tif");
    let nz = fixture("nz_1km_nan_nodata.tif");
    let variants: &[(&str, &Path, &[&str])] = &[
        (
            "deflate_pred3_f32.tif",
            &zion,
            &[
                "-ot",
                "Float32",
                "-co",
                "TILED=YES",
                "-co",
                "COMPRESS=DEFLATE",
                "-co",
                "PREDICTOR=3",
            ],
        ),
        (
            "zstd.tif",
            &zion,
            &["-co", "TILED=YES", "-co", "COMPRESS=ZSTD"],
        ),
        (
            "zstd_pred3_f64.tif",
            &nz,
            &[
                "-ot",
                "Float64",
                "-co",
                "COMPRESS=ZSTD",
                "-co",
                "PREDICTOR=3",
            ],
        ),
        (
            "lzw_pred2_i16.tif",
            &zion,
            &["-ot", "Int16", "-co", "COMPRESS=LZW", "-co", "PREDICTOR=2"],
        ),
        ("pixel_is_point.tif", &zion, &["-mo", "AREA_OR_POINT=Point"]),
        (
            "cog.tif",
            &nz,
            &[
                "-of",
                "COG",
                "-co",
                "BLOCKSIZE=256",
                "-co",
                "COMPRESS=DEFLATE",
                "-co",
                "PREDICTOR=YES",
            ],
        ),
        (
            "packbits_i32.tif",
            &zion,
            &["-ot", "Int32", "-co", "COMPRESS=PACKBITS"],
        ),
        (
            "u32_tiled.tif",
            &zion,
            &[
                "-ot",
                "UInt32",
                "-co",
                "TILED=YES",
                "-co",
                "BLOCKXSIZE=32",
                "-co",
                "BLOCKYSIZE=48",
            ],
        ),
        (
            "f64_deflate_pred2.tif",
            &zion,
            &[
                "-ot",
                "Float64",
                "-co",
                "COMPRESS=DEFLATE",
                "-co",
                "PREDICTOR=2",
            ],
        ),
        (
            "byte.tif",
            &fixture("texas_srtm90m_tiled_int16.tif"),
            &[
                "-ot",
                "Byte",
                "-scale",
                "140",
                "300",
                "0",
                "254",
                "-a_nodata",
                "255",
            ],
        ),
        (
            "geographic_deflate.tif",
            &fixture("arenal_aster30m_epsg4326.tif"),
            &[
                "-co",
                "COMPRESS=DEFLATE",
                "-co",
                "TILED=YES",
                "-co",
                "BLOCKXSIZE=64",
                "-co",
                "BLOCKYSIZE=64",
            ],
        ),
    ];
    for (name, src, extra) in variants {
        let dst = dir.path().join(name);
        gdal_translate(src, &dst, extra);
        check_against_gdal(&dst);
    }
    // The COG's overviews are recognised, and not mistaken for the image.
    let dem = Dem::open(&dir.path().join("cog.tif")).expect("open COG");
    match &dem.tiles[0].source {
        demsketch::raster::TileSource::Tiff(t) => {
            assert!(!t.overviews().is_empty(), "COG overviews found")
        }
        _ => panic!("COG read natively"),
    }
    assert_eq!(dem.sample_type, SampleType::Float32);
}

#[test]
fn pixel_is_point_shifts_half_a_pixel_like_gdal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dst = dir.path().join("point.tif");
    let src = fixture("vinschgau_250m_utm32n.tif");
    gdal_translate(&src, &dst, &["-mo", "AREA_OR_POINT=Point"]);
    let a = Dem::open(&src).expect("open").geotransform;
    let b = Dem::open(&dst).expect("open").geotransform;
    // GDAL keeps the corner where it was: both files describe the same grid.
    assert_eq!(a, b);
}

#[test]
fn vrt_reads_through_gdal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let vrt = dir.path().join("zion.vrt");
    let src = fixture("zion_srtm_utm12n.tif");
    run(
        "gdalbuildvrt",
        &["-q", &vrt.to_string_lossy(), &src.to_string_lossy()],
    );
    let a = Dem::open(&vrt).expect("open VRT");
    let b = Dem::open(&src).expect("open TIFF");
    assert_eq!(a.kind, demsketch::raster::LayerKind::Gdal);
    let wa = a.read_window::<f64>(a.full_window()).expect("read VRT");
    let wb = b.read_window::<f64>(b.full_window()).expect("read TIFF");
    assert_eq!(wa.valid, wb.valid);
    for i in 0..wa.data.len() {
        if wa.valid[i] {
            assert_eq!(wa.data[i], wb.data[i]);
        }
    }
}
