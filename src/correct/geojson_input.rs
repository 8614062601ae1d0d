//! Reading corrections from GeoJSON as QGIS writes it: a `FeatureCollection`
//! whose coordinates are WGS84 lon/lat (the RFC 7946 default) or, when the
//! file carries the legacy `crs` member (`{"type": "name", "properties":
//! {"name": "urn:ogc:def:crs:EPSG::32632"}}`), that CRS. Every feature is
//! turned into a [`Correction`] in the DEM's pixel space (and, for control
//! curves, its CRS), and validated: a one-line error names the feature by
//! its index and its `id` or `name`, and nothing is corrected when any
//! feature is bad.
//!
//! The feature's `kind` property says what it is:
//! - `lake`: Polygon or MultiPolygon (holes are islands); optional
//!   `level_m` (else the lowest shoreline height) and `blend_m`.
//! - `river`: LineString centreline with `width_m`; optional `blend_m` and
//!   `downstream` (`"end"` or `true`: the line runs downstream, its last
//!   vertex is the outlet; `"start"` or `false`: its first vertex is the
//!   outlet); without it the end with the lower DEM height is the outlet
//!   (DESIGN.md's corrections table). The older `flow` (`"line"`: as
//!   `downstream: "end"`; `"auto"`: by the heights) is still read, not
//!   with `downstream`. Or a Polygon reach (flow along its principal axis,
//!   from the higher end).
//! - `control_curve`: LineString with heights as Z coordinates or a
//!   `heights_m` array (one per vertex); optional `influence_m` and
//!   `slope_deg`, the cross slope at the curve when no cross-section is
//!   given: one number, the surface falling to the right of the line at
//!   that angle (negative: to the left), as a road's crossfall; or
//!   `[left, right]`, the fall away from the curve on each side (the
//!   paper's left and right slopes: `[10, 10]` a ridge, `[-10, -10]` a
//!   channel); see [`slope_sections`].
//! - `cross_section`: LineString with heights (as a control curve) and a
//!   `control_curve` property naming the `id` or `name` of the control
//!   curve it belongs to; it must cross that curve (in map view). Its
//!   heights are taken relative to its own height where it crosses: the
//!   section is moved vertically to meet the control curve there (as the
//!   paper translates its cross-section curves along the control curve).
//!   It is attached to the curve, not a correction of its own.
//! - `breakline`: LineString with heights as Z coordinates, a `heights_m`
//!   array (one per vertex) or one `height_m` for every vertex; at least two
//!   distinct positions, not crossing or touching itself; optional `hard`
//!   (`true`, the default: the surface may kink across the line but not
//!   blend; `false`: a soft breakline, smooth across) and `influence_m`
//!   (default three cells).
//! - `landform`: a silhouette stroke of a sketch view, `silhouette:
//!   {"view": NAME, "stroke": ID}`, with its boundary as the feature's
//!   Polygon (a `null` geometry: the default capsule) and an optional
//!   `shadow` (a LineString geometry object or its coordinates, in the
//!   file's CRS); see [`super::landform`].
//! - `noise_region`: a Polygon and `noise_stroke` (as `silhouette`), with
//!   an optional `amplitude_m`.
//!
//! Every kind also takes `id`, `name`, `kind` and QGIS's integer `fid`;
//! any other property is an error naming it (a misspelt `levle_m` is
//! refused, not ignored).

use std::path::Path;
use std::str::FromStr;

use geo::{Coord, LineString, MultiPolygon, Polygon, Validation};
use geojson::{GeoJson, GeometryValue, JsonObject, Position};

use crate::raster::Dem;
use crate::view::Georef;

/// One validated correction, in the DEM's pixel space (`(px, py)`, cell
/// centres at `+0.5`).
#[derive(Debug, Clone)]
pub struct Correction {
    /// Index of the feature in the collection.
    pub index: usize,
    /// The feature's `id` (or `name` property), if any.
    pub id: Option<String>,
    pub kind: CorrectionKind,
}

impl Correction {
    /// `feature 3 ("north_lake")`, for messages.
    pub fn label(&self) -> String {
        label(self.index, self.id.as_deref())
    }
}

fn label(index: usize, id: Option<&str>) -> String {
    match id {
        Some(id) => format!("feature {index} (\"{id}\")"),
        None => format!("feature {index}"),
    }
}

