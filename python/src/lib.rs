//! `demsketch._demsketch`: the native part of the Python package, a thin
//! PyO3 layer over the library crate (no algorithm of its own): open a DEM
//! and read a window as a numpy array ([`demsketch::raster::Dem`]), render
//! a first-person view as `demsketch view` does, run an edit as
//! `demsketch edit` does ([`demsketch::edit::guard`] then
//! [`demsketch::edit::run`]), and the array-job steps of a batch
//! ([`demsketch::batch::steps`]). Every error is a
//! `demsketch.DemsketchError` with the library's one-line message (an
//! edit below `--min-fit`: `demsketch.BelowMinFitError`); the GIL is
//! released around all work on rasters. Structured results (reports,
//! plans, summaries) cross as JSON text, parsed by `demsketch/__init__.py`.

use std::path::PathBuf;
use std::time::Duration;

use demsketch::batch::record::Done;
use demsketch::batch::{steps, BatchSettings, Plan};
use demsketch::edit::{EditError, EditOptions};
use demsketch::raster::{Dem, Destination, LayerKind, Window};
use demsketch::render::{shade, write_png, DepthBuffer, Scene, ShadeOptions};
use demsketch::view::{Camera, EyeHeight, Viewpoint};
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

pyo3::create_exception!(
    _demsketch,
    DemsketchError,
    PyException,
    "An error of demsketch: the library's one-line message."
);
pyo3::create_exception!(
    _demsketch,
    BelowMinFitError,
    DemsketchError,
    "An edit ran but a stroke's fit is below min_fit: nothing was written (the report was)."
);

fn err(e: impl std::fmt::Display) -> PyErr {
    DemsketchError::new_err(e.to_string())
}

fn timeout_of(s: f64) -> PyResult<Duration> {
    if s.is_finite() && (0.0..=1e9).contains(&s) {
        Ok(Duration::from_secs_f64(s))
    } else {
        Err(DemsketchError::new_err(format!(
            "lock_timeout {s} is not a number of seconds >= 0"
        )))
    }
}

/// A note of the library (a lock wait, a recovered edit), as the CLI says it.
fn note(m: &str) {
    eprintln!("demsketch: {m}");
}

/// A DEM: a GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL
/// opens, as `demsketch` reads it (one seamless grid across tiles, heights
/// in metres).
#[pyclass(module = "demsketch", name = "Dem", frozen)]
struct PyDem {
    dem: Dem,
}

