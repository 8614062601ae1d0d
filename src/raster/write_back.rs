//! Write-back of corrected heights: only the tiles an edit changes are
//! rewritten, each with its own layout (tiled or striped, block size),
//! compression, predictor, sample type, georeference, CRS, nodata and
//! metadata, plus a provenance entry that `gdalinfo` shows
//! ([`super::provenance`]). Within a GeoTIFF only the changed blocks are
//! re-encoded ([`super::block_patch`]) and overviews are refreshed over the
//! change ([`super::overviews`]); sidecars (`.ovr`, `.aux.xml`) follow
//! ([`super::sidecars`]). Unchanged tiles are hard-linked (or copied) byte
//! for byte, never re-encoded: copied (a reflink where the file system
//! has them; hard links only on request, `WriteOptions::link_unchanged`).
//!
//! Every write is staged and verified before it replaces anything: each
//! new tile is written into a staging directory beside its target
//! ([`super::atomic_file::Staging`]: exclusive, unpredictable name), with
//! GDAL's failures captured ([`super::gdal_errors`]); then it is re-read
//! (non-empty, opened by GDAL and by the native reader, the written window
//! equal to the values meant) and flushed to disk. Only when every tile
//! passed are they renamed into place: in place through the edit journal
//! ([`super::journal`]), so a kill between renames is finished by the next
//! run; a single-file output by one rename; a tile-directory output as the
//! whole staged directory. In-place rewrites keep each file's mode, owner
//! and extended attributes where permitted. Any failure (a full disk
//! included) leaves every input and output as it was, no temporary file
//! behind, and one error naming the target.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use gdal::raster::RasterCreationOptions;
use gdal::DriverManager;
use rayon::prelude::*;

use super::atomic_file::{commit_guard, copy_file_attributes, parent_dir, sync_dir, Staging};
use super::block_patch::{self, BlockEdit, PatchSettings};
use super::output_format::WriteOptions;
pub use super::provenance::PROVENANCE_KEY;
use super::sidecars::Sidecars;
use super::{gdal_errors, journal};
use super::{Dem, LayerKind, RasterError, SampleType, Tile, TileSource, Window};

/// Who changed a tile, and when.
#[derive(Debug, Clone)]
pub struct Provenance {
    /// Identifies the edit (e.g. the sketch file's name and a hash).
    pub edit_id: String,
}

impl Provenance {
    /// The history entry of this edit ([`super::provenance::entry`]).
    fn item(&self, changed_cells: usize, opts: &WriteOptions) -> String {
        super::provenance::entry(&self.edit_id, &rfc3339_now(), changed_cells, &opts.record)
    }
}

/// Where corrected tiles go.
#[derive(Debug, Clone)]
pub enum Destination {
    /// Replace the changed tiles of the input (atomically, tile by tile).
    InPlace,
    /// A new GeoTIFF (single-file input) or a new directory receiving the
    /// full tile set (tile-directory input).
    Path(PathBuf),
}

/// What a write-back did.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct WriteReport {
    /// Files that were rewritten (their final paths).
    pub tiles_written: Vec<PathBuf>,
    /// Files hard-linked or copied unchanged into the output directory.
    pub tiles_unchanged: Vec<PathBuf>,
    /// Cells whose stored value changed.
    pub changed_cells: usize,
}

/// Civil UTC time in RFC 3339, from the system clock; or, when the
/// environment sets `SOURCE_DATE_EPOCH` (seconds since 1970, the
/// reproducible-builds convention), that time: two runs of the same edits
/// then write byte-identical tiles (the provenance entry records the time).
pub fn rfc3339_now() -> String {
    let fixed = std::env::var("SOURCE_DATE_EPOCH")
        .ok()
        .and_then(|v| v.trim().parse::<i64>().ok());
    let secs = fixed.unwrap_or_else(|| {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_secs() as i64)
            .unwrap_or(0)
    });
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Days since 1970-01-01 to a civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

