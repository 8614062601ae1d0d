//! `export tiles`: a tree of XYZ web-map tiles of heights, `OUT/z/x/y.png`,
//! in Terrain-RGB or Terrarium ([`super::tile_encoding`]), for a range of
//! zooms, over the whole DEM or only over what an edit changed
//! ([`super::change_mask`]). Each tile is the DEM warped by GDAL into the
//! tile's grid ([`super::tile_warp`]), the tiles in parallel on rayon (one
//! GDAL handle per worker). Tiles with no valid height are not written (a
//! missing tile is "no data" to web maps).
//!
//! Written atomically: a new tree is built in a staging directory beside
//! `OUT` and renamed into place whole, with a TileJSON `tiles.json`
//! (bounds, zooms, the encoding as MapLibre names it); an update of an
//! existing tree (`--changed`) stages its tiles inside `OUT` and renames
//! each over the old one, so every tile is either the old or the new one.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use super::change_mask::ChangeMask;
use super::gdal_source::GdalSource;
use super::tile_encoding::{encode_png, Encoding};
use super::tile_warp::warp_tile;
use super::web_mercator::{lonlat_to_3857, pixel_span_m, tile_range, TileId, TILE_SIZE};
use super::ExportError;
use crate::raster::atomic_file::{
    commit_guard, parent_dir, sync_dir, write_bytes_verified, Staging,
};
use crate::raster::{lonlat_bounds, Dem};

/// What to export.
#[derive(Debug, Clone)]
pub struct TileOptions {
    pub encoding: Encoding,
    /// Inclusive zoom range.
    pub zooms: (u8, u8),
    /// Only the tiles over these cells (an edit's change).
    pub changed: Option<ChangeMask>,
    /// Refuse to start past this many tiles.
    pub max_tiles: usize,
    /// Show a progress bar on stderr.
    pub progress: bool,
}

/// What was written.
#[derive(Debug, Clone, Serialize)]
pub struct TilesReport {
    pub out: String,
    pub encoding: Encoding,
    pub zooms: [u8; 2],
    /// Tiles computed.
    pub tiles: usize,
    /// Tiles written (with at least one valid height).
    pub tiles_written: usize,
    /// Tiles with no valid height, not written.
    pub tiles_empty: usize,
    /// Only the tiles over an edit's change were computed.
    pub changed_only: bool,
    pub seconds: f64,
}

/// Export the tiles of `dem_path` into `out`; see the module documentation.
pub fn export_tiles(
    dem_path: &Path,
    out: &Path,
    opts: &TileOptions,
) -> Result<TilesReport, ExportError> {
    let t0 = Instant::now();
    let dem = Dem::open(dem_path)?;
    let tiles = match &opts.changed {
        Some(mask) => tiles_over_mask(mask, opts.zooms)?,
        None => tiles_over_dem(&dem, opts.zooms)?,
    };
    if tiles.len() > opts.max_tiles {
        return Err(ExportError::Input {
            path: dem_path.display().to_string(),
            message: format!(
                "zooms {}-{} make {} tiles, more than --max-tiles {} (lower the deepest zoom or raise --max-tiles)",
                opts.zooms.0, opts.zooms.1, tiles.len(), opts.max_tiles
            ),
        });
    }
    let target = TileTarget::prepare(out, opts)?;
    let src = GdalSource::new(&dem)?;
    drop(src.open()?);
    let pb = progress_bar(opts.progress, tiles.len() as u64);
    let vertical = dem.vertical.clone();
    let root = target.staging.path().to_path_buf();
    let results: Vec<Result<bool, ExportError>> = tiles
        .par_iter()
        .map_init(
            || src.open(),
            |ds, &tile| {
                let r = match ds {
                    Ok(ds) => write_tile(ds, tile, &vertical, opts.encoding, &root),
                    Err(e) => Err(ExportError::Internal(e.to_string())),
                };
                pb.inc(1);
                r
            },
        )
        .collect();
    pb.finish_and_clear();
    let mut written = Vec::new();
    for (tile, r) in tiles.iter().zip(results) {
        if r? {
            written.push(*tile);
        }
    }
    let report = TilesReport {
        out: out.display().to_string(),
        encoding: opts.encoding,
        zooms: [opts.zooms.0, opts.zooms.1],
        tiles: tiles.len(),
        tiles_written: written.len(),
        tiles_empty: tiles.len() - written.len(),
        changed_only: opts.changed.is_some(),
        seconds: 0.0,
    };
    target.commit(&written, &dem, opts)?;
    Ok(TilesReport {
        seconds: t0.elapsed().as_secs_f64(),
        ..report
    })
}

