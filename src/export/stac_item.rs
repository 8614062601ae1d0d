//! `export stac`: a STAC 1.1.0 Item describing a DEM (typically the
//! product of an edit) for catalogues and STAC browsers, with three
//! extensions: raster (the band's data type, nodata, unit, scale and
//! offset, resolution, statistics), projection (EPSG code or WKT2, shape,
//! transform, native bbox) and processing (software, time, lineage, and
//! the edit itself as `processing:expression`). The edit's provenance is
//! the DEM's own history (the `DEMSKETCH_PROVENANCE_N` metadata every
//! edit appends, parsed into objects under `demsketch:provenance`) and,
//! when given, the edit report (`demsketch:edit`: sketch, changed cells,
//! largest change, each stroke's fit; the report is also an asset).
//!
//! Geometry is the DEM's outline in lon/lat through PROJ, edges densified.
//! Asset links are written relative to the item's file when they can be.

use std::path::{Path, PathBuf};

use serde_json::{json, Map, Value};

use super::edit_report::EditReportSummary;
use super::ExportError;
use crate::raster::{Dem, SampleType};

/// The schemas the item declares.
pub const EXTENSIONS: [&str; 3] = [
    "https://stac-extensions.github.io/raster/v1.1.0/schema.json",
    "https://stac-extensions.github.io/projection/v1.1.0/schema.json",
    "https://stac-extensions.github.io/processing/v1.2.0/schema.json",
];

/// What the item says beyond the DEM itself.
#[derive(Debug, Clone, Default)]
pub struct StacOptions {
    /// Item id (default: the DEM's file stem).
    pub id: Option<String>,
    /// The edit report, if any, and where it is.
    pub report: Option<(PathBuf, EditReportSummary)>,
    /// href of the DEM asset (default: the DEM's path relative to the item).
    pub asset_href: Option<String>,
    /// Item time (default: the latest provenance entry's, else now).
    pub datetime: Option<String>,
}

/// The item of `dem`, to be written at `item_path`.
pub fn stac_item(dem: &Dem, item_path: &Path, opts: &StacOptions) -> Result<Value, ExportError> {
    let bounds = crate::raster::lonlat_bounds(&dem.crs, &dem.geotransform, dem.width, dem.height)
        .ok_or_else(|| ExportError::Input {
        path: dem.path.display().to_string(),
        message: "no CRS PROJ knows: a STAC item needs lon/lat bounds".into(),
    })?;
    let outline = outline_lonlat(dem)?;
    let history = provenance_history(dem);
    let now = crate::raster::rfc3339_now();
    let datetime = opts
        .datetime
        .clone()
        .or_else(|| {
            history
                .last()
                .and_then(|h| h["time"].as_str().map(String::from))
        })
        .unwrap_or_else(|| now.clone());
    let id = opts.id.clone().unwrap_or_else(|| {
        dem.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "dem".into())
    });
    let mut props = Map::new();
    props.insert("datetime".into(), json!(datetime));
    props.insert("created".into(), json!(now));
    props.insert("title".into(), json!(format!("DEM {id}")));
    props.insert(
        "description".into(),
        json!(match &opts.report {
            Some((_, r)) => format!(
                "{} corrected by demsketch edit with the sketch {}",
                r.dem, r.sketch
            ),
            None => format!("digital elevation model {}", dem.path.display()),
        }),
    );
    projection_fields(dem, &mut props);
    processing_fields(dem, opts, &history, &now, &mut props);
    props.insert("demsketch:provenance".into(), Value::Array(history));
    if let Some((_, r)) = &opts.report {
        props.insert("demsketch:edit".into(), edit_summary(r));
    }
    let mut assets = Map::new();
    assets.insert("dem".into(), dem_asset(dem, item_path, opts)?);
    if let Some((p, _)) = &opts.report {
        assets.insert(
            "edit_report".into(),
            json!({
                "href": relative_href(p, item_path),
                "type": "application/json",
                "title": "demsketch edit report",
                "roles": ["metadata"],
            }),
        );
    }
    Ok(json!({
        "type": "Feature",
        "stac_version": "1.1.0",
        "stac_extensions": EXTENSIONS,
        "id": id,
        "geometry": outline,
        "bbox": bounds,
        "properties": props,
        "links": [],
        "assets": assets,
    }))
}