fn write_err(path: &Path, message: impl std::fmt::Display) -> RasterError {
    RasterError::Write {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

/// The file name of a path (for staging it under the same name).
fn file_name(p: &Path) -> &std::ffi::OsStr {
    p.file_name().unwrap_or(std::ffi::OsStr::new("tile.tif"))
}

/// Can `v` be stored in `t` as itself? Not when it is outside the type's
/// range (integers: after rounding to nearest; Float32: beyond its largest
/// finite value) or when it lands on the nodata value `nodata` (quantized).
fn storable(t: SampleType, nodata: Option<f64>, v: f64) -> Result<(), String> {
    if !v.is_finite() {
        return Err("is not a finite number".into());
    }
    if let Some((lo, hi)) = t.integer_range() {
        let q = v.round();
        if q < lo || q > hi {
            return Err(format!("is outside the {t} range [{lo}, {hi}]"));
        }
    } else if t == SampleType::Float32 && v.abs() > f32::MAX as f64 {
        return Err(format!("is outside the {t} range"));
    }
    if let Some(nd) = nodata {
        if t.quantize(v) == nd {
            return Err(format!(
                "lands on the nodata value {nd} (it would turn a valid cell into a hole)"
            ));
        }
    }
    Ok(())
}

/// The new values of one tile: its full extent, quantized to its type.
struct TileEdit {
    tile: usize,
    /// Window in tile pixel coordinates that holds changes.
    local: Window,
    /// Quantized new values over `local` (row-major), NaN = keep the stored
    /// value.
    values: Vec<f64>,
    changed: usize,
}

impl TileEdit {
    fn block_edit(&self) -> BlockEdit<'_> {
        BlockEdit {
            local: self.local,
            values: &self.values,
        }
    }
}

impl Dem {
    /// Write new heights for `window` (row-major `values`, NaN = keep) back
    /// to the tiles. Nodata cells of the input stay nodata; values are rounded
    /// and clamped into integer types. Returns what was written.
    pub fn write_back(
        &self,
        window: Window,
        values: &[f64],
        dest: &Destination,
        provenance: &Provenance,
    ) -> Result<WriteReport, RasterError> {
        self.write_back_with(window, values, dest, provenance, &WriteOptions::default())
    }

    /// [`Dem::write_back`] with output options: format and creation
    /// options of `--out`, overview resampling, provenance details.
    pub fn write_back_with(
        &self,
        window: Window,
        values: &[f64],
        dest: &Destination,
        provenance: &Provenance,
        opts: &WriteOptions,
    ) -> Result<WriteReport, RasterError> {
        self.check_destination(dest)?;
        let edits = self.tile_edits(window, values)?;
        let changed_cells = edits.iter().map(|e| e.changed).sum();
        self.commit_edits(edits, changed_cells, dest, provenance, opts)
    }

    /// What [`Dem::write_back`] would change, without writing anything:
    /// the number of cells whose stored value would change, or the error a
    /// write-back would give (a height the sample type cannot hold, or one
    /// that lands on the nodata value). For dry runs.
    pub fn check_write_back(&self, window: Window, values: &[f64]) -> Result<usize, RasterError> {
        let edits = self.tile_edits(window, values)?;
        Ok(edits.iter().map(|e| e.changed).sum())
    }

    /// The quantized edits of every tile `window` touches (tiles without a
    /// changed cell left out).
    fn tile_edits(&self, window: Window, values: &[f64]) -> Result<Vec<TileEdit>, RasterError> {
        if values.len() != window.len() {
            return Err(write_err(
                &self.path,
                format!(
                    "{} values for a window of {} cells",
                    values.len(),
                    window.len()
                ),
            ));
        }
        let window =
            window
                .intersect(&self.full_window())
                .ok_or_else(|| RasterError::OutOfBounds {
                    path: self.path.clone(),
                    what: format!("{window:?}"),
                    width: self.width,
                    height: self.height,
                })?;
        // Stored values: heights in metres are converted to the tile's
        // scale, offset and unit (`Vertical::to_raw`) before quantizing.
        let original = self.read_window_raw::<f64>(window)?;
        // Per tile: which cells change once quantized. A new height the
        // tile's type cannot hold, or one that lands on its nodata value, is
        // an error (never clamped: that would write a wrong height, or turn
        // a valid cell into a hole).
        let edits: Vec<Result<TileEdit, RasterError>> = self
            .tiles_touching(&window)
            .into_par_iter()
            .filter_map(|ti| {
                let tile = &self.tiles[ti];
                let ov = tile.extent.intersect(&window)?;
                let mut vals = vec![0.0; ov.len()];
                let mut changed = 0;
                let nodata = tile.nodata.map(|v| tile.sample_type.quantize(v));
                for r in 0..ov.height {
                    for c in 0..ov.width {
                        let wi = ((ov.row - window.row) as usize + r) * window.width
                            + (ov.col - window.col) as usize
                            + c;
                        let old = original.data[wi];
                        let new = tile.vertical.to_raw(values[wi]);
                        // NaN = keep the stored value (nodata cells keep
                        // their raw nodata value, see `encode_tile`).
                        let v = if !original.valid[wi] || new.is_nan() {
                            f64::NAN
                        } else {
                            let cell = (ov.col + c as i64, ov.row + r as i64);
                            if let Err(problem) = storable(tile.sample_type, nodata, new) {
                                return Some(Err(RasterError::Write {
                                    path: tile.path.clone(),
                                    message: format!(
                                        "cell (col {}, row {}): new height {new} {problem}; nothing written",
                                        cell.0, cell.1
                                    ),
                                }));
                            }
                            tile.sample_type.quantize(new)
                        };
                        if !v.is_nan() && v != old {
                            changed += 1;
                        }
                        vals[r * ov.width + c] = v;
                    }
                }
                (changed > 0).then(|| Ok(TileEdit {
                    tile: ti,
                    local: Window::new(
                        ov.col - tile.extent.col,
                        ov.row - tile.extent.row,
                        ov.width,
                        ov.height,
                    ),
                    values: vals,
                    changed,
                }))
            })
            .collect();
        let edits: Vec<TileEdit> = edits.into_iter().collect::<Result<_, _>>()?;
        Ok(edits)
    }

    /// Write the tile edits to `dest`.
    /// CRS bounds `[min x, min y, max x, max y]` of the windows `edits`
    /// change.
    fn changed_bounds(&self, edits: &[TileEdit]) -> [f64; 4] {
        self.windows_bounds(edits.iter().map(|e| {
            let x = &self.tiles[e.tile].extent;
            Window::new(
                x.col + e.local.col,
                x.row + e.local.row,
                e.local.width,
                e.local.height,
            )
        }))
    }

    /// CRS bounds `[min x, min y, max x, max y]` of the union of `windows`
    /// (of the DEM grid); infinite and inverted when there are none.
    pub fn windows_bounds(&self, windows: impl IntoIterator<Item = Window>) -> [f64; 4] {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for w in windows {
            let (c0, r0) = (w.col as f64, w.row as f64);
            let (c1, r1) = (c0 + w.width as f64, r0 + w.height as f64);
            for (c, r) in [(c0, r0), (c1, r0), (c0, r1), (c1, r1)] {
                let (px, py) = self.geotransform.pixel_to_crs(c, r);
                b = [b[0].min(px), b[1].min(py), b[2].max(px), b[3].max(py)];
            }
        }
        b
    }

    fn commit_edits(
        &self,
        edits: Vec<TileEdit>,
        changed_cells: usize,
        dest: &Destination,
        provenance: &Provenance,
        opts: &WriteOptions,
    ) -> Result<WriteReport, RasterError> {
        match (dest, self.kind) {
            (Destination::InPlace, LayerKind::Gdal) => Err(RasterError::Unsupported {
                path: self.path.clone(),
                what: "in-place write to a non-GeoTIFF raster; give an output GeoTIFF with --out"
                    .into(),
            }),
            (Destination::InPlace, _)
                if edits.iter().any(|e| self.tiles[e.tile].read_by_gdal()) =>
            {
                let t = edits
                    .iter()
                    .map(|e| &self.tiles[e.tile])
                    .find(|t| t.read_by_gdal())
                    .map_or(self.path.clone(), |t| t.path.clone());
                Err(RasterError::Unsupported {
                    path: t,
                    what: "in-place write to a file read through GDAL (its encoding or CRS is not one demsketch writes back exactly); write a new GeoTIFF with --out".into(),
                })
            }
            (Destination::InPlace, _) => {
                // A gdal_retile.py pyramid beside the tiles: checked before
                // anything is written, refreshed over the change after.
                let pyramid = match self.kind {
                    LayerKind::TileDirectory if !edits.is_empty() && !opts.defer_pyramid => {
                        super::pyramid::Pyramid::discover(&self.path)?
                    }
                    _ => None,
                };
                let mut targets = self.write_in_place(&edits, provenance, opts)?;
                for e in &edits {
                    self.invalidate_tile(e.tile);
                }
                if let Some(p) = pyramid {
                    let resampling = opts.pyramid_resampling.as_deref().unwrap_or("near");
                    targets.extend(p.refresh(
                        self.changed_bounds(&edits),
                        resampling,
                        provenance,
                    )?);
                }
                Ok(WriteReport {
                    tiles_written: targets,
                    tiles_unchanged: vec![],
                    changed_cells,
                })
            }
            (Destination::Path(out), LayerKind::GeoTiff | LayerKind::Gdal) => {
                let targets = vec![out.clone()];
                let same_format = matches!(self.kind, LayerKind::GeoTiff)
                    && opts.keeps_geotiff(Some(out.as_path()));
                if edits.is_empty() && !same_format {
                    // Nothing changed, but another format: converted.
                    let keep_all = TileEdit {
                        tile: 0,
                        local: Window::new(0, 0, 1, 1),
                        values: vec![f64::NAN],
                        changed: 0,
                    };
                    self.write_single(out, &[keep_all], provenance, opts)?;
                    return Ok(WriteReport {
                        tiles_written: targets,
                        tiles_unchanged: vec![],
                        changed_cells,
                    });
                }
                if edits.is_empty() {
                    // Nothing changed: the output is a byte copy of the input
                    // (its sidecars too).
                    let dir = parent_dir(out);
                    let staging = Staging::new_in(dir).map_err(|e| {
                        write_err(
                            out,
                            format!("cannot create a temporary file: {e}; nothing written"),
                        )
                    })?;
                    let tmp = staging.file(file_name(out));
                    copy_verified(&self.tiles[0].path, &tmp, out, false)?;
                    {
                        let _commit = commit_guard();
                        std::fs::rename(&tmp, out)
                            .map_err(|e| write_err(out, format!("{e}; nothing written")))?;
                        let _ = sync_dir(dir);
                    }
                    super::sidecars::copy_unchanged(&self.tiles[0].path, out)?;
                    return Ok(WriteReport {
                        tiles_written: vec![],
                        tiles_unchanged: targets,
                        changed_cells,
                    });
                }
                self.write_single(out, &edits, provenance, opts)?;
                Ok(WriteReport {
                    tiles_written: targets,
                    tiles_unchanged: vec![],
                    changed_cells,
                })
            }
            (Destination::Path(out), LayerKind::TileDirectory) => {
                self.write_directory(out, &edits, provenance, changed_cells, opts)
            }
        }
    }

    /// Encode every edit into `staging` under its target's file name,
    /// verified, in parallel (`targets`: the final paths, which errors
    /// name). With `keep_attributes`, each staged file gets its tile's
    /// mode, owner and extended attributes. Returns the sidecars to move
    /// into place after the files.
    fn stage_edits(
        &self,
        edits: &[TileEdit],
        staging: &Staging,
        targets: &[PathBuf],
        provenance: &Provenance,
        opts: &WriteOptions,
        keep_attributes: bool,
    ) -> Result<Vec<Sidecars>, RasterError> {
        edits
            .par_iter()
            .zip(targets.par_iter())
            .map(|(e, target)| {
                let tile = &self.tiles[e.tile];
                let tmp = staging.file(file_name(target));
                let (written, errors) =
                    gdal_errors::capture(|| encode_tile(tile, e, &tmp, target, provenance, opts));
                let sidecars = written?;
                if let Some(err) = gdal_errors::first_failure(&errors, &tmp, target) {
                    sidecars.discard();
                    return Err(write_err(
                        target,
                        format!("GDAL could not write it: {err}; nothing changed"),
                    ));
                }
                let exact = opts.creation_options.is_empty();
                if let Err(m) = verify_tile(tile, e, &tmp, exact) {
                    sidecars.discard();
                    return Err(write_err(
                        target,
                        format!("the written file does not read back: {m}; nothing changed"),
                    ));
                }
                if keep_attributes {
                    // Where permitted: a file system without modes or
                    // owners does not stop the edit.
                    let _ = copy_file_attributes(&tile.path, &tmp);
                }
                Ok(sidecars)
            })
            .collect()
    }

    /// Rewrite the edited tiles of the input: staged and verified beside
    /// them, then renamed through the journal. Returns the tiles written.
    fn write_in_place(
        &self,
        edits: &[TileEdit],
        provenance: &Provenance,
        opts: &WriteOptions,
    ) -> Result<Vec<PathBuf>, RasterError> {
        let targets: Vec<PathBuf> = edits
            .iter()
            .map(|e| self.tiles[e.tile].path.clone())
            .collect();
        if targets.is_empty() {
            return Ok(targets);
        }
        let dir = parent_dir(&targets[0]).to_path_buf();
        if let Some(t) = targets.iter().find(|t| parent_dir(t) != dir.as_path()) {
            return Err(write_err(
                t,
                "tiles of one DEM in different directories cannot be rewritten in place",
            ));
        }
        let staging = Staging::new_in(&dir).map_err(|e| {
            write_err(
                &self.path,
                format!(
                    "cannot create a temporary file in {}: {e}; nothing changed",
                    dir.display()
                ),
            )
        })?;
        let sidecars = self.stage_edits(edits, &staging, &targets, provenance, opts, true)?;
        let names: Vec<String> = targets
            .iter()
            .map(|t| file_name(t).to_string_lossy().into_owned())
            .collect();
        let staged = journal::commit(&self.path, &dir, staging, &names)?;
        let moved = sidecars.iter().try_for_each(Sidecars::commit);
        let _ = std::fs::remove_dir_all(&staged);
        moved?;
        Ok(targets)
    }

    /// A single-file output: staged, verified and renamed to `out`, its
    /// sidecars after it.
    fn write_single(
        &self,
        out: &Path,
        edits: &[TileEdit],
        provenance: &Provenance,
        opts: &WriteOptions,
    ) -> Result<(), RasterError> {
        let dir = parent_dir(out);
        super::atomic_file::clean_stale(dir);
        let staging = Staging::new_in(dir).map_err(|e| {
            write_err(
                out,
                format!("cannot create a temporary file: {e}; nothing written"),
            )
        })?;
        let tmp = staging.file(file_name(out));
        let targets = vec![out.to_path_buf()];
        let sidecars = self.stage_edits(edits, &staging, &targets, provenance, opts, false)?;
        let _commit = commit_guard();
        if let Err(e) = std::fs::rename(&tmp, out) {
            sidecars.iter().for_each(Sidecars::discard);
            return Err(write_err(out, format!("{e}; nothing written")));
        }
        let _ = sync_dir(dir);
        for s in &sidecars {
            s.commit()?;
        }
        Ok(())
    }

    /// A tile-directory output: the full tile set staged in a directory
    /// beside `out` (unchanged tiles copied, edited ones encoded and
    /// verified), which then becomes `out` by one rename.
    fn write_directory(
        &self,
        out: &Path,
        edits: &[TileEdit],
        provenance: &Provenance,
        changed_cells: usize,
        opts: &WriteOptions,
    ) -> Result<WriteReport, RasterError> {
        let parent = parent_dir(out);
        super::atomic_file::clean_stale(parent);
        let staging = Staging::new_in(parent).map_err(|e| {
            write_err(
                out,
                format!("cannot create a staging directory: {e}; nothing written"),
            )
        })?;
        let mut report = WriteReport {
            changed_cells,
            ..Default::default()
        };
        let edited: std::collections::HashSet<usize> = edits.iter().map(|e| e.tile).collect();
        let unchanged: Vec<&Tile> = self
            .tiles
            .iter()
            .enumerate()
            .filter(|(ti, _)| !edited.contains(ti))
            .map(|(_, t)| t)
            .collect();
        unchanged.par_iter().try_for_each(|tile| {
            let name = file_name(&tile.path);
            let staged = staging.file(name);
            copy_verified(&tile.path, &staged, &out.join(name), opts.link_unchanged)?;
            super::sidecars::copy_unchanged(&tile.path, &staged)
        })?;
        report.tiles_unchanged = unchanged
            .iter()
            .map(|t| out.join(file_name(&t.path)))
            .collect();
        // The edited tiles are encoded straight into the staged directory,
        // their sidecars beside them there; errors name the input tile.
        let staged: Vec<PathBuf> = edits
            .iter()
            .map(|e| staging.file(file_name(&self.tiles[e.tile].path)))
            .collect();
        let sidecars = self.stage_edits(edits, &staging, &staged, provenance, opts, false)?;
        for s in &sidecars {
            s.commit()?;
        }
        report.tiles_written = edits
            .iter()
            .map(|e| out.join(file_name(&self.tiles[e.tile].path)))
            .collect();
        // The staging directory is made mode 700; the output gets the mode
        // a new directory gets.
        let mode = 0o777 & !current_umask();
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(staging.path(), std::fs::Permissions::from_mode(mode))
                .map_err(|e| write_err(out, format!("{e}; nothing written")))?;
        }
        let _commit = commit_guard();
        if out.is_dir() {
            std::fs::remove_dir(out)
                .map_err(|e| write_err(out, format!("{e}; nothing written")))?;
        }
        let kept = staging.keep();
        if let Err(e) = std::fs::rename(&kept, out) {
            let _ = std::fs::remove_dir_all(&kept);
            return Err(write_err(out, format!("{e}; nothing written")));
        }
        let _ = sync_dir(parent);
        Ok(report)
    }
    /// Refuse destinations that would overwrite the input or a non-empty
    /// directory, before anything is written.
    fn check_destination(&self, dest: &Destination) -> Result<(), RasterError> {
        let Destination::Path(out) = dest else {
            return Ok(());
        };
        let same = |a: &Path, b: &Path| match (a.canonicalize(), b.canonicalize()) {
            (Ok(x), Ok(y)) => x == y,
            _ => false,
        };
        if same(out, &self.path) {
            return Err(write_err(
                out,
                "is the input; use --in-place to rewrite the input",
            ));
        }
        match self.kind {
            LayerKind::TileDirectory => {
                if out.is_file() {
                    return Err(write_err(
                        out,
                        "is a file; a tile directory needs an output directory",
                    ));
                }
                if out.is_dir()
                    && std::fs::read_dir(out)
                        .map_err(|e| RasterError::io(out, e))?
                        .next()
                        .is_some()
                {
                    return Err(write_err(out, "already exists and is not empty"));
                }
                let parent = out
                    .parent()
                    .filter(|p| !p.as_os_str().is_empty())
                    .unwrap_or(Path::new("."));
                if !parent.is_dir() {
                    return Err(write_err(out, "its parent directory does not exist"));
                }
            }
            _ => {
                if out.is_dir() {
                    return Err(write_err(
                        out,
                        "is a directory; give the path of the output GeoTIFF",
                    ));
                }
                let parent = out
                    .parent()
                    .filter(|p| !p.as_os_str().is_empty())
                    .unwrap_or(Path::new("."));
                if !parent.is_dir() {
                    return Err(write_err(out, "its parent directory does not exist"));
                }
            }
        }
        Ok(())
    }
}

