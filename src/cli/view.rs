//! `demsketch view DEM (--sketch FILE [--view NAME] | --lon X --lat Y [camera
//! flags]) --out view.png [--overlay LIST] [--depth depth.tif] [--viewshed
//! vis.tif] [--features features.geojson]`: render what a person standing at
//! the viewpoint sees (shaded PNG with optional overlays of the view's
//! silhouettes, the visible ridge lines and the sketch's strokes), and
//! optionally the depth buffer, the viewshed and the features as GeoJSON.
//! Also defines the camera flags shared with `locate`.

use demsketch::features::geojson::{
    feature_collection_of_view, to_lonlat_with_georef, write_geojson,
};
use demsketch::features::{
    detect_ridges, extract_silhouettes, RidgeNetwork, RidgeParams, SilhouetteParams, Silhouettes,
};
use demsketch::raster::atomic_file::{verify_band, StagedOutputs};
use demsketch::raster::output_format::{output_driver, write_raster, RasterSpec};
use demsketch::raster::path_check::{self, dem_inputs, Input, Output};
use demsketch::raster::Dem;
use demsketch::render::{
    depth_for_file, draw_polyline, eye_frame, shade, viewshed_exact, viewshed_from_file,
    visible_polylines, write_png, DepthBuffer, Scene, ShadeOptions, DEPTH_NODATA,
};
use demsketch::sketch::{CameraSpec, SketchFile, ViewpointSpec};
use demsketch::view::{check_view_settings, Camera, SettingNames, Viewpoint};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Viewpoint and camera flags (DESIGN.md "Camera flags").
#[derive(clap::Args, Debug, Clone)]
pub struct CameraFlags {
    /// Viewpoint longitude, degrees WGS84.
    #[arg(long, allow_hyphen_values = true)]
    pub lon: Option<f64>,
    /// Viewpoint latitude, degrees WGS84.
    #[arg(long, allow_hyphen_values = true)]
    pub lat: Option<f64>,
    /// Eye height above the DEM surface, metres (default 1.7).
    #[arg(long, conflicts_with = "alt")]
    pub eye_height: Option<f64>,
    /// Absolute eye altitude in the DEM's vertical datum, metres.
    #[arg(long, allow_hyphen_values = true)]
    pub alt: Option<f64>,
    /// Heading, degrees clockwise from true north.
    #[arg(long, allow_hyphen_values = true)]
    pub heading: Option<f64>,
    /// Pitch, degrees, up positive.
    #[arg(long, allow_hyphen_values = true)]
    pub pitch: Option<f64>,
    /// Roll, degrees, clockwise positive.
    #[arg(long, allow_hyphen_values = true)]
    pub roll: Option<f64>,
    /// Horizontal field of view, degrees.
    #[arg(long)]
    pub hfov: Option<f64>,
    /// Image size WxH in pixels.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<(usize, usize)>,
    /// Maximum view distance in metres: only the DEM within it is read.
    #[arg(long)]
    pub max_distance: Option<f64>,
    /// Refraction coefficient k (apparent drop (1 - k) d^2 / 2R).
    #[arg(long, default_value_t = 1.0 / 7.0)]
    pub refraction: f64,
}

fn parse_size(s: &str) -> Result<(usize, usize), String> {
    super::parse_pair(
        s,
        &['x', 'X'],
        "size",
        "WxH (e.g. 1600x900)",
        ["width", "height"],
    )
}

/// A fully specified view: viewpoint, camera, strokes to overlay.
pub struct ResolvedView {
    pub viewpoint: Viewpoint,
    pub camera: Camera,
    pub strokes: Vec<Vec<[f64; 2]>>,
    /// The view's index in the sketch file (0 without one): silhouette
    /// feature ids carry it, as in an edit's report.
    pub view_index: usize,
    /// What gave an absolute eye, for the message that refuses one below
    /// the ground: `viewpoint --alt`, or the sketch view's `alt_m`.
    pub alt_label: String,
}

impl ResolvedView {
    /// Refuses an absolute eye at or below the ground the renderer draws
    /// at the viewpoint, as `edit` does.
    pub fn check_above_ground(&self, ground: f64) -> anyhow::Result<()> {
        super::check_above_ground(&self.alt_label, self.viewpoint.height, ground)
    }
}

