//! What the server holds between requests: the command line's choices
//! (the DEM, OUT, the edit's options), the opened DEM, the map overview
//! and its underlay,
//! the terrain of the last viewpoint (so that turning the camera does not
//! read the DEM again), the edit jobs and the private working directory
//! where sketches, reports and pictures of dry runs are kept.

use std::cell::RefCell;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use super::jobs::Jobs;
use super::overview::Overview;
use super::underlay::Underlay;
use super::ServeError;
use crate::features::RidgeNetwork;
use crate::raster::path_check::{check_outputs, dem_inputs, Output};
use crate::raster::{Dem, HeightMap, LayerKind};
use crate::render::{DepthBuffer, LocalTerrain};
use crate::view::{Georef, LocalFrame};

/// The command line's choices.
#[derive(Debug, Clone)]
pub struct ServeConfig {
    /// The DEM (a GeoTIFF, a tile directory, any raster GDAL opens).
    pub dem: PathBuf,
    /// Where an accepted edit is written (`None`: dry runs only).
    pub out: Option<PathBuf>,
    /// Only the DEM within this distance of a viewpoint is read, metres.
    pub max_distance_m: f64,
    /// Refraction coefficient k.
    pub refraction: f64,
    /// The edit's `--min-fit`.
    pub min_fit: f64,
    /// Longest side of the map overview, pixels.
    pub overview_px: usize,
    /// Most edits queued or running at once; more are refused (429).
    pub max_queued_edits: usize,
    /// A raster drawn with the map's hillshade (`--underlay`).
    pub underlay: Option<PathBuf>,
}

impl ServeConfig {
    /// The defaults of `demsketch edit` for `dem`, with `out`.
    pub fn new(dem: PathBuf, out: Option<PathBuf>) -> ServeConfig {
        ServeConfig {
            dem,
            out,
            max_distance_m: 50_000.0,
            refraction: 1.0 / 7.0,
            min_fit: crate::edit::DEFAULT_MIN_FIT,
            overview_px: 1024,
            max_queued_edits: 16,
            underlay: None,
        }
    }
}

/// The terrain around one viewpoint, kept for the next requests.
pub struct CachedScene {
    pub key: SceneKey,
    pub window: HeightMap,
    pub window_offset: (i64, i64),
    pub frame: LocalFrame,
    pub terrain: LocalTerrain,
    /// The ridge network of the window, computed when first asked for.
    pub ridges: std::sync::OnceLock<Result<RidgeNetwork, String>>,
}

/// What a cached scene depends on (the viewpoint, exactly as asked).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneKey {
    pub lon: f64,
    pub lat: f64,
    pub eye_height_m: Option<f64>,
    pub alt_m: Option<f64>,
}

/// Everything the handlers share.
pub struct Inner {
    pub config: ServeConfig,
    pub dem: Dem,
    pub overview: Overview,
    /// The `--underlay` on the overview's grid.
    pub underlay: Option<Underlay>,
    pub scene: Mutex<Option<Arc<CachedScene>>>,
    pub jobs: Jobs,
    /// Lets at most [`super::routes::MAX_RENDERS`] renders run at once.
    pub render_gate: tokio::sync::Semaphore,
    /// Private working directory (an exclusive temporary directory, mode
    /// 700, removed at exit and on SIGINT/SIGTERM with the edit's own
    /// staging directories).
    pub workdir: crate::raster::atomic_file::Staging,
    /// Picture buffers of finished renders, reused by the next ones.
    pub pictures: Mutex<Vec<Vec<u8>>>,
    /// Depth buffers of finished renders, reused by the next ones.
    pub depths: Mutex<Vec<DepthBuffer>>,
}

/// The server's state, cheap to clone into handlers.
#[derive(Clone)]
pub struct AppState(pub Arc<Inner>);

impl std::ops::Deref for AppState {
    type Target = Inner;
    fn deref(&self) -> &Inner {
        &self.0
    }
}

thread_local! {
    /// PROJ transformations are per thread ([`Georef`] is not `Send`).
    static GEOREF: RefCell<Option<Georef>> = const { RefCell::new(None) };
}

