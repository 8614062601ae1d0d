//! The tile pyramid of a batch's output (issue 15, item 5): a tile
//! directory with `gdal_retile.py -levels` subdirectories `1`, `2`, ...
//! ([`crate::raster::pyramid`]). The level tiles are shared by every group
//! (one level tile lies over the base tiles of several), so the edits of a
//! batch leave them as they are (`WriteOptions::defer_pyramid`) and the
//! batch's final step, once every edit is recorded done, recomputes them
//! over the union of the areas the edits changed, once per batch, with the
//! code `demsketch edit --in-place` refreshes them with
//! ([`Pyramid::refresh_areas`]).
//!
//! A level tile's cells are a function of the base alone, so the levels
//! hold the cells refreshing after every edit would give (what
//! `gdal_retile.py -levels` makes from the edited base); the level tiles
//! away from every change keep their bytes. (Their bytes are not those of
//! refreshing after every edit: a tile refreshed once records one
//! provenance entry, the batch's, where edits one by one record one per
//! edit.)
//!
//! Crash safety: each level tile is written by the in-place write-back
//! (staged, verified, journalled rename in its level directory). The step
//! is idempotent: a tile already up to date is not written again, so a
//! batch killed while refreshing resumes by running the step again (after
//! finishing the level directories' interrupted journals), which ends with
//! the same bytes. Once it completes, `STATE/pyramid.done.json` records it
//! and a later finish does not recompute it.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::plan::{tile_name, Plan};
use super::record::{read_json, state_dir, write_json, Done, Status};
use super::BatchError;
use crate::raster::provenance::sha256_hex;
use crate::raster::pyramid::Pyramid;
use crate::raster::{atomic_file, journal, Dem, LayerKind, Provenance, Window};

/// The record of the pyramid step in the state directory.
pub const PYRAMID_RECORD: &str = "pyramid.done.json";

/// What the pyramid step did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PyramidDone {
    /// Levels of the pyramid.
    pub levels: usize,
    /// The resampling (`--pyramid-resampling`).
    pub resampling: String,
    /// Changed areas refreshed over (one per edit that wrote cells).
    pub areas: usize,
    /// Level tiles rewritten, as `LEVEL/NAME`, in the order written.
    pub tiles_written: Vec<String>,
}

/// The provenance entry of the level tiles a batch refreshes: the
/// manifest's name and a digest of its edits' sketches, the same for every
/// way the batch runs (whole, array job, Dask).
fn provenance(plan: &Plan) -> Provenance {
    let sketches: Vec<&str> = plan
        .edits
        .iter()
        .map(|e| e.sketch_sha256.as_str())
        .collect();
    Provenance {
        edit_id: format!(
            "batch {}:{} edits:{}",
            tile_name(&plan.manifest),
            plan.edits.len(),
            &sha256_hex(sketches.join(",").as_bytes())[..16]
        ),
    }
}

/// The CRS bounds of what each edit of `records` changed: per edit that
/// wrote cells, the union of its written tiles within its window (for an
/// edit recovered on resume, which recorded neither, its planned tiles
/// within its footprint).
fn changed_areas(plan: &Plan, dem: &Dem, records: &[Done]) -> Vec<[f64; 4]> {
    let by_name: std::collections::HashMap<String, usize> = dem
        .tiles
        .iter()
        .enumerate()
        .map(|(i, t)| (tile_name(&t.path), i))
        .collect();
    let mut areas = Vec::new();
    for d in records {
        let Some(e) = plan.edits.get(d.index) else {
            continue;
        };
        let (window, tiles) = match d.status {
            Status::Written if !d.tiles_written.is_empty() => (
                d.window.map_or(e.footprint_window(), |w| {
                    Window::new(w[0], w[1], w[2].max(0) as usize, w[3].max(0) as usize)
                }),
                &d.tiles_written,
            ),
            Status::Recovered => (e.footprint_window(), &e.tiles),
            _ => continue,
        };
        let windows: Vec<Window> = tiles
            .iter()
            .filter_map(|n| by_name.get(n))
            .filter_map(|&i| dem.tiles[i].extent.intersect(&window))
            .collect();
        if windows.is_empty() {
            continue;
        }
        areas.push(dem.windows_bounds(windows));
    }
    areas
}

/// The pyramid step of a batch whose every edit is recorded done
/// (`records`, in manifest order): `None` when the output has no pyramid.
/// Call with the output's edit lock held exclusively; each recovery note
/// goes to `note`.
pub fn refresh(
    plan: &Plan,
    records: &[Done],
    note: &mut dyn FnMut(&str),
) -> Result<Option<PyramidDone>, BatchError> {
    if !plan.out.is_dir() {
        return Ok(None);
    }
    let record = state_dir(&plan.out).join(PYRAMID_RECORD);
    if let Some(done) = read_json::<PyramidDone>(&record)? {
        return Ok(Some(done));
    }
    // A refresh cut short: its level tiles' journals first.
    for k in 1.. {
        let dir = plan.out.join(k.to_string());
        if !dir.is_dir() {
            break;
        }
        for n in journal::recover(&plan.out, &dir)? {
            note(&n);
        }
        for n in atomic_file::clean_stale(&dir) {
            note(&n);
        }
    }
    let Some(pyramid) = Pyramid::discover(&plan.out)? else {
        return Ok(None);
    };
    let dem = Dem::open(&plan.out)?;
    if dem.kind != LayerKind::TileDirectory {
        return Ok(None);
    }
    let areas = changed_areas(plan, &dem, records);
    let resampling = plan
        .settings
        .pyramid_resampling
        .clone()
        .unwrap_or_else(|| "near".into());
    let written = pyramid.refresh_areas(&areas, &resampling, &provenance(plan))?;
    let rel = |p: &Path| {
        p.strip_prefix(&plan.out)
            .unwrap_or(p)
            .to_string_lossy()
            .into_owned()
    };
    let done = PyramidDone {
        levels: pyramid.levels(),
        resampling,
        areas: areas.len(),
        tiles_written: written.iter().map(|p| rel(p)).collect(),
    };
    write_json(&record, &done)?;
    Ok(Some(done))
}

/// The pyramid of the DEM a batch starts from, checked before anything is
/// written (every level tile one demsketch writes back in place): `None`
/// when it has none.
pub fn check(dem_path: &Path, dem: &Dem) -> Result<Option<Pyramid>, BatchError> {
    match dem.kind {
        LayerKind::TileDirectory => Ok(Pyramid::discover(dem_path)?),
        _ => Ok(None),
    }
}
