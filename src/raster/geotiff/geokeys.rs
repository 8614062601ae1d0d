//! GeoKeys (GeoTIFF 1.0/1.1 key directory) and their translation to a CRS:
//! the EPSG code where the keys give one, else a PROJ definition built from
//! the user-defined keys (projection method, parameters, ellipsoid), checked
//! by PROJ (through GDAL's OSR) and turned into WKT.

use std::collections::HashMap;
use std::path::Path;

use crate::raster::{Crs, RasterError};

/// A parsed GeoKey directory.
#[derive(Debug, Default, Clone)]
pub struct GeoKeys {
    shorts: HashMap<u16, u16>,
    doubles: HashMap<u16, Vec<f64>>,
    ascii: HashMap<u16, String>,
}

pub const GT_MODEL_TYPE: u16 = 1024;
pub const GT_RASTER_TYPE: u16 = 1025;
pub const GEOGRAPHIC_TYPE: u16 = 2048;
const GEOG_GEODETIC_DATUM: u16 = 2050;
const GEOG_ELLIPSOID: u16 = 2056;
const GEOG_SEMI_MAJOR: u16 = 2057;
const GEOG_SEMI_MINOR: u16 = 2058;
const GEOG_INV_FLATTENING: u16 = 2059;
const GEOG_PRIME_MERIDIAN_LONG: u16 = 2061;
pub const PROJECTED_CS_TYPE: u16 = 3072;
const PROJECTION: u16 = 3074;
const PROJ_COORD_TRANS: u16 = 3075;
const PROJ_LINEAR_UNITS: u16 = 3076;
const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;
const PROJ_STD_PARALLEL1: u16 = 3078;
const PROJ_STD_PARALLEL2: u16 = 3079;
const PROJ_NAT_ORIGIN_LONG: u16 = 3080;
const PROJ_NAT_ORIGIN_LAT: u16 = 3081;
const PROJ_FALSE_EASTING: u16 = 3082;
const PROJ_FALSE_NORTHING: u16 = 3083;
const PROJ_FALSE_ORIGIN_LONG: u16 = 3084;
const PROJ_FALSE_ORIGIN_LAT: u16 = 3085;
const PROJ_FALSE_ORIGIN_EASTING: u16 = 3086;
const PROJ_FALSE_ORIGIN_NORTHING: u16 = 3087;
const PROJ_CENTER_LONG: u16 = 3088;
const PROJ_CENTER_LAT: u16 = 3089;
const PROJ_SCALE_AT_NAT_ORIGIN: u16 = 3092;
const PROJ_SCALE_AT_CENTER: u16 = 3093;
const PROJ_AZIMUTH_ANGLE: u16 = 3094;
const PROJ_STRAIGHT_VERT_POLE_LONG: u16 = 3095;

const VERTICAL_CS_TYPE: u16 = 4096;
const VERTICAL_CITATION: u16 = 4097;
const VERTICAL_UNITS: u16 = 4099;

const USER_DEFINED: u16 = 32767;

/// Raster space convention of the GeoTIFF (`GTRasterTypeGeoKey`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RasterType {
    PixelIsArea,
    PixelIsPoint,
}

impl GeoKeys {
    /// Parse the key directory (`GeoKeyDirectoryTag`), with the double and
    /// ASCII parameter tags it refers to.
    pub fn parse(
        path: &Path,
        directory: &[u16],
        doubles: &[f64],
        ascii: &str,
    ) -> Result<GeoKeys, RasterError> {
        let bad = |detail: &str| RasterError::Corrupt {
            path: path.to_path_buf(),
            detail: format!("GeoKeyDirectory {detail}"),
        };
        if directory.len() < 4 {
            return Err(bad("is shorter than its header"));
        }
        let count = directory[3] as usize;
        if directory.len() < 4 + 4 * count {
            return Err(bad("lists more keys than it holds"));
        }
        let mut keys = GeoKeys::default();
        for k in 0..count {
            let e = &directory[4 + 4 * k..8 + 4 * k];
            let (id, location, n, offset) = (e[0], e[1], e[2] as usize, e[3] as usize);
            match location {
                0 => {
                    keys.shorts.insert(id, e[3]);
                }
                34736 => {
                    let v = doubles
                        .get(offset..offset + n)
                        .ok_or_else(|| bad("points past GeoDoubleParams"))?;
                    keys.doubles.insert(id, v.to_vec());
                }
                34737 => {
                    let s = ascii
                        .get(offset..offset + n)
                        .ok_or_else(|| bad("points past GeoAsciiParams"))?;
                    keys.ascii
                        .insert(id, s.trim_end_matches(['|', '\0']).to_string());
                }
                34735 => {
                    if let Some(v) = directory.get(offset) {
                        keys.shorts.insert(id, *v);
                    }
                }
                _ => {}
            }
        }
        Ok(keys)
    }