/// GDAL creation options that reproduce a GeoTIFF's layout and encoding
/// (BigTIFF kept BigTIFF).
fn creation_options(tile: &Tile, cog: bool) -> Vec<String> {
    let mut o = vec!["NUM_THREADS=ALL_CPUS".to_string()];
    let bigtiff = if super::output_format::is_bigtiff(&tile.path) {
        "BIGTIFF=YES"
    } else {
        "BIGTIFF=IF_SAFER"
    };
    if let TileSource::Tiff(t) = &tile.source {
        o.push(format!("COMPRESS={}", t.encoding.compression));
        if t.encoding.compression != "NONE" && t.encoding.predictor != 1 {
            o.push(format!("PREDICTOR={}", t.encoding.predictor));
        }
        if cog {
            o.push(format!("BLOCKSIZE={}", t.layout.block_width));
        } else {
            if t.layout.tiled {
                o.push("TILED=YES".into());
                o.push(format!("BLOCKXSIZE={}", t.layout.block_width));
            }
            o.push(format!("BLOCKYSIZE={}", t.layout.block_height));
        }
        o.push(bigtiff.into());
    } else {
        o.extend(["TILED=YES", "COMPRESS=DEFLATE", bigtiff].map(String::from));
    }
    if tile.sample_type == SampleType::Int8 {
        o.push("PIXELTYPE=SIGNEDBYTE".into());
    }
    o
}