/// What a correction does.
#[derive(Debug, Clone)]
pub enum CorrectionKind {
    /// A lake flattened to one level, islands as holes.
    Lake {
        /// The water area, pixel space.
        area: MultiPolygon<f64>,
        level_m: Option<f64>,
        blend_m: Option<f64>,
    },
    /// A river, flat across and non-increasing downstream.
    River {
        /// Centreline, pixel space, in the file's vertex order.
        centreline: Vec<[f64; 2]>,
        width_m: f64,
        blend_m: Option<f64>,
        /// Which way it flows (`downstream`, `flow`, else the heights).
        flow: super::river::Flow,
    },
    /// A river reach given as a polygon: flow along its principal axis
    /// (see [`super::river::apply_polygon`]).
    RiverArea {
        /// The water area, pixel space.
        area: MultiPolygon<f64>,
        blend_m: Option<f64>,
    },
    /// A 3D breakline: hard (the surface may kink across it, never blend)
    /// or soft (passes through it, smooth across); see [`super::breakline`].
    Breakline {
        /// `[x, y, z]` in the DEM's CRS and metres, at least two distinct
        /// positions, not crossing itself.
        points: Vec<[f64; 3]>,
        hard: bool,
        influence_m: Option<f64>,
    },
    /// A landform from a silhouette stroke (Gain et al. 2009), see
    /// [`super::landform`]; placed by [`super::landform::resolve`].
    Landform {
        silhouette: super::landform::StrokeRef,
        /// The boundary, pixel space (`None`: the default capsule).
        boundary: Option<MultiPolygon<f64>>,
        /// The shadow, DEM CRS (`None`: the default).
        shadow: Option<Vec<[f64; 2]>>,
        placed: Option<super::landform::Placed>,
    },
    /// A region given the noise of a representative stroke.
    NoiseRegion {
        /// The region, pixel space.
        area: MultiPolygon<f64>,
        stroke: super::landform::StrokeRef,
        amplitude_m: Option<f64>,
        placed: Option<super::landform::Placed>,
    },
    /// A curve the DEM must pass through.
    ControlCurve {
        /// `[x, y, z]` in the DEM's CRS and metres.
        points: Vec<[f64; 3]>,
        influence_m: Option<f64>,
        /// Cross-sections attached to the curve, `[x, y, z]` in the DEM's
        /// CRS, already moved to meet the curve's height where they cross
        /// (or made from `slope_deg`, see [`slope_sections`]).
        sections: Vec<Vec<[f64; 3]>>,
        /// `slope_deg`: the surface's fall away from the curve, degrees, on
        /// its left and right (looking along the line); one number `s` is
        /// the tilt `[-s, s]` (falling to the right).
        slope_deg: Option<[f64; 2]>,
    },
}

impl CorrectionKind {
    /// The `kind` property's value.
    pub fn name(&self) -> &'static str {
        match self {
            CorrectionKind::Lake { .. } => "lake",
            CorrectionKind::River { .. } | CorrectionKind::RiverArea { .. } => "river",
            CorrectionKind::ControlCurve { .. } => "control_curve",
            CorrectionKind::Breakline { .. } => "breakline",
            CorrectionKind::Landform { .. } => "landform",
            CorrectionKind::NoiseRegion { .. } => "noise_region",
        }
    }
}

/// How the file's coordinates map to the DEM's CRS.
enum Transform {
    Identity,
    Proj(proj::Proj),
    LonLat(Georef),
}

impl Transform {
    fn apply(&self, x: f64, y: f64) -> Result<(f64, f64), String> {
        match self {
            Transform::Identity => Ok((x, y)),
            // RFC 7946 positions: longitude, latitude in degrees.
            Transform::LonLat(_) if !(x.abs() <= 180.0 && y.abs() <= 90.0) => Err(format!(
                "position ({x}, {y}) is not a longitude in [-180, 180] and a latitude in [-90, 90]"
            )),
            Transform::LonLat(g) => g.lonlat_to_crs(x, y).map_err(|e| e.to_string()),
            Transform::Proj(p) => {
                let r = p
                    .convert((x, y))
                    .map_err(|e| format!("no position in the DEM's CRS for ({x}, {y}): {e}"))?;
                if r.0.is_finite() && r.1.is_finite() {
                    Ok(r)
                } else {
                    Err(format!("no position in the DEM's CRS for ({x}, {y})"))
                }
            }
        }
    }
}

/// Reads and validates every feature of `path` against `dem`. The error is
/// one line naming the file and, where it is about one feature, the feature.
pub fn read(path: &Path, dem: &Dem) -> Result<Vec<Correction>, String> {
    let p = path.display();
    let text = std::fs::read_to_string(path).map_err(|e| format!("{p}: cannot read: {e}"))?;
    parse(&text, &p.to_string(), dem)
}

/// The corrections of a FeatureCollection held in a sketch file's
/// `corrections` member; messages name `name` (the sketch file and the
/// member) and the feature.
pub fn from_value(v: &serde_json::Value, name: &str, dem: &Dem) -> Result<Vec<Correction>, String> {
    parse(&v.to_string(), name, dem)
}

/// The corrections of the GeoJSON `text`; messages name `p`.
fn parse(text: &str, p: &str, dem: &Dem) -> Result<Vec<Correction>, String> {
    let gj = GeoJson::from_str(text).map_err(|e| {
        format!(
            "{p}: not GeoJSON: {}",
            e.to_string().lines().next().unwrap_or("")
        )
    })?;
    let fc = match gj {
        GeoJson::FeatureCollection(fc) => fc,
        _ => return Err(format!("{p}: expected a GeoJSON FeatureCollection")),
    };
    let transform =
        transform_for(fc.foreign_members.as_ref(), dem).map_err(|m| format!("{p}: {m}"))?;
    if fc.features.is_empty() {
        return Err(format!("{p}: the FeatureCollection has no features"));
    }
    let parsed = fc
        .features
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let props = f.properties.clone().unwrap_or_default();
            let id = feature_id(f, &props);
            parse_feature(i, id.clone(), f.geometry.as_ref(), &props, &transform, dem)
                .map_err(|m| format!("{p}: {}: {m}", label(i, id.as_deref())))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut out = attach_sections(parsed).map_err(|m| format!("{p}: {m}"))?;
    for c in &mut out {
        let label = c.label();
        if let CorrectionKind::ControlCurve {
            points,
            sections,
            slope_deg: Some(slope),
            ..
        } = &mut c.kind
        {
            if !sections.is_empty() {
                return Err(format!(
                    "{p}: {}: slope_deg gives the cross slope when no cross-section is given; this curve has {} (give one or the other)",
                    label,
                    sections.len()
                ));
            }
            *sections = slope_sections(dem, points, *slope);
        }
    }
    Ok(out)
}

