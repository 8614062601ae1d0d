//! Overviews (reduced-resolution pyramids) refreshed over the changed area
//! only, with the resampling the file records, and their sidecars.
//!
//! Write-back edits a window of the full-resolution image; only the
//! overview cells whose source footprint meets that window can change. This
//! module recomputes those cells with GDAL's own resampling code and writes
//! them into the existing overview bands (internal, or an external `.ovr`),
//! leaving every other overview cell bit for bit as it was.
//!
//! How the new cells are computed: GDAL 3.6 has no public call that
//! regenerates a window of an overview, and its kernels are not simple
//! enough to copy exactly (AVERAGE weights fractional source pixels when the
//! size ratio is not an integer, levels cascade from the level above). So
//! the edited image, or the part of it that determines the changed cells,
//! is copied into an uncompressed GeoTIFF in GDAL's memory file system and
//! GDAL builds its pyramid there exactly as `gdaladdo -r R` would on the
//! result (internal overviews, or external with `-ro` when the target's are
//! external). When every level's size divides the image evenly and the
//! kernel reads no neighbours (NEAREST, AVERAGE, RMS, MODE), each overview
//! cell depends on its own block of source cells only, so a window aligned
//! to every factor gives the same cells as the whole image; otherwise
//! the whole image is used. Either way the cells over the change equal a
//! full `gdaladdo` on the result and the rest are never written.
//!
//! The resampling is, in order: the user's choice (`--overview-resampling`),
//! the `RESAMPLING` metadata item of the first overview (as newer GDAL's
//! `gdaladdo -r` records it; we record it the same way), and AVERAGE.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use gdal::raster::{Buffer, GdalType, RasterCreationOptions};
use gdal::{Dataset, DriverManager, GdalOpenFlags, Metadata};

use super::{RasterError, Window};

/// The resampling used when neither the user nor the file names one.
pub const DEFAULT_OVERVIEW_RESAMPLING: &str = "AVERAGE";

/// The metadata item (default domain of each overview band) that records
/// the resampling of the pyramid.
pub const RESAMPLING_ITEM: &str = "RESAMPLING";

/// The dataset item (default domain) that records it too: the COG driver
/// does not copy overview metadata, the main image's it does.
pub const DATASET_RESAMPLING_ITEM: &str = "DEMSKETCH_OVERVIEW_RESAMPLING";

/// The resampling methods GDAL's overview builder accepts.
pub const RESAMPLINGS: [&str; 10] = [
    "NEAREST",
    "AVERAGE",
    "RMS",
    "BILINEAR",
    "GAUSS",
    "CUBIC",
    "CUBICSPLINE",
    "LANCZOS",
    "MODE",
    "AVERAGE_MAGPHASE",
];

/// A resampling name checked against GDAL's list (case-insensitive), in
/// GDAL's spelling.
pub fn parse_resampling(s: &str) -> Result<&'static str, String> {
    let u = s.trim().to_ascii_uppercase();
    RESAMPLINGS
        .iter()
        .find(|r| **r == u)
        .copied()
        .ok_or_else(|| {
            format!(
                "overview resampling '{s}' is not one of {}",
                RESAMPLINGS.join(", ").to_ascii_lowercase()
            )
        })
}

/// The resampling a dataset's pyramid records, if any: the `RESAMPLING`
/// item of its first overview band (default or IMAGE_STRUCTURE domain), of
/// the dataset's IMAGE_STRUCTURE domain, or [`DATASET_RESAMPLING_ITEM`].
pub fn recorded_resampling(ds: &Dataset) -> Option<&'static str> {
    let band = ds.rasterband(1).ok()?;
    let ovr = band.overview(0).ok();
    ovr.as_ref()
        .and_then(|o| o.metadata_item(RESAMPLING_ITEM, ""))
        .or_else(|| {
            ovr.as_ref()
                .and_then(|o| o.metadata_item(RESAMPLING_ITEM, "IMAGE_STRUCTURE"))
        })
        .or_else(|| ds.metadata_item(RESAMPLING_ITEM, "IMAGE_STRUCTURE"))
        .or_else(|| ds.metadata_item(DATASET_RESAMPLING_ITEM, ""))
        .and_then(|r| parse_resampling(&r).ok())
}

