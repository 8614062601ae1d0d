//! Tile pyramids as `gdal_retile.py -levels N` makes them: the base tiles in
//! a directory and, in its subdirectories `1`, `2`, ... `N`, the tiles of
//! each level at half the resolution of the level below. After an edit
//! writes base tiles in place, [`Pyramid::refresh`] recomputes the level
//! tiles over the changed area the way `gdal_retile.py` computes them (each
//! level tile from the mosaic of the level below over its extent, with
//! GDAL's `GDALReprojectImage` and the pyramid's resampling), so every
//! level equals what `gdal_retile.py` would make from the edited base; the
//! other level tiles are not touched.
//!
//! The level tiles are rewritten through [`Dem::write_back`] (only their
//! changed blocks, staged, verified and renamed). The pyramid is checked
//! before the base is written ([`Pyramid::discover`]: every level tile a
//! GeoTIFF demsketch writes back natively), so a pyramid that cannot be
//! kept up to date stops the edit before anything is written.
//!
//! The resampling is not recorded in the files; it is the one given to
//! the edit (`--pyramid-resampling`), by default `near`, as
//! `gdal_retile.py`'s default.

use std::path::{Path, PathBuf};

use gdal::raster::Buffer;
use gdal::{Dataset, DriverManager};

use super::{Dem, Destination, Provenance, RasterError, Window};

/// The resampling names `gdal_retile.py -r` takes, with GDAL's algorithm.
const RESAMPLINGS: [(&str, gdal_sys::GDALResampleAlg::Type); 7] = [
    ("near", gdal_sys::GDALResampleAlg::GRA_NearestNeighbour),
    ("bilinear", gdal_sys::GDALResampleAlg::GRA_Bilinear),
    ("cubic", gdal_sys::GDALResampleAlg::GRA_Cubic),
    ("cubicspline", gdal_sys::GDALResampleAlg::GRA_CubicSpline),
    ("lanczos", gdal_sys::GDALResampleAlg::GRA_Lanczos),
    ("average", gdal_sys::GDALResampleAlg::GRA_Average),
    ("mode", gdal_sys::GDALResampleAlg::GRA_Mode),
];

/// `name` if it is a resampling of `gdal_retile.py -r`, else a message.
pub fn parse_resampling(name: &str) -> Result<&'static str, String> {
    RESAMPLINGS
        .iter()
        .find(|(n, _)| n.eq_ignore_ascii_case(name.trim()))
        .map(|(n, _)| *n)
        .ok_or_else(|| {
            let names: Vec<&str> = RESAMPLINGS.iter().map(|(n, _)| *n).collect();
            format!(
                "unknown pyramid resampling '{name}' (expected one of {})",
                names.join(", ")
            )
        })
}

/// One level tile: its file and where it lies.
#[derive(Debug, Clone)]
struct LevelTile {
    path: PathBuf,
    /// `[min x, min y, max x, max y]` in the CRS.
    bounds: [f64; 4],
}

/// The levels of a tile directory's pyramid (level 1 first).
#[derive(Debug, Clone)]
pub struct Pyramid {
    base: PathBuf,
    levels: Vec<Vec<LevelTile>>,
}

fn err(path: &Path, message: impl Into<String>) -> RasterError {
    RasterError::Write {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

/// The GeoTIFFs directly in `dir`, sorted.
fn tiffs(dir: &Path) -> Result<Vec<PathBuf>, RasterError> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| err(dir, format!("cannot list the pyramid level: {e}")))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && p.extension().is_some_and(|e| {
                    e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff")
                })
        })
        .collect();
    v.sort();
    Ok(v)
}

/// `[min x, min y, max x, max y]` of a raster with geotransform `gt`.
fn bounds_of(gt: [f64; 6], w: usize, h: usize) -> [f64; 4] {
    let (x0, x1) = (gt[0], gt[0] + gt[1] * w as f64);
    let (y0, y1) = (gt[3], gt[3] + gt[5] * h as f64);
    [x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1)]
}

fn overlaps(a: [f64; 4], b: [f64; 4]) -> bool {
    a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]
}

