//! Write only what changed: a GeoTIFF tile is edited in a byte copy of
//! itself, so that only the blocks (tiles or strips) the edit touches are
//! decoded, merged and re-encoded, each with the file's own compression and
//! predictor, and every other block stays the compressed bytes it was.
//!
//! The copy is updated by GDAL's GeoTIFF driver (libtiff): a re-encoded
//! block that fits where the old one was is written there, a larger one is
//! appended and its offset and byte count rewritten, and the directory is
//! rewritten at the end when a tag changed. The result is a valid GeoTIFF
//! for GDAL and libtiff alike, with every tag, the layout (tiled or striped,
//! block size, BigTIFF or not) and all metadata kept. An appended block
//! leaves its old bytes unused inside the file (a few kilobytes per edit).
//! This was chosen over assembling a new file with our own encoder: it is
//! the same code every GIS tool writes GeoTIFFs with, it covers every
//! compression GDAL writes, and the cost is a file copy (a reflink where
//! the file system has them) plus the changed blocks.
//!
//! A cloud-optimised GeoTIFF (COG) would lose its layout (its blocks must
//! come in order after all directories): it is patched the same way in
//! GDAL's memory file system, then written out whole by GDAL's COG driver
//! with the patched overviews as they are (`OVERVIEWS=FORCE_USE_EXISTING`),
//! which keeps it a valid COG.
//!
//! Overviews are refreshed over the edit only ([`super::overviews`]), the
//! stale statistics cleared, and a provenance entry appended.

use std::path::Path;

use gdal::raster::{Buffer, RasterCreationOptions};
use gdal::{Dataset, DriverManager, GdalOpenFlags, Metadata};

use super::overviews::{
    rebuild_all, record_resampling, refresh_overviews, resampling_for, RefreshStats,
};
use super::provenance::history_items;
use super::{sidecars, RasterError, Window};

/// One edit of one file, in that file's pixels.
pub struct BlockEdit<'a> {
    /// The window holding changes.
    pub local: Window,
    /// New values over `local` (row-major), NaN = keep the stored value.
    pub values: &'a [f64],
}

/// What to record and how to rebuild, for one patched file.
pub struct PatchSettings<'a> {
    /// The provenance entry to append.
    pub entry: &'a str,
    /// `--overview-resampling`, if given.
    pub overview_resampling: Option<&'a str>,
    /// Overviews are in an external `.ovr` (staged as `TMP.ovr`).
    pub external_overviews: bool,
    /// The file being written, as errors name it (never the temporary
    /// file).
    pub target: &'a Path,
}

fn update_flags() -> GdalOpenFlags {
    GdalOpenFlags::GDAL_OF_UPDATE | GdalOpenFlags::GDAL_OF_RASTER
}

/// Open `path` (a GeoTIFF) for update through GDAL.
fn open_update(path: &Path) -> gdal::errors::Result<Dataset> {
    Dataset::open_ex(
        path,
        gdal::DatasetOptions {
            open_flags: update_flags(),
            allowed_drivers: Some(&["GTiff"]),
            ..Default::default()
        },
    )
}

/// True when `ds` says it is a COG.
pub fn is_cog(ds: &Dataset) -> bool {
    ds.metadata_item("LAYOUT", "IMAGE_STRUCTURE").as_deref() == Some("COG")
}

/// Patch `source` into `tmp`: a byte copy, edited in place. `Ok(None)`
/// (and `tmp` removed) when the source is a COG, which
/// [`patch_cog`] writes instead.
pub fn patch_copy(
    source: &Path,
    tmp: &Path,
    edit: &BlockEdit,
    settings: &PatchSettings,
) -> Result<Option<RefreshStats>, RasterError> {
    let target = settings.target;
    std::fs::copy(source, tmp).map_err(|e| RasterError::io(target, e))?;
    start_writeback(tmp);
    let werr = |e: gdal::errors::GdalError| RasterError::Write {
        path: target.to_path_buf(),
        message: e.to_string(),
    };
    let mut ds = open_update(tmp).map_err(werr)?;
    if is_cog(&ds) {
        drop(ds);
        let _ = std::fs::remove_file(tmp);
        return Ok(None);
    }
    let stats = edit_dataset(&mut ds, edit, settings, target)?;
    ds.close().map_err(werr)?;
    Ok(Some(stats))
}

/// Starts the kernel writing the dirty pages of `path` (the fresh copy)
/// to disk without waiting for them (Linux `sync_file_range` with
/// `SYNC_FILE_RANGE_WRITE`), so that the copy goes to the disk while its
/// blocks are patched, and the `fsync` before the rename waits only for
/// what is left. Best effort: it guarantees nothing and a failure changes
/// nothing; the file is made durable by that `fsync`, as before.
fn start_writeback(path: &Path) {
    #[cfg(target_os = "linux")]
    if let Ok(f) = std::fs::File::open(path) {
        use std::os::fd::AsRawFd;
        // SAFETY: `f` is an open descriptor for the whole call; the call
        // only schedules write-out of its pages (offset 0, length 0: all).
        let _ = unsafe { libc::sync_file_range(f.as_raw_fd(), 0, 0, libc::SYNC_FILE_RANGE_WRITE) };
    }
    #[cfg(not(target_os = "linux"))]
    let _ = path;
}