#[pymethods]
impl PyDem {
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let dem = py.detach(|| Dem::open(&path)).map_err(err)?;
        Ok(PyDem { dem })
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.dem.path.clone()
    }
    /// Columns of the whole grid.
    #[getter]
    fn width(&self) -> usize {
        self.dem.width
    }
    /// Rows of the whole grid.
    #[getter]
    fn height(&self) -> usize {
        self.dem.height
    }
    /// The GDAL geotransform of the whole grid (6 numbers).
    #[getter]
    fn geotransform(&self) -> [f64; 6] {
        self.dem.geotransform.0
    }
    /// The CRS as GDAL takes it (WKT or PROJ string).
    #[getter]
    fn crs(&self) -> String {
        self.dem.crs.gdal_definition()
    }
    #[getter]
    fn nodata(&self) -> Option<f64> {
        self.dem.nodata
    }
    /// "geotiff", "tiles" (a tile directory) or "gdal".
    #[getter]
    fn kind(&self) -> &'static str {
        match self.dem.kind {
            LayerKind::GeoTiff => "geotiff",
            LayerKind::TileDirectory => "tiles",
            LayerKind::Gdal => "gdal",
        }
    }
    /// Number of files (tiles) of the DEM.
    #[getter]
    fn tiles(&self) -> usize {
        self.dem.tiles.len()
    }

    /// Heights in metres of the window of `width` x `height` cells whose
    /// top-left cell is (`col`, `row`), as a float32 array of shape
    /// (height, width); nodata cells and cells outside the DEM are NaN.
    /// The whole grid without arguments.
    #[pyo3(signature = (col=0, row=0, width=None, height=None))]
    fn read_window<'py>(
        &self,
        py: Python<'py>,
        col: i64,
        row: i64,
        width: Option<usize>,
        height: Option<usize>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let w = width.unwrap_or_else(|| self.dem.width.saturating_sub(col.max(0) as usize));
        let h = height.unwrap_or_else(|| self.dem.height.saturating_sub(row.max(0) as usize));
        let data = py
            .detach(|| self.dem.read_window::<f32>(Window::new(col, row, w, h)))
            .map_err(err)?;
        let a = PyArray1::from_vec(py, data.data);
        Ok(a.reshape([h, w])?.into_any())
    }

    /// The first-person view from (`lon`, `lat`) as `demsketch view DEM
    /// --lon --lat [camera flags] --out view.png` renders it (without
    /// overlays): an RGB uint8 array of shape (height, width, 3); also
    /// written as a PNG to `out` when given. `full_resolution`: as the
    /// command's `--full-resolution` (no coarser rings beyond the
    /// full-resolution reach).
    #[pyo3(signature = (lon, lat, *, heading=0.0, pitch=0.0, roll=0.0, hfov=60.0,
                        width=1600, height=900, eye_height=None, alt=None,
                        max_distance=None, refraction=1.0 / 7.0, out=None,
                        full_resolution=false))]
    #[allow(clippy::too_many_arguments)]
    fn view<'py>(
        &self,
        py: Python<'py>,
        lon: f64,
        lat: f64,
        heading: f64,
        pitch: f64,
        roll: f64,
        hfov: f64,
        width: usize,
        height: usize,
        eye_height: Option<f64>,
        alt: Option<f64>,
        max_distance: Option<f64>,
        refraction: f64,
        out: Option<PathBuf>,
        full_resolution: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        if eye_height.is_some() && alt.is_some() {
            return Err(DemsketchError::new_err("give eye_height or alt, not both"));
        }
        let height_of_eye = match alt {
            Some(a) => EyeHeight::Absolute(a),
            None => EyeHeight::AboveSurface(eye_height.unwrap_or(1.7)),
        };
        let camera = Camera::new(width, height, heading, pitch, roll, hfov).map_err(err)?;
        let vp = Viewpoint {
            lon,
            lat,
            height: height_of_eye,
        };
        let rgb = py
            .detach(|| -> Result<Vec<u8>, String> {
                let scene = if full_resolution {
                    Scene::open_wedge(&self.dem, &vp, max_distance, refraction, &camera)
                } else {
                    Scene::open_view_lod(&self.dem, &vp, max_distance, refraction, &camera)
                }
                .map_err(|e| e.to_string())?;
                let depth = DepthBuffer::render(&scene.terrain, &camera);
                // The CLI's sun: behind the viewer's right shoulder.
                let opts = ShadeOptions {
                    sun_azimuth_deg: camera.heading_deg + 135.0,
                    ..ShadeOptions::default()
                };
                let rgb = shade(&depth, &scene.terrain, &opts);
                if let Some(p) = &out {
                    write_png(p, width, height, &rgb).map_err(|e| e.to_string())?;
                }
                Ok(rgb)
            })
            .map_err(err)?;
        let a = PyArray1::from_vec(py, rgb);
        Ok(a.reshape([height, width, 3])?.into_any())
    }

    fn __repr__(&self) -> String {
        format!(
            "demsketch.Dem({:?}: {} x {}, {} file(s))",
            self.dem.path.display().to_string(),
            self.dem.width,
            self.dem.height,
            self.dem.tiles.len()
        )
    }
}

/// `demsketch edit DEM --sketch SKETCH (--out OUT | --in-place)`: the
/// report as JSON text. Takes the DEM's edit lock, finishes an edit a
/// killed run left, checks the outputs, as the CLI does.
#[pyfunction]
#[pyo3(signature = (dem, sketch, out=None, *, in_place=false, report=None, renders=None,
                    max_distance=50_000.0, refraction=1.0 / 7.0, max_lowering_iterations=4,
                    max_contour_iterations=6, min_fit=demsketch::edit::DEFAULT_MIN_FIT,
                    allow_partial=false, dry_run=false, lock_timeout=300.0))]
#[allow(clippy::too_many_arguments)]
fn edit(
    py: Python<'_>,
    dem: PathBuf,
    sketch: PathBuf,
    out: Option<PathBuf>,
    in_place: bool,
    report: Option<PathBuf>,
    renders: Option<PathBuf>,
    max_distance: f64,
    refraction: f64,
    max_lowering_iterations: usize,
    max_contour_iterations: usize,
    min_fit: f64,
    allow_partial: bool,
    dry_run: bool,
    lock_timeout: f64,
) -> PyResult<String> {
    let destination = match (out, in_place) {
        (None, true) => Destination::InPlace,
        (Some(p), false) => Destination::Path(p),
        (Some(_), true) => return Err(DemsketchError::new_err("give out or in_place, not both")),
        (None, false) => return Err(DemsketchError::new_err("give out=OUT or in_place=True")),
    };
    if !(min_fit.is_finite() && min_fit >= 0.0) {
        return Err(DemsketchError::new_err(format!(
            "min_fit {min_fit} is not a non-negative number"
        )));
    }
    if let Destination::Path(p) = &destination {
        if !dem.is_dir() {
            demsketch::raster::output_format::output_driver(p, None).map_err(err)?;
        }
    }
    let timeout = timeout_of(lock_timeout)?;
    let mut opts = EditOptions::new(destination);
    opts.report = report;
    opts.renders = renders;
    opts.max_distance_m = Some(max_distance);
    opts.refraction = refraction;
    opts.max_lowering_iterations = max_lowering_iterations;
    opts.max_contour_iterations = max_contour_iterations;
    opts.min_fit = min_fit;
    opts.allow_partial = allow_partial;
    opts.dry_run = dry_run;
    let result = py.detach(|| -> Result<_, String> {
        // The DEM the guard opened is the one the edit runs on (opened once).
        let (_lock, opened) =
            demsketch::edit::guard::prepare_open(&dem, &sketch, &opts, timeout, &mut note)
                .map_err(|e| e.to_string())?;
        Ok(demsketch::edit::run_opened(opened, &dem, &sketch, &opts))
    });
    match result.map_err(err)? {
        Ok(r) => serde_json::to_string(&r).map_err(err),
        Err(e @ EditError::BelowMinFit { .. }) => Err(BelowMinFitError::new_err(e.to_string())),
        Err(e) => Err(err(e)),
    }
}

