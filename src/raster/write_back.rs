//! Write-back of corrected heights: only the tiles an edit changes are
//! rewritten, each with its own layout (tiled or striped, block size),
//! compression, predictor, sample type, georeference, CRS, nodata and
//! metadata, plus a provenance item that `gdalinfo` shows. Overviews in the
//! input are rebuilt. Unchanged tiles of a tile-directory output are copied
//! byte for byte (a reflink where the file system has them; hard links
//! only on request, [`WriteOptions::link_unchanged`]), never re-encoded.
//!
//! Every write is staged and verified before it replaces anything: each
//! new tile is encoded into a staging directory beside its target
//! ([`super::atomic_file::Staging`]: exclusive, unpredictable name), with
//! GDAL's failures captured ([`super::gdal_errors`]); then it is re-read
//! (non-empty, opened by GDAL and by the native reader, the written window
//! equal to the values meant) and flushed to disk. Only when every tile
//! passed are they renamed into place: in place through the edit journal
//! ([`super::journal`]), so a kill between renames is finished by the next
//! run; a single-file output by one rename; a tile-directory output as the
//! whole staged directory. In-place rewrites keep each file's mode, owner
//! and extended attributes. Any failure (a full disk included) leaves
//! every input and output as it was, no temporary file behind, and one
//! error naming the target.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use gdal::raster::{Buffer, RasterCreationOptions};
use gdal::{DriverManager, GdalOpenFlags, Metadata};
use rayon::prelude::*;

use super::atomic_file::{commit_guard, copy_file_attributes, parent_dir, sync_dir, Staging};
use super::{gdal_errors, journal};
use super::{Dem, LayerKind, RasterError, SampleType, Tile, TileSource, Window};

/// The metadata item written into every rewritten tile.
pub const PROVENANCE_KEY: &str = "DEMSKETCH_PROVENANCE";

/// Who changed a tile, and when.
#[derive(Debug, Clone)]
pub struct Provenance {
    /// Identifies the edit (e.g. the sketch file's name and a hash).
    pub edit_id: String,
}