impl CameraFlags {
    /// Viewpoint and camera from the flags (flags override `base` values).
    pub fn resolve(&self) -> anyhow::Result<ResolvedView> {
        let (Some(lon), Some(lat)) = (self.lon, self.lat) else {
            anyhow::bail!("give the viewpoint as --lon X --lat Y (or --sketch FILE)");
        };
        // The sketch format's viewpoint ranges, before PROJ sees it, and
        // its defaults.
        let vp = ViewpointSpec {
            lon,
            lat,
            eye_height_m: self.eye_height,
            alt_m: self.alt,
        };
        vp.check_flag_ranges().map_err(anyhow::Error::msg)?;
        check_view_settings(self.max_distance, self.refraction, SettingNames::Flags)?;
        let d = CameraSpec::default();
        let (w, h) = self.size.unwrap_or((d.width as usize, d.height as usize));
        let camera = Camera::new(
            w,
            h,
            self.heading.unwrap_or(d.heading_deg),
            self.pitch.unwrap_or(d.pitch_deg),
            self.roll.unwrap_or(d.roll_deg),
            self.hfov.unwrap_or(d.hfov_deg),
        )?;
        Ok(ResolvedView {
            viewpoint: vp.resolved(),
            camera,
            strokes: Vec::new(),
            view_index: 0,
            alt_label: "viewpoint --alt".into(),
        })
    }
}

/// What `--overlay` can draw over the picture.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum Overlay {
    /// The view's silhouettes (skyline and every visible occlusion edge), red.
    Silhouettes,
    /// T-junctions where one silhouette ends behind another, blue dots.
    Junctions,
    /// The visible parts of the DEM's ridge lines (PPA), yellow.
    Ridges,
    /// The strokes of the sketch file's view, magenta.
    Strokes,
}

/// Examples shown at the end of `demsketch view --help`.
pub const VIEW_EXAMPLES: &str = "\
Examples:
  demsketch view fixtures/zion_srtm_utm12n.tif --lon -112.998 --lat 37.188 \\
      --heading 10 --pitch 4 --overlay silhouettes,ridges --out zion.png
  demsketch view dem.tif --sketch sketch.json --view north-rim --out v.png \\
      --depth depth.tif --viewshed vis.tif --features features.geojson

The view comes from --sketch FILE [--view NAME] (camera flags override its
values) or from --lon/--lat and the camera flags alone. Errors (viewpoint
outside the DEM or on nodata, bad camera, unreadable files) are one line on
stderr with exit code 1; nothing is written then. Each output file is
written to a temporary file beside it, read back and checked, then renamed
into place: a full disk or a write error leaves the old file as it was.
An output may not name the DEM, one of its tiles, the sketch, or another
output.";

/// Arguments of `demsketch view`.
#[derive(clap::Args, Debug)]
pub struct ViewArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// Sketch file whose view (viewpoint, camera, strokes) to render.
    #[arg(long)]
    pub sketch: Option<PathBuf>,
    /// Name of the view in the sketch file (default: the first).
    #[arg(long, requires = "sketch")]
    pub view: Option<String>,
    #[command(flatten)]
    pub camera: CameraFlags,
    /// Output picture (8-bit RGB: lit terrain, distance haze, sky): PNG for
    /// .png, otherwise the GDAL format of the extension (.tif, .jpg, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// What to draw over the picture, comma-separated [default: strokes when
    /// the sketch has any].
    #[arg(long, value_enum, value_delimiter = ',')]
    pub overlay: Vec<Overlay>,
    /// Also write the depth buffer (Float32, image space, metres from the
    /// eye; sky is nodata, -9999).
    #[arg(long)]
    pub depth: Option<PathBuf>,
    /// Also write the viewshed (GeoTIFF on the DEM grid, 255 visible / 0 not,
    /// like gdal_viewshed; cells beyond --max-distance are 0).
    #[arg(long)]
    pub viewshed: Option<PathBuf>,
    /// Target height above the surface for the viewshed, metres (a finite
    /// number; negative: below the surface).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub target_height: f64,
    /// Compute --viewshed with one exact line of sight per cell instead of
    /// horizon propagation (tens of times slower; the propagation agrees
    /// with it on at least 99 % of cells).
    #[arg(long, requires = "viewshed")]
    pub viewshed_exact: bool,
    /// Also write the view's features as GeoJSON: silhouettes (with their
    /// pixel polylines), T-junctions and the ridge lines of the part of the
    /// DEM the camera's horizontal field of view takes in, in lon/lat/z;
    /// each feature's id is the feature_id an edit's report gives it.
    /// Beyond the full-resolution reach (see --full-resolution) the far
    /// silhouettes and the skyline are traced on the coarser terrain (their
    /// points within a coarse cell, at most a pixel across, of the DEM's
    /// highest cell there) and ridge lines are listed only within the
    /// reach, as an edit detects them: the part of the DEM an edit can move
    /// (the collection's "full_resolution_reach_m" says how far that is).
    #[arg(long)]
    pub features: Option<PathBuf>,
    /// Read and draw the whole view at the DEM's resolution. By default a
    /// view that reaches farther than max(20 km, the distance at which 2
    /// DEM cells span a pixel) is exact only out to there, and drawn
    /// beyond from rings of block maxima 2, 4, 8 ... times coarser (each
    /// coarse cell the highest of the cells it covers, and at most a pixel
    /// across; read from the tiles' overviews when every tile has them),
    /// as an edit's views are: far ridges keep their skyline, never lower,
    /// for a fraction of the time on a large DEM. With this flag the far
    /// terrain is exact too and ridge lines are listed over the whole
    /// wedge, for the time and memory of reading it all.
    #[arg(long)]
    pub full_resolution: bool,
    /// Format of --depth and --viewshed, a GDAL driver name as
    /// gdal_translate's -of (written -of or --of) [default: from each
    /// file's extension; GeoTIFF without one].
    #[arg(long = "of", value_name = "FORMAT")]
    pub format: Option<String>,
    /// Creation option NAME=VALUE for --depth and --viewshed, as
    /// gdal_translate's -co (repeatable).
    #[arg(long = "co", value_name = "NAME=VALUE")]
    pub creation_options: Vec<String>,
}