/// How far each side of a control curve the cross slope of `slope_deg` is
/// imposed, in cells: the slope is that of the surface *at* the curve;
/// beyond, the field of influence blends it into the terrain.
pub const SLOPE_SECTION_CELLS: f64 = 2.0;

/// Cross-sections from a control curve's `slope_deg` (`[left, right]`,
/// degrees; positive: the surface falls away from the curve on that side),
/// as the paper translates a cross-section curve along the control curve:
/// one every [`SLOPE_SECTION_CELLS`] cells of arc length (and at every
/// vertex), perpendicular to the curve there, reaching
/// [`SLOPE_SECTION_CELLS`] cells to each side, its heights the curve's
/// minus `tan(slope) * distance`.
pub fn slope_sections(dem: &Dem, points: &[[f64; 3]], slope: [f64; 2]) -> Vec<Vec<[f64; 3]>> {
    let gt = dem.geotransform.0;
    let centre = dem
        .geotransform
        .pixel_to_crs(dem.width as f64 / 2.0, dem.height as f64 / 2.0);
    let lat = if dem.crs.geographic { centre.1 } else { 0.0 };
    let cell = crate::deform::locality::cell_size_m(
        &dem.geotransform,
        dem.crs.geographic,
        lat.clamp(-89.9, 89.9),
    );
    // Metres per CRS unit along x and y.
    let m = [
        cell.hx / gt[1].abs().max(1e-300),
        cell.hy / gt[5].abs().max(1e-300),
    ];
    let reach = SLOPE_SECTION_CELLS * cell.hx.max(cell.hy);
    let step = reach;
    let (tl, tr) = (slope[0].to_radians().tan(), slope[1].to_radians().tan());
    let mut out = Vec::new();
    for (k, w) in points.windows(2).enumerate() {
        let (a, b) = (w[0], w[1]);
        let (dx, dy) = ((b[0] - a[0]) * m[0], (b[1] - a[1]) * m[1]);
        let len = dx.hypot(dy);
        if len <= 0.0 {
            continue;
        }
        // Unit tangent (metres) and its left normal.
        let (ux, uy) = (dx / len, dy / len);
        let (lx, ly) = (-uy, ux);
        let n = (len / step).ceil().max(1.0) as usize;
        let last = k + 2 == points.len();
        for j in 0..n + usize::from(last) {
            let t = j as f64 / n as f64;
            let c = [
                a[0] + t * (b[0] - a[0]),
                a[1] + t * (b[1] - a[1]),
                a[2] + t * (b[2] - a[2]),
            ];
            let at = |d: f64| {
                // d > 0: left of the line, d < 0: right.
                let fall = if d >= 0.0 { tl * d } else { tr * -d };
                [c[0] + lx * d / m[0], c[1] + ly * d / m[1], c[2] - fall]
            };
            out.push(vec![
                at(reach),
                at(0.5 * reach),
                c,
                at(-0.5 * reach),
                at(-reach),
            ]);
        }
    }
    out
}

/// A parsed feature: a correction, or a cross-section to attach to one.
enum Parsed {
    /// (boxed: a correction is several times a cross-section's size)
    Correction(Box<Correction>),
    Section {
        index: usize,
        id: Option<String>,
        /// The `id` or `name` of its control curve.
        curve: String,
        /// `[x, y, z]`, DEM's CRS.
        points: Vec<[f64; 3]>,
    },
}

/// Attaches every cross-section to the control curve it names, moved
/// vertically to meet the curve where they cross. The error names the
/// cross-section.
fn attach_sections(parsed: Vec<Parsed>) -> Result<Vec<Correction>, String> {
    let mut out = Vec::new();
    let mut sections = Vec::new();
    for p in parsed {
        match p {
            Parsed::Correction(c) => out.push(*c),
            Parsed::Section {
                index,
                id,
                curve,
                points,
            } => sections.push((index, id, curve, points)),
        }
    }
    if out.is_empty() {
        return Err("no features other than cross-sections".into());
    }
    for (index, id, curve, points) in sections {
        let name = label(index, id.as_deref());
        let target = out
            .iter_mut()
            .find(|c| c.id.as_deref() == Some(curve.as_str()))
            .ok_or_else(|| {
                format!("{name}: no feature \"{curve}\" to attach the cross-section to")
            })?;
        let CorrectionKind::ControlCurve {
            points: cp,
            sections,
            ..
        } = &mut target.kind
        else {
            return Err(format!(
                "{name}: feature \"{curve}\" is a {}, not a control curve",
                target.kind.name()
            ));
        };
        let (zc, zs) = crossing(cp, &points).ok_or_else(|| {
            format!("{name}: the cross-section does not cross its control curve \"{curve}\"")
        })?;
        let dz = zc - zs;
        sections.push(points.iter().map(|q| [q[0], q[1], q[2] + dz]).collect());
    }
    Ok(out)
}

