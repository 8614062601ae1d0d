//! GeoJSON export of terrain features, for `demsketch view --features` and for
//! looking at features in a GIS: every silhouette and ridge line becomes a
//! `LineString` feature with `[lon, lat, z]` positions (WGS84 degrees, z the
//! true terrain height in the DEM's vertical datum), and properties `kind`
//! (`"silhouette"` or `"ridge"`), `id` and `length` (metres along the 3D
//! curve). Every feature's `id` (the Feature's RFC 7946 `id` member and the
//! `id` and `feature_id` properties) is unique in the collection and is the
//! `feature_id` an edit's report gives the same feature
//! ([`crate::sketch::FeatureSource`]: ridges by ridge line, silhouettes by
//! view index and curve); T-junctions get ids above both. Silhouettes also carry their image polyline (`pixels`), whether they
//! are part of the skyline, and their depth range; T-junctions become `Point`
//! features of kind `"t_junction"` naming the occluded and occluding
//! silhouette.
//!
//! The CRS-to-WGS84 mapping is passed in as a closure, so that the caller can
//! use the view module's PROJ transformation ([`crate::view::Georef`]) or any
//! other; [`to_lonlat_with_georef`] wraps the former.

use std::path::Path;

use serde_json::{json, Map, Value};

use super::{FeatureError, RidgeNetwork, Silhouettes};
use crate::view::Georef;

/// Maps a CRS point `(x, y)` to WGS84 `(lon, lat)` in degrees.
pub type ToLonLat<'a> = dyn Fn(f64, f64) -> Result<(f64, f64), String> + 'a;

/// A [`ToLonLat`] closure using the view module's PROJ transformation.
pub fn to_lonlat_with_georef(
    georef: &Georef,
) -> impl Fn(f64, f64) -> Result<(f64, f64), String> + '_ {
    move |x, y| georef.crs_to_lonlat(x, y).map_err(|e| e.to_string())
}

fn round(v: f64, digits: i32) -> f64 {
    let s = 10f64.powi(digits);
    (v * s).round() / s
}

fn position(to_lonlat: &ToLonLat, p: [f64; 3]) -> Result<Value, FeatureError> {
    let (lon, lat) = to_lonlat(p[0], p[1]).map_err(FeatureError::Projection)?;
    if !(lon.is_finite() && lat.is_finite()) {
        return Err(FeatureError::Projection(format!(
            "no lon/lat for CRS point ({}, {})",
            p[0], p[1]
        )));
    }
    Ok(json!([round(lon, 8), round(lat, 8), round(p[2], 3)]))
}

/// The id of T-junction `index` of view `view`: above every silhouette id
/// (and below 2^53, so that JSON readers keep it exact).
fn junction_id(view: usize, index: usize) -> usize {
    JUNCTION_ID_BASE + (view << 32) + index
}

/// T-junction ids start here (silhouettes from
/// [`crate::sketch::SILHOUETTE_ID_BASE`], ridges below it).
pub const JUNCTION_ID_BASE: usize = 1 << 52;

/// A Feature whose `id` (RFC 7946's member, which OGR takes as the FID) and
/// `id` / `feature_id` properties are `id`.
fn feature(geometry: Value, mut properties: Map<String, Value>, id: usize) -> Value {
    properties.insert("id".into(), json!(id));
    properties.insert("feature_id".into(), json!(id));
    json!({"type": "Feature", "id": id, "geometry": geometry, "properties": properties})
}

/// GeoJSON features of the silhouettes of one view (`view` names the view in
/// the properties when given), ids as an edit's report gives them for view
/// 0 ([`silhouette_features_of_view`]).
pub fn silhouette_features(
    sil: &Silhouettes,
    view: Option<&str>,
    to_lonlat: &ToLonLat,
) -> Result<Vec<Value>, FeatureError> {
    silhouette_features_of_view(sil, view, 0, to_lonlat)
}

