//! `demsketch export tiles|cog|geojson|stac|gltf`: a DEM (typically one an
//! edit corrected) to the formats web maps, catalogues and 3D viewers
//! read. Parses flags, calls [`demsketch::export`] and prints; each
//! subcommand's output is written atomically or not at all.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use demsketch::export::{
    change_mask, cog, curves_geojson, edit_report, gltf_mesh, stac_item, web_mercator, xyz_tiles,
    Encoding, ExportError,
};
use demsketch::raster::atomic_file::{write_bytes_verified, StagedOutputs};
use demsketch::raster::Dem;

use super::InternalError;

/// Shown by `export --help`.
pub const EXPORT_AFTER_HELP: &str = "\
Examples:
  # Terrain-RGB tiles of zooms 8 to 12 for MapLibre (raster-dem, encoding \"mapbox\"):
  demsketch export tiles fixed.tif --encoding terrain-rgb --zoom 8-12 --out tiles/
  # After an edit, rewrite only the tiles over the change in that tree:
  demsketch edit dem.tif --sketch s.json --out fixed.tif --dz dz.tif --report r.json
  demsketch export tiles fixed.tif --encoding terrain-rgb --zoom 8-12 --out tiles/ --changed dz.tif
  # Cloud Optimized GeoTIFF, STAC item, GeoJSON of the edit, glTF mesh:
  demsketch export cog fixed.tif --out fixed_cog.tif
  demsketch export stac fixed_cog.tif --report r.json --out fixed_cog.json
  demsketch export geojson fixed.tif --report r.json --dz dz.tif --out edit.geojson
  demsketch export gltf fixed.tif --bounds -113.1,37.2,-112.9,37.4 --out zion.glb

Exit codes: 0 written; 1 a user error (one line naming the file and the
problem; nothing written); 2 an internal error (nothing written).";

#[derive(clap::Args, Debug)]
pub struct ExportArgs {
    #[command(subcommand)]
    pub what: ExportCommand,
}

#[derive(clap::Subcommand, Debug)]
pub enum ExportCommand {
    /// Terrain-RGB or Terrarium PNG tiles (XYZ, Web Mercator) for web maps.
    #[command(after_help = TILES_AFTER_HELP)]
    Tiles(TilesArgs),
    /// A Cloud Optimized GeoTIFF (GDAL's COG driver: tiled, overviews).
    Cog(CogArgs),
    /// The placed 3D curves of an edit and the change footprint, as GeoJSON.
    Geojson(GeojsonArgs),
    /// A STAC 1.1.0 item (raster, projection, processing extensions) with the edit's provenance.
    Stac(StacArgs),
    /// A triangle mesh of an area as binary glTF (.glb) in a local east-north-up frame.
    #[command(after_help = GLTF_AFTER_HELP)]
    Gltf(GltfArgs),
}