/// `demsketch batch plan DEM --jobs JOBS --out OUT --plan PLAN`: the plan
/// as JSON text.
#[pyfunction]
#[pyo3(signature = (dem, jobs, out, plan, *, max_distance=50_000.0, refraction=1.0 / 7.0,
                    max_lowering_iterations=4, max_contour_iterations=6,
                    min_fit=demsketch::edit::DEFAULT_MIN_FIT, allow_partial=false,
                    pyramid_resampling=None))]
#[allow(clippy::too_many_arguments)]
fn batch_plan(
    py: Python<'_>,
    dem: PathBuf,
    jobs: PathBuf,
    out: PathBuf,
    plan: PathBuf,
    max_distance: f64,
    refraction: f64,
    max_lowering_iterations: usize,
    max_contour_iterations: usize,
    min_fit: f64,
    allow_partial: bool,
    pyramid_resampling: Option<String>,
) -> PyResult<String> {
    let settings = BatchSettings {
        max_distance_m: max_distance,
        refraction,
        max_lowering_iterations,
        max_contour_iterations,
        min_fit,
        allow_partial,
        pyramid_resampling,
    };
    let p = py
        .detach(|| steps::plan_to_file(&dem, &jobs, &out, &plan, settings))
        .map_err(err)?;
    Ok(p.to_json())
}

/// The number of groups (array-job indices) of the plan at `plan`.
#[pyfunction]
fn batch_groups(py: Python<'_>, plan: PathBuf) -> PyResult<usize> {
    let p = py.detach(|| Plan::read(&plan)).map_err(err)?;
    Ok(p.groups.len())
}

/// `demsketch batch run --plan PLAN --index INDEX`: what the group did,
/// as JSON text ({"group", "skipped", "done": [records]}).
#[pyfunction]
#[pyo3(signature = (plan, index, *, lock_timeout=300.0))]
fn batch_run(py: Python<'_>, plan: PathBuf, index: usize, lock_timeout: f64) -> PyResult<String> {
    let timeout = timeout_of(lock_timeout)?;
    let progress = |_: &Done, _: bool| {};
    let (_, outcome) = py
        .detach(|| steps::run_index(&plan, index, timeout, &mut note, &progress))
        .map_err(err)?;
    let v = serde_json::json!({
        "group": outcome.group,
        "skipped": outcome.skipped,
        "done": outcome.done,
    });
    Ok(v.to_string())
}

/// `demsketch batch finish --plan PLAN`: the summary as JSON text (also
/// written to the state directory's summary.json).
#[pyfunction]
#[pyo3(signature = (plan, *, lock_timeout=300.0))]
fn batch_finish(py: Python<'_>, plan: PathBuf, lock_timeout: f64) -> PyResult<String> {
    let timeout = timeout_of(lock_timeout)?;
    let s = py
        .detach(|| steps::finish_plan(&plan, timeout, &mut note))
        .map_err(err)?;
    serde_json::to_string(&s).map_err(err)
}

#[pymodule]
fn _demsketch(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyDem>()?;
    m.add_function(wrap_pyfunction!(edit, m)?)?;
    m.add_function(wrap_pyfunction!(batch_plan, m)?)?;
    m.add_function(wrap_pyfunction!(batch_groups, m)?)?;
    m.add_function(wrap_pyfunction!(batch_run, m)?)?;
    m.add_function(wrap_pyfunction!(batch_finish, m)?)?;
    // Named as `demsketch` exports them, so that pickle (a Dask task's
    // error sent to the client) finds them.
    for (name, t) in [
        ("DemsketchError", m.py().get_type::<DemsketchError>()),
        ("BelowMinFitError", m.py().get_type::<BelowMinFitError>()),
    ] {
        t.setattr("__module__", "demsketch")?;
        m.add(name, t)?;
    }
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