/// Encode one edited tile into `tmp` (to be renamed to `target`): a
/// GeoTIFF written as its input was is patched block by block
/// ([`block_patch`]); anything else (another format, `-co`, a GDAL-read
/// input) is encoded whole by [`encode_tile_copy`]. Returns the sidecars to
/// move into place after it. The bytes are made durable before the
/// caller's rename makes them visible.
fn encode_tile(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    target: &Path,
    provenance: &Provenance,
    opts: &WriteOptions,
) -> Result<Sidecars, RasterError> {
    let entry = provenance.item(edit.changed, opts);
    let native = matches!(&tile.source, TileSource::Tiff(_));
    let internal_ovr = matches!(&tile.source, TileSource::Tiff(t) if !t.overviews().is_empty());
    let out_path = (target != tile.path.as_path()).then_some(target);
    let mut sidecars = Sidecars::stage(&tile.path, tmp, target, internal_ovr)?;
    let settings = PatchSettings {
        entry: &entry,
        overview_resampling: opts.overview_resampling.as_deref(),
        external_overviews: sidecars.overviews.is_some(),
        target: error_name(tile, target),
    };
    let written = (|| -> Result<(), RasterError> {
        if native && opts.keeps_geotiff(out_path) {
            let patched = block_patch::patch_copy(&tile.path, tmp, &edit.block_edit(), &settings)?;
            if patched.is_none() {
                let cog_opts = creation_options(tile, true);
                block_patch::patch_cog(&tile.path, tmp, &edit.block_edit(), &settings, &cog_opts)?;
            }
            return Ok(());
        }
        let (extra, driver) = encode_tile_copy(tile, edit, tmp, target, &settings, opts)?;
        sidecars.extra = extra;
        if driver != "GTiff" {
            // Another format has its own overviews (or none): the input's
            // external ones do not describe it.
            if let Some((staged, _)) = sidecars.overviews.take() {
                let _ = std::fs::remove_file(staged);
            }
        }
        Ok(())
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(tmp);
        sidecars.discard();
        return Err(name_the_target(e, tmp, settings.target));
    }
    std::fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| RasterError::io(settings.target, e))?;
    Ok(sidecars)
}

