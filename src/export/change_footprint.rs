//! The outline of an edit's change: the changed cells of a
//! [`ChangeMask`] polygonised by GDAL (`GDALPolygonize`, as
//! `gdal_polygonize.py` does it: one polygon per 4-connected patch of
//! cells, holes kept, edges on cell boundaries), reprojected to WGS84
//! longitude/latitude (RFC 7946 axis order) and gathered into one GeoJSON
//! MultiPolygon. [`super::curves_geojson`] puts it beside the placed
//! curves.

use gdal::vector::LayerAccess;
use serde_json::Value;

use super::change_mask::ChangeMask;
use super::ExportError;

/// The changed cells as a GeoJSON MultiPolygon geometry in lon/lat;
/// `None` when no cell changed.
pub fn footprint_lonlat(mask: &ChangeMask) -> Result<Option<Value>, ExportError> {
    if mask.count() == 0 {
        return Ok(None);
    }
    let gerr = |e: gdal::errors::GdalError| ExportError::Internal(format!("footprint: {e}"));
    let mut srs = gdal::spatial_ref::SpatialRef::from_definition(&mask.crs.gdal_definition())
        .map_err(|e| ExportError::Input {
            path: mask.source.clone(),
            message: format!("its CRS is unknown to GDAL: {e}"),
        })?;
    // The polygons' coordinates are the geotransform's (x east, y north):
    // on a geographic CRS, GDAL 3's authority order (latitude first) would
    // read them swapped.
    srs.set_axis_mapping_strategy(gdal::spatial_ref::AxisMappingStrategy::TraditionalGisOrder);
    // The mask as a Byte raster in memory (1 changed; 0, skipped, else).
    let mem = gdal::DriverManager::get_driver_by_name("MEM").map_err(gerr)?;
    let mut ds = mem
        .create_with_band_type::<u8, _>("", mask.width, mask.height, 1)
        .map_err(gerr)?;
    ds.set_geo_transform(&mask.geotransform.0).map_err(gerr)?;
    ds.set_spatial_ref(&srs).map_err(gerr)?;
    let mut band = ds.rasterband(1).map_err(gerr)?;
    let bytes: Vec<u8> = mask.changed.iter().map(|&c| c as u8).collect();
    let mut buf = gdal::raster::Buffer::new((mask.width, mask.height), bytes);
    band.write((0, 0), (mask.width, mask.height), &mut buf)
        .map_err(gerr)?;
    let vdrv = gdal::DriverManager::get_driver_by_name("Memory").map_err(gerr)?;
    let mut vds = vdrv.create_vector_only("").map_err(gerr)?;
    let layer = vds
        .create_layer(gdal::vector::LayerOptions {
            name: "footprint",
            srs: Some(&srs),
            ty: gdal_sys::OGRwkbGeometryType::wkbPolygon,
            options: None,
        })
        .map_err(gerr)?;
    layer
        .create_defn_fields(&[("v", gdal_sys::OGRFieldType::OFTInteger)])
        .map_err(gerr)?;
    // SAFETY: valid band and layer handles that outlive the call; the band
    // is its own mask (zero cells produce no polygon); no progress callback.
    let rc = unsafe {
        gdal_sys::GDALPolygonize(
            band.c_rasterband(),
            band.c_rasterband(),
            layer.c_layer(),
            0,
            std::ptr::null_mut(),
            None,
            std::ptr::null_mut(),
        )
    };
    if rc != gdal_sys::CPLErr::CE_None {
        return Err(ExportError::Internal(
            "footprint: GDALPolygonize failed".into(),
        ));
    }
    let mut wgs84 = gdal::spatial_ref::SpatialRef::from_epsg(4326).map_err(gerr)?;
    wgs84.set_axis_mapping_strategy(gdal::spatial_ref::AxisMappingStrategy::TraditionalGisOrder);
    let to_ll = gdal::spatial_ref::CoordTransform::new(&srs, &wgs84).map_err(gerr)?;
    let mut polygons = Vec::new();
    let mut layer = layer;
    for f in layer.features() {
        let Some(g) = f.geometry() else { continue };
        let ll = g.transform(&to_ll).map_err(gerr)?;
        let json: Value = serde_json::from_str(&ll.json().map_err(gerr)?)
            .map_err(|e| ExportError::Internal(format!("footprint: {e}")))?;
        match json["type"].as_str() {
            Some("Polygon") => polygons.push(json["coordinates"].clone()),
            Some("MultiPolygon") => {
                polygons.extend(json["coordinates"].as_array().cloned().unwrap_or_default())
            }
            _ => {}
        }
    }
    Ok(Some(serde_json::json!({
        "type": "MultiPolygon",
        "coordinates": polygons,
    })))
}
