//! `demsketch view DEM (--sketch FILE [--view NAME] | --lon X --lat Y [camera
//! flags]) --out view.png [--depth depth.tif] [--viewshed vis.tif]`: render
//! what a person standing at the viewpoint sees (shaded PNG, strokes of the
//! sketch overlaid), and optionally the depth buffer and the viewshed.
//! Also defines the camera flags shared with `locate`.

use anyhow::Context;
use demsketch::raster::Dem;
use demsketch::render::{
    draw_polyline, shade, viewshed, write_depth_tiff, write_png, write_viewshed_tiff, DepthBuffer,
    Scene, ShadeOptions,
};
use demsketch::view::{Camera, EyeHeight, Viewpoint};
use serde::Deserialize;
use std::path::PathBuf;

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
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size '{s}' must be WxH, e.g. 1600x900"))?;
    let w: usize = w
        .trim()
        .parse()
        .map_err(|_| format!("size '{s}': bad width"))?;
    let h: usize = h
        .trim()
        .parse()
        .map_err(|_| format!("size '{s}': bad height"))?;
    Ok((w, h))
}

/// The view of a sketch file (DESIGN.md "Sketch file"), as far as `view` needs it.
#[derive(Deserialize, Debug, Clone)]
struct SketchFile {
    views: Vec<SketchView>,
}

#[derive(Deserialize, Debug, Clone)]
struct SketchView {
    #[serde(default)]
    name: Option<String>,
    viewpoint: SketchViewpoint,
    #[serde(default)]
    camera: SketchCamera,
    #[serde(default)]
    strokes: Vec<SketchStroke>,
}

#[derive(Deserialize, Debug, Clone)]
struct SketchViewpoint {
    lon: f64,
    lat: f64,
    eye_height_m: Option<f64>,
    alt_m: Option<f64>,
}

#[derive(Deserialize, Debug, Clone, Default)]
struct SketchCamera {
    heading_deg: Option<f64>,
    pitch_deg: Option<f64>,
    roll_deg: Option<f64>,
    hfov_deg: Option<f64>,
    width: Option<usize>,
    height: Option<usize>,
}

#[derive(Deserialize, Debug, Clone)]
struct SketchStroke {
    points: Vec<[f64; 2]>,
}

/// A fully specified view: viewpoint, camera, strokes to overlay.
pub struct ResolvedView {
    pub viewpoint: Viewpoint,
    pub camera: Camera,
    pub strokes: Vec<Vec<[f64; 2]>>,
}

impl CameraFlags {
    /// Viewpoint and camera from the flags (flags override `base` values).
    pub fn resolve(&self) -> anyhow::Result<ResolvedView> {
        let (Some(lon), Some(lat)) = (self.lon, self.lat) else {
            anyhow::bail!("give the viewpoint as --lon X --lat Y (or --sketch FILE)");
        };
        let height = match (self.alt, self.eye_height) {
            (Some(a), _) => EyeHeight::Absolute(a),
            (None, h) => EyeHeight::AboveSurface(h.unwrap_or(1.7)),
        };
        let (w, h) = self.size.unwrap_or((1600, 900));
        let camera = Camera::new(
            w,
            h,
            self.heading.unwrap_or(0.0),
            self.pitch.unwrap_or(0.0),
            self.roll.unwrap_or(0.0),
            self.hfov.unwrap_or(60.0),
        )?;
        Ok(ResolvedView {
            viewpoint: Viewpoint { lon, lat, height },
            camera,
            strokes: Vec::new(),
        })
    }
}

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
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the depth buffer (Float32 TIFF, metres, inf = sky).
    #[arg(long)]
    pub depth: Option<PathBuf>,
    /// Also write the viewshed (GeoTIFF on the DEM grid, 255 visible / 0 not).
    #[arg(long)]
    pub viewshed: Option<PathBuf>,
    /// Target height above the surface for the viewshed, metres.
    #[arg(long, default_value_t = 0.0)]
    pub target_height: f64,
}

/// The view to render: from the sketch file, with camera flags overriding.
fn resolve_view(args: &ViewArgs) -> anyhow::Result<ResolvedView> {
    let Some(path) = &args.sketch else {
        return args.camera.resolve();
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read sketch file", path.display()))?;
    let file: SketchFile = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: not a sketch file: {e}", path.display()))?;
    let v = match &args.view {
        Some(name) => file
            .views
            .iter()
            .find(|v| v.name.as_deref() == Some(name.as_str()))
            .ok_or_else(|| anyhow::anyhow!("{}: no view named '{name}'", path.display()))?,
        None => file
            .views
            .first()
            .ok_or_else(|| anyhow::anyhow!("{}: no views", path.display()))?,
    };
    let f = &args.camera;
    let mut flags = CameraFlags {
        lon: f.lon.or(Some(v.viewpoint.lon)),
        lat: f.lat.or(Some(v.viewpoint.lat)),
        eye_height: f.eye_height.or(v.viewpoint.eye_height_m),
        alt: f.alt.or(v.viewpoint.alt_m),
        heading: f.heading.or(v.camera.heading_deg),
        pitch: f.pitch.or(v.camera.pitch_deg),
        roll: f.roll.or(v.camera.roll_deg),
        hfov: f.hfov.or(v.camera.hfov_deg),
        size: f.size,
        max_distance: f.max_distance,
        refraction: f.refraction,
    };
    if flags.size.is_none() {
        if let (Some(w), Some(h)) = (v.camera.width, v.camera.height) {
            flags.size = Some((w, h));
        }
    }
    if f.eye_height.is_some() {
        flags.alt = None;
    }
    let mut r = flags.resolve()?;
    r.strokes = v.strokes.iter().map(|s| s.points.clone()).collect();
    Ok(r)
}

pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    let view = resolve_view(&args)?;
    let dem = Dem::open(&args.dem)?;
    let scene = Scene::open(
        &dem,
        &view.viewpoint,
        args.camera.max_distance,
        args.camera.refraction,
    )?;
    let depth = DepthBuffer::render(&scene.terrain, &view.camera);
    let mut rgb = shade(&depth, &scene.terrain, &ShadeOptions::default());
    for s in &view.strokes {
        draw_polyline(
            &mut rgb,
            view.camera.width,
            view.camera.height,
            s,
            [230, 40, 40],
            2.0,
        );
    }
    write_png(&args.out, view.camera.width, view.camera.height, &rgb)?;
    if let Some(p) = &args.depth {
        write_depth_tiff(&depth, p)?;
    }
    if let Some(p) = &args.viewshed {
        let vs = viewshed(&scene.terrain, &scene.window, args.target_height);
        write_viewshed_tiff(&vs, p)?;
    }
    Ok(())
}