/// Where the polylines `a` and `b` first cross in map view: the height of
/// each there (linear along its segment).
pub fn crossing(a: &[[f64; 3]], b: &[[f64; 3]]) -> Option<(f64, f64)> {
    for sa in a.windows(2) {
        for sb in b.windows(2) {
            let (p, r) = (sa[0], [sa[1][0] - sa[0][0], sa[1][1] - sa[0][1]]);
            let (q, w) = (sb[0], [sb[1][0] - sb[0][0], sb[1][1] - sb[0][1]]);
            let den = r[0] * w[1] - r[1] * w[0];
            if den == 0.0 {
                continue;
            }
            let (dx, dy) = (q[0] - p[0], q[1] - p[1]);
            let t = (dx * w[1] - dy * w[0]) / den;
            let u = (dx * r[1] - dy * r[0]) / den;
            if (0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u) {
                let za = sa[0][2] + t * (sa[1][2] - sa[0][2]);
                let zb = sb[0][2] + u * (sb[1][2] - sb[0][2]);
                return Some((za, zb));
            }
        }
    }
    None
}

/// The feature's `id` member, else its `id` or `name` property.
fn feature_id(f: &geojson::Feature, props: &JsonObject) -> Option<String> {
    if let Some(id) = &f.id {
        return Some(match id {
            geojson::feature::Id::String(s) => s.clone(),
            geojson::feature::Id::Number(n) => n.to_string(),
        });
    }
    ["id", "name"].iter().find_map(|k| match props.get(*k) {
        Some(serde_json::Value::String(s)) => Some(s.clone()),
        Some(serde_json::Value::Number(n)) => Some(n.to_string()),
        _ => None,
    })
}

/// The EPSG code named by a legacy `crs` member, `None` for lon/lat.
fn legacy_epsg(members: Option<&JsonObject>) -> Result<Option<u32>, String> {
    let Some(crs) = members.and_then(|m| m.get("crs")) else {
        return Ok(None);
    };
    let name = crs
        .get("properties")
        .and_then(|p| p.get("name"))
        .and_then(|n| n.as_str())
        .ok_or("the \"crs\" member has no properties.name")?;
    if name.contains("CRS84") {
        return Ok(None);
    }
    let up = name.to_ascii_uppercase();
    let digits: String = up
        .rsplit(|c: char| !c.is_ascii_digit())
        .next()
        .unwrap_or("")
        .to_string();
    match (up.contains("EPSG"), digits.parse::<u32>()) {
        (true, Ok(4326)) => Ok(None),
        (true, Ok(code)) => Ok(Some(code)),
        _ => Err(format!(
            "the \"crs\" member names \"{name}\"; only EPSG codes and CRS84 are understood"
        )),
    }
}

fn transform_for(members: Option<&JsonObject>, dem: &Dem) -> Result<Transform, String> {
    let name = dem.path.display().to_string();
    match legacy_epsg(members)? {
        Some(code) if dem.crs.epsg == Some(code) => Ok(Transform::Identity),
        Some(code) => {
            let def = dem.crs.proj_definition();
            proj::Proj::new_known_crs(&format!("EPSG:{code}"), &def, None)
                .map(Transform::Proj)
                .map_err(|e| format!("no transformation from EPSG:{code} to the DEM's CRS: {e}"))
        }
        None if dem.crs.epsg == Some(4326) => Ok(Transform::Identity),
        None => Georef::for_crs(&dem.crs, &name)
            .map(Transform::LonLat)
            .map_err(|e| e.to_string()),
    }
}

fn number(props: &JsonObject, key: &str) -> Result<Option<f64>, String> {
    match props.get(key) {
        None | Some(serde_json::Value::Null) => Ok(None),
        Some(v) => match v.as_f64() {
            Some(x) if x.is_finite() => Ok(Some(x)),
            _ => Err(format!("property {key} must be a number, not {v}")),
        },
    }
}

fn positive(props: &JsonObject, key: &str) -> Result<Option<f64>, String> {
    match number(props, key)? {
        Some(x) if x <= 0.0 => Err(format!("property {key} must be positive, not {x}")),
        v => Ok(v),
    }
}

