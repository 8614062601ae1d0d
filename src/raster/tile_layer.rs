//! The tile layer: one DEM made of one GeoTIFF, a directory of GeoTIFF tiles
//! on a common grid, or any raster GDAL opens (VRT included). It presents the
//! whole DEM as one pixel grid and reads any window of it as one seamless
//! array with a nodata mask. Reading is lazy (only the blocks a window
//! touches are decoded), decoded blocks are cached under a memory bound, and
//! decoding runs in parallel on rayon.
//!
//! Heights leave the layer in metres: each tile's band scale, offset and
//! vertical unit ([`Vertical`]) are applied after the nodata test, so that
//! everything downstream works in metres ([`Dem::read_window_raw`] gives
//! the stored values, for write-back).
//!
//! The native decoder reads what it reads exactly (and fast); whatever it
//! does not (GDAL virtual file systems such as `/vsizip/`, LERC or JPEG
//! compression, CRSs it cannot build from GeoKeys) is read through GDAL.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;
use tiff::decoder::DecodingResult;

use super::block_cache::BlockCache;
use super::geotiff::{memory_budget, GeoTiff};
use super::vertical::vertical_of_srs;
use super::{
    Crs, GeoTransform, HeightMap, RasterError, Sample, SampleType, Vertical, Window, WindowData,
};

/// Where a tile's pixels come from.
pub enum TileSource {
    /// Decoded natively (GeoTIFF). Shared: a DEM reopened for a second
    /// look ([`Dem::reopened`]) holds the same parsed file, not a copy of
    /// its block tables (1,024 tiles copied twice an edit cost about 10 M
    /// instructions).
    Tiff(Arc<GeoTiff>),
    /// Read through GDAL (VRT and every other format GDAL opens).
    Gdal(Mutex<gdal::Dataset>),
}

/// One file of the layer and where it sits in the layer's grid.
pub struct Tile {
    pub path: PathBuf,
    pub source: TileSource,
    /// The tile's pixels in the layer grid.
    pub extent: Window,
    pub sample_type: SampleType,
    pub nodata: Option<f64>,
    pub geotransform: GeoTransform,
    /// Stored value -> metres (band scale, offset, vertical unit).
    pub vertical: Vertical,
}

impl Tile {
    /// True when the tile is read through GDAL rather than natively.
    pub fn read_by_gdal(&self) -> bool {
        matches!(self.source, TileSource::Gdal(_))
    }
}

/// What kind of input the layer was opened from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LayerKind {
    GeoTiff,
    TileDirectory,
    Gdal,
}

/// A tile as opened, before it is placed on the layer grid.
struct Part {
    tile: Tile,
    /// The CRS of a tile GDAL reads (a native tile's is its GeoTIFF's).
    gdal_crs: Option<Crs>,
    /// The CRS is a projected or geographic one (not local or absent).
    earth_crs: bool,
}

impl Part {
    fn crs(&self) -> &Crs {
        // (A GDAL tile always has its CRS: the last arm is not reached.)
        static UNKNOWN: Crs = Crs {
            epsg: None,
            wkt: String::new(),
            proj: None,
            geographic: false,
        };
        match (&self.gdal_crs, &self.tile.source) {
            (Some(c), _) => c,
            (None, TileSource::Tiff(t)) => &t.crs,
            (None, TileSource::Gdal(_)) => &UNKNOWN,
        }
    }
}

/// A DEM as one grid over all its tiles.
pub struct Dem {
    pub path: PathBuf,
    pub kind: LayerKind,
    pub tiles: Vec<Tile>,
    pub width: usize,
    pub height: usize,
    pub geotransform: GeoTransform,
    pub crs: Crs,
    pub nodata: Option<f64>,
    pub sample_type: SampleType,
    /// The first tile's vertical description (unit, datum, scale, offset).
    pub vertical: Vertical,
    /// Decoded blocks (shared with the DEMs [`Dem::reopened`] from this one).
    cache: Arc<BlockCache>,
    /// Heights that [`Dem::read_height_map`] returns instead of the stored
    /// ones over a window ([`Dem::with_overlay`]).
    overlay: Option<(Window, std::sync::Arc<Vec<f32>>)>,
}

fn is_tiff_name(p: &Path) -> bool {
    matches!(
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref(),
        Some("tif" | "tiff" | "gtiff")
    )
}

/// True when `a` and `b` agree to `rel` relative precision.
fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-300)
}

fn nodata_eq(a: Option<f64>, b: Option<f64>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(x), Some(y)) => x == y || (x.is_nan() && y.is_nan()),
        _ => false,
    }
}