/// `e` with every mention of the temporary file `tmp` (GDAL's messages
/// name the file it writes) replaced by `target`, the file the user named.
fn name_the_target(e: RasterError, tmp: &Path, target: &Path) -> RasterError {
    let fix = |m: String| {
        m.replace(
            tmp.to_string_lossy().as_ref(),
            target.to_string_lossy().as_ref(),
        )
    };
    match e {
        RasterError::Write { message, .. } => RasterError::Write {
            path: target.to_path_buf(),
            message: fix(message),
        },
        RasterError::Gdal { path, message } => RasterError::Gdal {
            path,
            message: fix(message),
        },
        other => other,
    }
}

/// The name errors give for a tile written to `target`: the tile itself
/// for a tile directory's staging copy (a name the user knows), else the
/// target.
fn error_name<'a>(tile: &'a Tile, target: &'a Path) -> &'a Path {
    let staged = target
        .parent()
        .and_then(|p| p.file_name())
        .is_some_and(|n| n.to_string_lossy().contains(".demsketch-"));
    if staged {
        &tile.path
    } else {
        target
    }
}

/// Encode one edited tile into `tmp` through GDAL: the source is copied to
/// memory with all its metadata, the edit applied, and the result written
/// in the output's format (the source's creation options for a GeoTIFF,
/// the user's `-co` over them); a GeoTIFF's overviews are rebuilt with the
/// recorded resampling. Returns the extra files the driver wrote, staged,
/// and the driver.
fn encode_tile_copy(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    target: &Path,
    settings: &PatchSettings,
    opts: &WriteOptions,
) -> Result<(super::output_format::StagedFiles, String), RasterError> {
    let gerr = |e: gdal::errors::GdalError| RasterError::gdal(&tile.path, e);
    // Decode a compressed source with all cores (GTiff's NUM_THREADS open
    // option; "@" keeps other drivers from warning about an option they
    // lack). An uncompressed one has nothing to decode: the worker pool
    // would cost more than the copy.
    let uncompressed =
        matches!(&tile.source, TileSource::Tiff(t) if t.encoding.compression == "NONE");
    let src = gdal::Dataset::open_ex(
        &tile.path,
        gdal::DatasetOptions {
            open_options: (!uncompressed).then_some(&["@NUM_THREADS=ALL_CPUS"][..]),
            ..Default::default()
        },
    )
    .map_err(gerr)?;
    let mem_driver = DriverManager::get_driver_by_name("MEM").map_err(gerr)?;
    let mut mem = src
        .create_copy(&mem_driver, "", &RasterCreationOptions::default())
        .map_err(gerr)?;
    super::vertical::keep_band_vertical(&src, &mem).map_err(gerr)?;
    block_patch::write_edit(&mem, &edit.block_edit()).map_err(gerr)?;
    block_patch::append_provenance(&mut mem, settings.entry).map_err(gerr)?;
    super::sidecars::clear_statistics(&mem);
    let src_cog = block_patch::is_cog(&src);
    let driver = match &opts.format {
        Some(_) => super::output_format::output_driver(target, opts.format.as_deref())
            .map_err(|m| write_err(target, m))?,
        None if src_cog => "COG".to_string(),
        None => {
            super::output_format::output_driver(target, None).map_err(|m| write_err(target, m))?
        }
    };
    let cog = driver == "COG";
    let base = if cog || driver == "GTiff" {
        creation_options(tile, cog)
    } else {
        Vec::new()
    };
    let options = super::output_format::merge_options(base, &opts.creation_options);
    let extra = super::output_format::write_copy(&mem, &driver, &options, tmp, target)?;
    // The COG driver builds its own overviews; a GeoTIFF gets the source's.
    if driver == "GTiff" {
        let resampling = super::overviews::resampling_for(&src, settings.overview_resampling);
        let factors: Vec<i32> = match &tile.source {
            TileSource::Tiff(t) => t
                .overviews()
                .iter()
                .map(|(w, _)| ((t.width as f64 / *w as f64).round() as i32).max(2))
                .collect(),
            TileSource::Gdal(_) => Vec::new(),
        };
        let werr = |e: gdal::errors::GdalError| write_err(settings.target, e);
        let mut ds = gdal::Dataset::open_ex(
            tmp,
            gdal::DatasetOptions {
                open_flags: gdal::GdalOpenFlags::GDAL_OF_UPDATE
                    | gdal::GdalOpenFlags::GDAL_OF_RASTER,
                allowed_drivers: Some(&["GTiff"]),
                ..Default::default()
            },
        )
        .map_err(werr)?;
        if !factors.is_empty() {
            super::overviews::rebuild_all(&mut ds, &factors, resampling, settings.target)?;
        } else if settings.external_overviews {
            super::overviews::refresh_overviews(
                &ds,
                edit.local,
                resampling,
                true,
                settings.target,
            )?;
        }
        ds.close().map_err(werr)?;
    }
    Ok((extra, driver))
}