fn parse_feature(
    index: usize,
    id: Option<String>,
    geometry: Option<&geojson::Geometry>,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<Parsed, String> {
    let kind = match props.get("kind") {
        Some(serde_json::Value::String(s)) => s.as_str(),
        Some(v) => return Err(format!("property kind must be a string, not {v}")),
        None => {
            return Err(
                "no \"kind\" property (lake, river, control_curve, cross_section, breakline, landform or noise_region)"
                    .into(),
            )
        }
    };
    check_properties(kind, geometry.map(|g| &g.value), props)?;
    if kind == "landform" {
        let kind = parse_landform(geometry.map(|g| &g.value), props, t, dem)?;
        return Ok(Parsed::Correction(Box::new(Correction { index, id, kind })));
    }
    let geom = &geometry.ok_or("has no geometry")?.value;
    let kind = match kind {
        "noise_region" => parse_noise_region(geom, props, t, dem)?,
        "lake" => parse_lake(geom, props, t, dem)?,
        "river" => parse_river(geom, props, t, dem)?,
        "control_curve" => parse_curve(geom, props, t, dem)?,
        "breakline" => parse_breakline(geom, props, t, dem)?,
        "cross_section" => {
            // `control` is DESIGN.md's name for it; `control_curve` the
            // guide's (both read, one at a time).
            if props.contains_key("control") && props.contains_key("control_curve") {
                return Err(
                    "a cross-section names its control curve once: control or control_curve, not both"
                        .into(),
                );
            }
            let named = props.get("control_curve").or_else(|| props.get("control"));
            let curve = match named {
                Some(serde_json::Value::String(s)) => s.clone(),
                Some(serde_json::Value::Number(n)) => n.to_string(),
                _ => {
                    return Err(
                        "a cross-section needs a control_curve property naming its control curve"
                            .into(),
                    )
                }
            };
            let CorrectionKind::ControlCurve { points, .. } = parse_curve(geom, props, t, dem)?
            else {
                return Err("a cross-section must be a LineString with heights".into());
            };
            if points.len() < 2 {
                return Err("a cross-section needs at least two positions".into());
            }
            return Ok(Parsed::Section {
                index,
                id,
                curve,
                points,
            });
        }
        other => {
            return Err(format!(
                "unknown kind \"{other}\" (expected lake, river, control_curve, cross_section, breakline, landform or noise_region)"
            ))
        }
    };
    Ok(Parsed::Correction(Box::new(Correction { index, id, kind })))
}

/// Properties every feature may carry: `kind`, the `id` or `name` that
/// names it, and `fid`, the integer QGIS adds to every feature it writes
/// from a GeoPackage layer.
const COMMON_PROPERTIES: [&str; 4] = ["id", "name", "kind", "fid"];

/// The properties a feature of `kind` may carry besides
/// [`COMMON_PROPERTIES`] (a river's depend on its geometry: a centreline
/// has a width and a flow direction, a polygon reach neither). `None` for
/// an unknown kind.
fn kind_properties(
    kind: &str,
    geometry: Option<&GeometryValue>,
) -> Option<&'static [&'static str]> {
    Some(match kind {
        "lake" => &["level_m", "blend_m"],
        "river" => match geometry {
            Some(GeometryValue::Polygon { .. } | GeometryValue::MultiPolygon { .. }) => {
                &["blend_m"]
            }
            _ => &["width_m", "downstream", "flow", "blend_m"],
        },
        "control_curve" => &["heights_m", "influence_m", "slope_deg"],
        "cross_section" => &["control_curve", "control", "heights_m"],
        "breakline" => &["heights_m", "height_m", "hard", "influence_m"],
        "landform" => &["silhouette", "shadow"],
        "noise_region" => &["noise_stroke", "amplitude_m"],
        _ => return None,
    })
}

/// Refuses a property that a feature of `kind` does not have (a misspelt
/// `levle_m` is an error, not ignored), and a `fid` that is not an integer
/// as QGIS writes it. An unknown kind is left to [`parse_feature`]'s error.
fn check_properties(
    kind: &str,
    geometry: Option<&GeometryValue>,
    props: &JsonObject,
) -> Result<(), String> {
    let Some(own) = kind_properties(kind, geometry) else {
        return Ok(());
    };
    let allowed = || own.iter().chain(COMMON_PROPERTIES.iter());
    // The first unknown one by name (the map keeps its keys sorted).
    if let Some(bad) = props.keys().find(|k| !allowed().any(|a| a == k)) {
        let expected: Vec<&str> = allowed().copied().collect();
        return Err(format!(
            "unknown property \"{bad}\" for a {kind} (expected one of: {})",
            expected.join(", ")
        ));
    }
    match props.get("fid") {
        None | Some(serde_json::Value::Null) => Ok(()),
        Some(v) if v.is_i64() || v.is_u64() => Ok(()),
        Some(v) => Err(format!(
            "property fid must be an integer (the feature number QGIS writes), not {v}"
        )),
    }
}

/// A position in the DEM's CRS and pixel space, checked to lie on the DEM.
fn place(pos: &Position, t: &Transform, dem: &Dem) -> Result<([f64; 2], [f64; 2]), String> {
    let c = pos.as_slice();
    if c.len() < 2 || !c.iter().all(|v| v.is_finite()) {
        return Err(format!("position {c:?} is not a finite [x, y]"));
    }
    let (x, y) = t.apply(c[0], c[1])?;
    let (px, py) = dem
        .geotransform
        .crs_to_pixel(x, y)
        .ok_or("the DEM's geotransform is singular")?;
    if !(px >= 0.0 && py >= 0.0 && px <= dem.width as f64 && py <= dem.height as f64) {
        return Err(format!(
            "position ({}, {}) lies outside the DEM",
            c[0], c[1]
        ));
    }
    Ok(([x, y], [px, py]))
}

fn ring(r: &[Position], t: &Transform, dem: &Dem) -> Result<LineString<f64>, String> {
    let pts = r
        .iter()
        .map(|p| place(p, t, dem).map(|(_, px)| Coord { x: px[0], y: px[1] }))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(LineString::new(pts))
}