/// Patch a COG `source` in memory and write it to `tmp` with GDAL's COG
/// driver, keeping its patched overviews. `cog_options`: the creation
/// options that reproduce its encoding.
pub fn patch_cog(
    source: &Path,
    tmp: &Path,
    edit: &BlockEdit,
    settings: &PatchSettings,
    cog_options: &[String],
) -> Result<RefreshStats, RasterError> {
    let target = settings.target;
    let werr = |e: gdal::errors::GdalError| RasterError::Write {
        path: target.to_path_buf(),
        message: e.to_string(),
    };
    let bytes = std::fs::read(source).map_err(|e| RasterError::io(source, e))?;
    let mem = MemCopy::new(bytes).map_err(werr)?;
    let stats = {
        let mut ds = open_update(Path::new(&mem.name)).map_err(werr)?;
        let stats = edit_dataset(&mut ds, edit, settings, target)?;
        ds.flush_cache().map_err(werr)?;
        let driver = DriverManager::get_driver_by_name("COG").map_err(werr)?;
        let mut opts: Vec<String> = cog_options.to_vec();
        opts.push("OVERVIEWS=FORCE_USE_EXISTING".into());
        let out = ds
            .create_copy(&driver, tmp, &RasterCreationOptions::from_iter(opts))
            .map_err(|e| RasterError::Write {
                path: target.to_path_buf(),
                message: format!("GDAL could not write the COG: {e}"),
            })?;
        out.close().map_err(werr)?;
        stats
    };
    Ok(stats)
}

/// A file's bytes in GDAL's memory file system, removed on drop.
struct MemCopy {
    name: String,
}

impl MemCopy {
    fn new(bytes: Vec<u8>) -> gdal::errors::Result<MemCopy> {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static N: AtomicUsize = AtomicUsize::new(0);
        let name = format!(
            "/vsimem/demsketch-{}-{}-patch.tif",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        );
        // Written through GDAL's own file API, so that GDAL owns (and may
        // grow) a buffer from its allocator: a buffer handed over from Rust
        // comes from ours (mimalloc in the binary), and GDAL's realloc of
        // it would corrupt the heap.
        let c_name = std::ffi::CString::new(name.as_str())?;
        // SAFETY: valid C strings; the handle is checked and closed; the
        // write reads `bytes.len()` bytes from a live slice.
        let written = unsafe {
            let fp = gdal_sys::VSIFOpenL(c_name.as_ptr(), c"wb".as_ptr());
            if fp.is_null() {
                return Err(gdal::errors::GdalError::NullPointer {
                    method_name: "VSIFOpenL",
                    msg: name.clone(),
                });
            }
            let n = gdal_sys::VSIFWriteL(bytes.as_ptr().cast(), 1, bytes.len(), fp);
            gdal_sys::VSIFCloseL(fp);
            n
        };
        let copy = MemCopy { name };
        if written != bytes.len() {
            return Err(gdal::errors::GdalError::NullPointer {
                method_name: "VSIFWriteL",
                msg: format!(
                    "{} of {} bytes written to {}",
                    written,
                    bytes.len(),
                    copy.name
                ),
            });
        }
        Ok(copy)
    }
}

impl Drop for MemCopy {
    fn drop(&mut self) {
        let _ = gdal::vsi::unlink_mem_file(&self.name);
    }
}

/// Apply `edit` to band 1 of `ds` (open for update), append the
/// provenance entry, clear the stale statistics and refresh the overviews
/// over the edit.
pub fn edit_dataset(
    ds: &mut Dataset,
    edit: &BlockEdit,
    settings: &PatchSettings,
    target: &Path,
) -> Result<RefreshStats, RasterError> {
    let werr = |e: gdal::errors::GdalError| RasterError::Write {
        path: target.to_path_buf(),
        message: e.to_string(),
    };
    write_edit(ds, edit).map_err(werr)?;
    append_provenance(ds, settings.entry).map_err(werr)?;
    sidecars::clear_statistics(ds);
    let resampling = resampling_for(ds, settings.overview_resampling);
    match refresh_overviews(
        ds,
        edit.local,
        resampling,
        settings.external_overviews,
        target,
    ) {
        Ok(stats) => {
            if stats.levels > 0 {
                record_resampling(ds, resampling).map_err(werr)?;
            }
            Ok(stats)
        }
        // A pyramid gdaladdo would not make (odd level sizes): rebuilt whole.
        Err(RasterError::Write { .. }) if !settings.external_overviews => {
            let band = ds.rasterband(1).map_err(werr)?;
            let w = band.size().0 as f64;
            let factors: Vec<i32> = (0..band.overview_count().map_err(werr)?.max(0) as usize)
                .map(|k| {
                    band.overview(k)
                        .map(|o| ((w / o.size().0 as f64).round() as i32).max(2))
                })
                .collect::<Result<_, _>>()
                .map_err(werr)?;
            rebuild_all(ds, &factors, resampling, target)?;
            Ok(RefreshStats {
                levels: factors.len(),
                cells: 0,
                whole_image: true,
            })
        }
        Err(e) => Err(e),
    }
}

/// Write the edit into band 1 of `ds`: over its window, the stored values
/// with the edit merged in (cells to keep take their stored value back, so
/// nodata stays the file's own nodata value, bit for bit).
pub fn write_edit(ds: &Dataset, edit: &BlockEdit) -> gdal::errors::Result<()> {
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

/// Append `entry` to the provenance history of `ds`.
pub fn append_provenance(ds: &mut Dataset, entry: &str) -> gdal::errors::Result<()> {
    let existing = ds.metadata_domain("").unwrap_or_default();
    for (k, v) in history_items(&existing, entry) {
        ds.set_metadata_item(&k, &v, "")?;
    }
    Ok(())
}
