//! `export geojson`: what an edit did, as a GeoJSON FeatureCollection in
//! WGS84 longitude/latitude (RFC 7946) that QGIS or a web map overlays on
//! the DEM: one `LineString` with Z heights per stroke, the 3D curve the
//! stroke was placed at (from the report's `placed_curve`, in the DEM's
//! CRS, reprojected through PROJ; heights are absolute, metres, in the
//! DEM's vertical datum), with the stroke's view, id, match and fit as
//! properties; and one `MultiPolygon`, the change footprint
//! ([`super::change_footprint`]) of a dz raster or, without one, of the
//! report's deformation window.

use std::path::Path;

use serde_json::{json, Value};

use super::change_footprint::footprint_lonlat;
use super::change_mask::ChangeMask;
use super::edit_report::EditReportSummary;
use super::ExportError;
use crate::raster::Crs;

/// The feature collection of an edit: placed curves (in `crs`, the DEM's)
/// and the footprint of `mask`.
pub fn edit_features(
    report: &EditReportSummary,
    report_path: &Path,
    crs: &Crs,
    mask: Option<&ChangeMask>,
) -> Result<Value, ExportError> {
    let mut features = Vec::new();
    let has_curves = report.strokes.iter().any(|s| s.placed_curve.len() >= 2);
    if has_curves {
        let to_ll =
            proj::Proj::new_known_crs(&crs.proj_definition(), "EPSG:4326", None).map_err(|e| {
                ExportError::Input {
                    path: report_path.display().to_string(),
                    message: format!("the DEM's CRS is unknown to PROJ: {e}"),
                }
            })?;
        for s in &report.strokes {
            let coords: Vec<Value> = s
                .placed_curve
                .iter()
                .filter_map(|p| {
                    let (lon, lat) = to_ll.convert((p[0], p[1])).ok()?;
                    Some(json!([round(lon, 8), round(lat, 8), round(p[2], 3)]))
                })
                .collect();
            if coords.len() < 2 {
                continue;
            }
            features.push(json!({
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": coords},
                "properties": {
                    "kind": "placed_curve",
                    "view": s.view,
                    "stroke": s.id,
                    "source_stroke": s.source_id,
                    "match_kind": s.match_kind,
                    "status": s.status,
                    "fitted_fraction": s.fitted_fraction,
                    "depth_m": s.depth_m,
                },
            }));
        }
    }
    if let Some(mask) = mask {
        if let Some(geometry) = footprint_lonlat(mask)? {
            features.push(json!({
                "type": "Feature",
                "geometry": geometry,
                "properties": {
                    "kind": "change_footprint",
                    "source": mask.source,
                    "changed_cells": mask.count(),
                    "max_abs_dz_m": mask.max_abs_dz_m,
                },
            }));
        }
    }
    Ok(json!({
        "type": "FeatureCollection",
        "name": format!("demsketch edit of {}", report.dem),
        "properties": {
            "dem": report.dem,
            "sketch": report.sketch,
            "output": report.output,
            "written": report.written,
            "changed_cells": report.changed_cells,
            "max_abs_displacement_m": report.max_abs_displacement_m,
            "placed_curves_in_report": has_curves,
        },
        "features": features,
    }))
}

/// `v` rounded to `digits` decimals (GeoJSON files stay readable).
fn round(v: f64, digits: i32) -> f64 {
    let f = 10f64.powi(digits);
    (v * f).round() / f
}