/// GeoJSON features of the silhouettes of view `view_index` of a sketch:
/// each silhouette's id is the report's `feature_id` for it
/// ([`crate::sketch::FeatureSource`]), junctions get ids of their own.
pub fn silhouette_features_of_view(
    sil: &Silhouettes,
    view: Option<&str>,
    view_index: usize,
    to_lonlat: &ToLonLat,
) -> Result<Vec<Value>, FeatureError> {
    let mut out = Vec::with_capacity(sil.curves.len() + sil.junctions.len());
    for c in &sil.curves {
        let coords = c
            .samples
            .iter()
            .map(|s| position(to_lonlat, s.world))
            .collect::<Result<Vec<_>, _>>()?;
        let pixels: Vec<Value> = c
            .samples
            .iter()
            .map(|s| json!([round(s.pixel[0], 3), round(s.pixel[1], 3)]))
            .collect();
        let (dmin, dmax) = c.samples.iter().fold((f64::INFINITY, 0f64), |(a, b), s| {
            (a.min(s.depth), b.max(s.depth))
        });
        let mut props = Map::new();
        props.insert("kind".into(), json!("silhouette"));
        props.insert("curve".into(), json!(c.id));
        props.insert("length".into(), json!(round(c.local_length_m(), 2)));
        props.insert("length_px".into(), json!(round(c.pixel_length(), 2)));
        props.insert("skyline".into(), json!(c.skyline));
        props.insert("depth_min".into(), json!(round(dmin, 2)));
        props.insert("depth_max".into(), json!(round(dmax, 2)));
        props.insert("pixels".into(), Value::Array(pixels));
        if let Some(v) = view {
            props.insert("view".into(), json!(v));
        }
        let id = crate::sketch::FeatureSource::Silhouette {
            view: view_index,
            curve: c.id,
        }
        .id();
        out.push(feature(
            json!({"type": "LineString", "coordinates": coords}),
            props,
            id,
        ));
    }
    for (k, j) in sil.junctions.iter().enumerate() {
        // The junction's terrain point: the occluded silhouette's end sample.
        let Some(c) = sil.curves.get(j.occluded as usize) else {
            continue;
        };
        let s = match j.end {
            super::CurveEnd::Start => c.samples.first(),
            super::CurveEnd::End => c.samples.last(),
        };
        let Some(s) = s else { continue };
        let mut props = Map::new();
        props.insert("kind".into(), json!("t_junction"));
        let sid = |i: u32| {
            sil.curves.get(i as usize).map(|c| {
                crate::sketch::FeatureSource::Silhouette {
                    view: view_index,
                    curve: c.id,
                }
                .id()
            })
        };
        props.insert("occluded".into(), json!(sid(j.occluded)));
        props.insert("occluder".into(), json!(sid(j.occluder)));
        props.insert(
            "pixel".into(),
            json!([round(j.pixel[0], 3), round(j.pixel[1], 3)]),
        );
        if let Some(v) = view {
            props.insert("view".into(), json!(v));
        }
        out.push(feature(
            json!({"type": "Point", "coordinates": position(to_lonlat, s.world)?}),
            props,
            junction_id(view_index, k),
        ));
    }
    Ok(out)
}

/// GeoJSON features of a ridge network.
pub fn ridge_features(
    net: &RidgeNetwork,
    to_lonlat: &ToLonLat,
) -> Result<Vec<Value>, FeatureError> {
    net.lines
        .iter()
        .map(|l| {
            let coords = net
                .line_points(l)
                .iter()
                .map(|&p| position(to_lonlat, p))
                .collect::<Result<Vec<_>, _>>()?;
            let mut props = Map::new();
            props.insert("kind".into(), json!("ridge"));
            props.insert("length".into(), json!(round(l.length_m, 2)));
            props.insert("nodes".into(), json!(l.nodes));
            let id = crate::sketch::FeatureSource::Ridge { line: l.id }.id();
            Ok(feature(
                json!({"type": "LineString", "coordinates": coords}),
                props,
                id,
            ))
        })
        .collect()
}

/// A `FeatureCollection` of the given silhouettes and ridges (view 0).
pub fn feature_collection(
    silhouettes: Option<&Silhouettes>,
    ridges: Option<&RidgeNetwork>,
    to_lonlat: &ToLonLat,
) -> Result<Value, FeatureError> {
    feature_collection_of_view(silhouettes, ridges, 0, to_lonlat)
}

/// A `FeatureCollection` of the silhouettes of view `view_index` of a
/// sketch and the ridges, every feature with a unique id equal to the edit
/// report's `feature_id`.
pub fn feature_collection_of_view(
    silhouettes: Option<&Silhouettes>,
    ridges: Option<&RidgeNetwork>,
    view_index: usize,
    to_lonlat: &ToLonLat,
) -> Result<Value, FeatureError> {
    let mut features = Vec::new();
    if let Some(s) = silhouettes {
        features.extend(silhouette_features_of_view(s, None, view_index, to_lonlat)?);
    }
    if let Some(r) = ridges {
        features.extend(ridge_features(r, to_lonlat)?);
    }
    Ok(json!({"type": "FeatureCollection", "features": features}))
}

/// Write `value` to `path` atomically and verified
/// ([`crate::raster::atomic_file::replace_file`]: a staging directory
/// beside it, the file read back and parsed equal to `value`, then renamed).
pub fn write_geojson(path: &Path, value: &Value) -> Result<(), FeatureError> {
    let text = serde_json::to_vec(value).map_err(|e| FeatureError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    crate::raster::atomic_file::replace_file(
        path,
        |tmp| {
            crate::raster::atomic_file::write_bytes_verified(tmp, &text).map_err(|e| e.to_string())
        },
        |tmp| {
            let back: Value =
                serde_json::from_slice(&std::fs::read(tmp).map_err(|e| e.to_string())?)
                    .map_err(|e| e.to_string())?;
            if &back == value {
                Ok(())
            } else {
                Err("it differs from what was written".into())
            }
        },
    )
    .map_err(|message| FeatureError::Write {
        path: path.to_path_buf(),
        message,
    })
}