/// The DEM's outline as a lon/lat Polygon (edges densified, 20 points a side).
fn outline_lonlat(dem: &Dem) -> Result<Value, ExportError> {
    let to_ll =
        proj::Proj::new_known_crs(&dem.crs.proj_definition(), "EPSG:4326", None).map_err(|e| {
            ExportError::Input {
                path: dem.path.display().to_string(),
                message: format!("its CRS is unknown to PROJ: {e}"),
            }
        })?;
    let (w, h) = (dem.width as f64, dem.height as f64);
    let n = 20;
    let mut ring = Vec::new();
    let sides: [(f64, f64, f64, f64); 4] = [
        (0.0, 0.0, 0.0, h),
        (0.0, h, w, h),
        (w, h, w, 0.0),
        (w, 0.0, 0.0, 0.0),
    ];
    for (ax, ay, bx, by) in sides {
        for i in 0..n {
            let t = i as f64 / n as f64;
            let (x, y) = dem
                .geotransform
                .pixel_to_crs(ax + (bx - ax) * t, ay + (by - ay) * t);
            if let Ok((lon, lat)) = to_ll.convert((x, y)) {
                ring.push(json!([lon, lat]));
            }
        }
    }
    if ring.len() < 4 {
        return Err(ExportError::Input {
            path: dem.path.display().to_string(),
            message: "its corners do not convert to lon/lat".into(),
        });
    }
    ring.push(ring[0].clone());
    Ok(json!({"type": "Polygon", "coordinates": [ring]}))
}

/// `proj:*` fields of the DEM.
fn projection_fields(dem: &Dem, props: &mut Map<String, Value>) {
    let g = dem.geotransform.0;
    props.insert("proj:epsg".into(), json!(dem.crs.epsg));
    if dem.crs.epsg.is_none() && !dem.crs.wkt.is_empty() {
        props.insert("proj:wkt2".into(), json!(dem.crs.wkt));
    }
    props.insert("proj:shape".into(), json!([dem.height, dem.width]));
    // STAC's order is the affine's rows: [a, b, c, d, e, f].
    props.insert(
        "proj:transform".into(),
        json!([g[1], g[2], g[0], g[4], g[5], g[3]]),
    );
    let b = dem.geotransform.bounds(dem.width, dem.height);
    props.insert("proj:bbox".into(), json!(b));
}

/// `processing:*` fields: software, time, lineage, the edit.
fn processing_fields(
    dem: &Dem,
    opts: &StacOptions,
    history: &[Value],
    now: &str,
    props: &mut Map<String, Value>,
) {
    props.insert(
        "processing:software".into(),
        json!({"demsketch": env!("CARGO_PKG_VERSION")}),
    );
    let latest = history.last();
    props.insert(
        "processing:datetime".into(),
        json!(latest.and_then(|h| h["time"].as_str()).unwrap_or(now)),
    );
    let lineage = match (&opts.report, latest) {
        (Some((_, r)), _) => format!(
            "demsketch edit of {} with the sketch {}: {} cells changed, largest change {:.2} m",
            r.dem, r.sketch, r.changed_cells, r.max_abs_displacement_m
        ),
        (None, Some(h)) => format!(
            "demsketch edit of {} ({} edit(s) in the file's history)",
            h["input"].as_str().unwrap_or("a DEM"),
            history.len()
        ),
        (None, None) => format!("{} described by demsketch export stac", dem.path.display()),
    };
    props.insert("processing:lineage".into(), json!(lineage));
    if let Some(h) = latest {
        props.insert(
            "processing:expression".into(),
            json!({"format": "demsketch-edit", "expression": h}),
        );
    }
}

/// What the report says of the edit.
fn edit_summary(r: &EditReportSummary) -> Value {
    let strokes: Vec<Value> = r
        .strokes
        .iter()
        .map(|s| {
            json!({
                "view": s.view, "stroke": s.id, "match_kind": s.match_kind,
                "status": s.status, "fitted_fraction": s.fitted_fraction,
            })
        })
        .collect();
    json!({
        "dem": r.dem, "sketch": r.sketch, "output": r.output, "written": r.written,
        "changed_cells": r.changed_cells,
        "max_abs_displacement_m": r.max_abs_displacement_m,
        "deformation_window": r.window,
        "strokes": strokes,
    })
}

