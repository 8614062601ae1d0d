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