/// The process's file mode creation mask (read without changing it for
/// longer than the call).
fn current_umask() -> u32 {
    use rustix::fs::Mode;
    let old = rustix::process::umask(Mode::from_raw_mode(0o022));
    rustix::process::umask(old);
    old.as_raw_mode() as u32
}

/// Copy an unchanged file `src` to `dst` (a staging path; `target` is what
/// errors name): a reflink or a byte copy of the file a symlink points to,
/// or with `link` a hard link to that file (a copy where linking fails).
/// Checked: same size as the source.
fn copy_verified(src: &Path, dst: &Path, target: &Path, link: bool) -> Result<(), RasterError> {
    let real = src.canonicalize().map_err(|e| {
        write_err(
            target,
            format!("cannot read {}: {e}; nothing written", src.display()),
        )
    })?;
    let linked = link && std::fs::hard_link(&real, dst).is_ok();
    if !linked {
        reflink_copy::reflink_or_copy(&real, dst).map_err(|e| {
            write_err(
                target,
                format!("cannot copy {}: {e}; nothing written", src.display()),
            )
        })?;
        std::fs::File::open(dst)
            .and_then(|f| f.sync_all())
            .map_err(|e| write_err(target, format!("{e}; nothing written")))?;
    }
    match (std::fs::metadata(&real), std::fs::metadata(dst)) {
        (Ok(a), Ok(b)) if a.len() == b.len() => Ok(()),
        _ => Err(write_err(
            target,
            format!(
                "the copy of {} is incomplete; nothing written",
                src.display()
            ),
        )),
    }
}