/// The DEM asset with its `raster:bands`.
fn dem_asset(dem: &Dem, item_path: &Path, opts: &StacOptions) -> Result<Value, ExportError> {
    let is_cog = is_cog(&dem.path);
    let media = if dem.kind == crate::raster::LayerKind::TileDirectory {
        "application/octet-stream"
    } else if is_cog {
        "image/tiff; application=geotiff; profile=cloud-optimized"
    } else {
        "image/tiff; application=geotiff"
    };
    let mut band = Map::new();
    band.insert("data_type".into(), json!(data_type(dem.sample_type)));
    if let Some(nd) = dem.nodata {
        band.insert(
            "nodata".into(),
            if nd.is_nan() { json!("nan") } else { json!(nd) },
        );
    }
    band.insert("unit".into(), json!("m"));
    let v = &dem.vertical;
    if v.scale != 1.0 || v.offset != 0.0 || v.unit_to_metre != 1.0 {
        band.insert("scale".into(), json!(v.scale * v.unit_to_metre));
        band.insert("offset".into(), json!(v.offset * v.unit_to_metre));
    }
    band.insert("sampling".into(), json!("area"));
    band.insert("spatial_resolution".into(), json!(resolution_m(dem)));
    if let Some((lo, hi)) = dem.min_max()? {
        band.insert("statistics".into(), json!({"minimum": lo, "maximum": hi}));
    }
    let href = opts
        .asset_href
        .clone()
        .unwrap_or_else(|| relative_href(&dem.path, item_path));
    Ok(json!({
        "href": href,
        "type": media,
        "title": "elevation",
        "roles": ["data"],
        "raster:bands": [band],
    }))
}

/// STAC's name of a sample type.
fn data_type(t: SampleType) -> &'static str {
    match t {
        SampleType::Int8 => "int8",
        SampleType::UInt8 => "uint8",
        SampleType::Int16 => "int16",
        SampleType::UInt16 => "uint16",
        SampleType::Int32 => "int32",
        SampleType::UInt32 => "uint32",
        SampleType::Float32 => "float32",
        SampleType::Float64 => "float64",
    }
}

/// Cell size in metres (mean of the two axes; degrees at the DEM's
/// centre latitude for a geographic CRS).
fn resolution_m(dem: &Dem) -> f64 {
    let (gx, gy) = dem.geotransform.pixel_size();
    if dem.crs.geographic {
        let (_, lat) = dem
            .geotransform
            .pixel_to_crs(dem.width as f64 / 2.0, dem.height as f64 / 2.0);
        let m = 111_320.0;
        (gx.abs() * m * lat.to_radians().cos() + gy.abs() * m) / 2.0
    } else {
        (gx.abs() + gy.abs()) / 2.0
    }
}

/// Whether GDAL sees a COG layout.
fn is_cog(path: &Path) -> bool {
    use gdal::Metadata;
    gdal::Dataset::open(path)
        .ok()
        .and_then(|d| d.metadata_item("LAYOUT", "IMAGE_STRUCTURE"))
        .as_deref()
        == Some("COG")
}

/// The provenance history of the DEM's files, oldest first, each entry's
/// `key=value; ...` as an object (entries shared by tiles once).
pub fn provenance_history(dem: &Dem) -> Vec<Value> {
    use gdal::Metadata;
    let prefix = format!("{}_", crate::raster::PROVENANCE_KEY);
    let mut entries: Vec<(usize, String)> = Vec::new();
    for t in &dem.tiles {
        let Ok(ds) = gdal::Dataset::open(&t.path) else {
            continue;
        };
        for item in ds.metadata_domain("").unwrap_or_default() {
            let Some((k, v)) = item.split_once('=') else {
                continue;
            };
            if let Some(n) = k
                .strip_prefix(&prefix)
                .and_then(|n| n.parse::<usize>().ok())
            {
                if !entries.iter().any(|(_, e)| e == v) {
                    entries.push((n, v.to_string()));
                }
            }
        }
    }
    entries.sort();
    entries
        .into_iter()
        .map(|(_, e)| {
            let mut m = Map::new();
            for part in e.split("; ") {
                if let Some((k, v)) = part.split_once('=') {
                    let v = v.trim();
                    let val = if k == "changed_cells" {
                        v.parse::<u64>()
                            .map(Value::from)
                            .unwrap_or_else(|_| json!(v))
                    } else {
                        json!(v)
                    };
                    m.insert(k.trim().to_string(), val);
                }
            }
            Value::Object(m)
        })
        .collect()
}

/// `target` relative to the directory of `item` when both are plain
/// paths under a common directory, else `target` as given.
fn relative_href(target: &Path, item: &Path) -> String {
    let abs = |p: &Path| std::fs::canonicalize(p).ok();
    let item_dir = item
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if let (Some(t), Some(d)) = (abs(target), abs(item_dir)) {
        if let Ok(rel) = t.strip_prefix(&d) {
            return format!("./{}", rel.display());
        }
        return t.display().to_string();
    }
    target.display().to_string()
}