impl Dem {
    /// Open a GeoTIFF, a directory of GeoTIFF tiles, or a raster GDAL opens.
    pub fn open(path: &Path) -> Result<Dem, RasterError> {
        if is_gdal_virtual(path) {
            let tile = Self::open_gdal(path)?;
            return Self::mosaic(path, LayerKind::Gdal, vec![tile]);
        }
        let meta = std::fs::metadata(path).map_err(|e| RasterError::io(path, e))?;
        if meta.is_dir() {
            // The entries' types come with the listing: only symbolic
            // links cost a stat (to find where they lead).
            let mut files: Vec<(std::ffi::OsString, PathBuf, bool)> = std::fs::read_dir(path)
                .map_err(|e| RasterError::io(path, e))?
                .filter_map(|e| e.ok())
                .filter_map(|e| {
                    let p = e.path();
                    if !is_tiff_name(&p) {
                        return None;
                    }
                    match e.file_type().ok()? {
                        t if t.is_file() => Some((e.file_name(), p, true)),
                        t if t.is_symlink() => {
                            let to_file = p.is_file();
                            Some((e.file_name(), p, to_file))
                        }
                        _ => None,
                    }
                })
                .collect();
            // One parent: the order of the paths is that of the names,
            // compared as bytes (cheaper than comparing paths).
            files.sort_unstable_by(|a, b| a.0.as_encoded_bytes().cmp(b.0.as_encoded_bytes()));
            // A tile name whose symlink leads nowhere is a missing tile,
            // not a hole to skip silently.
            if let Some((_, broken, _)) = files.iter().find(|(_, _, is_file)| !is_file) {
                let to = std::fs::read_link(broken)
                    .map(|t| t.display().to_string())
                    .unwrap_or_default();
                return Err(RasterError::io(
                    broken.clone(),
                    std::io::Error::new(
                        std::io::ErrorKind::NotFound,
                        format!("broken symbolic link: the tile it points to ({to}) is not a file"),
                    ),
                ));
            }
            if files.is_empty() {
                return Err(RasterError::EmptyDirectory {
                    path: path.to_path_buf(),
                });
            }
            // One memory budget for every tile's header checks.
            let budget = memory_budget();
            let tiles = files
                .par_iter()
                .with_min_len(64)
                .map(|(_, f, _)| Self::open_tile(f, budget))
                .collect::<Result<Vec<_>, _>>()?;
            Self::mosaic(path, LayerKind::TileDirectory, tiles)
        } else if is_tiff_name(path) || Self::sniff_tiff(path) {
            let tile = Self::open_tile(path, memory_budget())?;
            Self::mosaic(path, LayerKind::GeoTiff, vec![tile])
        } else {
            let tile = Self::open_gdal(path)?;
            Self::mosaic(path, LayerKind::Gdal, vec![tile])
        }
    }

