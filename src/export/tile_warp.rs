//! One web-map tile of heights: the DEM warped by GDAL into the tile's
//! 256 x 256 grid in EPSG:3857 with bilinear resampling, exactly as
//! `gdalwarp -t_srs EPSG:3857 -te XMIN YMIN XMAX YMAX -ts 256 256 -r
//! bilinear -ot Float32` makes it (the same GDAL call with the same
//! options, so the same values: GDAL's approximate transformer, error
//! threshold 0.125 pixel, and, when a tile pixel spans several DEM cells,
//! GDAL's widened bilinear kernel). Heights come out in metres (the band's
//! scale, offset and vertical unit applied: the bilinear weights commute
//! with them), nodata as NaN.

use std::ffi::{c_char, c_int, CString};
use std::ptr::null_mut;

use super::web_mercator::{TileId, TILE_SIZE};
use crate::raster::Vertical;

/// The gdalwarp options of a tile (the command line the tile equals).
pub fn warp_args(tile: TileId) -> Vec<String> {
    let b = tile.bounds_3857();
    let n = TILE_SIZE.to_string();
    let mut v: Vec<String> = ["-of", "MEM", "-t_srs", "EPSG:3857", "-te"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    v.extend(b.iter().map(|x| format!("{x:.10}")));
    v.extend(
        [
            "-ts",
            &n,
            &n,
            "-r",
            "bilinear",
            "-ot",
            "Float32",
            "-dstnodata",
            "nan",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    v
}

/// The tile's heights (metres, NaN = nodata), row-major from the north.
pub fn warp_tile(
    src: &gdal::Dataset,
    tile: TileId,
    vertical: &Vertical,
) -> Result<Vec<f32>, String> {
    let args = warp_args(tile);
    let cargs = args
        .iter()
        .map(|a| CString::new(a.as_str()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    let mut argv: Vec<*mut c_char> = cargs
        .iter()
        .map(|a| a.as_ptr() as *mut c_char)
        .chain(std::iter::once(null_mut()))
        .collect();
    // SAFETY: `argv` is a NULL-terminated list of valid C strings that
    // outlive the call; the options are freed once; the source handle is
    // valid for the call; a non-null result is a new dataset we own.
    let ds = unsafe {
        let opts = gdal_sys::GDALWarpAppOptionsNew(argv.as_mut_ptr(), null_mut());
        if opts.is_null() {
            return Err("GDAL refused the warp options".into());
        }
        let mut srcs = [src.c_dataset()];
        let mut usage: c_int = 0;
        let h = gdal_sys::GDALWarp(
            c"".as_ptr(),
            null_mut(),
            1,
            srcs.as_mut_ptr(),
            opts,
            &mut usage,
        );
        gdal_sys::GDALWarpAppOptionsFree(opts);
        if h.is_null() {
            let msg = std::ffi::CStr::from_ptr(gdal_sys::CPLGetLastErrorMsg())
                .to_string_lossy()
                .into_owned();
            return Err(format!(
                "GDAL warp of tile {}/{}/{}: {msg}",
                tile.z, tile.x, tile.y
            ));
        }
        gdal::Dataset::from_c_dataset(h)
    };
    let band = ds.rasterband(1).map_err(|e| e.to_string())?;
    let buf = band
        .read_as::<f32>((0, 0), (TILE_SIZE, TILE_SIZE), (TILE_SIZE, TILE_SIZE), None)
        .map_err(|e| e.to_string())?;
    let mut data = buf.data().to_vec();
    if !vertical.is_identity() {
        for v in data.iter_mut().filter(|v| v.is_finite()) {
            *v = vertical.to_metres(*v as f64) as f32;
        }
    }
    Ok(data)
}
