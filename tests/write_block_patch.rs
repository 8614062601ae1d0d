//! Write only what changed: an edit of a tiled (and a striped) compressed
//! GeoTIFF re-encodes only the blocks it touches; every other block keeps
//! its compressed bytes (found through GDAL's BLOCK_OFFSET/BLOCK_SIZE
//! items), and every pixel of the result, read by GDAL's Python bindings,
//! is the edited value or the input's.

mod common;

use std::path::Path;

use common::*;
use demsketch::raster::{Dem, Destination, Provenance, Window};
use gdal::Metadata;

/// (offset, size) of every block of band 1, row-major, from GDAL.
fn blocks(path: &Path) -> Vec<((usize, usize), u64, u64)> {
    let ds = gdal::Dataset::open(path).expect("open");
    let band = ds.rasterband(1).expect("band");
    let (bw, bh) = band.block_size();
    let (w, h) = band.size();
    let mut v = Vec::new();
    for by in 0..h.div_ceil(bh) {
        for bx in 0..w.div_ceil(bw) {
            let item = |k: &str| -> u64 {
                band.metadata_item(&format!("{k}_{bx}_{by}"), "TIFF")
                    .and_then(|s| s.parse().ok())
                    .expect("GDAL names the block's offset and size")
            };
            v.push(((bx, by), item("BLOCK_OFFSET"), item("BLOCK_SIZE")));
        }
    }
    v
}

/// Every pixel of `path` read with osgeo (GDAL's Python bindings), as text
/// lines of float32 bit patterns, row-major.
fn osgeo_bits(path: &Path) -> Vec<u32> {
    let out = std::process::Command::new("/usr/bin/python3")
        .args([
            "-c",
            "import sys\nfrom osgeo import gdal\nimport numpy as np\nds = gdal.Open(sys.argv[1])\na = ds.GetRasterBand(1).ReadAsArray().astype(np.float32)\nsys.stdout.buffer.write(a.tobytes())",
            &path.to_string_lossy(),
        ])
        .output()
        .expect("run python3 with osgeo");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
        .chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn check(src: &Path, out: &Path, win: Window, dest: &Destination) {
    let before_blocks = blocks(src);
    let before_bytes = std::fs::read(src).expect("read input");
    let before_px = osgeo_bits(src);
    let dem = Dem::open(src).expect("open");
    let (w, h) = (dem.width, dem.height);
    let old = dem.read_window::<f64>(win).expect("read");
    let new: Vec<f64> = old.data.iter().map(|v| v + 7.0).collect();
    let report = dem
        .write_back(
            win,
            &new,
            dest,
            &Provenance {
                edit_id: "patch".into(),
            },
        )
        .expect("write back");
    drop(dem);
    assert!(report.changed_cells > 0);
    let after_blocks = blocks(out);
    let after_bytes = std::fs::read(out).expect("read output");
    let layout = {
        let ds = gdal::Dataset::open(out).expect("open");
        ds.rasterband(1).expect("band").block_size()
    };
    let (bw, bh) = layout;
    let (mut kept, mut rewritten) = (0, 0);
    for (&((bx, by), o0, n0), &(_, o1, n1)) in before_blocks.iter().zip(&after_blocks) {
        let (x0, x1) = ((bx * bw) as i64, ((bx + 1) * bw) as i64);
        let (y0, y1) = ((by * bh) as i64, ((by + 1) * bh) as i64);
        let touches = x0 < win.col_end() && x1 > win.col && y0 < win.row_end() && y1 > win.row;
        let a = &before_bytes[o0 as usize..(o0 + n0) as usize];
        let b = &after_bytes[o1 as usize..(o1 + n1) as usize];
        if touches {
            assert_ne!(a, b, "block ({bx}, {by}) over the edit re-encoded");
            rewritten += 1;
        } else {
            assert_eq!(
                a, b,
                "block ({bx}, {by}) away from the edit keeps its compressed bytes"
            );
            kept += 1;
        }
    }
    assert!(
        kept > rewritten && rewritten > 0,
        "{kept} kept, {rewritten} rewritten"
    );
    // Every pixel, as GDAL's Python bindings read it.
    let after_px = osgeo_bits(out);
    assert_eq!(after_px.len(), w * h);
    for r in 0..h {
        for c in 0..w {
            let i = r * w + c;
            let (cc, rr) = (c as i64, r as i64);
            let inside = cc >= win.col && cc < win.col_end() && rr >= win.row && rr < win.row_end();
            let want = if inside {
                let wi = (rr - win.row) as usize * win.width + (cc - win.col) as usize;
                if old.valid[wi] {
                    (new[wi] as f32).to_bits()
                } else {
                    before_px[i]
                }
            } else {
                before_px[i]
            };
            assert_eq!(after_px[i], want, "pixel ({c}, {r})");
        }
    }
    // Layout and encoding as before.
    let (a, b) = (gdalinfo(src), gdalinfo(out));
    assert_eq!(a["bands"][0]["block"], b["bands"][0]["block"]);
    assert_eq!(
        a["metadata"]["IMAGE_STRUCTURE"],
        b["metadata"]["IMAGE_STRUCTURE"]
    );
}

#[test]
fn tiled_deflate_geotiff_rewrites_only_the_touched_tiles() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("tiled.tif");
    gdal_translate(
        &fixture("nz_1km_nan_nodata.tif"),
        &src,
        &[
            "-co",
            "TILED=YES",
            "-co",
            "BLOCKXSIZE=128",
            "-co",
            "BLOCKYSIZE=128",
            "-co",
            "COMPRESS=DEFLATE",
            "-co",
            "PREDICTOR=3",
        ],
    );
    let out = dir.path().join("out.tif");
    let win = Window::new(600, 700, 150, 40);
    check(&src, &out, win, &Destination::Path(out.clone()));
}

#[test]
fn striped_lzw_geotiff_in_place_rewrites_only_the_touched_strips() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("striped.tif");
    gdal_translate(
        &fixture("vinschgau_250m_utm32n.tif"),
        &src,
        &[
            "-co",
            "COMPRESS=LZW",
            "-co",
            "PREDICTOR=2",
            "-co",
            "BLOCKYSIZE=8",
        ],
    );
    // In place: `check` reads the input before the write.
    let win = Window::new(100, 100, 50, 20);
    check(&src, &src, win, &Destination::InPlace);
}

#[test]
fn bigtiff_stays_bigtiff() {
    let dir = tempfile::tempdir().expect("tempdir");
    let src = dir.path().join("big.tif");
    gdal_translate(
        &fixture("zion_srtm_utm12n.tif"),
        &src,
        &[
            "-co",
            "BIGTIFF=YES",
            "-co",
            "TILED=YES",
            "-co",
            "COMPRESS=ZSTD",
        ],
    );
    let out = dir.path().join("out.tif");
    let dem = Dem::open(&src).expect("open");
    let win = Window::new(10, 10, 20, 20);
    let old = dem.read_window::<f64>(win).expect("read");
    let new: Vec<f64> = old.data.iter().map(|v| v + 3.0).collect();
    dem.write_back(
        win,
        &new,
        &Destination::Path(out.clone()),
        &Provenance {
            edit_id: "big".into(),
        },
    )
    .expect("write");
    let head = std::fs::read(&out).expect("read")[..4].to_vec();
    assert!(
        head == b"II+\0" || head == b"MM\0+",
        "BigTIFF kept: {head:?}"
    );
}
