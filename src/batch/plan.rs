//! The plan of a batch: every edit's footprint ([`super::footprint`]) and
//! the tiles under it, and the groups: edits whose footprints share a tile
//! are joined (transitively) into one group and applied in manifest order;
//! two groups share no tile. An edit reads and writes only the tiles of its
//! footprint, so an edit of one group never reads a tile another group
//! writes, and the bytes every group writes are the same whichever group
//! runs first, or at the same time: the result is that of applying every
//! edit one after another in manifest order.
//!
//! The plan is written as JSON (`demsketch batch plan --plan plan.json`);
//! groups are addressed by their index (`demsketch batch run --index N`),
//! numbered in the order of their first edit.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::footprint::{dem_georef, footprint};
use super::manifest::{EditKind, Manifest};
use super::BatchError;
use crate::edit::{EditOptions, DEFAULT_MIN_FIT};
use crate::raster::{Dem, Destination, Window};

/// The plan file's format tag.
pub const PLAN_FORMAT: &str = "demsketch-batch-plan/1";

/// The flags every edit of the batch runs with (those of `demsketch edit`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BatchSettings {
    pub max_distance_m: f64,
    pub refraction: f64,
    pub max_lowering_iterations: usize,
    pub max_contour_iterations: usize,
    pub min_fit: f64,
    pub allow_partial: bool,
    /// `--pyramid-resampling`: the resampling of a tile directory's
    /// `gdal_retile.py -levels` pyramid, refreshed by the batch's final
    /// step ([`super::pyramid`]); `None`: near.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pyramid_resampling: Option<String>,
}

impl Default for BatchSettings {
    /// `demsketch edit`'s defaults.
    fn default() -> Self {
        BatchSettings {
            max_distance_m: 50_000.0,
            refraction: 1.0 / 7.0,
            max_lowering_iterations: 4,
            max_contour_iterations: 6,
            min_fit: DEFAULT_MIN_FIT,
            allow_partial: false,
            pyramid_resampling: None,
        }
    }
}

impl BatchSettings {
    /// The options of one edit: exactly those `demsketch edit OUT
    /// --in-place` with the same flags uses (so that the provenance each
    /// tile records, and so its bytes, are the same).
    pub fn edit_options(&self, report: Option<PathBuf>) -> EditOptions {
        let mut o = EditOptions::new(Destination::InPlace);
        o.report = report;
        o.max_distance_m = Some(self.max_distance_m);
        o.refraction = self.refraction;
        o.max_lowering_iterations = self.max_lowering_iterations;
        o.max_contour_iterations = self.max_contour_iterations;
        o.min_fit = self.min_fit;
        o.allow_partial = self.allow_partial;
        o.progress = false;
        // The pyramid is the batch's final step, over every edit at once
        // (super::pyramid).
        o.write.defer_pyramid = true;
        o
    }

    /// The settings a plan file may hold: those `demsketch edit` accepts
    /// for its flags (a view distance that is a positive number of metres,
    /// a finite refraction coefficient, a `min_fit` that is a number >= 0
    /// ([`crate::view::check_min_fit`]), a known pyramid resampling). A plan file is input like any other: a hand-edited one
    /// with `"max_distance_m": 0` would otherwise read the whole DEM.
    pub fn check(&self) -> Result<(), String> {
        crate::view::check_view_settings(
            Some(self.max_distance_m),
            self.refraction,
            crate::view::SettingNames::Fields,
        )
        .map_err(|e| format!("settings: {e}"))?;
        crate::view::check_min_fit(self.min_fit, crate::view::SettingNames::Fields)
            .map_err(|e| format!("settings: {e}"))?;
        if let Some(r) = &self.pyramid_resampling {
            crate::raster::pyramid::parse_resampling(r)
                .map_err(|e| format!("settings: pyramid_resampling: {e}"))?;
        }
        Ok(())
    }

    /// The view distance the footprints use (`None`: the whole DEM).
    pub fn max_d(&self) -> Option<f64> {
        crate::view::distance_limit(Some(self.max_distance_m))
    }
}