impl Pyramid {
    /// The pyramid of the tile directory `base`: its subdirectories `1`,
    /// `2`, ... (consecutive from 1) holding GeoTIFFs; `None` when it has
    /// none. Every level tile must be a GeoTIFF demsketch writes back in
    /// place, else an error naming it (checked before any write).
    pub fn discover(base: &Path) -> Result<Option<Pyramid>, RasterError> {
        let mut levels = Vec::new();
        for k in 1.. {
            let dir = base.join(k.to_string());
            if !dir.is_dir() {
                break;
            }
            let mut tiles = Vec::new();
            for path in tiffs(&dir)? {
                let dem = Dem::open(&path)?;
                if dem.tiles.iter().any(|t| t.read_by_gdal()) {
                    return Err(RasterError::Unsupported {
                        path: path.clone(),
                        what: "pyramid level tile read through GDAL: demsketch cannot keep it up to date in place".into(),
                    });
                }
                tiles.push(LevelTile {
                    bounds: bounds_of(dem.geotransform.0, dem.width, dem.height),
                    path,
                });
            }
            if tiles.is_empty() {
                break;
            }
            levels.push(tiles);
        }
        Ok((!levels.is_empty()).then(|| Pyramid {
            base: base.to_path_buf(),
            levels,
        }))
    }

    /// Number of levels.
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// The level tiles' files, level 1 first.
    pub fn level_tiles(&self) -> Vec<Vec<PathBuf>> {
        self.levels
            .iter()
            .map(|l| l.iter().map(|t| t.path.clone()).collect())
            .collect()
    }

    /// Recompute the level tiles over `changed` (CRS bounds `[min x, min
    /// y, max x, max y]` of the base cells an edit changed) with
    /// `resampling` (a name of [`parse_resampling`]); the level tiles
    /// written.
    pub fn refresh(
        &self,
        changed: [f64; 4],
        resampling: &str,
        provenance: &Provenance,
    ) -> Result<Vec<PathBuf>, RasterError> {
        self.refresh_areas(&[changed], resampling, provenance)
    }

    /// [`Pyramid::refresh`] over several changed areas at once (the edits
    /// of a batch): each level tile over any of them is recomputed once,
    /// from the level below as it is then, and written only where its
    /// cells differ. A level tile's cells are a function of the base
    /// alone, so this gives the cells refreshing after every edit would,
    /// and running it again changes nothing (a refresh cut short is
    /// finished by running it again).
    pub fn refresh_areas(
        &self,
        changed: &[[f64; 4]],
        resampling: &str,
        provenance: &Provenance,
    ) -> Result<Vec<PathBuf>, RasterError> {
        let alg = RESAMPLINGS
            .iter()
            .find(|(n, _)| *n == parse_resampling(resampling).unwrap_or("near"))
            .map_or(gdal_sys::GDALResampleAlg::GRA_NearestNeighbour, |r| r.1);
        let mut written = Vec::new();
        let mut below: Vec<PathBuf> = tiffs(&self.base)?;
        let mut areas: Vec<[f64; 4]> = changed
            .iter()
            .copied()
            .filter(|a| a.iter().all(|v| v.is_finite()) && a[0] <= a[2] && a[1] <= a[3])
            .collect();
        for level in &self.levels {
            // What a kernel of the level below reaches, around each change.
            let mut next = areas.clone();
            let mut any = false;
            for t in level {
                let margin = self.kernel_margin(t)?;
                let mut hit = false;
                for (area, n) in areas.iter().zip(next.iter_mut()) {
                    let grown = [
                        area[0] - margin,
                        area[1] - margin,
                        area[2] + margin,
                        area[3] + margin,
                    ];
                    if !overlaps(t.bounds, grown) {
                        continue;
                    }
                    hit = true;
                    *n = [
                        n[0].min(t.bounds[0].max(grown[0])),
                        n[1].min(t.bounds[1].max(grown[1])),
                        n[2].max(t.bounds[2].min(grown[2])),
                        n[3].max(t.bounds[3].min(grown[3])),
                    ];
                }
                if !hit {
                    continue;
                }
                if rebuild_tile(t, &below, alg, provenance)? {
                    written.push(t.path.clone());
                }
                any = true;
            }
            if !any {
                break;
            }
            areas = next;
            below = level.iter().map(|t| t.path.clone()).collect();
        }
        Ok(written)
    }