/// Refuse outputs in formats that cannot be written, before any work.
fn check_outputs(args: &ViewArgs) -> anyhow::Result<()> {
    for p in [&args.depth, &args.viewshed].into_iter().flatten() {
        output_driver(p, args.format.as_deref()).map_err(|m| anyhow::anyhow!(m))?;
    }
    demsketch::raster::output_format::check_creation_options(&args.creation_options)
        .map_err(|m| anyhow::anyhow!(m))?;
    if !is_png(&args.out) {
        output_driver(&args.out, None).map_err(|m| anyhow::anyhow!(m))?;
    }
    if let Some(f) = &args.features {
        let ext = f
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if !matches!(ext.as_str(), "geojson" | "json") {
            anyhow::bail!(
                "{}: --features writes GeoJSON; give a .geojson name (convert with ogr2ogr)",
                f.display()
            );
        }
    }
    Ok(())
}

fn is_png(p: &Path) -> bool {
    p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"))
}

/// Write the picture: PNG natively, any other format through GDAL
/// (three Byte bands).
fn write_picture(path: &Path, w: usize, h: usize, rgb: &[u8]) -> anyhow::Result<()> {
    if is_png(path) {
        write_png(path, w, h, rgb)?;
        return Ok(());
    }
    let bands: Vec<Vec<u8>> = (0..3)
        .map(|b| rgb.iter().skip(b).step_by(3).copied().collect())
        .collect();
    let spec = RasterSpec {
        width: w,
        height: h,
        ..Default::default()
    };
    write_raster(path, &spec, bands)?;
    Ok(())
}

/// The view to render: from the sketch file, with camera flags overriding.
fn resolve_view(args: &ViewArgs) -> anyhow::Result<ResolvedView> {
    let Some(path) = &args.sketch else {
        return args.camera.resolve();
    };
    // The sketch as `edit` reads it: the same parser and the same ranges
    // (one line naming the file, the view and the field's path).
    let file = SketchFile::from_path(path)?;
    let view_index = match &args.view {
        Some(name) => file
            .views
            .iter()
            .position(|v| v.name == *name)
            .ok_or_else(|| anyhow::anyhow!("{}: no view named '{name}'", path.display()))?,
        // (a sketch has at least one view)
        None => 0,
    };
    let v = &file.views[view_index];
    let (vp, c) = (&v.viewpoint, &v.camera);
    let f = &args.camera;
    // An eye the flags give replaces the sketch's, however either gives it.
    let (eye_height, alt) = if f.eye_height.is_some() || f.alt.is_some() {
        (f.eye_height, f.alt)
    } else {
        (vp.eye_height_m, vp.alt_m)
    };
    let flags = CameraFlags {
        lon: f.lon.or(Some(vp.lon)),
        lat: f.lat.or(Some(vp.lat)),
        eye_height,
        alt,
        heading: f.heading.or(Some(c.heading_deg)),
        pitch: f.pitch.or(Some(c.pitch_deg)),
        roll: f.roll.or(Some(c.roll_deg)),
        hfov: f.hfov.or(Some(c.hfov_deg)),
        size: f.size.or(Some((c.width as usize, c.height as usize))),
        max_distance: f.max_distance,
        refraction: f.refraction,
    };
    let mut r = flags.resolve()?;
    r.strokes = v.strokes.iter().map(|s| s.points.clone()).collect();
    r.view_index = view_index;
    if f.alt.is_none() {
        r.alt_label = format!("{}: view \"{}\": viewpoint alt_m", path.display(), v.name);
    }
    Ok(r)
}