    pub fn short(&self, id: u16) -> Option<u16> {
        self.shorts.get(&id).copied()
    }

    fn double(&self, id: u16) -> Option<f64> {
        self.doubles.get(&id).and_then(|v| v.first().copied())
    }

    /// The vertical CRS the keys name (`VerticalCSTypeGeoKey`, GeoTIFF 1.1
    /// and GDAL's compound CRSs): its name and (unit name, metres per unit),
    /// from the EPSG code or from `VerticalUnitsGeoKey` and the citation.
    pub fn vertical(&self) -> Option<(String, Option<(String, f64)>)> {
        let code = self.short(VERTICAL_CS_TYPE).filter(|&c| c != 0);
        let units = self.short(VERTICAL_UNITS).and_then(|u| match u {
            9001 => Some(("metre".to_string(), 1.0)),
            9002 => Some(("foot".to_string(), 0.3048)),
            9003 => Some(("US survey foot".to_string(), 1200.0 / 3937.0)),
            _ => None,
        });
        let citation = self.ascii.get(&VERTICAL_CITATION).cloned();
        match code {
            Some(c) if c != USER_DEFINED => {
                let (name, unit) = crate::raster::vertical::vertical_of_epsg(u32::from(c))
                    .unwrap_or_else(|| (format!("EPSG:{c}"), None));
                Some((name, unit.or(units)))
            }
            _ if units.is_some() || citation.is_some() => Some((
                citation.unwrap_or_else(|| "user-defined vertical CRS".into()),
                units,
            )),
            _ => None,
        }
    }

    /// PixelIsArea unless the keys say PixelIsPoint.
    pub fn raster_type(&self) -> RasterType {
        match self.short(GT_RASTER_TYPE) {
            Some(2) => RasterType::PixelIsPoint,
            _ => RasterType::PixelIsArea,
        }
    }

    /// The EPSG code of the horizontal CRS, where the keys give one.
    pub fn epsg(&self) -> Option<u32> {
        match self.short(GT_MODEL_TYPE) {
            Some(2) => self
                .short(GEOGRAPHIC_TYPE)
                .filter(|&c| c != USER_DEFINED && c != 0)
                .map(u32::from),
            _ => self
                .short(PROJECTED_CS_TYPE)
                .filter(|&c| c != USER_DEFINED && c != 0)
                .map(u32::from)
                .or_else(|| {
                    // Geographic files that omit the model type.
                    self.short(GEOGRAPHIC_TYPE)
                        .filter(|&c| {
                            c != USER_DEFINED && c != 0 && self.short(PROJECTED_CS_TYPE).is_none()
                        })
                        .map(u32::from)
                }),
        }
    }

    /// True when the model is geographic (degrees).
    pub fn is_geographic(&self) -> bool {
        match self.short(GT_MODEL_TYPE) {
            Some(2) => true,
            Some(_) => false,
            None => {
                self.short(PROJECTED_CS_TYPE).is_none() && self.short(GEOGRAPHIC_TYPE).is_some()
            }
        }
    }