/// Record `resampling` as the pyramid's on `ds` (open for update, or in
/// memory): on every overview band and as [`DATASET_RESAMPLING_ITEM`].
pub fn record_resampling(ds: &mut Dataset, resampling: &str) -> gdal::errors::Result<()> {
    {
        let band = ds.rasterband(1)?;
        for k in 0..band.overview_count()?.max(0) as usize {
            band.overview(k)?
                .set_metadata_item(RESAMPLING_ITEM, resampling, "")?;
        }
    }
    ds.set_metadata_item(DATASET_RESAMPLING_ITEM, resampling, "")
}

/// The resampling to use: `chosen`, else the recorded one, else AVERAGE.
pub fn resampling_for(ds: &Dataset, chosen: Option<&str>) -> &'static str {
    chosen
        .and_then(|c| parse_resampling(c).ok())
        .or_else(|| recorded_resampling(ds))
        .unwrap_or(DEFAULT_OVERVIEW_RESAMPLING)
}

/// How many source cells beyond its own footprint a kernel reads, in cells
/// of the level it reads from (GDAL's kernel radii).
fn kernel_radius(resampling: &str) -> usize {
    match resampling {
        "NEAREST" | "AVERAGE" | "RMS" | "MODE" | "AVERAGE_MAGPHASE" => 0,
        "BILINEAR" => 1,
        "CUBIC" | "CUBICSPLINE" | "GAUSS" => 2,
        _ => 3, // LANCZOS
    }
}

/// What one refresh did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RefreshStats {
    /// Overview levels refreshed.
    pub levels: usize,
    /// Overview cells (re)written, over all levels.
    pub cells: usize,
    /// True when the whole image had to be read (sizes not dividing
    /// evenly, or a kernel reading neighbours).
    pub whole_image: bool,
}