/// Refuse output paths that name an input (a DEM tile, the sketch) or
/// each other, before anything is rendered or written.
fn check_view_outputs(args: &ViewArgs, dem: &Dem) -> anyhow::Result<()> {
    let mut inputs = dem_inputs(dem);
    if let Some(s) = &args.sketch {
        inputs.push(Input {
            what: format!("the sketch {}", s.display()),
            path: s.clone(),
            is_dir: false,
        });
    }
    let outputs: Vec<Output> = [
        ("--out", Some(&args.out)),
        ("--depth", args.depth.as_ref()),
        ("--viewshed", args.viewshed.as_ref()),
        ("--features", args.features.as_ref()),
    ]
    .into_iter()
    .filter_map(|(flag, p)| {
        p.map(|p| Output {
            flag: flag.into(),
            path: p.clone(),
            is_dir: false,
        })
    })
    .collect();
    path_check::check_outputs(&inputs, &outputs)?;
    Ok(())
}

/// The scene of the view: the camera's wedge, exact out to the
/// full-resolution reach and in coarser rings beyond
/// ([`Scene::open_view_lod`]), or exact throughout with
/// `--full-resolution` ([`Scene::open_wedge`]).
fn open_scene(args: &ViewArgs, dem: &Dem, view: &ResolvedView) -> anyhow::Result<Scene> {
    let (vp, max_d, k) = (
        &view.viewpoint,
        args.camera.max_distance,
        args.camera.refraction,
    );
    let scene = if args.full_resolution {
        Scene::open_wedge(dem, vp, max_d, k, &view.camera)?
    } else {
        Scene::open_view_lod(dem, vp, max_d, k, &view.camera)?
    };
    let rings = scene.terrain.far_layer_sizes();
    if super::verbose() && !rings.is_empty() {
        let ks: Vec<String> = rings.iter().map(|(k, _)| k.to_string()).collect();
        eprintln!(
            "demsketch: exact out to {:.0} m ({} x {} cells), rings {} times coarser beyond",
            scene.terrain.max_distance,
            scene.window.width,
            scene.window.height,
            ks.join(", ")
        );
    }
    Ok(scene)
}

/// `demsketch view`: open the camera's wedge, render it and find its
/// features, draw the picture, then stage every output and commit them
/// together.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    let t_all = Instant::now();
    check_outputs(&args)?;
    let view = resolve_view(&args)?;
    demsketch::render::check_target_height(args.target_height)?;
    // Each cell is read once: decoded blocks are not cached.
    let dem = Dem::open(&args.dem)?.without_block_cache();
    check_view_outputs(&args, &dem)?;
    // A picture and its features need only what the camera's horizontal
    // field of view takes in, and only that is read: the picture, the
    // silhouettes and the ridges come from the terrain of that wedge (the
    // ridges detected over its exact part, as an edit detects them for its
    // views; coarser rings beyond the full-resolution reach). The
    // viewshed, which covers every cell within the distance, is swept
    // apart, reading the DEM in bands outward from the eye
    // ([`viewshed_from_file`]), so that --viewshed changes none of them.
    let scene = open_scene(&args, &dem, &view)?;
    view.check_above_ground(scene.frame.ground)?;
    super::timing("load", t_all.elapsed().as_secs_f64());
    let t = Instant::now();
    let overlays = overlays_of(&args, &view);
    let rendered = render_with_features(&args, &scene, &view, &overlays)?;
    super::timing("render and features", t.elapsed().as_secs_f64());
    let t = Instant::now();
    let rgb = draw_picture(&scene, &view, &rendered, &overlays);
    // Every output is written and checked in a staging directory first,
    // and all replace their targets together at the end: a failure of one
    // (a full disk) leaves every file as it was.
    let mut staged = StagedOutputs::default();
    let written = (|| -> anyhow::Result<()> {
        let (w, h) = (view.camera.width, view.camera.height);
        let p = staged.stage(&args.out).map_err(anyhow::Error::msg)?;
        write_picture(&p, w, h, &rgb)?;
        if let Some(target) = &args.depth {
            stage_depth(&args, &mut staged, target, &rendered.depth)?;
        }
        if let Some(target) = &args.viewshed {
            stage_viewshed(&args, &mut staged, target, &dem, &scene, &view)?;
        }
        if let Some(target) = &args.features {
            stage_features(&mut staged, target, &scene, &view, &rendered)?;
        }
        Ok(())
    })();
    if let Err(e) = written {
        let m = staged.hide(&format!("{e:#}"));
        anyhow::bail!("{m}; nothing written");
    }
    staged.commit().map_err(anyhow::Error::msg)?;
    super::timing("write", t.elapsed().as_secs_f64());
    super::timing("total", t_all.elapsed().as_secs_f64());
    Ok(())
}