    fn sniff_tiff(path: &Path) -> bool {
        use std::io::Read;
        let mut b = [0u8; 4];
        std::fs::File::open(path)
            .and_then(|mut f| f.read_exact(&mut b))
            .map(|_| matches!(&b, b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+"))
            .unwrap_or(false)
    }

    /// Open one GeoTIFF natively, or through GDAL where the native decoder
    /// does not support it (GDAL's error is kept only if GDAL fails too and
    /// the native one says less).
    fn open_tile(path: &Path, budget: u64) -> Result<Part, RasterError> {
        let t = match GeoTiff::open_with_budget(path, budget) {
            Ok(t) => t,
            Err(native @ (RasterError::NotNative { .. } | RasterError::Crs { .. })) => {
                // GDAL's own complaints are not shown: if it fails too, the
                // native error says what is wrong in one line.
                // A CRS the native reader cannot build must come out of GDAL
                // as a CRS, or the native error stands.
                let crs_problem = matches!(&native, RasterError::Crs { .. })
                    || matches!(&native, RasterError::NotNative { what, .. } if what.contains("projection"));
                return match quiet_gdal(|| Self::open_gdal(path)) {
                    Ok(part) if !crs_problem || part.earth_crs => Ok(part),
                    _ => Err(native),
                };
            }
            Err(e) => return Err(e),
        };
        Ok(Part {
            earth_crs: true,
            gdal_crs: None,
            tile: Tile {
                path: path.to_path_buf(),
                extent: Window::new(0, 0, t.width as usize, t.height as usize),
                sample_type: t.sample_type,
                nodata: t.nodata,
                geotransform: t.geotransform,
                vertical: t.vertical.clone(),
                source: TileSource::Tiff(Arc::new(t)),
            },
        })
    }

    fn open_gdal(path: &Path) -> Result<Part, RasterError> {
        let ds = gdal::Dataset::open(path).map_err(|e| RasterError::gdal(path, e))?;
        let (w, h) = ds.raster_size();
        let gt = ds
            .geo_transform()
            .map_err(|_| RasterError::NoGeoreference {
                path: path.to_path_buf(),
            })?;
        let band = ds.rasterband(1).map_err(|e| RasterError::gdal(path, e))?;
        let sample_type =
            SampleType::from_gdal(band.band_type()).ok_or_else(|| RasterError::Unsupported {
                path: path.to_path_buf(),
                what: format!("band type {:?}", band.band_type()),
            })?;
        let nodata = band.no_data_value();
        let (scale, offset, unit) = (band.scale(), band.offset(), band.unit());
        let srs = ds.spatial_ref().ok();
        let crs = Crs {
            epsg: srs.as_ref().and_then(horizontal_epsg),
            wkt: ds.projection(),
            proj: srs.as_ref().and_then(|s| s.to_proj4().ok()),
            geographic: srs.as_ref().map(|s| s.is_geographic()).unwrap_or(false),
        };
        let vertical = Vertical::of_file(
            path,
            scale,
            offset,
            &unit,
            srs.as_ref().and_then(vertical_of_srs),
        )?;
        Ok(Part {
            earth_crs: srs
                .as_ref()
                .is_some_and(|s| s.is_projected() || s.is_geographic()),
            gdal_crs: Some(crs),
            tile: Tile {
                path: path.to_path_buf(),
                extent: Window::new(0, 0, w, h),
                sample_type,
                nodata,
                geotransform: GeoTransform(gt),
                vertical,
                source: TileSource::Gdal(Mutex::new(ds)),
            },
        })
    }

    /// Place tiles on one grid, checking CRS, pixel size, alignment, sample
    /// type and nodata against the first tile.
    fn mosaic(path: &Path, kind: LayerKind, parts: Vec<Part>) -> Result<Dem, RasterError> {
        let first = &parts[0];
        let (ref_path, ref_gt, ref_crs, ref_nodata, ref_type, ref_vertical) = (
            first.tile.path.clone(),
            first.tile.geotransform,
            first.crs().clone(),
            first.tile.nodata,
            first.tile.sample_type,
            first.tile.vertical.clone(),
        );
        let g = ref_gt.0;
        let mismatch = |p: &Path, what: String| RasterError::TileMismatch {
            path: p.to_path_buf(),
            reference: ref_path.clone(),
            what,
        };
        // Pixel offsets of each tile relative to the first.
        let mut placed = Vec::with_capacity(parts.len());
        for part in &parts {
            let (tile, crs) = (&part.tile, part.crs());
            let (p, t) = (&tile.path, tile.geotransform.0);
            if !crs.same_as(&ref_crs) {
                return Err(mismatch(p, "different CRS".into()));
            }
            if !(close(t[1], g[1], 1e-9) && close(t[5], g[5], 1e-9) && t[2] == g[2] && t[4] == g[4])
            {
                return Err(mismatch(
                    p,
                    format!(
                        "pixel size {} x {} differs from {} x {}",
                        t[1], t[5], g[1], g[5]
                    ),
                ));
            }
            let (px, py) = ref_gt
                .crs_to_pixel(t[0], t[3])
                .ok_or_else(|| mismatch(p, "singular geotransform".into()))?;
            let (cx, cy) = (px.round(), py.round());
            if (px - cx).abs() > 1e-6 || (py - cy).abs() > 1e-6 {
                return Err(mismatch(
                    p,
                    format!("not aligned on the pixel grid (offset {px:.6}, {py:.6} pixels)"),
                ));
            }
            if tile.sample_type != ref_type {
                return Err(mismatch(
                    p,
                    format!("sample type {} differs from {ref_type}", tile.sample_type),
                ));
            }
            if !nodata_eq(tile.nodata, ref_nodata) {
                return Err(mismatch(
                    p,
                    format!("nodata {:?} differs from {ref_nodata:?}", tile.nodata),
                ));
            }
            placed.push((cx as i64, cy as i64));
        }
        let c0 = placed.iter().map(|t| t.0).min().unwrap_or(0);
        let r0 = placed.iter().map(|t| t.1).min().unwrap_or(0);
        let tiles: Vec<Tile> = parts
            .into_iter()
            .zip(placed)
            .map(|(Part { mut tile, .. }, (c, r))| {
                tile.extent = Window::new(c - c0, r - r0, tile.extent.width, tile.extent.height);
                tile
            })
            .collect();
        if let Some((i, j)) = first_overlap(&tiles) {
            return Err(mismatch(
                &tiles[i].path,
                format!("overlaps tile {}", tiles[j].path.display()),
            ));
        }
        let width = tiles.iter().map(|t| t.extent.col_end()).max().unwrap_or(0) as usize;
        let height = tiles.iter().map(|t| t.extent.row_end()).max().unwrap_or(0) as usize;
        let cache_budget = (memory_budget() / 4).min(usize::MAX as u64) as usize;
        Ok(Dem {
            path: path.to_path_buf(),
            kind,
            geotransform: ref_gt.offset(c0 as f64, r0 as f64),
            crs: ref_crs,
            nodata: ref_nodata,
            sample_type: ref_type,
            vertical: ref_vertical,
            tiles,
            width,
            height,
            cache: Arc::new(BlockCache::new(cache_budget)),
            overlay: None,
        })
    }

    /// This DEM without a cache of decoded blocks, for a DEM whose windows
    /// are read once (`view`): the blocks of a large window are not kept
    /// beside it (they would double what the read holds, in fresh pages).
    pub fn without_block_cache(mut self) -> Dem {
        self.cache = Arc::new(BlockCache::new(0));
        self
    }

    /// This DEM with its cache of decoded blocks bounded by `bytes` (when
    /// under the default, a quarter of the memory budget): for work that
    /// reads one large window once and then small ones (an edit reads the
    /// views' wedges, then the deformation's windows), so that the large
    /// window's blocks are not all kept beside it.
    pub fn with_block_cache_budget(mut self, bytes: usize) -> Dem {
        if bytes < self.cache.budget() {
            self.cache = Arc::new(BlockCache::new(bytes));
        }
        self
    }

    /// The window covering the whole DEM.
    pub fn full_window(&self) -> Window {
        Window::new(0, 0, self.width, self.height)
    }

    /// The smallest window that covers the CRS rectangle
    /// `[xmin, ymin, xmax, ymax]`, clipped to the DEM.
    pub fn window_for_bounds(&self, b: [f64; 4]) -> Option<Window> {
        let corners = [(b[0], b[1]), (b[0], b[3]), (b[2], b[1]), (b[2], b[3])];
        let mut c = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for (x, y) in corners {
            let (px, py) = self.geotransform.crs_to_pixel(x, y)?;
            c = [c[0].min(px), c[1].min(py), c[2].max(px), c[3].max(py)];
        }
        let w = Window::new(
            c[0].floor() as i64,
            c[1].floor() as i64,
            (c[2].ceil() - c[0].floor()).max(0.0) as usize,
            (c[3].ceil() - c[1].floor()).max(0.0) as usize,
        );
        w.intersect(&self.full_window())
    }

    /// Read a window of heights in metres as one seamless array across
    /// tiles. Cells outside every tile, and nodata cells, are invalid (their
    /// value is NaN).
    pub fn read_window<T: Sample>(&self, win: Window) -> Result<WindowData<T>, RasterError> {
        self.read(win, true, true, true)
    }

    /// Read a window of stored values (before scale, offset and unit), as
    /// [`Dem::read_window`] otherwise does.
    pub fn read_window_raw<T: Sample>(&self, win: Window) -> Result<WindowData<T>, RasterError> {
        self.read(win, false, true, true)
    }

    /// Read a window, in metres when `metres`, else as stored. Nodata is
    /// tested on the stored value, in the precision of the sample type as
    /// GDAL does (a Float32 file's nodata of -3.4e38 is the f32 nearest to
    /// it); the conversion to metres is done in f64, before rounding to `T`.
    /// Without `mask` the validity mask is left empty (a height map marks
    /// invalid cells NaN and needs none). Without `cached` the blocks
    /// decoded are not kept (cached ones are still used): for cells read
    /// once, which would only push out the blocks worth keeping.
    fn read<T: Sample>(
        &self,
        win: Window,
        metres: bool,
        mask: bool,
        cached: bool,
    ) -> Result<WindowData<T>, RasterError> {
        let n = win.len();
        let bytes = (n as u64).saturating_mul(std::mem::size_of::<T>() as u64 + 1);
        let budget = memory_budget();
        if bytes > budget {
            return Err(RasterError::TooLarge {
                path: self.path.clone(),
                width: win.width as u64,
                height: win.height as u64,
                sample: std::any::type_name::<T>().into(),
                bytes,
                budget,
            });
        }
        // Nodata is the same for every tile (checked at open).
        let nodata = self.nodata.map(|v| self.sample_type.quantize(v));
        let jobs = self.read_jobs(win);
        // Fail fast: decode one block (kept in the cache) before the window
        // is allocated, so that a broken or crafted file costs little.
        if let Some(&(ti, Some(bi))) = jobs.first() {
            if let (TileSource::Tiff(tiff), true) = (&self.tiles[ti].source, cached) {
                self.block((ti, bi), tiff, true)?;
            }
        }
        let mut data =
            super::alloc::try_filled(n, T::nan()).ok_or_else(|| RasterError::TooLarge {
                path: self.path.clone(),
                width: win.width as u64,
                height: win.height as u64,
                sample: std::any::type_name::<T>().into(),
                bytes,
                budget,
            })?;
        let out = SharedOut {
            ptr: data.as_mut_ptr(),
            len: n,
        };
        jobs.par_iter()
            .map(|&(ti, block)| -> Result<(), RasterError> {
                let tile = &self.tiles[ti];
                match (&tile.source, block) {
                    (TileSource::Tiff(tiff), Some(bi)) => {
                        let decoded = self.block((ti, bi), tiff, cached)?;
                        copy_block(tile, tiff, bi, &decoded, win, metres, nodata, &out)
                    }
                    (TileSource::Gdal(ds), _) => {
                        copy_gdal_tile(tile, ds, win, metres, nodata, &out)
                    }
                    (TileSource::Tiff(_), None) => Ok(()),
                }
            })
            .collect::<Result<Vec<()>, _>>()?;
        if !mask {
            return Ok(WindowData {
                window: win,
                data,
                valid: Vec::new(),
            });
        }
        // Cells outside every tile, and nodata (set to NaN above), are
        // invalid.
        let mut valid =
            super::alloc::try_filled(n, false).ok_or_else(|| RasterError::TooLarge {
                path: self.path.clone(),
                width: win.width as u64,
                height: win.height as u64,
                sample: "mask".into(),
                bytes,
                budget,
            })?;
        data.par_chunks(win.width.max(1))
            .zip(valid.par_chunks_mut(win.width.max(1)))
            .for_each(|(d, v)| {
                for (x, ok) in d.iter().zip(v.iter_mut()) {
                    *ok = !x.to_f64().is_nan();
                }
            });
        Ok(WindowData {
            window: win,
            data,
            valid,
        })
    }

    /// What reading `win` takes: (tile, block) pairs for native tiles, the
    /// whole overlap for GDAL ones.
    fn read_jobs(&self, win: Window) -> Vec<(usize, Option<u32>)> {
        let mut jobs: Vec<(usize, Option<u32>)> = Vec::new();
        for (ti, tile) in self.tiles.iter().enumerate() {
            let Some(ov) = tile.extent.intersect(&win) else {
                continue;
            };
            match &tile.source {
                TileSource::Tiff(tiff) => {
                    let l = &tiff.layout;
                    let lc0 = (ov.col - tile.extent.col) as u32;
                    let lr0 = (ov.row - tile.extent.row) as u32;
                    let lc1 = lc0 + ov.width as u32 - 1;
                    let lr1 = lr0 + ov.height as u32 - 1;
                    for by in lr0 / l.block_height..=lr1 / l.block_height {
                        for bx in lc0 / l.block_width..=lc1 / l.block_width {
                            jobs.push((ti, Some(by * l.blocks_across + bx)));
                        }
                    }
                }
                TileSource::Gdal(_) => jobs.push((ti, None)),
            }
        }
        jobs
    }

    /// Block `key` (tile, block) decoded: from the cache, or decoded (and
    /// kept when `cached`).
    fn block(
        &self,
        key: (usize, u32),
        tiff: &GeoTiff,
        cached: bool,
    ) -> Result<Arc<DecodingResult>, RasterError> {
        Ok(match self.cache.get(key) {
            Some(b) => b,
            None => {
                let b = Arc::new(tiff.decode_block(key.1)?);
                if cached {
                    self.cache.insert(key, b.clone());
                }
                b
            }
        })
    }

    /// This DEM as it reads with `heights` (metres, NaN = nodata, row-major
    /// over `window`) in place of its stored heights there: what an edit
    /// in progress sees of its own result before anything is written. Only
    /// [`Dem::read_height_map`] sees them; writes, and the checks of what
    /// a write changes, work on the stored values.
    pub fn with_overlay(mut self, window: Window, heights: Vec<f32>) -> Dem {
        debug_assert_eq!(heights.len(), window.len());
        self.overlay = Some((window, std::sync::Arc::new(heights)));
        self
    }

    /// The same DEM opened again, without reading it again: native tiles
    /// share their bytes (and mapping) with this one, GDAL tiles are
    /// opened anew; no overlay; the cache of decoded blocks shared (the
    /// files are the same). For a second look at the DEM through an overlay
    /// ([`Dem::with_overlay`]) at the cost of the tile list, not of opening
    /// every tile (and mapping its header) again.
    pub fn reopened(&self) -> Result<Dem, RasterError> {
        let tiles = self
            .tiles
            .iter()
            .map(|t| -> Result<Tile, RasterError> {
                let source = match &t.source {
                    TileSource::Tiff(g) => TileSource::Tiff(Arc::clone(g)),
                    TileSource::Gdal(_) => {
                        let ds = gdal::Dataset::open(&t.path)
                            .map_err(|e| RasterError::gdal(&t.path, e))?;
                        TileSource::Gdal(Mutex::new(ds))
                    }
                };
                Ok(Tile {
                    path: t.path.clone(),
                    source,
                    extent: t.extent,
                    sample_type: t.sample_type,
                    nodata: t.nodata,
                    geotransform: t.geotransform,
                    vertical: t.vertical.clone(),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Dem {
            path: self.path.clone(),
            kind: self.kind,
            tiles,
            width: self.width,
            height: self.height,
            geotransform: self.geotransform,
            crs: self.crs.clone(),
            nodata: self.nodata,
            sample_type: self.sample_type,
            vertical: self.vertical.clone(),
            cache: Arc::clone(&self.cache),
            overlay: None,
        })
    }

    /// This DEM `k` times coarser, read from its tiles' overviews: every
    /// tile native, with an overview exactly `k` times coarser, and placed
    /// on the layer grid at a multiple of `k` (its overview's cells then lie
    /// on the coarse grid). `None` otherwise, or with an overlay (the
    /// overviews do not see it). Its cache of decoded blocks is empty and
    /// bounded by nothing kept (its cells are read once).
    ///
    /// Only the tiles that touch `within` (DEM cells) are opened so, and
    /// are in it: the coarse DEM is nodata elsewhere (a ring reads the box
    /// of a wedge out of thousands of tiles).
    pub fn overview_layer(&self, k: usize, within: Window) -> Option<Dem> {
        let k32 = u32::try_from(k).ok()?;
        if k < 2 || self.overlay.is_some() || self.tiles.is_empty() {
            return None;
        }
        let ki = k as i64;
        let mut tiles = Vec::new();
        for t in self
            .tiles
            .iter()
            .filter(|t| t.extent.intersect(&within).is_some())
        {
            let TileSource::Tiff(g) = &t.source else {
                return None;
            };
            if t.extent.col % ki != 0 || t.extent.row % ki != 0 {
                return None;
            }
            let ov = g.overview(k32)?;
            let extent = Window::new(
                t.extent.col / ki,
                t.extent.row / ki,
                ov.width as usize,
                ov.height as usize,
            );
            tiles.push(Tile {
                path: t.path.clone(),
                geotransform: ov.geotransform,
                source: TileSource::Tiff(Arc::new(ov)),
                extent,
                sample_type: t.sample_type,
                nodata: t.nodata,
                vertical: t.vertical.clone(),
            });
        }
        let g = self.geotransform.0;
        let kf = k as f64;
        Some(Dem {
            path: self.path.clone(),
            kind: self.kind,
            tiles,
            width: self.width.div_ceil(k),
            height: self.height.div_ceil(k),
            geotransform: GeoTransform([g[0], g[1] * kf, g[2] * kf, g[3], g[4] * kf, g[5] * kf]),
            crs: self.crs.clone(),
            nodata: self.nodata,
            sample_type: self.sample_type,
            vertical: self.vertical.clone(),
            cache: Arc::new(BlockCache::new(0)),
            overlay: None,
        })
    }

    /// The window of [`Dem::with_overlay`]'s heights, if any.
    pub fn overlay_window(&self) -> Option<Window> {
        self.overlay.as_ref().map(|(w, _)| *w)
    }

    /// Read a window as a [`HeightMap`] (f32, NaN = nodata).
    pub fn read_height_map(&self, win: Window) -> Result<HeightMap, RasterError> {
        self.height_map(win, true)
    }

    /// [`Dem::read_height_map`] keeping no decoded block in the cache: for
    /// cells read once (the far rings of a long view).
    pub fn read_height_map_once(&self, win: Window) -> Result<HeightMap, RasterError> {
        self.height_map(win, false)
    }

    fn height_map(&self, win: Window, cached: bool) -> Result<HeightMap, RasterError> {
        // NaN marks the invalid cells: no mask is made.
        let mut w = self.read::<f32>(win, true, false, cached)?;
        if let Some((ow, heights)) = &self.overlay {
            if let Some(both) = ow.intersect(&win) {
                for r in both.row..both.row + both.height as i64 {
                    let src = ((r - ow.row) as usize) * ow.width + (both.col - ow.col) as usize;
                    let dst = ((r - win.row) as usize) * win.width + (both.col - win.col) as usize;
                    w.data[dst..dst + both.width].copy_from_slice(&heights[src..src + both.width]);
                }
            }
        }
        Ok(HeightMap {
            width: win.width,
            height: win.height,
            data: w.data,
            geotransform: self.geotransform.offset(win.col as f64, win.row as f64),
            crs: self.crs.clone(),
        })
    }

    /// Smallest and largest valid height in metres. Native tiles are
    /// scanned block by block (memory: a block per thread, and a broken
    /// block fails before anything large is allocated); GDAL tiles in bands
    /// of rows.
    pub fn min_max(&self) -> Result<Option<(f64, f64)>, RasterError> {
        let nodata = self.nodata.map(|v| self.sample_type.quantize(v));
        let merge = |a: Option<(f64, f64)>, b: Option<(f64, f64)>| match (a, b) {
            (Some(x), Some(y)) => Some((x.0.min(y.0), x.1.max(y.1))),
            (x, None) => x,
            (None, y) => y,
        };
        let per_tile = self
            .tiles
            .iter()
            .map(|tile| -> Result<Option<(f64, f64)>, RasterError> {
                match &tile.source {
                    TileSource::Tiff(tiff) => {
                        let blocks = u32::try_from(tiff.layout.count()).unwrap_or(u32::MAX);
                        (0..blocks)
                            .into_par_iter()
                            .map(|bi| -> Result<Option<(f64, f64)>, RasterError> {
                                let b = tiff.decode_block(bi)?;
                                let (_, _, w, h) = tiff.block_extent(bi);
                                let n = w as usize * h as usize;
                                if super::sample_type::decoded_bytes(&b)
                                    < n * tiff.sample_type.bytes()
                                {
                                    return Err(RasterError::Corrupt {
                                        path: tiff.path.clone(),
                                        detail: format!("block {bi} decodes to too few samples"),
                                    });
                                }
                                let mut raw =
                                    super::alloc::try_filled(n, 0f64).ok_or_else(|| {
                                        RasterError::Corrupt {
                                            path: tiff.path.clone(),
                                            detail: format!(
                                                "block {bi}: cannot allocate {n} samples"
                                            ),
                                        }
                                    })?;
                                f64::copy_from_block(&b, 0, &mut raw);
                                Ok(raw
                                    .iter()
                                    .filter(|r| !r.is_nan() && Some(**r) != nodata)
                                    .map(|r| tile.vertical.to_metres(*r))
                                    .fold(None, |acc, v| merge(acc, Some((v, v)))))
                            })
                            .try_reduce(|| None, |a, b| Ok(merge(a, b)))
                    }
                    TileSource::Gdal(_) => {
                        let e = tile.extent;
                        let rows = ((16 << 20) / e.width.max(1)).clamp(1, e.height.max(1));
                        let mut acc = None;
                        let mut row = 0;
                        while row < e.height {
                            let h = rows.min(e.height - row);
                            let w = self.read_window::<f64>(Window::new(
                                e.col,
                                e.row + row as i64,
                                e.width,
                                h,
                            ))?;
                            for (v, ok) in w.data.iter().zip(&w.valid) {
                                if *ok {
                                    acc = merge(acc, Some((*v, *v)));
                                }
                            }
                            row += h;
                        }
                        Ok(acc)
                    }
                }
            });
        let mut acc = None;
        for t in per_tile {
            acc = merge(acc, t?);
        }
        Ok(acc)
    }

    /// Indices of the tiles a window touches.
    pub fn tiles_touching(&self, win: &Window) -> Vec<usize> {
        (0..self.tiles.len())
            .filter(|&i| self.tiles[i].extent.intersect(win).is_some())
            .collect()
    }

    pub(crate) fn invalidate_tile(&self, tile: usize) {
        self.cache.invalidate_tile(tile)
    }
}

/// The first tile (in the layer's order) that overlaps an earlier one, and
/// the first earlier one it overlaps: `(later, earlier)`. Whether any two
/// overlap is decided by a sweep over the columns in O(n log n); only
/// then are pairs compared, to name the same two tiles as a pairwise
/// check in order would.
fn first_overlap(tiles: &[Tile]) -> Option<(usize, usize)> {
    let extents: Vec<Window> = tiles.iter().map(|t| t.extent).collect();
    if !any_overlap(&extents) {
        return None;
    }
    (1..extents.len()).find_map(|i| {
        (0..i)
            .find(|&j| extents[j].intersect(&extents[i]).is_some())
            .map(|j| (i, j))
    })
}

/// True when two of `extents` share a cell. Sweeps the rectangles in
/// order of their first column; the ones still open at the sweep's column
/// are kept by first row. While none overlap, the open ones are disjoint
/// row ranges, so a new rectangle can only meet the open one that starts
/// last before its end row.
fn any_overlap(extents: &[Window]) -> bool {
    use std::cmp::Reverse;
    use std::collections::{BTreeMap, BinaryHeap};
    let mut order: Vec<&Window> = extents
        .iter()
        .filter(|w| w.width > 0 && w.height > 0)
        .collect();
    order.sort_unstable_by_key(|w| (w.col, w.row));
    // First row -> end row of the open rectangles; their end columns, to
    // close them as the sweep passes.
    let mut open: BTreeMap<i64, i64> = BTreeMap::new();
    let mut ends: BinaryHeap<Reverse<(i64, i64)>> = BinaryHeap::new();
    for w in order {
        while let Some(&Reverse((col_end, row))) = ends.peek() {
            if col_end > w.col {
                break;
            }
            ends.pop();
            open.remove(&row);
        }
        if let Some((_, &row_end)) = open.range(..w.row_end()).next_back() {
            if row_end > w.row {
                return true;
            }
        }
        open.insert(w.row, w.row_end());
        ends.push(Reverse((w.col_end(), w.row)));
    }
    false
}

/// Set nodata cells (and NaN) of stored values to NaN.
#[inline]
fn mask_nodata<T: Sample>(out: &mut [T], nodata: Option<f64>) {
    // (a select per cell, no branch: vectorises)
    let nan = T::nan();
    match nodata {
        None => {
            for x in out.iter_mut() {
                *x = if x.to_f64().is_nan() { nan } else { *x };
            }
        }
        Some(nd) => {
            for x in out.iter_mut() {
                let f = x.to_f64();
                *x = if f.is_nan() | (f == nd) { nan } else { *x };
            }
        }
    }
}

/// Store stored values `raw` as metres into `out` (nodata and NaN as NaN).
#[inline]
fn store_metres<T: Sample>(raw: &[f64], out: &mut [T], nodata: Option<f64>, v: &Vertical) {
    for (o, &r) in out.iter_mut().zip(raw) {
        *o = if r.is_nan() || Some(r) == nodata {
            T::nan()
        } else {
            T::from_f64(v.to_metres(r))
        };
    }
}

/// Run `f` with GDAL's error messages on this thread discarded (a GDAL
/// attempt whose failure is reported otherwise).
fn quiet_gdal<R>(f: impl FnOnce() -> R) -> R {
    // SAFETY: pushing and popping a handler on the calling thread's stack;
    // CPLQuietErrorHandler is GDAL's own no-op handler.
    unsafe { gdal_sys::CPLPushErrorHandler(Some(gdal_sys::CPLQuietErrorHandler)) };
    let r = f();
    unsafe { gdal_sys::CPLPopErrorHandler() };
    r
}

/// True for GDAL virtual file system paths (`/vsizip/`, `/vsigzip/`,
/// `/vsicurl/`, ...), which only GDAL opens.
fn is_gdal_virtual(path: &Path) -> bool {
    path.to_str().is_some_and(|s| s.starts_with("/vsi"))
}

/// The EPSG code of the horizontal part of a CRS: the CRS's own for a
/// projected or geographic one, the horizontal component's for a compound.
fn horizontal_epsg(srs: &gdal::spatial_ref::SpatialRef) -> Option<u32> {
    if srs.is_compound() {
        for key in ["COMPD_CS|PROJCS|AUTHORITY", "COMPD_CS|GEOGCS|AUTHORITY"] {
            if srs.get_attr_value(key, 0).ok().flatten().as_deref() == Some("EPSG") {
                return srs
                    .get_attr_value(key, 1)
                    .ok()
                    .flatten()
                    .and_then(|c| c.parse().ok());
            }
        }
        return None;
    }
    (srs.auth_name().as_deref() == Some("EPSG"))
        .then(|| srs.auth_code().ok())
        .flatten()
        .map(|c| c as u32)
}

/// Copies the cells of native block `bi` of `tile` that lie in `win` into
/// `out` (the window's samples), in metres when `metres`, nodata masked.
#[allow(clippy::too_many_arguments)]
fn copy_block<T: Sample>(
    tile: &Tile,
    tiff: &GeoTiff,
    bi: u32,
    decoded: &DecodingResult,
    win: Window,
    metres: bool,
    nodata: Option<f64>,
    out: &SharedOut<T>,
) -> Result<(), RasterError> {
    let (bc, br, bw, bh) = tiff.block_extent(bi);
    let bwin = Window::new(
        tile.extent.col + bc as i64,
        tile.extent.row + br as i64,
        bw as usize,
        bh as usize,
    );
    let Some(ov) = bwin.intersect(&win) else {
        return Ok(());
    };
    let row_len = tiff.decoded_row_len(bi);
    let conv = (metres && !tile.vertical.is_identity()).then_some(&tile.vertical);
    let mut row = if conv.is_some() {
        vec![0f64; ov.width]
    } else {
        Vec::new()
    };
    if super::sample_type::decoded_bytes(decoded) < row_len * bh as usize * tiff.sample_type.bytes()
    {
        return Err(RasterError::Corrupt {
            path: tiff.path.clone(),
            detail: format!("block {bi} decodes to too few samples"),
        });
    }
    for r in 0..ov.height {
        let src_row = (ov.row - bwin.row) as usize + r;
        let src = src_row * row_len + (ov.col - bwin.col) as usize;
        let dst = (ov.row - win.row) as usize + r;
        let dst = dst * win.width + (ov.col - win.col) as usize;
        // SAFETY: blocks are disjoint rectangles of the
        // window, so no two jobs write the same cells.
        let out = unsafe { out.slice(dst, ov.width) };
        match &conv {
            None => {
                T::copy_from_block(decoded, src, out);
                mask_nodata(out, nodata);
            }
            Some(v) => {
                f64::copy_from_block(decoded, src, &mut row);
                store_metres(&row, out, nodata, v);
            }
        }
    }
    Ok(())
}

/// Reads the overlap of GDAL tile `tile` with `win` into `out` (the
/// window's samples), in metres when `metres`, nodata masked.
fn copy_gdal_tile<T: Sample>(
    tile: &Tile,
    ds: &Mutex<gdal::Dataset>,
    win: Window,
    metres: bool,
    nodata: Option<f64>,
    out: &SharedOut<T>,
) -> Result<(), RasterError> {
    let Some(ov) = tile.extent.intersect(&win) else {
        return Ok(());
    };
    let mut buf = vec![0f64; ov.len()];
    {
        let ds = ds
            .lock()
            .map_err(|_| RasterError::gdal(&tile.path, "dataset lock poisoned"))?;
        let band = ds
            .rasterband(1)
            .map_err(|e| RasterError::gdal(&tile.path, e))?;
        band.read_into_slice::<f64>(
            (
                (ov.col - tile.extent.col) as isize,
                (ov.row - tile.extent.row) as isize,
            ),
            (ov.width, ov.height),
            (ov.width, ov.height),
            &mut buf,
            None,
        )
        .map_err(|e| RasterError::gdal(&tile.path, e))?;
    }
    for r in 0..ov.height {
        let dst = ((ov.row - win.row) as usize + r) * win.width + (ov.col - win.col) as usize;
        // SAFETY: tiles do not overlap (checked at open).
        let out = unsafe { out.slice(dst, ov.width) };
        let src = &buf[r * ov.width..(r + 1) * ov.width];
        if metres && !tile.vertical.is_identity() {
            store_metres(src, out, nodata, &tile.vertical);
        } else {
            for (o, v) in out.iter_mut().zip(src) {
                *o = T::from_f64(*v);
            }
            mask_nodata(out, nodata);
        }
    }
    Ok(())
}

/// Disjoint mutable access to the output of a parallel window read.
struct SharedOut<T> {
    ptr: *mut T,
    len: usize,
}
unsafe impl<T: Send> Sync for SharedOut<T> {}
unsafe impl<T: Send> Send for SharedOut<T> {}
impl<T> SharedOut<T> {
    /// # Safety
    /// Callers must not hand out overlapping ranges concurrently.
    #[allow(clippy::mut_from_ref)]
    unsafe fn slice(&self, start: usize, len: usize) -> &mut [T] {
        assert!(start + len <= self.len, "window slice out of range");
        std::slice::from_raw_parts_mut(self.ptr.add(start), len)
    }
}

/// Read a whole DEM (file, tile directory or GDAL raster) as a [`HeightMap`].
pub fn read_height_map(path: &Path) -> Result<HeightMap, RasterError> {
    let dem = Dem::open(path)?;
    dem.read_height_map(dem.full_window())
}

#[cfg(test)]
mod tests {
    use super::{any_overlap, Window};

    /// The sweep agrees with comparing every pair, on random rectangles
    /// (lattices with gaps, touching edges, shifted and empty ones).
    #[test]
    fn sweep_finds_the_overlaps_pairs_find() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = |n: u64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n) as i64
        };
        let mut found = 0;
        for case in 0..2000 {
            let n = 1 + next(12) as usize;
            let mut ws = Vec::new();
            for _ in 0..n {
                let (c, r) = if case % 2 == 0 {
                    (4 * next(5), 4 * next(5))
                } else {
                    (next(16), next(16))
                };
                let (w, h) = if case % 2 == 0 {
                    (4 - (next(9) / 8), 4)
                } else {
                    (next(7), next(7))
                };
                ws.push(Window::new(c, r, w as usize, h as usize));
            }
            let pairs = (0..ws.len()).any(|i| (0..i).any(|j| ws[i].intersect(&ws[j]).is_some()));
            assert_eq!(any_overlap(&ws), pairs, "case {case}: {ws:?}");
            found += usize::from(pairs);
        }
        assert!(found > 100 && found < 1900, "{found} overlapping cases");
    }

    #[test]
    fn a_lattice_does_not_overlap() {
        let ws: Vec<Window> = (0..64)
            .flat_map(|r| (0..64).map(move |c| Window::new(c * 16, r * 16, 16, 16)))
            .collect();
        assert!(!any_overlap(&ws));
        let mut shifted = ws.clone();
        shifted[1000].col += 1;
        assert!(any_overlap(&shifted));
    }
}