fn polygon(rings: &[Vec<Position>], t: &Transform, dem: &Dem) -> Result<Polygon<f64>, String> {
    let (outer, holes) = rings.split_first().ok_or("a polygon without rings")?;
    if outer.len() < 4 {
        return Err("a polygon ring needs at least 4 positions".into());
    }
    let outer = ring(outer, t, dem)?;
    let holes = holes
        .iter()
        .map(|h| ring(h, t, dem))
        .collect::<Result<Vec<_>, _>>()?;
    let poly = Polygon::new(outer, holes);
    poly.check_validation()
        .map_err(|e| format!("invalid polygon: {e}"))?;
    Ok(poly)
}

fn parse_lake(
    geom: &GeometryValue,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<CorrectionKind, String> {
    Ok(CorrectionKind::Lake {
        area: lake_area(geom, t, dem)?,
        level_m: number(props, "level_m")?,
        blend_m: positive(props, "blend_m")?,
    })
}

/// The area of a lake (or a river given as its area): a Polygon or a
/// MultiPolygon.
fn lake_area(geom: &GeometryValue, t: &Transform, dem: &Dem) -> Result<MultiPolygon, String> {
    let polys = match geom {
        GeometryValue::Polygon { coordinates } => vec![polygon(coordinates, t, dem)?],
        GeometryValue::MultiPolygon { coordinates } => coordinates
            .iter()
            .map(|p| polygon(p, t, dem))
            .collect::<Result<_, _>>()?,
        other => {
            return Err(format!(
                "a lake must be a Polygon or MultiPolygon, not a {}",
                other.type_name()
            ))
        }
    };
    Ok(MultiPolygon::new(polys))
}

fn parse_river(
    geom: &GeometryValue,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<CorrectionKind, String> {
    let line = match geom {
        GeometryValue::LineString { coordinates } => coordinates,
        GeometryValue::Polygon { .. } | GeometryValue::MultiPolygon { .. } => {
            // Read as a lake's: a level_m, unused here, must still be a
            // number.
            let area = lake_area(geom, t, dem)?;
            number(props, "level_m")?;
            return Ok(CorrectionKind::RiverArea {
                area,
                blend_m: positive(props, "blend_m")?,
            });
        }
        other => {
            return Err(format!(
                "a river must be a LineString centreline with width_m or a Polygon, not a {}",
                other.type_name()
            ))
        }
    };
    let centreline = line
        .iter()
        .map(|p| place(p, t, dem).map(|(_, px)| px))
        .collect::<Result<Vec<_>, _>>()?;
    if centreline.len() < 2 || centreline.windows(2).all(|w| w[0] == w[1]) {
        return Err("a river centreline needs two distinct positions".into());
    }
    let width_m = positive(props, "width_m")?.ok_or("a river centreline needs width_m")?;
    use super::river::Flow;
    let flow = match (props.get("downstream"), props.get("flow")) {
        (Some(_), Some(_)) => {
            return Err("a river's direction is given once: downstream or flow, not both".into())
        }
        (Some(d), None) => match d {
            serde_json::Value::Bool(true) => Flow::Line,
            serde_json::Value::Bool(false) => Flow::Reversed,
            serde_json::Value::String(s) if s == "end" => Flow::Line,
            serde_json::Value::String(s) if s == "start" => Flow::Reversed,
            other => {
                return Err(format!(
                    "downstream {other} must be \"end\" or true (the line is drawn downstream: its last vertex is the outlet) or \"start\" or false (its first vertex is the outlet)"
                ))
            }
        },
        (None, Some(f)) => match f.as_str() {
            Some("line") => Flow::Line,
            Some("auto") => Flow::Heights,
            _ => return Err(format!("flow {f} must be \"line\" or \"auto\"")),
        },
        (None, None) => Flow::Heights,
    };
    Ok(CorrectionKind::River {
        centreline,
        width_m,
        blend_m: positive(props, "blend_m")?,
        flow,
    })
}

fn parse_curve(
    geom: &GeometryValue,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<CorrectionKind, String> {
    let line = line_string(geom, "a control curve")?;
    if line.is_empty() {
        return Err("a control curve needs at least one position".into());
    }
    let heights: Option<Vec<f64>> = match props.get("heights_m") {
        None | Some(serde_json::Value::Null) => None,
        Some(serde_json::Value::Array(a)) => Some(
            a.iter()
                .map(|v| v.as_f64().filter(|x| x.is_finite()))
                .collect::<Option<Vec<_>>>()
                .ok_or("heights_m must be an array of numbers")?,
        ),
        Some(_) => return Err("heights_m must be an array of numbers".into()),
    };
    if let Some(h) = &heights {
        if h.len() != line.len() {
            return Err(format!(
                "heights_m has {} values for {} positions",
                h.len(),
                line.len()
            ));
        }
    }
    let points = line
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let z = match &heights {
                Some(h) => h[i],
                None => match p.as_slice().get(2) {
                    Some(z) if z.is_finite() => *z,
                    _ => {
                        return Err(format!(
                            "position {i} has no height (give Z coordinates or heights_m)"
                        ))
                    }
                },
            };
            place(p, t, dem).map(|(xy, _)| [xy[0], xy[1], z])
        })
        .collect::<Result<Vec<_>, _>>()?;
    let slope_deg = match props.get("slope_deg") {
        None | Some(serde_json::Value::Null) => None,
        Some(v) => {
            let pair = match v {
                serde_json::Value::Array(a) if a.len() == 2 => {
                    a.iter().map(|x| x.as_f64()).collect::<Option<Vec<_>>>()
                }
                serde_json::Value::Array(_) => None,
                // One number: the tilt of a road's crossfall, falling to
                // the right of the line (rising on its left).
                other => other.as_f64().map(|x| vec![-x, x]),
            };
            match pair.as_deref() {
                Some(&[l, r]) if l.abs() < 90.0 && r.abs() < 90.0 => Some([l, r]),
                _ => {
                    return Err(format!(
                        "slope_deg {v} must be a number of degrees in (-90, 90) or two of them [left, right]"
                    ))
                }
            }
        }
    };
    Ok(CorrectionKind::ControlCurve {
        points,
        influence_m: positive(props, "influence_m")?,
        sections: Vec::new(),
        slope_deg,
    })
}

/// The heights of a breakline's positions: Z coordinates, a `heights_m`
/// array or one `height_m` (the error names the first position without).
fn breakline_heights(line: &[Position], props: &JsonObject) -> Result<Vec<f64>, String> {
    if let Some(h) = number(props, "height_m")? {
        if props.get("heights_m").is_some_and(|v| !v.is_null()) {
            return Err("give heights_m or height_m, not both".into());
        }
        return Ok(vec![h; line.len()]);
    }
    let VertexHeights(h) = per_vertex_heights(line, props)?;
    h.into_iter()
        .enumerate()
        .map(|(i, z)| {
            z.ok_or_else(|| {
                format!("position {i} has no height (give Z coordinates, heights_m or height_m)")
            })
        })
        .collect()
}

/// Per-vertex heights from `heights_m` or the Z coordinates (`None` where
/// a position has neither).
struct VertexHeights(Vec<Option<f64>>);

fn per_vertex_heights(line: &[Position], props: &JsonObject) -> Result<VertexHeights, String> {
    match props.get("heights_m") {
        None | Some(serde_json::Value::Null) => Ok(VertexHeights(
            line.iter()
                .map(|p| p.as_slice().get(2).copied().filter(|z| z.is_finite()))
                .collect(),
        )),
        Some(serde_json::Value::Array(a)) => {
            let h = a
                .iter()
                .map(|v| v.as_f64().filter(|x| x.is_finite()))
                .collect::<Option<Vec<_>>>()
                .ok_or("heights_m must be an array of numbers")?;
            if h.len() != line.len() {
                return Err(format!(
                    "heights_m has {} values for {} positions",
                    h.len(),
                    line.len()
                ));
            }
            Ok(VertexHeights(h.into_iter().map(Some).collect()))
        }
        Some(_) => Err("heights_m must be an array of numbers".into()),
    }
}

/// Where the polyline `px` (pixel space) crosses or touches itself: the
/// indices of the first two non-adjacent segments that meet (adjacent
/// segments meet only at their shared vertex unless they fold back).
pub fn self_intersection(px: &[[f64; 2]]) -> Option<(usize, usize)> {
    let n = px.len().saturating_sub(1);
    let bbox = |i: usize| {
        let (a, b) = (px[i], px[i + 1]);
        [
            a[0].min(b[0]),
            a[1].min(b[1]),
            a[0].max(b[0]),
            a[1].max(b[1]),
        ]
    };
    let boxes: Vec<[f64; 4]> = (0..n).map(bbox).collect();
    for i in 0..n {
        for j in i + 1..n {
            let (p, q) = (boxes[i], boxes[j]);
            if p[0] > q[2] || q[0] > p[2] || p[1] > q[3] || q[1] > p[3] {
                continue;
            }
            let meet = if j == i + 1 {
                folds_back(px[i], px[i + 1], px[j + 1])
            } else {
                segments_meet(px[i], px[i + 1], px[j], px[j + 1])
            };
            if meet {
                return Some((i, j));
            }
        }
    }
    None
}

fn orient(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

fn on_segment(a: [f64; 2], b: [f64; 2], p: [f64; 2]) -> bool {
    p[0] >= a[0].min(b[0])
        && p[0] <= a[0].max(b[0])
        && p[1] >= a[1].min(b[1])
        && p[1] <= a[1].max(b[1])
}

/// True when the closed segments `a`-`b` and `c`-`d` share a point.
fn segments_meet(a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]) -> bool {
    let (d1, d2) = (orient(c, d, a), orient(c, d, b));
    let (d3, d4) = (orient(a, b, c), orient(a, b, d));
    if ((d1 > 0.0 && d2 < 0.0) || (d1 < 0.0 && d2 > 0.0))
        && ((d3 > 0.0 && d4 < 0.0) || (d3 < 0.0 && d4 > 0.0))
    {
        return true;
    }
    (d1 == 0.0 && on_segment(c, d, a))
        || (d2 == 0.0 && on_segment(c, d, b))
        || (d3 == 0.0 && on_segment(a, b, c))
        || (d4 == 0.0 && on_segment(a, b, d))
}

/// The coordinates of `geom` when it is a LineString; `what` names the
/// feature kind in the error.
fn line_string<'a>(geom: &'a GeometryValue, what: &str) -> Result<&'a [Position], String> {
    match geom {
        GeometryValue::LineString { coordinates } => Ok(coordinates),
        other => Err(format!(
            "{what} must be a LineString, not a {}",
            other.type_name()
        )),
    }
}