/// One edit of the plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannedEdit {
    /// Position in the manifest (0-based).
    pub index: usize,
    pub id: String,
    /// A sketch or corrections (plans written before corrections edits
    /// existed have no `kind`: sketches).
    #[serde(default)]
    pub kind: EditKind,
    /// The sketch or corrections file.
    pub sketch: PathBuf,
    pub sketch_sha256: String,
    /// `[col, row, width, height]` on the DEM grid.
    pub footprint: [i64; 4],
    /// File names of the tiles under the footprint.
    pub tiles: Vec<String>,
    /// Index of its group.
    pub group: usize,
}

impl PlannedEdit {
    pub fn footprint_window(&self) -> Window {
        let f = self.footprint;
        Window::new(f[0], f[1], f[2].max(0) as usize, f[3].max(0) as usize)
    }
}

/// A group: edits applied one after another, in manifest order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Group {
    pub index: usize,
    /// Indices of its edits, ascending.
    pub edits: Vec<usize>,
    /// File names of every tile its edits may read or write.
    pub tiles: Vec<String>,
}

/// A batch plan (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plan {
    pub format: String,
    /// The DEM the batch starts from.
    pub dem: PathBuf,
    /// The output every edit rewrites in place (absolute).
    pub out: PathBuf,
    pub manifest: PathBuf,
    pub settings: BatchSettings,
    pub edits: Vec<PlannedEdit>,
    pub groups: Vec<Group>,
}