/// Check a staged tile before it may replace anything: not empty, opened
/// by GDAL with the tile's size, and (with `exact`: the output keeps the
/// input's encoding, no `-co`) its edited window read back by GDAL equal to
/// the values meant (the stored values with the edit merged in, as the
/// sample type stores them), and the same window decoded by the native
/// reader agreeing with GDAL.
fn verify_tile(tile: &Tile, edit: &TileEdit, tmp: &Path, exact: bool) -> Result<(), String> {
    let one = |e: &dyn std::fmt::Display| super::atomic_file::one_line(&e.to_string());
    let size = std::fs::metadata(tmp).map_err(|e| e.to_string())?.len();
    if size == 0 {
        return Err("it is empty".into());
    }
    let ds = gdal::Dataset::open(tmp).map_err(|e| format!("GDAL cannot open it: {}", one(&e)))?;
    let (w, h) = ds.raster_size();
    if (w, h) != (tile.extent.width, tile.extent.height) {
        return Err(format!(
            "{w} x {h} pixels instead of {} x {}",
            tile.extent.width, tile.extent.height
        ));
    }
    let win = edit.local;
    let read = |d: &gdal::Dataset| {
        d.rasterband(1).and_then(|b| {
            b.read_as::<f64>(
                (win.col as isize, win.row as isize),
                (win.width, win.height),
                (win.width, win.height),
                None,
            )
        })
    };
    let got = read(&ds).map_err(|e| format!("GDAL cannot read it: {}", one(&e)))?;
    drop(ds);
    if !exact || edit.changed == 0 {
        return Ok(());
    }
    let src = gdal::Dataset::open(&tile.path).map_err(|e| one(&e))?;
    let stored = read(&src).map_err(|e| one(&e))?;
    let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
    let got = got.data();
    for (i, (&v, &old)) in edit.values.iter().zip(stored.data()).enumerate() {
        let want = if v.is_nan() {
            old
        } else {
            tile.sample_type.quantize(v)
        };
        if !same(got[i], want) {
            return Err(format!(
                "cell (col {}, row {}) reads {} instead of {want}",
                win.col + (i % win.width) as i64,
                win.row + (i / win.width) as i64,
                got[i]
            ));
        }
    }
    // (as stored, as GDAL reads it: no scale, offset or unit applied)
    let native = super::Dem::open(tmp)
        .and_then(|d| d.read_window_raw::<f64>(win))
        .map_err(|e| format!("demsketch cannot read it back: {e}"))?;
    let nodata = tile.nodata.map(|v| tile.sample_type.quantize(v));
    for (i, &g) in got.iter().enumerate() {
        let ok = if native.valid[i] {
            same(native.data[i], g)
        } else {
            g.is_nan() || Some(g) == nodata
        };
        if !ok {
            return Err(format!(
                "cell (col {}, row {}): the native reader and GDAL disagree",
                win.col + (i % win.width) as i64,
                win.row + (i / win.width) as i64
            ));
        }
    }
    Ok(())
}