/// Refresh the overviews of band 1 of `ds` (open for update, the edit
/// already written) over `changed` (full-resolution pixels), with
/// `resampling` (the caller records it, [`record_resampling`]). `external`
/// says the overviews live in an `.ovr` (built as `gdaladdo -ro` builds
/// them). `target` names the file in errors.
pub fn refresh_overviews(
    ds: &Dataset,
    changed: Window,
    resampling: &str,
    external: bool,
    target: &Path,
) -> Result<RefreshStats, RasterError> {
    let werr = |m: String| RasterError::Write {
        path: target.to_path_buf(),
        message: m,
    };
    let gerr = |e: gdal::errors::GdalError| werr(format!("overviews: {e}"));
    let band = ds.rasterband(1).map_err(gerr)?;
    let count = band.overview_count().map_err(gerr)?.max(0) as usize;
    if count == 0 || changed.is_empty() {
        return Ok(RefreshStats::default());
    }
    let (w, h) = band.size();
    let mut levels = Vec::with_capacity(count);
    for k in 0..count {
        levels.push(band.overview(k).map_err(gerr)?.size());
    }
    let factors: Vec<usize> = levels
        .iter()
        .map(|&(ow, _)| ((w as f64 / ow as f64).round() as usize).max(1))
        .collect();
    // gdaladdo makes a level of factor f ceil(W / f) x ceil(H / f): a
    // pyramid of other sizes cannot be rebuilt the same way.
    for (&(ow, oh), &f) in levels.iter().zip(&factors) {
        if w.div_ceil(f) != ow || h.div_ceil(f) != oh {
            return Err(werr(format!(
                "overview {ow} x {oh} is not a 1/{f} level of the {w} x {h} image; rebuild it with gdaladdo"
            )));
        }
    }
    // Every level's ratio an integer: a window aligned to all factors gives
    // the whole image's cells.
    let align = factors.iter().fold(1usize, |a, &f| lcm(a, f));
    let windowed = kernel_radius(resampling) == 0
        && factors.iter().all(|&f| w % f == 0 && h % f == 0)
        && align <= w.min(h);
    let changed = changed
        .intersect(&Window::new(0, 0, w, h))
        .unwrap_or(changed);
    let region = if windowed {
        let f = align as i64;
        let c0 = changed.col.div_euclid(f) * f;
        let r0 = changed.row.div_euclid(f) * f;
        let c1 = (changed.col_end() + f - 1).div_euclid(f) * f;
        let r1 = (changed.row_end() + f - 1).div_euclid(f) * f;
        Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize)
    } else {
        Window::new(0, 0, w, h)
    };
    let fresh = FreshPyramid::build(ds, region, &factors, resampling, external, target)?;
    let mut stats = RefreshStats {
        levels: count,
        cells: 0,
        whole_image: !windowed,
    };
    let radius = kernel_radius(resampling);
    for (k, (&(ow, oh), &f)) in levels.iter().zip(&factors).enumerate() {
        // The level's cells whose footprint meets the change, with a margin
        // for fractional footprints and the kernel's reach through the
        // cascade of levels above.
        let margin = if windowed { 0 } else { 1 + radius * (k + 1) };
        let rx = w as f64 / ow as f64;
        let ry = h as f64 / oh as f64;
        let lo = |v: i64, r: f64| ((v as f64 / r).floor() as i64 - margin as i64).max(0);
        let hi =
            |v: i64, r: f64, n: usize| ((v as f64 / r).ceil() as i64 + margin as i64).min(n as i64);
        let (c0, c1) = (lo(changed.col, rx), hi(changed.col_end(), rx, ow));
        let (r0, r1) = (lo(changed.row, ry), hi(changed.row_end(), ry, oh));
        if c1 <= c0 || r1 <= r0 {
            continue;
        }
        let win = Window::new(c0, r0, (c1 - c0) as usize, (r1 - r0) as usize);
        let offset = (region.col / f as i64, region.row / f as i64);
        let values = fresh.read_level(k, win, offset).map_err(gerr)?;
        let mut ovr = band.overview(k).map_err(gerr)?;
        let size = (win.width, win.height);
        ovr.write(
            (win.col as isize, win.row as isize),
            size,
            &mut Buffer::new(size, values),
        )
        .map_err(gerr)?;
        stats.cells += win.len();
    }
    Ok(stats)
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

fn lcm(a: usize, b: usize) -> usize {
    a / gcd(a, b) * b
}