    /// The PROJ string of the ellipsoid / datum of a user-defined CRS.
    fn ellipsoid_proj(&self) -> String {
        match self.short(GEOG_GEODETIC_DATUM) {
            Some(6326) => return "+datum=WGS84".into(),
            Some(6269) => return "+datum=NAD83".into(),
            Some(6267) => return "+datum=NAD27".into(),
            _ => {}
        }
        match self.short(GEOGRAPHIC_TYPE) {
            Some(4326) => return "+datum=WGS84".into(),
            Some(4269) => return "+datum=NAD83".into(),
            _ => {}
        }
        match self.short(GEOG_ELLIPSOID) {
            Some(7030) => return "+ellps=WGS84".into(),
            Some(7019) => return "+ellps=GRS80".into(),
            Some(7022) => return "+ellps=intl".into(),
            Some(7004) => return "+ellps=bessel".into(),
            Some(7008) => return "+ellps=clrk66".into(),
            _ => {}
        }
        match (
            self.double(GEOG_SEMI_MAJOR),
            self.double(GEOG_INV_FLATTENING),
            self.double(GEOG_SEMI_MINOR),
        ) {
            (Some(a), Some(rf), _) if rf > 0.0 => format!("+a={a} +rf={rf}"),
            (Some(a), _, Some(b)) => format!("+a={a} +b={b}"),
            (Some(a), _, None) => format!("+a={a} +b={a}"),
            _ => "+ellps=WGS84".into(),
        }
    }

    /// A PROJ definition of a user-defined projected CRS, from the projection
    /// method (`ProjCoordTransGeoKey`) and its parameters. `None` where the
    /// method is not one of those DEM products use.
    pub fn user_defined_proj(&self) -> Option<String> {
        let d = |id: u16| self.double(id);
        let p0 = |ids: &[u16]| ids.iter().find_map(|&i| d(i)).unwrap_or(0.0);
        let lon0 = p0(&[
            PROJ_NAT_ORIGIN_LONG,
            PROJ_CENTER_LONG,
            PROJ_FALSE_ORIGIN_LONG,
            PROJ_STRAIGHT_VERT_POLE_LONG,
        ]);
        let lat0 = p0(&[PROJ_NAT_ORIGIN_LAT, PROJ_CENTER_LAT, PROJ_FALSE_ORIGIN_LAT]);
        let fe = p0(&[PROJ_FALSE_EASTING, PROJ_FALSE_ORIGIN_EASTING]);
        let fnn = p0(&[PROJ_FALSE_NORTHING, PROJ_FALSE_ORIGIN_NORTHING]);
        let k = d(PROJ_SCALE_AT_NAT_ORIGIN)
            .or(d(PROJ_SCALE_AT_CENTER))
            .unwrap_or(1.0);
        let method = match self.short(PROJ_COORD_TRANS)? {
            1 => format!("+proj=tmerc +lat_0={lat0} +lon_0={lon0} +k={k}"),
            7 => format!("+proj=merc +lon_0={lon0} +k={k}"),
            8 => format!(
                "+proj=lcc +lat_1={} +lat_2={} +lat_0={lat0} +lon_0={lon0}",
                d(PROJ_STD_PARALLEL1)?,
                d(PROJ_STD_PARALLEL2)?
            ),
            9 => format!("+proj=lcc +lat_1={lat0} +lat_0={lat0} +lon_0={lon0} +k_0={k}"),
            10 => format!("+proj=laea +lat_0={lat0} +lon_0={lon0}"),
            11 => format!(
                "+proj=aea +lat_1={} +lat_2={} +lat_0={lat0} +lon_0={lon0}",
                d(PROJ_STD_PARALLEL1)?,
                d(PROJ_STD_PARALLEL2)?
            ),
            12 => format!("+proj=aeqd +lat_0={lat0} +lon_0={lon0}"),
            15 => format!(
                "+proj=stere +lat_0={} +lat_ts={lat0} +lon_0={lon0} +k={k}",
                if lat0 >= 0.0 { 90 } else { -90 }
            ),
            16 => format!("+proj=sterea +lat_0={lat0} +lon_0={lon0} +k={k}"),
            17 => format!(
                "+proj=eqc +lat_ts={} +lon_0={lon0}",
                d(PROJ_STD_PARALLEL1).unwrap_or(lat0)
            ),
            3 => format!(
                "+proj=omerc +lat_0={lat0} +lonc={lon0} +alpha={} +k={k}",
                d(PROJ_AZIMUTH_ANGLE)?
            ),
            _ => return None,
        };
        let units = match self.short(PROJ_LINEAR_UNITS) {
            Some(9002) => "+units=ft".to_string(),
            Some(9003) => "+units=us-ft".to_string(),
            Some(USER_DEFINED) => format!("+to_meter={}", d(PROJ_LINEAR_UNIT_SIZE).unwrap_or(1.0)),
            _ => "+units=m".to_string(),
        };
        let pm = d(GEOG_PRIME_MERIDIAN_LONG)
            .filter(|v| *v != 0.0)
            .map(|v| format!(" +pm={v}"))
            .unwrap_or_default();
        Some(format!(
            "{method} +x_0={fe} +y_0={fnn} {}{pm} {units} +no_defs +type=crs",
            self.ellipsoid_proj()
        ))
    }