const TILES_AFTER_HELP: &str = "\
Encodings (height in metres from a pixel's red, green, blue bytes):
  terrain-rgb  -10000 + (R * 65536 + G * 256 + B) * 0.1      (Mapbox; MapLibre \"mapbox\")
  terrarium    R * 256 + G + B / 256 - 32768                 (MapLibre \"terrarium\")

Each tile is the DEM warped by GDAL into the tile's 256 x 256 pixels in
EPSG:3857 with bilinear resampling: what `gdalwarp -t_srs EPSG:3857 -te
XMIN YMIN XMAX YMAX -ts 256 256 -r bilinear -ot Float32` gives for that
tile, encoded. Nodata pixels are transparent (alpha 0, colour of 0 m);
tiles without any height are not written. OUT/z/x/y.png (y from the
north) and OUT/tiles.json (TileJSON 3.0.0 with \"encoding\").

--changed DZ.tif|REPORT.json computes only the tiles an edit changed: the
cells of `edit --dz` with |dz| > --min-dz, or the deformation window of an
`edit --report`; the tiles are renamed one by one into an existing OUT.";

const GLTF_AFTER_HELP: &str = "\
Frame: east-north-up metres on WGS84 with its origin at the centre of the
area (that longitude and latitude, height 0), the DEM's heights as
ellipsoidal heights; glTF is y-up: x = east, y = up, z = south. The origin
is written in the file (asset.extras.demsketch). One vertex per valid cell
centre (every --step-th cell), two triangles per square of valid cells,
per-vertex normals, 32-bit indices.";

#[derive(clap::Args, Debug)]
pub struct TilesArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// Height encoding: terrain-rgb (Mapbox) or terrarium.
    #[arg(long, value_parser = Encoding::parse)]
    pub encoding: Encoding,
    /// Zoom level or inclusive range, like 10 or 8-12.
    #[arg(long, value_parser = web_mercator::parse_zoom_range)]
    pub zoom: (u8, u8),
    /// Directory of the tile tree (created; with --changed, may exist).
    #[arg(long)]
    pub out: PathBuf,
    /// Only the tiles an edit changed: its --dz raster or its --report JSON.
    #[arg(long, value_name = "DZ.tif|REPORT.json")]
    pub changed: Option<PathBuf>,
    /// With a --changed dz raster: cells with |dz| above this are changed,
    /// metres (>= 0).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub min_dz: f64,
    /// Refuse to start past this many tiles.
    #[arg(long, default_value_t = 1_000_000)]
    pub max_tiles: usize,
    /// Print what was written as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct CogArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// The Cloud Optimized GeoTIFF to write.
    #[arg(long)]
    pub out: PathBuf,
    /// COG driver creation option NAME=VALUE, over demsketch's defaults
    /// (COMPRESS=DEFLATE PREDICTOR=YES BLOCKSIZE=512 OVERVIEWS=AUTO
    /// RESAMPLING=AVERAGE BIGTIFF=IF_SAFER); repeatable, written -co or --co.
    #[arg(long = "co", value_name = "NAME=VALUE")]
    pub creation_options: Vec<String>,
    /// Print what was written as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args, Debug)]
pub struct GeojsonArgs {
    /// The DEM the edit wrote (or its input: the CRS of the report's curves).
    pub dem: PathBuf,
    /// The edit report (`demsketch edit --report`).
    #[arg(long)]
    pub report: PathBuf,
    /// The edit's height change (`demsketch edit --dz`): the footprint is
    /// its cells with |dz| > --min-dz (default: the report's window).
    #[arg(long, value_name = "DZ.tif")]
    pub dz: Option<PathBuf>,
    /// Cells with |dz| above this are changed, metres (>= 0).
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    pub min_dz: f64,
    /// The GeoJSON file to write.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(clap::Args, Debug)]
pub struct StacArgs {
    /// The product to describe (a GeoTIFF or COG, or a tile directory).
    pub dem: PathBuf,
    /// The item (JSON) to write.
    #[arg(long)]
    pub out: PathBuf,
    /// The edit report: its summary goes into the item, the file becomes an asset.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Item id [default: the DEM's file stem].
    #[arg(long)]
    pub id: Option<String>,
    /// href of the DEM asset (a URL where it will be served) [default: its
    /// path relative to the item].
    #[arg(long)]
    pub asset_href: Option<String>,
    /// Item datetime, RFC 3339 UTC like 2024-05-01T12:00:00Z [default: the
    /// latest edit in the DEM's provenance, else now].
    #[arg(long, value_parser = parse_datetime)]
    pub datetime: Option<String>,
}

#[derive(clap::Args, Debug)]
pub struct GltfArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens.
    pub dem: PathBuf,
    /// The binary glTF (.glb) to write.
    #[arg(long)]
    pub out: PathBuf,
    /// Area as lon/lat WEST,SOUTH,EAST,NORTH in degrees, west < east,
    /// south < north, longitudes in [-180, 180], latitudes in [-90, 90]
    /// [default: the whole DEM].
    #[arg(long, allow_hyphen_values = true, value_name = "W,S,E,N")]
    pub bounds: Option<String>,
    /// Take every STEP-th cell in each direction.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub step: u32,
    /// Refuse meshes with more vertices than this.
    #[arg(long, default_value_t = 4_000_000)]
    pub max_vertices: usize,
    /// Print what was written as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

fn parse_datetime(s: &str) -> Result<String, String> {
    let ok = s.len() >= 20
        && s.as_bytes().get(4) == Some(&b'-')
        && s.as_bytes().get(10) == Some(&b'T')
        && (s.ends_with('Z') || s.ends_with("+00:00"));
    if ok {
        Ok(s.to_string())
    } else {
        Err(format!(
            "--datetime '{s}' must be RFC 3339 UTC, like 2024-05-01T12:00:00Z"
        ))
    }
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    match args.what {
        ExportCommand::Tiles(a) => tiles(a),
        ExportCommand::Cog(a) => cog_cmd(a),
        ExportCommand::Geojson(a) => geojson(a),
        ExportCommand::Stac(a) => stac(a),
        ExportCommand::Gltf(a) => gltf(a),
    }
}

/// User errors pass as they are (exit 1), the rest as internal (exit 2).
fn lift(e: ExportError) -> anyhow::Error {
    if e.is_user_error() {
        e.into()
    } else {
        InternalError(e.to_string()).into()
    }
}

fn tiles(a: TilesArgs) -> anyhow::Result<()> {
    change_mask::check_min_dz(a.min_dz)?;
    let changed = match &a.changed {
        Some(p) => {
            let dem = Dem::open(&a.dem)?;
            Some(change_mask::read(p, &dem, a.min_dz).map_err(lift)?)
        }
        None => None,
    };
    if let Some(m) = &changed {
        if m.count() == 0 && !super::quiet() {
            eprintln!("demsketch: {}: no changed cell: no tile to write", m.source);
        }
    }
    let opts = xyz_tiles::TileOptions {
        encoding: a.encoding,
        zooms: a.zoom,
        changed,
        max_tiles: a.max_tiles,
        progress: std::io::stderr().is_terminal() && !super::quiet(),
    };
    let r = xyz_tiles::export_tiles(&a.dem, &a.out, &opts).map_err(lift)?;
    super::timing("tiles", r.seconds);
    if a.json {
        super::print_stdout(&serde_json::to_string_pretty(&r).context("report")?)
            .context("stdout")?;
    } else if !super::quiet() {
        eprintln!(
            "{}: {} tiles written ({} without data skipped), zooms {}-{}, {:.2} s ({:.0} tiles/s)",
            r.out,
            r.tiles_written,
            r.tiles_empty,
            r.zooms[0],
            r.zooms[1],
            r.seconds,
            r.tiles as f64 / r.seconds.max(1e-9)
        );
    }
    Ok(())
}

fn cog_cmd(a: CogArgs) -> anyhow::Result<()> {
    let r = cog::export_cog(&a.dem, &a.out, &a.creation_options).map_err(lift)?;
    super::timing("cog", r.seconds);
    if a.json {
        super::print_stdout(&serde_json::to_string_pretty(&r).context("report")?)
            .context("stdout")?;
    } else if !super::quiet() {
        eprintln!(
            "{}: COG {} x {}, {} overview(s), {} bytes, {:.2} s",
            r.out, r.width, r.height, r.overviews, r.bytes, r.seconds
        );
    }
    Ok(())
}

fn geojson(a: GeojsonArgs) -> anyhow::Result<()> {
    change_mask::check_min_dz(a.min_dz)?;
    let dem = Dem::open(&a.dem)?;
    let report = edit_report::read(&a.report).map_err(lift)?;
    let mask = match &a.dz {
        Some(dz) => change_mask::from_dz(dz, a.min_dz),
        None => change_mask::from_report(&a.report, &dem),
    }
    .map_err(lift)?;
    let fc =
        curves_geojson::edit_features(&report, &a.report, &dem.crs, Some(&mask)).map_err(lift)?;
    if !fc["properties"]["placed_curves_in_report"]
        .as_bool()
        .unwrap_or(false)
        && !super::quiet()
    {
        eprintln!(
            "demsketch: {}: no placed_curve in the report (an older demsketch?): only the footprint is written",
            a.report.display()
        );
    }
    let mut text = serde_json::to_string_pretty(&fc).context("GeoJSON")?;
    text.push('\n');
    write_file(&a.out, text.as_bytes())?;
    if !super::quiet() {
        let n = fc["features"].as_array().map(|f| f.len()).unwrap_or(0);
        eprintln!("{}: {n} feature(s)", a.out.display());
    }
    Ok(())
}

fn stac(a: StacArgs) -> anyhow::Result<()> {
    let dem = Dem::open(&a.dem)?;
    let report = match &a.report {
        Some(p) => Some((p.clone(), edit_report::read(p).map_err(lift)?)),
        None => None,
    };
    let opts = stac_item::StacOptions {
        id: a.id.clone(),
        report,
        asset_href: a.asset_href.clone(),
        datetime: a.datetime.clone(),
    };
    let item = stac_item::stac_item(&dem, &a.out, &opts).map_err(lift)?;
    let mut text = serde_json::to_string_pretty(&item).context("STAC item")?;
    text.push('\n');
    write_file(&a.out, text.as_bytes())?;
    if !super::quiet() {
        eprintln!(
            "{}: STAC item \"{}\"",
            a.out.display(),
            item["id"].as_str().unwrap_or("")
        );
    }
    Ok(())
}

fn gltf(a: GltfArgs) -> anyhow::Result<()> {
    let bounds = a
        .bounds
        .as_deref()
        .map(gltf_mesh::parse_bounds)
        .transpose()?;
    let opts = gltf_mesh::MeshOptions {
        bounds_lonlat: bounds,
        step: a.step as usize,
        max_vertices: a.max_vertices,
    };
    let r = gltf_mesh::export_gltf(&a.dem, &a.out, &opts).map_err(lift)?;
    if a.json {
        super::print_stdout(&serde_json::to_string_pretty(&r).context("report")?)
            .context("stdout")?;
    } else if !super::quiet() {
        eprintln!(
            "{}: {} vertices, {} triangles, origin {:.6}, {:.6} (ENU; glTF x east, y up, z south)",
            r.out, r.vertices, r.triangles, r.origin_lonlat[0], r.origin_lonlat[1]
        );
    }
    Ok(())
}

/// Write one small file atomically (staged beside it, verified, renamed).
fn write_file(out: &std::path::Path, bytes: &[u8]) -> anyhow::Result<()> {
    let mut staged = StagedOutputs::default();
    let tmp = staged.stage(out).map_err(|m| anyhow::anyhow!("{m}"))?;
    write_bytes_verified(&tmp, bytes)
        .map_err(|e| anyhow::anyhow!("{}: cannot write: {e}", out.display()))?;
    staged.commit().map_err(|m| anyhow::anyhow!("{m}"))
}
