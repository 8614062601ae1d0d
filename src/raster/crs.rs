//! Coordinate reference systems of DEMs: an EPSG code where one is known and
//! always a WKT definition, so that PROJ (viewpoints) and GDAL (write-back)
//! agree on what the coordinates mean.

use serde::Serialize;

/// A DEM's horizontal coordinate reference system.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Crs {
    /// EPSG code of the horizontal CRS, when the file names one.
    pub epsg: Option<u32>,
    /// WKT2 definition (what PROJ and GDAL accept); empty when unknown.
    pub wkt: String,
    /// PROJ string of a user-defined CRS built from GeoKeys, if any.
    pub proj: Option<String>,
    /// True when the CRS is geographic (coordinates in degrees).
    pub geographic: bool,
}

impl Crs {
    /// The definition to hand to PROJ: `EPSG:n` where known, else the WKT or
    /// PROJ string.
    pub fn proj_definition(&self) -> String {
        match (&self.epsg, &self.proj) {
            (Some(code), _) => format!("EPSG:{code}"),
            (None, Some(p)) if self.wkt.is_empty() => p.clone(),
            _ => self.wkt.clone(),
        }
    }

    /// The definition to hand to GDAL when writing a raster: the WKT where
    /// there is one (it keeps every parameter), else [`Crs::proj_definition`];
    /// empty when the CRS is unknown.
    pub fn gdal_definition(&self) -> String {
        if self.wkt.is_empty() {
            self.proj_definition()
        } else {
            self.wkt.clone()
        }
    }

    /// Same horizontal CRS (used to check that tiles agree).
    pub fn same_as(&self, other: &Crs) -> bool {
        match (self.epsg, other.epsg) {
            (Some(a), Some(b)) => a == b,
            _ => self.wkt == other.wkt && self.proj == other.proj,
        }
    }
}

/// Run an OSR import quietly (GDAL's error printer would add a line to the
/// one-line message): its OGR error code, or GDAL's message for it.
fn quiet_import(what: &str, f: impl FnOnce() -> gdal_sys::OGRErr::Type) -> Result<(), String> {
    // SAFETY: a handler pushed and popped on this thread around `f`;
    // CPLGetLastErrorMsg returns a string GDAL owns, copied at once.
    unsafe {
        gdal_sys::CPLErrorReset();
        gdal_sys::CPLPushErrorHandler(Some(gdal_sys::CPLQuietErrorHandler));
    }
    let rv = f();
    let msg = unsafe {
        gdal_sys::CPLPopErrorHandler();
        let m = gdal_sys::CPLGetLastErrorMsg();
        if m.is_null() {
            String::new()
        } else {
            std::ffi::CStr::from_ptr(m).to_string_lossy().into_owned()
        }
    };
    if rv == gdal_sys::OGRErr::OGRERR_NONE {
        Ok(())
    } else if msg.is_empty() {
        Err(format!("{what} failed (OGR error {rv})"))
    } else {
        Err(msg.lines().next().unwrap_or("").to_string())
    }
}

/// A spatial reference from an EPSG code. Unlike gdal 0.19's
/// `SpatialRef::from_epsg`, the handle is freed when the import fails (found
/// by the fuzz harness's leak checker: an unknown code leaked it), and GDAL
/// prints nothing.
pub(crate) fn srs_from_epsg(code: u32) -> Result<gdal::spatial_ref::SpatialRef, String> {
    let srs = gdal::spatial_ref::SpatialRef::new().map_err(|e| e.to_string())?;
    let code =
        std::ffi::c_int::try_from(code).map_err(|_| format!("EPSG:{code} is out of range"))?;
    // SAFETY: `srs` owns a live handle for the duration of the call.
    quiet_import("OSRImportFromEPSG", || unsafe {
        gdal_sys::OSRImportFromEPSG(srs.to_c_hsrs(), code)
    })?;
    Ok(srs)
}

/// A spatial reference from a PROJ string (PROJ checks it), freed on
/// failure (see [`srs_from_epsg`]).
pub(crate) fn srs_from_proj4(definition: &str) -> Result<gdal::spatial_ref::SpatialRef, String> {
    let srs = gdal::spatial_ref::SpatialRef::new().map_err(|e| e.to_string())?;
    let c = std::ffi::CString::new(definition).map_err(|e| e.to_string())?;
    // SAFETY: as above; GDAL copies the string.
    quiet_import("OSRImportFromProj4", || unsafe {
        gdal_sys::OSRImportFromProj4(srs.to_c_hsrs(), c.as_ptr())
    })?;
    Ok(srs)
}