/// True when the segment `b`-`c` turns straight back over `a`-`b`.
fn folds_back(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> bool {
    let (u, v) = ([a[0] - b[0], a[1] - b[1]], [c[0] - b[0], c[1] - b[1]]);
    orient(a, b, c) == 0.0 && u[0] * v[0] + u[1] * v[1] > 0.0
}

fn parse_breakline(
    geom: &GeometryValue,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<CorrectionKind, String> {
    let line = line_string(geom, "a breakline")?;
    let heights = breakline_heights(line, props)?;
    let mut points: Vec<[f64; 3]> = Vec::new();
    let mut px: Vec<[f64; 2]> = Vec::new();
    let mut orig = Vec::new();
    for (k, (p, z)) in line.iter().zip(heights).enumerate() {
        let (xy, pix) = place(p, t, dem)?;
        // Repeated positions (as digitising leaves them) are dropped.
        if px.last() != Some(&pix) {
            points.push([xy[0], xy[1], z]);
            px.push(pix);
            orig.push(k);
        }
    }
    if px.len() < 2 {
        return Err(format!(
            "a breakline needs at least two distinct positions, it has {}",
            px.len()
        ));
    }
    if let Some((i, j)) = self_intersection(&px) {
        return Err(format!(
            "the breakline crosses itself (the segment from position {} meets the one from position {})",
            orig[i], orig[j]
        ));
    }
    let hard = match props.get("hard") {
        None | Some(serde_json::Value::Null) => true,
        Some(serde_json::Value::Bool(b)) => *b,
        Some(v) => return Err(format!("property hard must be true or false, not {v}")),
    };
    Ok(CorrectionKind::Breakline {
        points,
        hard,
        influence_m: positive(props, "influence_m")?,
    })
}

/// A `silhouette` or `noise_stroke` property: `{"view": NAME, "stroke": ID}`.
fn stroke_ref(props: &JsonObject, key: &str) -> Result<super::landform::StrokeRef, String> {
    let v = props
        .get(key)
        .ok_or_else(|| format!("needs a {key} property ({{\"view\": NAME, \"stroke\": ID}})"))?;
    let field = |k: &str| match v.get(k) {
        Some(serde_json::Value::String(s)) => Ok(s.clone()),
        Some(serde_json::Value::Number(n)) => Ok(n.to_string()),
        _ => Err(format!(
            "property {key} must be {{\"view\": NAME, \"stroke\": ID}}, not {v}"
        )),
    };
    Ok(super::landform::StrokeRef {
        view: field("view")?,
        stroke: field("stroke")?,
    })
}

/// A Polygon or MultiPolygon in pixel space (`what` names the feature).
fn area(
    geom: &GeometryValue,
    t: &Transform,
    dem: &Dem,
    what: &str,
) -> Result<MultiPolygon<f64>, String> {
    match geom {
        GeometryValue::Polygon { coordinates } => {
            Ok(MultiPolygon::new(vec![polygon(coordinates, t, dem)?]))
        }
        GeometryValue::MultiPolygon { coordinates } => Ok(MultiPolygon::new(
            coordinates
                .iter()
                .map(|p| polygon(p, t, dem))
                .collect::<Result<_, _>>()?,
        )),
        other => Err(format!(
            "{what} must be a Polygon or MultiPolygon, not a {}",
            other.type_name()
        )),
    }
}

fn parse_landform(
    geom: Option<&GeometryValue>,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<CorrectionKind, String> {
    let silhouette = stroke_ref(props, "silhouette")?;
    let boundary = match geom {
        None => None,
        Some(g) => Some(area(g, t, dem, "a landform's boundary")?),
    };
    let shadow = match props.get("shadow") {
        None | Some(serde_json::Value::Null) => None,
        Some(v) => {
            let coords = v.get("coordinates").unwrap_or(v);
            let pos: Vec<Position> = serde_json::from_value(coords.clone()).map_err(|_| {
                "property shadow must be a LineString (or its coordinates)".to_string()
            })?;
            if v.get("type").is_some_and(|ty| ty != "LineString") {
                return Err("property shadow must be a LineString".into());
            }
            let mut xy: Vec<[f64; 2]> = Vec::new();
            let mut px: Vec<[f64; 2]> = Vec::new();
            for p in &pos {
                let (a, b) = place(p, t, dem)?;
                if px.last() != Some(&b) {
                    xy.push(a);
                    px.push(b);
                }
            }
            if px.len() < 2 {
                return Err("the shadow needs at least two distinct positions".into());
            }
            if let Some((i, j)) = self_intersection(&px) {
                return Err(format!("the shadow crosses itself (segments {i} and {j})"));
            }
            Some(xy)
        }
    };
    Ok(CorrectionKind::Landform {
        silhouette,
        boundary,
        shadow,
        placed: None,
    })
}

fn parse_noise_region(
    geom: &GeometryValue,
    props: &JsonObject,
    t: &Transform,
    dem: &Dem,
) -> Result<CorrectionKind, String> {
    Ok(CorrectionKind::NoiseRegion {
        area: area(geom, t, dem, "a noise region")?,
        stroke: stroke_ref(props, "noise_stroke")?,
        amplitude_m: positive(props, "amplitude_m")?,
        placed: None,
    })
}