/// Warp, encode and write one tile under `root`; false when it has no
/// valid height (nothing written).
fn write_tile(
    ds: &gdal::Dataset,
    tile: TileId,
    vertical: &crate::raster::Vertical,
    encoding: Encoding,
    root: &Path,
) -> Result<bool, ExportError> {
    let heights = warp_tile(ds, tile, vertical).map_err(ExportError::Internal)?;
    if !heights.iter().any(|h| h.is_finite()) {
        return Ok(false);
    }
    let png = encode_png(&heights, TILE_SIZE, encoding).map_err(ExportError::Internal)?;
    let path = root.join(tile.relative_path());
    let werr = |e: std::io::Error| ExportError::Write {
        path: root.display().to_string(),
        message: e.to_string(),
    };
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(werr)?;
    }
    write_bytes_verified(&path, &png).map_err(werr)?;
    Ok(true)
}

/// The tiles of zooms `z0..=z1` that cover the DEM's lon/lat bounds.
pub fn tiles_over_dem(dem: &Dem, (z0, z1): (u8, u8)) -> Result<Vec<TileId>, ExportError> {
    let b = lonlat_bounds(&dem.crs, &dem.geotransform, dem.width, dem.height).ok_or_else(|| {
        ExportError::Input {
            path: dem.path.display().to_string(),
            message: "no CRS PROJ knows: cannot place it on the web map".into(),
        }
    })?;
    let (x0, y0) = lonlat_to_3857(b[0], b[1]);
    let (x1, y1) = lonlat_to_3857(b[2], b[3]);
    let mut tiles = Vec::new();
    for z in z0..=z1 {
        if let Some((tx0, tx1, ty0, ty1)) = tile_range(z, [x0, y0, x1, y1]) {
            for x in tx0..=tx1 {
                for y in ty0..=ty1 {
                    tiles.push(TileId { z, x, y });
                }
            }
        }
    }
    Ok(tiles)
}

/// The tiles of zooms `z0..=z1` whose heights the changed cells reach:
/// each run of changed cells grown by one cell (the bilinear kernel) and,
/// at each zoom, by one tile pixel (GDAL widens the kernel when a tile
/// pixel spans several cells).
pub fn tiles_over_mask(mask: &ChangeMask, (z0, z1): (u8, u8)) -> Result<Vec<TileId>, ExportError> {
    let boxes = run_boxes_3857(mask)?;
    let mut set = BTreeSet::new();
    for z in z0..=z1 {
        let pad = pixel_span_m(z) * 1.5;
        for b in &boxes {
            let g = [b[0] - pad, b[1] - pad, b[2] + pad, b[3] + pad];
            if let Some((tx0, tx1, ty0, ty1)) = tile_range(z, g) {
                for x in tx0..=tx1 {
                    for y in ty0..=ty1 {
                        set.insert(TileId { z, x, y });
                    }
                }
            }
        }
    }
    Ok(set.into_iter().collect())
}

/// EPSG:3857 boxes of the mask's runs, each grown by one cell.
fn run_boxes_3857(mask: &ChangeMask) -> Result<Vec<[f64; 4]>, ExportError> {
    let to_ll =
        proj::Proj::new_known_crs(&mask.crs.proj_definition(), "EPSG:4326", None).map_err(|e| {
            ExportError::Input {
                path: mask.source.clone(),
                message: format!("its CRS is unknown to PROJ: {e}"),
            }
        })?;
    let gt = &mask.geotransform;
    let mut boxes = Vec::new();
    for (row, c0, c1) in mask.runs() {
        let (px0, px1) = (c0 as f64 - 1.0, c1 as f64 + 1.0);
        let (py0, py1) = (row as f64 - 1.0, row as f64 + 2.0);
        let steps = ((px1 - px0) / 16.0).ceil().max(1.0) as usize;
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for i in 0..=steps {
            let px = px0 + (px1 - px0) * i as f64 / steps as f64;
            for py in [py0, py1] {
                let (x, y) = gt.pixel_to_crs(px, py);
                if let Ok((lon, lat)) = to_ll.convert((x, y)) {
                    let (mx, my) = lonlat_to_3857(lon, lat);
                    b = [b[0].min(mx), b[1].min(my), b[2].max(mx), b[3].max(my)];
                }
            }
        }
        if b.iter().all(|v| v.is_finite()) {
            boxes.push(b);
        }
    }
    Ok(boxes)
}

/// Where the tiles are written first, and how they reach `OUT`.
struct TileTarget {
    out: PathBuf,
    staging: Staging,
    /// `OUT` exists: tiles are renamed into it one by one.
    update: bool,
}