impl Provenance {
    fn item(&self, changed_cells: usize) -> String {
        format!(
            "tool=demsketch {}; edit={}; time={}; changed_cells={changed_cells}",
            env!("CARGO_PKG_VERSION"),
            self.edit_id,
            rfc3339_now()
        )
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

/// How a write-back writes.
#[derive(Debug, Clone, Copy, Default)]
pub struct WriteOptions {
    /// Hard-link the unchanged tiles of a tile-directory output to the
    /// input's instead of copying them (`--link`): faster and free of
    /// space, but a tool that later modifies an output tile in place then
    /// modifies the input too.
    pub link_unchanged: bool,
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

/// Civil UTC time in RFC 3339, from the system clock.
pub fn rfc3339_now() -> String {
    let secs = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
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

/// A failure while writing `tmp`, told as a failure of `target`: the
/// temporary file is never named to the user.
fn retarget(e: RasterError, tmp: &Path, target: &Path) -> RasterError {
    let t = target.display().to_string();
    let text = e.to_string().replace(&tmp.display().to_string(), &t);
    let mut text = text;
    while let Some(rest) = text.strip_prefix(&format!("{t}: ")) {
        text = rest.to_string();
    }
    write_err(
        target,
        format!("{}; nothing changed", super::atomic_file::one_line(&text)),
    )
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

    /// [`Dem::write_back`] with [`WriteOptions`].
    pub fn write_back_with(
        &self,
        window: Window,
        values: &[f64],
        dest: &Destination,
        provenance: &Provenance,
        options: &WriteOptions,
    ) -> Result<WriteReport, RasterError> {
        self.check_destination(dest)?;
        let edits = self.tile_edits(window, values)?;
        let changed_cells = edits.iter().map(|e| e.changed).sum();
        self.commit_edits(edits, changed_cells, dest, provenance, options)
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
        let original = self.read_window::<f64>(window)?;
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
                        let new = values[wi];
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
    fn commit_edits(
        &self,
        edits: Vec<TileEdit>,
        changed_cells: usize,
        dest: &Destination,
        provenance: &Provenance,
        options: &WriteOptions,
    ) -> Result<WriteReport, RasterError> {
        match (dest, self.kind) {
            (Destination::InPlace, LayerKind::Gdal) => Err(RasterError::Unsupported {
                path: self.path.clone(),
                what: "in-place write to a non-GeoTIFF raster; give an output GeoTIFF with --out"
                    .into(),
            }),
            (Destination::InPlace, _) => {
                let targets = self.write_in_place(&edits, provenance)?;
                for e in &edits {
                    self.invalidate_tile(e.tile);
                }
                Ok(WriteReport {
                    tiles_written: targets,
                    tiles_unchanged: vec![],
                    changed_cells,
                })
            }
            (Destination::Path(out), LayerKind::GeoTiff | LayerKind::Gdal) => {
                self.write_single(out, &edits, provenance, changed_cells)
            }
            (Destination::Path(out), LayerKind::TileDirectory) => {
                self.write_directory(out, &edits, provenance, changed_cells, options)
            }
        }
    }

    /// Encode every edit into `staging` (under its tile's file name, or
    /// `name` for a single output), verified, in parallel. `targets` give
    /// the path each is told as in errors.
    fn stage_edits(
        &self,
        edits: &[TileEdit],
        staging: &Staging,
        targets: &[PathBuf],
        provenance: &Provenance,
        keep_attributes: bool,
    ) -> Result<(), RasterError> {
        edits
            .par_iter()
            .zip(targets.par_iter())
            .try_for_each(|(e, target)| {
                let tile = &self.tiles[e.tile];
                let tmp = staging.file(file_name(target));
                stage_tile(tile, e, &tmp, target, provenance)?;
                if keep_attributes {
                    // Where permitted: a file system without modes or
                    // owners does not stop the edit.
                    let _ = copy_file_attributes(&tile.path, &tmp);
                }
                Ok(())
            })
    }

    /// Rewrite the edited tiles of the input: staged and verified beside
    /// them, then renamed through the journal. Returns the tiles written.
    fn write_in_place(
        &self,
        edits: &[TileEdit],
        provenance: &Provenance,
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
        self.stage_edits(edits, &staging, &targets, provenance, true)?;
        let names: Vec<String> = targets
            .iter()
            .map(|t| file_name(t).to_string_lossy().into_owned())
            .collect();
        journal::commit(&self.path, &dir, staging, &names)?;
        Ok(targets)
    }

    /// A single-file output: the edited file (or a byte copy of the input
    /// when nothing changed), staged, verified and renamed to `out`.
    fn write_single(
        &self,
        out: &Path,
        edits: &[TileEdit],
        provenance: &Provenance,
        changed_cells: usize,
    ) -> Result<WriteReport, RasterError> {
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
        let unchanged = edits.is_empty();
        if unchanged {
            copy_verified(&self.tiles[0].path, &tmp, out, false)?;
        } else {
            self.stage_edits(edits, &staging, &targets, provenance, false)?;
        }
        {
            let _commit = commit_guard();
            std::fs::rename(&tmp, out)
                .map_err(|e| write_err(out, format!("{e}; nothing written")))?;
            let _ = sync_dir(dir);
        }
        Ok(WriteReport {
            tiles_written: if unchanged { vec![] } else { targets.clone() },
            tiles_unchanged: if unchanged { targets } else { vec![] },
            changed_cells,
        })
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
        options: &WriteOptions,
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
            copy_verified(
                &tile.path,
                &staging.file(name),
                &out.join(name),
                options.link_unchanged,
            )
        })?;
        report.tiles_unchanged = unchanged
            .iter()
            .map(|t| out.join(file_name(&t.path)))
            .collect();
        let targets: Vec<PathBuf> = edits
            .iter()
            .map(|e| out.join(file_name(&self.tiles[e.tile].path)))
            .collect();
        self.stage_edits(edits, &staging, &targets, provenance, false)?;
        report.tiles_written = targets;
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
    let real = src
        .canonicalize()
        .map_err(|e| retarget(RasterError::io(src, e), dst, target))?;
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
    let (a, b) = (std::fs::metadata(&real), std::fs::metadata(dst));
    match (a, b) {
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

/// GDAL creation options that reproduce a GeoTIFF's layout and encoding.
fn creation_options(tile: &Tile, cog: bool) -> Vec<String> {
    let mut o = vec!["NUM_THREADS=ALL_CPUS".to_string()];
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
            o.push("BIGTIFF=IF_SAFER".into());
        }
    } else {
        o.extend(["TILED=YES", "COMPRESS=DEFLATE", "BIGTIFF=IF_SAFER"].map(String::from));
    }
    if tile.sample_type == SampleType::Int8 {
        o.push("PIXELTYPE=SIGNEDBYTE".into());
    }
    o
}

/// Stage one edited tile: encode it into `tmp` with GDAL's failures
/// captured, then re-read and check it ([`verify_tile`]). Errors name
/// `target`.
fn stage_tile(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    target: &Path,
    provenance: &Provenance,
) -> Result<(), RasterError> {
    let (written, errors) = gdal_errors::capture(|| encode_tile(tile, edit, tmp, provenance));
    let written = written.map_err(|e| retarget(e, tmp, target))?;
    if let Some(e) = gdal_errors::first_failure(&errors, tmp, target) {
        return Err(write_err(
            target,
            format!("GDAL could not write it: {e}; nothing changed"),
        ));
    }
    verify_tile(tile, edit, tmp, &written).map_err(|m| {
        write_err(
            target,
            format!("the written file does not read back: {m}; nothing changed"),
        )
    })?;
    std::fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| retarget(RasterError::io(tmp, e), tmp, target))
}

/// Check a staged tile before it may replace anything: not empty, opened
/// by GDAL with the tile's size, its edited window read back by GDAL equal
/// to `written` (the raw values written, as the sample type stores them),
/// and the same window decoded by the native reader agreeing with GDAL.
fn verify_tile(tile: &Tile, edit: &TileEdit, tmp: &Path, written: &[f64]) -> Result<(), String> {
    let size = std::fs::metadata(tmp).map_err(|e| e.to_string())?.len();
    if size == 0 {
        return Err("it is empty".into());
    }
    let (ds, errors) = gdal_errors::capture(|| gdal::Dataset::open(tmp));
    let ds = ds.map_err(|e| {
        format!(
            "GDAL cannot open it: {}",
            super::atomic_file::one_line(&e.to_string())
        )
    })?;
    let (w, h) = ds.raster_size();
    if (w, h) != (tile.extent.width, tile.extent.height) {
        return Err(format!(
            "{w} x {h} pixels instead of {} x {}",
            tile.extent.width, tile.extent.height
        ));
    }
    let win = edit.local;
    let (read, more) = gdal_errors::capture(|| {
        let band = ds.rasterband(1)?;
        band.read_as::<f64>(
            (win.col as isize, win.row as isize),
            (win.width, win.height),
            (win.width, win.height),
            None,
        )
    });
    let read = read.map_err(|e| {
        format!(
            "GDAL cannot read it: {}",
            super::atomic_file::one_line(&e.to_string())
        )
    })?;
    if let Some(e) = errors.iter().chain(&more).next() {
        return Err(format!("GDAL: {e}"));
    }
    drop(ds);
    let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
    let got = read.data();
    if let Some(i) = (0..got.len()).find(|&i| !same(got[i], tile.sample_type.quantize(written[i])))
    {
        return Err(format!(
            "cell (col {}, row {}) reads {} instead of {}",
            win.col + (i % win.width) as i64,
            win.row + (i / win.width) as i64,
            got[i],
            written[i]
        ));
    }
    let native = super::Dem::open(tmp)
        .and_then(|d| d.read_window::<f64>(win))
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

/// Encode one edited tile into `tmp`: an uncompressed GeoTIFF (not a COG)
/// by [`update_tile_copy`], anything else by [`encode_tile_copy`]. Returns
/// the raw values written over the edit's window.
fn encode_tile(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    provenance: &Provenance,
) -> Result<Vec<f64>, RasterError> {
    let uncompressed =
        matches!(&tile.source, TileSource::Tiff(t) if t.encoding.compression == "NONE");
    let done = if uncompressed {
        update_tile_copy(tile, edit, tmp, provenance)
    } else {
        Ok(None)
    };
    match done? {
        Some(written) => Ok(written),
        None => encode_tile_copy(tile, edit, tmp, provenance),
    }
}

/// Write the edit into band 1 of `ds`: over its window, the stored values
/// with the edit merged in (cells to keep take their stored value back, so
/// nodata stays the file's own nodata value, bit for bit). Returns the
/// values written.
fn write_edit(ds: &gdal::Dataset, edit: &TileEdit) -> gdal::errors::Result<Vec<f64>> {
    let mut band = ds.rasterband(1)?;
    let size = (edit.local.width, edit.local.height);
    let origin = (edit.local.col as isize, edit.local.row as isize);
    let stored = band.read_as::<f64>(origin, size, size, None)?;
    let merged: Vec<f64> = edit
        .values
        .iter()
        .zip(stored.data())
        .map(|(&v, &old)| if v.is_nan() { old } else { v })
        .collect();
    band.write(origin, size, &mut Buffer::new(size, merged.clone()))?;
    Ok(merged)
}

/// Rebuild the overviews of a written tile where the source had them, as
/// gdaladdo puts them (after the full-resolution image).
fn rebuild_overviews(tile: &Tile, ds: &mut gdal::Dataset, tmp: &Path) -> Result<(), RasterError> {
    if let TileSource::Tiff(t) = &tile.source {
        if !t.overviews.is_empty() {
            let factors: Vec<i32> = t
                .overviews
                .iter()
                .map(|(w, _)| ((t.width as f64 / *w as f64).round() as i32).max(2))
                .collect();
            let resampling = if tile.sample_type.is_integer() {
                "NEAREST"
            } else {
                "AVERAGE"
            };
            ds.build_overviews(resampling, &factors, &[])
                .map_err(|e| write_err(tmp, format!("GDAL could not rebuild overviews: {e}")))?;
        }
    }
    Ok(())
}

/// An uncompressed GeoTIFF is edited where it lies in a byte copy of the
/// source: every tag, the layout and the rest of the image stay exactly as
/// they were, and GDAL rewrites only the edited window, the provenance item
/// and the overviews (in place: uncompressed blocks keep their size). Much
/// cheaper than re-encoding the whole file. Returns the values written, or
/// `None` (and `tmp` removed) when the copy is a COG, whose layout an
/// in-place update would break. Write failures GDAL reports only through
/// its error handler are the caller's to collect.
fn update_tile_copy(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    provenance: &Provenance,
) -> Result<Option<Vec<f64>>, RasterError> {
    let is_cog = gdal::Dataset::open(&tile.path)
        .map(|d| d.metadata_item("LAYOUT", "IMAGE_STRUCTURE").as_deref() == Some("COG"))
        .map_err(|e| RasterError::gdal(&tile.path, e))?;
    if is_cog {
        return Ok(None);
    }
    let update = |path: &Path| -> Result<Vec<f64>, RasterError> {
        let werr = |e: gdal::errors::GdalError| write_err(path, e);
        let mut ds = gdal::Dataset::open_ex(
            path,
            gdal::DatasetOptions {
                open_flags: GdalOpenFlags::GDAL_OF_UPDATE | GdalOpenFlags::GDAL_OF_RASTER,
                allowed_drivers: Some(&["GTiff"]),
                ..Default::default()
            },
        )
        .map_err(werr)?;
        let written = write_edit(&ds, edit).map_err(werr)?;
        ds.set_metadata_item(PROVENANCE_KEY, &provenance.item(edit.changed), "")
            .map_err(werr)?;
        rebuild_overviews(tile, &mut ds, path)?;
        ds.flush_cache().map_err(werr)?;
        ds.close().map_err(werr)?;
        Ok(written)
    };
    let size = std::fs::metadata(&tile.path)
        .map_err(|e| RasterError::io(&tile.path, e))?
        .len();
    if size <= MEMORY_COPY_LIMIT {
        let bytes = std::fs::read(&tile.path).map_err(|e| RasterError::io(&tile.path, e))?;
        super::atomic_file::through_memory(tmp, Some(bytes), update)
            .map(Some)
            .map_err(|m| write_err(tmp, m))
    } else {
        std::fs::copy(&tile.path, tmp).map_err(|e| RasterError::io(tmp, e))?;
        update(tmp).map(Some)
    }
}

/// Files up to this size are updated or encoded in memory and written out
/// by demsketch itself (see [`super::atomic_file::through_memory`]).
const MEMORY_COPY_LIMIT: u64 = 256 << 20;

/// Encode one edited tile into `tmp` through GDAL: the source is copied to
/// memory with all its metadata, the edit applied, overviews rebuilt, and
/// the result written with the source's creation options. Returns the
/// values written over the edit's window.
fn encode_tile_copy(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    provenance: &Provenance,
) -> Result<Vec<f64>, RasterError> {
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
    let written = write_edit(&mem, edit).map_err(gerr)?;
    mem.set_metadata_item(PROVENANCE_KEY, &provenance.item(edit.changed), "")
        .map_err(gerr)?;
    let cog = src.metadata_item("LAYOUT", "IMAGE_STRUCTURE").as_deref() == Some("COG");
    let driver =
        DriverManager::get_driver_by_name(if cog { "COG" } else { "GTiff" }).map_err(gerr)?;
    let opts = RasterCreationOptions::from_iter(creation_options(tile, cog));
    super::atomic_file::through_memory(tmp, None, |path| -> Result<(), RasterError> {
        let mut ds = mem
            .create_copy(&driver, path, &opts)
            .map_err(|e| write_err(path, format!("GDAL could not write the tile: {e}")))?;
        // The COG driver builds its own overviews.
        if !cog {
            rebuild_overviews(tile, &mut ds, path)?;
        }
        ds.flush_cache().map_err(|e| write_err(path, e))?;
        ds.close().map_err(|e| write_err(path, e))
    })
    .map_err(|m| write_err(tmp, m))?;
    Ok(written)
}