/// A unique name in GDAL's memory file system.
fn vsimem_name(what: &str) -> String {
    static N: AtomicUsize = AtomicUsize::new(0);
    format!(
        "/vsimem/demsketch-{}-{}-{what}.tif",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// The pyramid GDAL builds over `region` of the edited image, in memory.
struct FreshPyramid {
    name: String,
    ds: Option<Dataset>,
}

impl FreshPyramid {
    fn build(
        ds: &Dataset,
        region: Window,
        factors: &[usize],
        resampling: &str,
        external: bool,
        target: &Path,
    ) -> Result<FreshPyramid, RasterError> {
        let gerr = |e: gdal::errors::GdalError| RasterError::Write {
            path: target.to_path_buf(),
            message: format!("overviews: {e}"),
        };
        let band = ds.rasterband(1).map_err(gerr)?;
        let size = (region.width, region.height);
        let data = band
            .read_as::<f64>((region.col as isize, region.row as isize), size, size, None)
            .map_err(gerr)?;
        let nodata = band.no_data_value();
        let mut fresh = FreshPyramid {
            name: vsimem_name("pyramid"),
            ds: None,
        };
        let mem = create_like(band.band_type(), &fresh.name, size).map_err(gerr)?;
        {
            let mut b = mem.rasterband(1).map_err(gerr)?;
            if let Some(nd) = nodata {
                b.set_no_data_value(Some(nd)).map_err(gerr)?;
            }
            b.write(
                (0, 0),
                size,
                &mut Buffer::new(size, data.into_shape_and_vec().1),
            )
            .map_err(gerr)?;
        }
        let levels: Vec<i32> = factors.iter().map(|&f| f as i32).collect();
        let mut built = if external {
            mem.close().map_err(gerr)?;
            Dataset::open_ex(
                &fresh.name,
                gdal::DatasetOptions {
                    open_flags: GdalOpenFlags::GDAL_OF_READONLY | GdalOpenFlags::GDAL_OF_RASTER,
                    ..Default::default()
                },
            )
            .map_err(gerr)?
        } else {
            mem
        };
        built
            .build_overviews(resampling, &levels, &[])
            .map_err(gerr)?;
        fresh.ds = Some(built);
        Ok(fresh)
    }

    /// Level `k`'s cells over `win` (level pixels of the whole image), the
    /// region starting at `offset` in that level.
    fn read_level(
        &self,
        k: usize,
        win: Window,
        offset: (i64, i64),
    ) -> gdal::errors::Result<Vec<f64>> {
        let Some(ds) = &self.ds else {
            return Ok(vec![f64::NAN; win.len()]);
        };
        let ovr = ds.rasterband(1)?.overview(k)?;
        let size = (win.width, win.height);
        let buf = ovr.read_as::<f64>(
            ((win.col - offset.0) as isize, (win.row - offset.1) as isize),
            size,
            size,
            None,
        )?;
        Ok(buf.into_shape_and_vec().1)
    }
}

impl Drop for FreshPyramid {
    fn drop(&mut self) {
        self.ds = None;
        let _ = gdal::vsi::unlink_mem_file(format!("{}.ovr", self.name));
        let _ = gdal::vsi::unlink_mem_file(&self.name);
    }
}

/// An uncompressed tiled GeoTIFF at `name` of the given band type.
fn create_like(
    t: gdal::raster::GdalDataType,
    name: &str,
    (w, h): (usize, usize),
) -> gdal::errors::Result<Dataset> {
    use gdal::raster::GdalDataType as G;
    fn make<T: GdalType>(name: &str, w: usize, h: usize) -> gdal::errors::Result<Dataset> {
        let driver = DriverManager::get_driver_by_name("GTiff")?;
        let opts = RasterCreationOptions::from_iter(["TILED=YES", "BIGTIFF=IF_SAFER"]);
        driver.create_with_band_type_with_options::<T, _>(name, w, h, 1, &opts)
    }
    match t {
        G::UInt8 => make::<u8>(name, w, h),
        G::Int16 => make::<i16>(name, w, h),
        G::UInt16 => make::<u16>(name, w, h),
        G::Int32 => make::<i32>(name, w, h),
        G::UInt32 => make::<u32>(name, w, h),
        G::Float32 => make::<f32>(name, w, h),
        _ => make::<f64>(name, w, h),
    }
}

/// Rebuild the whole pyramid of `ds` (levels `factors`) with `resampling`,
/// recording it: for pyramids whose sizes [`refresh_overviews`] cannot
/// reproduce.
pub fn rebuild_all(
    ds: &mut Dataset,
    factors: &[i32],
    resampling: &str,
    target: &Path,
) -> Result<(), RasterError> {
    let gerr = |e: gdal::errors::GdalError| RasterError::Write {
        path: target.to_path_buf(),
        message: format!("GDAL could not rebuild overviews: {e}"),
    };
    ds.build_overviews(resampling, factors, &[]).map_err(gerr)?;
    record_resampling(ds, resampling).map_err(gerr)
}