    /// How far (CRS units) a level tile's pixels reach into the level
    /// below: four of its own pixels (two of a kernel's radius at the 2x
    /// step, for every resampling up to Lanczos' three, with room).
    fn kernel_margin(&self, t: &LevelTile) -> Result<f64, RasterError> {
        let ds = Dataset::open(&t.path).map_err(|e| err(&t.path, e.to_string()))?;
        let gt = ds
            .geo_transform()
            .map_err(|e| err(&t.path, e.to_string()))?;
        Ok(4.0 * gt[1].abs().max(gt[5].abs()))
    }
}

/// Recompute level tile `t` from the tiles `below` as `gdal_retile.py`
/// does (`createPyramidTile`: the mosaic of the level below over the
/// tile's extent, `GDALReprojectImage` into the tile's grid), and write the
/// cells that differ; whether any did.
fn rebuild_tile(
    t: &LevelTile,
    below: &[PathBuf],
    alg: gdal_sys::GDALResampleAlg::Type,
    provenance: &Provenance,
) -> Result<bool, RasterError> {
    let gerr = |e: gdal::errors::GdalError| err(&t.path, e.to_string());
    let tile = Dataset::open(&t.path).map_err(gerr)?;
    let gt = tile.geo_transform().map_err(gerr)?;
    let (w, h) = tile.raster_size();
    let band = tile.rasterband(1).map_err(gerr)?;
    let band_type = band.band_type();
    let nodata = band.no_data_value();
    let current = band
        .read_as::<f64>((0, 0), (w, h), (w, h), None)
        .map_err(gerr)?;
    let mem = DriverManager::get_driver_by_name("MEM").map_err(gerr)?;
    // The source: the level below over the tile's extent, at its cell size.
    let first = below
        .first()
        .ok_or_else(|| err(&t.path, "the level below has no tiles"))?;
    let below_gt = Dataset::open(first)
        .and_then(|d| d.geo_transform())
        .map_err(gerr)?;
    let (sx, sy) = (below_gt[1], below_gt[5]);
    let (minx, maxy) = (gt[0], gt[3]);
    let (maxx, miny) = (gt[0] + gt[1] * w as f64, gt[3] + gt[5] * h as f64);
    let sw = ((maxx - minx) / sx + 0.5) as usize;
    let sh = ((miny - maxy) / sy + 0.5) as usize;
    let mut src = create_mem(&mem, sw, sh, band_type).map_err(gerr)?;
    src.set_geo_transform(&[minx, sx, 0.0, maxy, 0.0, sy])
        .map_err(gerr)?;
    src.set_projection(&tile.projection()).map_err(gerr)?;
    {
        let mut b = src.rasterband(1).map_err(gerr)?;
        if let Some(nd) = nodata {
            b.fill(nd, None).map_err(gerr)?;
            b.set_no_data_value(Some(nd)).map_err(gerr)?;
        }
    }
    let extent = [
        minx.min(maxx),
        miny.min(maxy),
        minx.max(maxx),
        miny.max(maxy),
    ];
    for p in below {
        copy_overlap(p, &mut src, extent, (minx, maxy, sx, sy), (sw, sh))?;
    }
    // The target: the tile's grid, filled with nodata first.
    let mut dst = create_mem(&mem, w, h, band_type).map_err(gerr)?;
    dst.set_geo_transform(&gt).map_err(gerr)?;
    dst.set_projection(&tile.projection()).map_err(gerr)?;
    {
        let mut b = dst.rasterband(1).map_err(gerr)?;
        if let Some(nd) = nodata {
            b.fill(nd, None).map_err(gerr)?;
            b.set_no_data_value(Some(nd)).map_err(gerr)?;
        }
    }
    // SAFETY: both datasets are open MEM datasets owned here; no
    // transformer callbacks or options are passed.
    let rc = unsafe {
        gdal_sys::GDALReprojectImage(
            src.c_dataset(),
            std::ptr::null(),
            dst.c_dataset(),
            std::ptr::null(),
            alg,
            0.0,
            0.0,
            None,
            std::ptr::null_mut(),
            std::ptr::null_mut(),
        )
    };
    if rc != gdal_sys::CPLErr::CE_None {
        return Err(err(
            &t.path,
            "GDALReprojectImage failed for the pyramid tile",
        ));
    }
    let new = dst
        .rasterband(1)
        .and_then(|b| b.read_as::<f64>((0, 0), (w, h), (w, h), None))
        .map_err(gerr)?;
    drop(tile);
    let (old, new) = (current.data(), new.data());
    if old == new {
        return Ok(false);
    }
    // Only the differing cells; NaN keeps a cell as stored. (An edit
    // never turns a valid cell into nodata, so neither does a level.)
    let dem = Dem::open(&t.path)?;
    let v = &dem.tiles[0].vertical;
    let values: Vec<f64> = old
        .iter()
        .zip(new)
        .map(|(&o, &n)| {
            if o == n || nodata.is_some_and(|nd| n == nd) {
                f64::NAN
            } else {
                v.to_metres(n)
            }
        })
        .collect();
    let report = dem.write_back(
        Window::new(0, 0, w, h),
        &values,
        &Destination::InPlace,
        provenance,
    )?;
    Ok(report.changed_cells > 0)
}