/// The overlays to draw: `--overlay`, or the strokes when the sketch's
/// view has any.
fn overlays_of(args: &ViewArgs, view: &ResolvedView) -> Vec<Overlay> {
    if !args.overlay.is_empty() {
        args.overlay.clone()
    } else if view.strokes.is_empty() {
        Vec::new()
    } else {
        vec![Overlay::Strokes]
    }
}

/// What the view shows: its depth buffer, and the silhouettes and ridges
/// when an overlay or `--features` needs them.
struct Rendered {
    depth: DepthBuffer,
    silhouettes: Option<Silhouettes>,
    ridges: Option<RidgeNetwork>,
}

/// Renders the scene and finds the features the outputs need. The ridges
/// need only the heights read: they are detected while the view is
/// rendered and its silhouettes extracted (each stage has serial parts
/// that leave a core idle).
fn render_with_features(
    args: &ViewArgs,
    scene: &Scene,
    view: &ResolvedView,
    overlays: &[Overlay],
) -> anyhow::Result<Rendered> {
    let want = |o: Overlay| overlays.contains(&o);
    let need_sil =
        args.features.is_some() || want(Overlay::Silhouettes) || want(Overlay::Junctions);
    let need_ridges = args.features.is_some() || want(Overlay::Ridges);
    let (terrain, window) = (&scene.terrain, &scene.window);
    let t = Instant::now();
    let (ridges, (depth, silhouettes)) = rayon::join(
        || {
            need_ridges
                .then(|| detect_ridges(window, &RidgeParams::default()))
                .transpose()
        },
        || {
            let depth = DepthBuffer::render(terrain, &view.camera);
            super::timing("render", t.elapsed().as_secs_f64());
            let silhouettes = need_sil
                .then(|| extract_silhouettes(terrain, &depth, &SilhouetteParams::default()))
                .transpose();
            (depth, silhouettes)
        },
    );
    Ok(Rendered {
        depth,
        silhouettes: silhouettes?,
        ridges: ridges?,
    })
}

/// The shaded picture with its overlays (8-bit RGB). The sun stands behind
/// the viewer's right shoulder, so the slopes facing the viewer are lit.
fn draw_picture(
    scene: &Scene,
    view: &ResolvedView,
    rendered: &Rendered,
    overlays: &[Overlay],
) -> Vec<u8> {
    let want = |o: Overlay| overlays.contains(&o);
    let terrain = &scene.terrain;
    let (w, h) = (view.camera.width, view.camera.height);
    let opts = ShadeOptions {
        sun_azimuth_deg: view.camera.heading_deg + 135.0,
        ..ShadeOptions::default()
    };
    let mut rgb = shade(&rendered.depth, terrain, &opts);
    let line = (w.max(h) as f64 / 800.0).clamp(1.0, 4.0);
    if let (true, Some(net)) = (want(Overlay::Ridges), &rendered.ridges) {
        let cell = terrain.frame.p[0][0].hypot(terrain.frame.p[1][0]);
        for l in &net.lines {
            for part in visible_polylines(terrain, &rendered.depth, net.line_points(l), 2.0 * cell)
            {
                draw_polyline(&mut rgb, w, h, &part, [255, 214, 0], line);
            }
        }
    }
    if let Some(sil) = &rendered.silhouettes {
        if want(Overlay::Silhouettes) {
            for c in &sil.curves {
                draw_polyline(&mut rgb, w, h, &c.pixels(), [225, 30, 30], line);
            }
        }
        if want(Overlay::Junctions) {
            for j in &sil.junctions {
                draw_polyline(&mut rgb, w, h, &[j.pixel], [20, 60, 255], 3.0 * line);
            }
        }
    }
    if want(Overlay::Strokes) {
        for s in &view.strokes {
            draw_polyline(&mut rgb, w, h, s, [230, 0, 200], line + 1.0);
        }
    }
    rgb
}