impl TileTarget {
    /// A new tree needs a new `OUT`; `--changed` may update an existing
    /// one, of the same encoding (its `tiles.json` says which).
    fn prepare(out: &Path, opts: &TileOptions) -> Result<TileTarget, ExportError> {
        let werr = |m: String| ExportError::Write {
            path: out.display().to_string(),
            message: m,
        };
        let update = match std::fs::metadata(out) {
            Ok(m) if m.is_dir() => true,
            Ok(_) => return Err(werr("exists and is not a directory".into())),
            Err(_) => false,
        };
        if update && opts.changed.is_none() {
            return Err(werr(
                "exists: a whole tree goes to a new directory (--changed updates an existing tree)"
                    .into(),
            ));
        }
        if update {
            check_tree_encoding(out, opts.encoding)?;
        }
        let parent = if update { out } else { parent_dir(out) };
        if !parent.is_dir() {
            return Err(werr("its parent directory does not exist".into()));
        }
        let staging = Staging::new_in(parent)
            .map_err(|e| werr(format!("cannot create a staging directory: {e}")))?;
        Ok(TileTarget {
            out: out.to_path_buf(),
            staging,
            update,
        })
    }

    /// Move the written tiles into place.
    fn commit(self, written: &[TileId], dem: &Dem, opts: &TileOptions) -> Result<(), ExportError> {
        let werr = |p: &Path, e: std::io::Error| ExportError::Write {
            path: p.display().to_string(),
            message: e.to_string(),
        };
        if self.update {
            let _commit = commit_guard();
            for t in written {
                let rel = t.relative_path();
                let to = self.out.join(&rel);
                if let Some(d) = to.parent() {
                    std::fs::create_dir_all(d).map_err(|e| werr(d, e))?;
                }
                std::fs::rename(self.staging.path().join(&rel), &to).map_err(|e| werr(&to, e))?;
            }
            return Ok(());
        }
        let tilejson = tilejson(dem, opts, written);
        write_bytes_verified(&self.staging.path().join("tiles.json"), tilejson.as_bytes())
            .map_err(|e| werr(&self.out, e))?;
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(self.staging.path(), std::fs::Permissions::from_mode(0o755))
            .map_err(|e| werr(&self.out, e))?;
        let _commit = commit_guard();
        let kept = self.staging.keep();
        if let Err(e) = std::fs::rename(&kept, &self.out) {
            let _ = std::fs::remove_dir_all(&kept);
            return Err(werr(&self.out, e));
        }
        let _ = sync_dir(parent_dir(&self.out));
        Ok(())
    }
}

/// An existing tree's `tiles.json`, if any, must name `encoding`.
fn check_tree_encoding(out: &Path, encoding: Encoding) -> Result<(), ExportError> {
    let tj = out.join("tiles.json");
    let Ok(text) = std::fs::read_to_string(&tj) else {
        return Ok(());
    };
    let v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
    match v["encoding"].as_str() {
        Some(e) if e != encoding.maplibre_name() => Err(ExportError::Input {
            path: tj.display().to_string(),
            message: format!(
                "the tree is encoded \"{e}\", not \"{}\" (--encoding)",
                encoding.maplibre_name()
            ),
        }),
        _ => Ok(()),
    }
}

/// A TileJSON 3.0.0 description of the tree (what MapLibre's `raster-dem`
/// source reads through `url`).
fn tilejson(dem: &Dem, opts: &TileOptions, written: &[TileId]) -> String {
    let bounds = lonlat_bounds(&dem.crs, &dem.geotransform, dem.width, dem.height)
        .unwrap_or([-180.0, -85.0511, 180.0, 85.0511]);
    let v = serde_json::json!({
        "tilejson": "3.0.0",
        "name": dem.path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default(),
        "description": format!("heights of {} as {} PNG tiles, written by demsketch export tiles", dem.path.display(), opts.encoding.maplibre_name()),
        "tiles": ["{z}/{x}/{y}.png"],
        "scheme": "xyz",
        "minzoom": opts.zooms.0,
        "maxzoom": opts.zooms.1,
        "bounds": bounds,
        "encoding": opts.encoding.maplibre_name(),
        "tileSize": TILE_SIZE,
        "tile_count": written.len(),
    });
    let mut s = serde_json::to_string_pretty(&v).unwrap_or_default();
    s.push('\n');
    s
}

/// Tiles done, with rate and ETA; hidden unless `on`.
fn progress_bar(on: bool, len: u64) -> indicatif::ProgressBar {
    use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
    let target = if on {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let pb = ProgressBar::with_draw_target(Some(len), target);
    if let Ok(style) =
        ProgressStyle::with_template("{bar:30} {pos}/{len} tiles [{elapsed}, {per_sec}, eta {eta}]")
    {
        pb.set_style(style);
    }
    pb
}
