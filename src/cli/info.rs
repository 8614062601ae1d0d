//! `demsketch info DEM [--json]`: what a DEM is, as `gdalinfo` would say it,
//! for single GeoTIFFs, tile directories and GDAL rasters alike. The
//! vertical description (unit, datum, band scale and offset) is shown as the
//! file gives it; min/max are heights in metres, as demsketch uses them.

use std::path::PathBuf;

use anyhow::Context;
use demsketch::raster::{lonlat_bounds, Dem, TileSource};
use serde_json::json;

#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// A GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens (VRT...).
    pub dem: PathBuf,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Skip the min/max scan (which reads every block).
    #[arg(long)]
    pub no_stats: bool,
}

/// `demsketch info`: what the DEM is (size, CRS, bounds, nodata, sample
/// type, tiles, encoding, vertical unit and datum, and its range unless
/// `--no-stats`), as gdalinfo-like text or as JSON.
pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    let dem = Dem::open(&args.dem)?;
    let min_max = if args.no_stats {
        None
    } else {
        dem.min_max()
            .with_context(|| "reading values for min/max")?
    };
    if args.json {
        super::print_stdout(&serde_json::to_string_pretty(&info_json(&dem, min_max))?)?;
    } else {
        print_info(&dem, min_max);
    }
    Ok(())
}

/// The `--json` description of `dem`.
fn info_json(dem: &Dem, min_max: Option<(f64, f64)>) -> serde_json::Value {
    let gt = dem.geotransform;
    let (px, py) = gt.pixel_size();
    let bounds = gt.bounds(dem.width, dem.height);
    let ll = lonlat_bounds(&dem.crs, &gt, dem.width, dem.height);
    let nodata = match dem.nodata {
        None => serde_json::Value::Null,
        Some(v) if v.is_nan() => json!("nan"),
        Some(v) => json!(v),
    };
    let tiles: Vec<_> = dem
        .tiles
        .iter()
        .map(|t| {
            let (layout, encoding) = match &t.source {
                TileSource::Tiff(g) => (
                    json!({"tiled": g.layout.tiled, "block": [g.layout.block_width, g.layout.block_height]}),
                    json!({"compression": g.encoding.compression, "predictor": g.encoding.predictor,
                           "overviews": g.overviews(), "pixel_is_point": g.raster_type == demsketch::raster::geotiff::RasterType::PixelIsPoint}),
                ),
                TileSource::Gdal(_) => (json!(null), json!({"driver": "GDAL"})),
            };
            json!({"path": t.path.to_string_lossy(), "col": t.extent.col, "row": t.extent.row,
                   "width": t.extent.width, "height": t.extent.height,
                   "layout": layout, "encoding": encoding})
        })
        .collect();
    json!({
        "path": dem.path.to_string_lossy(),
        "kind": dem.kind,
        "width": dem.width,
        "height": dem.height,
        "geotransform": gt.0,
        "pixel_size": [px, py],
        "bounds": bounds,
        "bounds_lonlat": ll,
        "epsg": dem.crs.epsg,
        "wkt": dem.crs.wkt,
        "proj": dem.crs.proj,
        "geographic": dem.crs.geographic,
        "nodata": nodata,
        "sample_type": dem.sample_type.gdal_name(),
        "tiles": dem.tiles.len(),
        "tile_list": tiles,
        "vertical": {
            "unit": dem.vertical.unit,
            "unit_to_metre": dem.vertical.unit_to_metre,
            "unit_source": dem.vertical.unit_source,
            "datum": dem.vertical.datum,
            "scale": dem.vertical.scale,
            "offset": dem.vertical.offset,
        },
        "read_by_gdal": dem.tiles.iter().any(|t| t.read_by_gdal()),
        "min": min_max.map(|m| m.0),
        "max": min_max.map(|m| m.1),
        "min_max_unit": "metre",
    })
}

/// The text description of `dem`, gdalinfo-like, one field a line.
fn print_info(dem: &Dem, min_max: Option<(f64, f64)>) {
    let gt = dem.geotransform;
    let (px, py) = gt.pixel_size();
    let bounds = gt.bounds(dem.width, dem.height);
    let ll = lonlat_bounds(&dem.crs, &gt, dem.width, dem.height);
    println!("DEM:          {}", dem.path.display());
    println!("Kind:         {:?}, {} file(s)", dem.kind, dem.tiles.len());
    println!("Size:         {} x {} pixels", dem.width, dem.height);
    println!("Sample type:  {}", dem.sample_type);
    match dem.crs.epsg {
        Some(c) => println!(
            "CRS:          EPSG:{c}{}",
            if dem.crs.geographic {
                " (geographic)"
            } else {
                ""
            }
        ),
        None => println!(
            "CRS:          {}",
            dem.crs
                .proj
                .as_deref()
                .unwrap_or("user-defined (see --json for WKT)")
        ),
    }
    println!("Geotransform: {:?}", gt.0);
    println!("Pixel size:   {px} x {py}");
    println!(
        "Bounds:       x {} .. {}, y {} .. {}",
        bounds[0], bounds[2], bounds[1], bounds[3]
    );
    if let Some(b) = ll {
        println!(
            "Lon/lat:      W {:.6} S {:.6} E {:.6} N {:.6}",
            b[0], b[1], b[2], b[3]
        );
    }
    println!(
        "Nodata:       {}",
        match dem.nodata {
            None => "none".into(),
            Some(v) => v.to_string(),
        }
    );
    if dem.tiles.iter().any(|t| t.read_by_gdal()) {
        println!("Encoding:     read through GDAL (not written back in place)");
    }
    if let Some(TileSource::Tiff(g)) = dem.tiles.first().map(|t| &t.source) {
        println!(
            "Encoding:     {} {}x{} blocks, {}, predictor {}{}",
            if g.layout.tiled { "tiled" } else { "striped" },
            g.layout.block_width,
            g.layout.block_height,
            g.encoding.compression,
            g.encoding.predictor,
            if g.overviews().is_empty() {
                String::new()
            } else {
                format!(", {} overview(s)", g.overviews().len())
            }
        );
    }
    let v = &dem.vertical;
    println!(
        "Vertical:     unit {} ({}), datum {}, scale {}, offset {}",
        v.unit,
        match v.unit_source {
            demsketch::raster::vertical::UnitSource::Band => "band unit",
            demsketch::raster::vertical::UnitSource::Crs => "vertical CRS",
            demsketch::raster::vertical::UnitSource::Default => "none given, metres assumed",
        },
        v.datum.as_deref().unwrap_or("none given"),
        v.scale,
        v.offset
    );
    if let Some((lo, hi)) = min_max {
        println!("Min/max:      {lo} / {hi} m");
    }
}