/// A one-band MEM dataset of `band_type`.
fn create_mem(
    mem: &gdal::Driver,
    w: usize,
    h: usize,
    band_type: gdal::raster::GdalDataType,
) -> gdal::errors::Result<Dataset> {
    use gdal::raster::GdalDataType as T;
    match band_type {
        T::UInt8 => mem.create_with_band_type::<u8, _>("", w, h, 1),
        T::UInt16 => mem.create_with_band_type::<u16, _>("", w, h, 1),
        T::Int16 => mem.create_with_band_type::<i16, _>("", w, h, 1),
        T::UInt32 => mem.create_with_band_type::<u32, _>("", w, h, 1),
        T::Int32 => mem.create_with_band_type::<i32, _>("", w, h, 1),
        T::Float32 => mem.create_with_band_type::<f32, _>("", w, h, 1),
        _ => mem.create_with_band_type::<f64, _>("", w, h, 1),
    }
}

/// Copy the part of raster `path` inside `extent` into `dst` (grid origin
/// `(minx, maxy)`, cell `(sx, sy)`, size `size`), as `gdal_retile.py`'s
/// mosaic does (pixel offsets rounded to the nearest).
fn copy_overlap(
    path: &Path,
    dst: &mut Dataset,
    extent: [f64; 4],
    grid: (f64, f64, f64, f64),
    size: (usize, usize),
) -> Result<(), RasterError> {
    let gerr = |e: gdal::errors::GdalError| err(path, e.to_string());
    let ds = Dataset::open(path).map_err(gerr)?;
    let g = ds.geo_transform().map_err(gerr)?;
    let (w, h) = ds.raster_size();
    let b = bounds_of(g, w, h);
    let (x0, x1) = (b[0].max(extent[0]), b[2].min(extent[2]));
    let (y0, y1) = (b[1].max(extent[1]), b[3].min(extent[3]));
    if !(x1 > x0 && y1 > y0) {
        return Ok(());
    }
    let (minx, maxy, sx, sy) = grid;
    let round = |v: f64| (v + 0.5).floor() as i64;
    let (sc, sr) = (round((x0 - g[0]) / g[1]), round((y1 - g[3]) / g[5]));
    let (dc, dr) = (round((x0 - minx) / sx), round((y1 - maxy) / sy));
    let cw = round((x1 - x0) / sx)
        .min(size.0 as i64 - dc)
        .min(w as i64 - sc);
    let ch = round((y0 - y1) / sy)
        .min(size.1 as i64 - dr)
        .min(h as i64 - sr);
    if cw <= 0 || ch <= 0 || sc < 0 || sr < 0 || dc < 0 || dr < 0 {
        return Ok(());
    }
    let (cw, ch) = (cw as usize, ch as usize);
    let data = ds
        .rasterband(1)
        .and_then(|band| band.read_as::<f64>((sc as isize, sr as isize), (cw, ch), (cw, ch), None))
        .map_err(gerr)?;
    let mut out = dst.rasterband(1).map_err(gerr)?;
    let mut buf = Buffer::new((cw, ch), data.data().to_vec());
    out.write((dc as isize, dr as isize), (cw, ch), &mut buf)
        .map_err(gerr)?;
    Ok(())
}