    /// The CRS these keys describe. EPSG codes are resolved through GDAL's
    /// PROJ database to WKT; user-defined projections are built as PROJ
    /// strings, validated by PROJ and converted to WKT. Each distinct
    /// definition is looked up once per process ([`resolved`]): the tiles
    /// of a directory share one CRS, and a PROJ look-up costs more than
    /// reading a small tile's header.
    pub fn crs(&self, path: &Path) -> Result<Crs, RasterError> {
        let geographic = self.is_geographic();
        let crs_err = |message: String| RasterError::Crs {
            path: path.to_path_buf(),
            message,
        };
        if let Some(code) = self.epsg() {
            let key = CrsKey::Epsg(code, geographic);
            return resolved(key, || {
                let srs = crate::raster::crs::srs_from_epsg(code)
                    .map_err(|e| format!("EPSG:{code} is not a known CRS ({e})"))?;
                Ok(Crs {
                    epsg: Some(code),
                    wkt: srs.to_wkt().unwrap_or_default(),
                    proj: None,
                    geographic,
                })
            })
            .map_err(crs_err);
        }
        let definition = if geographic {
            format!("+proj=longlat {} +no_defs +type=crs", self.ellipsoid_proj())
        } else {
            match self.user_defined_proj() {
                Some(p) => p,
                None => {
                    return Err(RasterError::NotNative {
                        path: path.to_path_buf(),
                        what: format!(
                        "user-defined projection (ProjCoordTransGeoKey {}, ProjectionGeoKey {})",
                        self.short(PROJ_COORD_TRANS)
                            .map_or("absent".into(), |c| c.to_string()),
                        self.short(PROJECTION)
                            .map_or("absent".into(), |c| c.to_string())
                    ),
                    })
                }
            }
        };
        let key = CrsKey::Proj(definition.clone(), geographic);
        resolved(key, || {
            // PROJ (through GDAL's OSR, which frees what it made on
            // failure, unlike the proj crate's constructor) checks the
            // definition.
            let wkt = crate::raster::crs::srs_from_proj4(&definition)
                .and_then(|s| s.to_wkt().map_err(|e| e.to_string()))
                .map_err(|e| {
                    format!("PROJ rejects the CRS built from the GeoKeys '{definition}': {e}")
                })?;
            Ok(Crs {
                epsg: None,
                wkt,
                proj: Some(definition.clone()),
                geographic,
            })
        })
        .map_err(crs_err)
    }
}

/// What a CRS built from GeoKeys depends on: the EPSG code, or the PROJ
/// definition built from the user-defined keys (and whether it is
/// geographic).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum CrsKey {
    Epsg(u32, bool),
    Proj(String, bool),
}

/// The CRS (or the message of the error) for `key`, built by `build` the
/// first time the process sees it. PROJ's database does not change while
/// the process runs, so the answer is the same for every tile naming it.
fn resolved(key: CrsKey, build: impl FnOnce() -> Result<Crs, String>) -> Result<Crs, String> {
    use std::sync::{Arc, Mutex, OnceLock};
    type Cache = Mutex<HashMap<CrsKey, Arc<Result<Crs, String>>>>;
    static CACHE: OnceLock<Cache> = OnceLock::new();
    let cache = CACHE.get_or_init(Default::default);
    // Only the shared answer is taken under the lock; it is copied after.
    let hit = cache.lock().ok().and_then(|c| c.get(&key).cloned());
    if let Some(hit) = hit {
        return (*hit).clone();
    }
    // Built outside the lock: tiles opened in parallel may build the same
    // CRS twice at first, with the same result.
    let value = build();
    if let Ok(mut c) = cache.lock() {
        c.entry(key).or_insert_with(|| Arc::new(value.clone()));
    }
    value
}