/// Union-find root of `i`.
fn root(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// Group the edits: `tiles[e]` are the tile indices of edit `e`'s
/// footprint. Returns, per group in order of its first edit, its edits in
/// ascending order.
pub fn group_edits(tiles: &[Vec<usize>]) -> Vec<Vec<usize>> {
    let n = tiles.len();
    let mut parent: Vec<usize> = (0..n).collect();
    let mut owner: std::collections::HashMap<usize, usize> = std::collections::HashMap::new();
    for (e, ts) in tiles.iter().enumerate() {
        for &t in ts {
            match owner.get(&t) {
                Some(&o) => {
                    let (a, b) = (root(&mut parent, o), root(&mut parent, e));
                    if a != b {
                        parent[a.max(b)] = a.min(b);
                    }
                }
                None => {
                    owner.insert(t, e);
                }
            }
        }
    }
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut index_of: std::collections::HashMap<usize, usize> = std::collections::HashMap::new();
    for e in 0..n {
        let r = root(&mut parent, e);
        let g = *index_of.entry(r).or_insert_with(|| {
            groups.push(Vec::new());
            groups.len() - 1
        });
        groups[g].push(e);
    }
    groups
}

/// The file name of a tile.
pub fn tile_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

impl Plan {
    /// Plan the edits of `manifest` on `dem` (opened from `dem_path`),
    /// to be applied in place on `out`.
    pub fn build(
        dem_path: &Path,
        dem: &Dem,
        manifest: &Manifest,
        out: &Path,
        mut settings: BatchSettings,
    ) -> Result<Plan, BatchError> {
        let georef = dem_georef(dem).map_err(|m| BatchError::Plan {
            path: dem_path.display().to_string(),
            message: m,
        })?;
        // Level tiles are shared by every group: the edits leave them and
        // the batch's final step refreshes them (super::pyramid). A
        // pyramid demsketch cannot keep up to date stops the batch here.
        if let Some(r) = &settings.pyramid_resampling {
            let name =
                crate::raster::pyramid::parse_resampling(r).map_err(|m| BatchError::Plan {
                    path: dem_path.display().to_string(),
                    message: m,
                })?;
            settings.pyramid_resampling = Some(name.to_string());
        }
        super::pyramid::check(dem_path, dem)?;
        let mut windows = Vec::new();
        let mut tile_sets = Vec::new();
        for e in &manifest.edits {
            let w = match &e.parsed {
                Some(sketch) => footprint(dem, &georef, sketch, settings.max_d()),
                None => crate::correct::footprint(dem, &e.sketch).map_err(|err| err.to_string()),
            }
            .map_err(|m| BatchError::Manifest {
                path: manifest.path.display().to_string(),
                message: format!("edit \"{}\" ({}): {m}", e.id, e.sketch.display()),
            })?;
            tile_sets.push(dem.tiles_touching(&w));
            windows.push(w);
        }
        // The names of the output's files: the tiles' own, or for a single
        // GeoTIFF the output's.
        let name_of = |t: usize| match dem.kind {
            crate::raster::LayerKind::TileDirectory => tile_name(&dem.tiles[t].path),
            _ => tile_name(out),
        };
        let grouped = group_edits(&tile_sets);
        let mut group_of = vec![0; manifest.edits.len()];
        let groups: Vec<Group> = grouped
            .iter()
            .enumerate()
            .map(|(g, es)| {
                let mut ts: Vec<usize> = es.iter().flat_map(|&e| tile_sets[e].clone()).collect();
                ts.sort_unstable();
                ts.dedup();
                for &e in es {
                    group_of[e] = g;
                }
                Group {
                    index: g,
                    edits: es.clone(),
                    tiles: ts.iter().map(|&t| name_of(t)).collect(),
                }
            })
            .collect();
        let edits = manifest
            .edits
            .iter()
            .enumerate()
            .map(|(k, e)| {
                let w = windows[k];
                PlannedEdit {
                    index: k,
                    id: e.id.clone(),
                    kind: e.kind,
                    sketch: e.sketch.clone(),
                    sketch_sha256: e.sketch_sha256.clone(),
                    footprint: [w.col, w.row, w.width as i64, w.height as i64],
                    tiles: tile_sets[k].iter().map(|&t| name_of(t)).collect(),
                    group: group_of[k],
                }
            })
            .collect();
        let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        Ok(Plan {
            format: PLAN_FORMAT.into(),
            dem: abs(dem_path),
            out: abs(out),
            manifest: abs(&manifest.path),
            settings,
            edits,
            groups,
        })
    }

    /// The plan as JSON text.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// Read a plan file and check that it holds together (every edit in
    /// exactly one group, indices in order).
    pub fn read(path: &Path) -> Result<Plan, BatchError> {
        let bad = |m: String| BatchError::Plan {
            path: path.display().to_string(),
            message: m,
        };
        let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
        let plan: Plan =
            serde_json::from_str(&text).map_err(|e| bad(format!("not a batch plan: {e}")))?;
        if plan.format != PLAN_FORMAT {
            return Err(bad(format!(
                "format \"{}\" is not {PLAN_FORMAT}",
                plan.format
            )));
        }
        plan.settings.check().map_err(bad)?;
        plan.check().map_err(bad)?;
        Ok(plan)
    }

    /// Every edit in exactly one group and in its group's list, in order;
    /// indices equal to positions; groups share no tile.
    fn check(&self) -> Result<(), String> {
        let mut seen = vec![false; self.edits.len()];
        let mut owner: std::collections::HashMap<&str, usize> = Default::default();
        for (g, grp) in self.groups.iter().enumerate() {
            if grp.index != g {
                return Err(format!("group {g} has index {}", grp.index));
            }
            if !grp.edits.windows(2).all(|w| w[0] < w[1]) {
                return Err(format!("group {g}: edits not in manifest order"));
            }
            for &e in &grp.edits {
                match (self.edits.get(e), seen.get(e)) {
                    (Some(pe), Some(false)) if pe.group == g => seen[e] = true,
                    _ => {
                        return Err(format!(
                            "group {g}: edit {e} is unknown, repeated or in another group"
                        ))
                    }
                }
            }
            for t in &grp.tiles {
                if let Some(o) = owner.insert(t.as_str(), g) {
                    return Err(format!("groups {o} and {g} share tile {t}"));
                }
            }
        }
        for (k, e) in self.edits.iter().enumerate() {
            if e.index != k || !seen[k] {
                return Err(format!("edit {k} (\"{}\") is in no group", e.id));
            }
            let gt = &self.groups[e.group].tiles;
            if let Some(t) = e.tiles.iter().find(|t| !gt.contains(t)) {
                return Err(format!("edit \"{}\": tile {t} is not its group's", e.id));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edits_sharing_a_tile_are_one_group_transitively() {
        // 0 and 2 share tile 5, 2 and 3 share tile 9; 1 and 4 alone.
        let tiles = vec![vec![1, 5], vec![2], vec![5, 9], vec![9, 10], vec![3]];
        assert_eq!(group_edits(&tiles), vec![vec![0, 2, 3], vec![1], vec![4]]);
    }

    #[test]
    fn a_late_edit_can_join_two_groups() {
        let tiles = vec![vec![1], vec![2], vec![1, 2]];
        assert_eq!(group_edits(&tiles), vec![vec![0, 1, 2]]);
    }
}