impl AppState {
    /// Open the DEM, check OUT against it (as `edit` does), build the map
    /// overview and the working directory.
    pub fn new(config: ServeConfig) -> Result<AppState, ServeError> {
        let dem = Dem::open(&config.dem).map_err(|e| ServeError::BadRequest(e.to_string()))?;
        if let Some(out) = &config.out {
            let outputs = [Output {
                flag: "--out".into(),
                path: out.clone(),
                is_dir: dem.kind == LayerKind::TileDirectory,
            }];
            check_outputs(&dem_inputs(&dem), &outputs)
                .map_err(|e| ServeError::BadRequest(e.to_string()))?;
            if dem.kind != LayerKind::TileDirectory {
                crate::raster::output_format::output_driver(out, None)
                    .map_err(ServeError::BadRequest)?;
            }
        }
        let t = std::time::Instant::now();
        let overview = Overview::build(&dem, config.overview_px)?;
        if overview.read_in_full && t.elapsed().as_secs_f64() > 0.5 {
            let target = if config.dem.is_file() {
                config.dem.display().to_string()
            } else {
                "TILE (each tile)".to_string()
            };
            eprintln!(
                "demsketch serve: note: {}: the map took {:.1} s because the DEM has no overviews \
                 (every cell was read); `gdaladdo -r average {target} 2 4 8 16 32` makes it open at once",
                config.dem.display(),
                t.elapsed().as_secs_f64()
            );
        }
        let underlay = match &config.underlay {
            Some(p) => Some(Underlay::build(p, &dem, &overview)?),
            None => None,
        };
        let workdir = crate::raster::atomic_file::Staging::new_in(&std::env::temp_dir())
            .map_err(|e| ServeError::Internal(format!("cannot create a working directory: {e}")))?;
        let jobs = Jobs::new(config.max_queued_edits);
        Ok(AppState(Arc::new(Inner {
            config,
            dem,
            overview,
            underlay,
            scene: Mutex::new(None),
            jobs,
            render_gate: tokio::sync::Semaphore::new(super::routes::MAX_RENDERS),
            workdir,
            pictures: Mutex::new(Vec::new()),
            depths: Mutex::new(Vec::new()),
        })))
    }

    /// The DEM's name in messages.
    pub fn dem_name(&self) -> String {
        self.config.dem.display().to_string()
    }

    /// A picture buffer of an earlier render (or a new one).
    pub fn take_picture(&self) -> Vec<u8> {
        self.pictures
            .lock()
            .ok()
            .and_then(|mut p| p.pop())
            .unwrap_or_default()
    }

    /// Give a picture buffer back for the next render (at most
    /// [`super::routes::MAX_RENDERS`] are kept).
    pub fn give_picture(&self, buf: Vec<u8>) {
        if let Ok(mut p) = self.pictures.lock() {
            if p.len() < super::routes::MAX_RENDERS {
                p.push(buf);
            }
        }
    }

    /// The depth buffer of `camera` over `terrain`, rendered into the
    /// buffers of an earlier render when one is free (see
    /// [`DepthBuffer::render_reusing`]); give it back with
    /// [`AppState::give_depth`].
    pub fn render_depth(
        &self,
        terrain: &LocalTerrain,
        camera: &crate::view::Camera,
    ) -> DepthBuffer {
        let old = self.depths.lock().ok().and_then(|mut d| d.pop());
        match old {
            Some(old) => DepthBuffer::render_reusing(terrain, camera, old),
            None => DepthBuffer::render(terrain, camera),
        }
    }

    /// Give a depth buffer back for the next render (at most
    /// [`super::routes::MAX_RENDERS`] are kept).
    pub fn give_depth(&self, depth: DepthBuffer) {
        if let Ok(mut d) = self.depths.lock() {
            if d.len() < super::routes::MAX_RENDERS {
                d.push(depth);
            }
        }
    }

    /// Run `f` with this thread's [`Georef`] of the DEM.
    pub fn with_georef<T>(
        &self,
        f: impl FnOnce(&Georef) -> Result<T, ServeError>,
    ) -> Result<T, ServeError> {
        GEOREF.with(|g| {
            let mut g = g.borrow_mut();
            if g.is_none() {
                *g = Some(
                    Georef::for_crs(&self.dem.crs, &self.dem_name())
                        .map_err(|e| ServeError::Unprocessable(e.to_string()))?,
                );
            }
            match g.as_ref() {
                Some(geo) => f(geo),
                None => Err(ServeError::Internal("no georeference".into())),
            }
        })
    }
}