/// True when `target` is written losslessly (GeoTIFF or COG with no
/// creation options), so that it can be read back and compared.
fn lossless(args: &ViewArgs, target: &Path) -> bool {
    args.creation_options.is_empty()
        && matches!(
            output_driver(target, args.format.as_deref()).as_deref(),
            Ok("GTiff") | Ok("COG")
        )
}

/// Stages `--depth`: the depth buffer as Float32 metres, sky as nodata.
fn stage_depth(
    args: &ViewArgs,
    staged: &mut StagedOutputs,
    target: &Path,
    depth: &DepthBuffer,
) -> anyhow::Result<()> {
    let p = staged.stage(target).map_err(anyhow::Error::msg)?;
    let data = depth_for_file(depth);
    let spec = RasterSpec {
        width: depth.width,
        height: depth.height,
        nodata: Some(DEPTH_NODATA),
        description: Some("distance from the eye, m (nodata: sky)".into()),
        format: args.format.clone(),
        creation_options: args.creation_options.clone(),
        ..Default::default()
    };
    write_raster(&p, &spec, vec![data.clone()])?;
    if lossless(args, target) {
        verify_band(&p, depth.width, depth.height, &data)
            .map_err(|m| anyhow::anyhow!("{}: {m}", p.display()))?;
    }
    Ok(())
}

/// Stages `--viewshed`, on the window a view reads within the distance
/// (the DEM around the eye), like the exact reference: swept outward from
/// the eye in bands read from the file, or one exact line of sight per
/// cell with `--viewshed-exact`.
fn stage_viewshed(
    args: &ViewArgs,
    staged: &mut StagedOutputs,
    target: &Path,
    dem: &Dem,
    scene: &Scene,
    view: &ResolvedView,
) -> anyhow::Result<()> {
    let max_d = demsketch::view::distance_limit(args.camera.max_distance);
    let window = Scene::window_of(
        dem,
        &scene.georef,
        view.viewpoint.lon,
        view.viewpoint.lat,
        max_d,
    )?;
    let vs = if args.viewshed_exact {
        let full = Scene::open(
            dem,
            &view.viewpoint,
            args.camera.max_distance,
            args.camera.refraction,
        )?;
        viewshed_exact(&full.terrain, &full.window, args.target_height)
    } else {
        let frame = eye_frame(dem, &scene.georef, &view.viewpoint, args.camera.refraction)?;
        viewshed_from_file(dem, &frame, max_d, args.target_height)?.crop(window)
    };
    let p = staged.stage(target).map_err(anyhow::Error::msg)?;
    let spec = RasterSpec {
        width: vs.width,
        height: vs.height,
        geotransform: Some(vs.geotransform.0),
        crs: vs.crs.gdal_definition(),
        format: args.format.clone(),
        creation_options: args.creation_options.clone(),
        ..Default::default()
    };
    write_raster(&p, &spec, vec![vs.data.clone()])?;
    if lossless(args, target) {
        verify_band(&p, vs.width, vs.height, &vs.data)
            .map_err(|m| anyhow::anyhow!("{}: {m}", p.display()))?;
    }
    Ok(())
}

/// Stages `--features`: the view's silhouettes, T-junctions and ridge
/// lines as GeoJSON in lon/lat/z.
fn stage_features(
    staged: &mut StagedOutputs,
    target: &Path,
    scene: &Scene,
    view: &ResolvedView,
    rendered: &Rendered,
) -> anyhow::Result<()> {
    let to_ll = to_lonlat_with_georef(&scene.georef);
    let mut fc = feature_collection_of_view(
        rendered.silhouettes.as_ref(),
        rendered.ridges.as_ref(),
        view.view_index,
        &to_ll,
    )?;
    // Where the view reaches beyond the full-resolution terrain, how far
    // that goes (a foreign member of the collection): the ridges stop
    // there, and the silhouettes whose depth_min is beyond it are traced on
    // the coarser rings.
    if !scene.terrain.far_layer_sizes().is_empty() {
        fc["full_resolution_reach_m"] = serde_json::Value::from(scene.terrain.max_distance.round());
    }
    let p = staged.stage(target).map_err(anyhow::Error::msg)?;
    write_geojson(&p, &fc)?;
    Ok(())
}
