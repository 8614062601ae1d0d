//! Write-back of corrected heights: only the tiles an edit changes are
//! rewritten, each with its own layout (tiled or striped, block size),
//! compression, predictor, sample type, georeference, CRS, nodata and
//! metadata, plus a provenance item that `gdalinfo` shows. Overviews in the
//! input are rebuilt. Unchanged tiles are hard-linked (or copied) byte for
//! byte, never re-encoded.
//!
//! Every write is atomic: tiles are encoded to temporary files in the target
//! directory and renamed into place only once all of them are complete; a
//! tile directory output is staged beside `OUT` and renamed to `OUT` at the
//! end. An interruption leaves each file either old or new, and a failure
//! leaves nothing behind.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use gdal::raster::{Buffer, RasterCreationOptions};
use gdal::{DriverManager, GdalOpenFlags, Metadata};
use rayon::prelude::*;

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

/// A temporary path beside `target`, unique to this process.
fn temp_beside(target: &Path) -> PathBuf {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "tile".into());
    target.with_file_name(format!(".{name}.demsketch-{}.tmp", std::process::id()))
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
        self.check_destination(dest)?;
        let edits = self.tile_edits(window, values)?;
        let changed_cells = edits.iter().map(|e| e.changed).sum();
        self.commit_edits(edits, changed_cells, dest, provenance)
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
    fn commit_edits(
        &self,
        edits: Vec<TileEdit>,
        changed_cells: usize,
        dest: &Destination,
        provenance: &Provenance,
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
                let targets: Vec<PathBuf> = edits
                    .iter()
                    .map(|e| self.tiles[e.tile].path.clone())
                    .collect();
                self.encode_and_commit(&edits, &targets, provenance)?;
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
                let targets = vec![out.clone()];
                if edits.is_empty() {
                    // Nothing changed: the output is a byte copy of the input.
                    let tmp = temp_beside(out);
                    std::fs::copy(&self.tiles[0].path, &tmp)
                        .map_err(|e| RasterError::io(out, e))?;
                    std::fs::rename(&tmp, out).map_err(|e| RasterError::io(out, e))?;
                    return Ok(WriteReport {
                        tiles_written: vec![],
                        tiles_unchanged: targets,
                        changed_cells,
                    });
                }
                self.encode_and_commit(&edits, &targets, provenance)?;
                Ok(WriteReport {
                    tiles_written: targets,
                    tiles_unchanged: vec![],
                    changed_cells,
                })
            }
            (Destination::Path(out), LayerKind::TileDirectory) => {
                self.write_directory(out, &edits, provenance, changed_cells)
            }
        }
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

    /// Encode every edited tile to a temporary file beside its target, then,
    /// once all succeeded, rename them into place.
    fn encode_and_commit(
        &self,
        edits: &[TileEdit],
        targets: &[PathBuf],
        provenance: &Provenance,
    ) -> Result<(), RasterError> {
        let temps: Vec<PathBuf> = targets.iter().map(|t| temp_beside(t)).collect();
        let result = edits
            .par_iter()
            .zip(temps.par_iter())
            .try_for_each(|(e, tmp)| encode_tile(&self.tiles[e.tile], e, tmp, provenance));
        if let Err(err) = result {
            for t in &temps {
                let _ = std::fs::remove_file(t);
            }
            return Err(err);
        }
        for (tmp, target) in temps.iter().zip(targets) {
            if let Err(e) = std::fs::rename(tmp, target) {
                for t in &temps {
                    let _ = std::fs::remove_file(t);
                }
                return Err(RasterError::io(target, e));
            }
        }
        Ok(())
    }

    fn write_directory(
        &self,
        out: &Path,
        edits: &[TileEdit],
        provenance: &Provenance,
        changed_cells: usize,
    ) -> Result<WriteReport, RasterError> {
        let stage = temp_beside(out);
        if stage.exists() {
            let _ = std::fs::remove_dir_all(&stage);
        }
        std::fs::create_dir(&stage).map_err(|e| RasterError::io(&stage, e))?;
        let run = || -> Result<WriteReport, RasterError> {
            let mut report = WriteReport {
                changed_cells,
                ..Default::default()
            };
            let edited: std::collections::HashSet<usize> = edits.iter().map(|e| e.tile).collect();
            for (ti, tile) in self.tiles.iter().enumerate() {
                if edited.contains(&ti) {
                    continue;
                }
                let name = tile.path.file_name().unwrap_or_default();
                let target = stage.join(name);
                if std::fs::hard_link(&tile.path, &target).is_err() {
                    std::fs::copy(&tile.path, &target).map_err(|e| RasterError::io(&target, e))?;
                }
                report.tiles_unchanged.push(out.join(name));
            }
            let targets: Vec<PathBuf> = edits
                .iter()
                .map(|e| stage.join(self.tiles[e.tile].path.file_name().unwrap_or_default()))
                .collect();
            self.encode_and_commit(edits, &targets, provenance)?;
            report.tiles_written = edits
                .iter()
                .map(|e| out.join(self.tiles[e.tile].path.file_name().unwrap_or_default()))
                .collect();
            if out.is_dir() {
                std::fs::remove_dir(out).map_err(|e| RasterError::io(out, e))?;
            }
            std::fs::rename(&stage, out).map_err(|e| RasterError::io(out, e))?;
            Ok(report)
        };
        let r = run();
        if r.is_err() {
            let _ = std::fs::remove_dir_all(&stage);
        }
        r
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

/// Encode one edited tile into `tmp`: an uncompressed GeoTIFF (not a COG)
/// by [`update_tile_copy`], anything else by [`encode_tile_copy`]. The bytes
/// are made durable before the caller's rename makes them visible.
fn encode_tile(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    provenance: &Provenance,
) -> Result<(), RasterError> {
    let uncompressed =
        matches!(&tile.source, TileSource::Tiff(t) if t.encoding.compression == "NONE");
    let done = if uncompressed {
        update_tile_copy(tile, edit, tmp, provenance)
    } else {
        Ok(false)
    };
    let written = match done {
        Ok(true) => Ok(()),
        Ok(false) => encode_tile_copy(tile, edit, tmp, provenance),
        Err(e) => Err(e),
    };
    if let Err(e) = written {
        let _ = std::fs::remove_file(tmp);
        return Err(e);
    }
    std::fs::File::open(tmp)
        .and_then(|f| f.sync_all())
        .map_err(|e| RasterError::io(tmp, e))?;
    Ok(())
}

/// Write the edit into band 1 of `ds`: over its window, the stored values
/// with the edit merged in (cells to keep take their stored value back, so
/// nodata stays the file's own nodata value, bit for bit).
fn write_edit(ds: &gdal::Dataset, edit: &TileEdit) -> gdal::errors::Result<()> {
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
    band.write(origin, size, &mut Buffer::new(size, merged))
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
/// cheaper than re-encoding the whole file. `Ok(false)` (and `tmp` removed)
/// when the copy is a COG, whose layout an in-place update would break.
fn update_tile_copy(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    provenance: &Provenance,
) -> Result<bool, RasterError> {
    std::fs::copy(&tile.path, tmp).map_err(|e| RasterError::io(tmp, e))?;
    let werr = |e: gdal::errors::GdalError| write_err(tmp, e);
    let mut ds = gdal::Dataset::open_ex(
        tmp,
        gdal::DatasetOptions {
            open_flags: GdalOpenFlags::GDAL_OF_UPDATE | GdalOpenFlags::GDAL_OF_RASTER,
            allowed_drivers: Some(&["GTiff"]),
            ..Default::default()
        },
    )
    .map_err(werr)?;
    if ds.metadata_item("LAYOUT", "IMAGE_STRUCTURE").as_deref() == Some("COG") {
        drop(ds);
        let _ = std::fs::remove_file(tmp);
        return Ok(false);
    }
    write_edit(&ds, edit).map_err(werr)?;
    ds.set_metadata_item(PROVENANCE_KEY, &provenance.item(edit.changed), "")
        .map_err(werr)?;
    rebuild_overviews(tile, &mut ds, tmp)?;
    ds.close().map_err(werr)?;
    Ok(true)
}

/// Encode one edited tile into `tmp` through GDAL: the source is copied to
/// memory with all its metadata, the edit applied, overviews rebuilt, and
/// the result written with the source's creation options.
fn encode_tile_copy(
    tile: &Tile,
    edit: &TileEdit,
    tmp: &Path,
    provenance: &Provenance,
) -> Result<(), RasterError> {
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
    write_edit(&mem, edit).map_err(gerr)?;
    mem.set_metadata_item(PROVENANCE_KEY, &provenance.item(edit.changed), "")
        .map_err(gerr)?;
    let cog = src.metadata_item("LAYOUT", "IMAGE_STRUCTURE").as_deref() == Some("COG");
    let driver =
        DriverManager::get_driver_by_name(if cog { "COG" } else { "GTiff" }).map_err(gerr)?;
    let opts = RasterCreationOptions::from_iter(creation_options(tile, cog));
    let mut ds = mem
        .create_copy(&driver, tmp, &opts)
        .map_err(|e| write_err(tmp, format!("GDAL could not write the tile: {e}")))?;
    // The COG driver builds its own overviews.
    if !cog {
        rebuild_overviews(tile, &mut ds, tmp)?;
    }
    ds.close().map_err(|e| write_err(tmp, e))
}
