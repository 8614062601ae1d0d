#!/usr/bin/env bash
# Rebuilds the seed corpus of the GeoTIFF fuzz target (fuzz/corpus/geotiff_decode)
# from the fixtures: small crops (a few KB each) in the encodings and layouts
# the native decoder reads.
set -euo pipefail
cd "$(dirname "$0")/.."
out=fuzz/corpus/geotiff_decode
rm -rf "$out" && mkdir -p "$out"
export GDAL_PAM_ENABLED=NO
t() { gdal_translate -q -srcwin "$2" "$3" 24 20 "${@:5}" "fixtures/$1" "$out/$4.tif"; }
t zion_srtm_utm12n.tif 200 200 zion_none_strips -co BLOCKYSIZE=3
t zion_srtm_utm12n.tif 200 200 zion_deflate_tiled_pred2 -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16 -co COMPRESS=DEFLATE -co PREDICTOR=2
t zion_srtm_utm12n.tif 200 200 zion_lzw -co COMPRESS=LZW
t zion_srtm_utm12n.tif 200 200 zion_zstd_tiled -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16 -co COMPRESS=ZSTD
t zion_srtm_utm12n.tif 200 200 zion_packbits -co COMPRESS=PACKBITS
t zion_srtm_utm12n.tif 200 200 zion_bigendian -co ENDIANNESS=BIG -co COMPRESS=DEFLATE
t zion_srtm_utm12n.tif 200 200 zion_bigtiff -co BIGTIFF=YES -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16
t zion_srtm_utm12n.tif 200 200 zion_int32_scaled -ot Int32 -scale 0 1 0 10 -a_scale 0.1 -co COMPRESS=DEFLATE
t nz_1km_nan_nodata.tif 300 300 nz_float32_pred3 -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16 -co COMPRESS=DEFLATE -co PREDICTOR=3
t nz_1km_nan_nodata.tif 300 300 nz_float64_lzw_pred3 -ot Float64 -co COMPRESS=LZW -co PREDICTOR=3
t texas_srtm90m_tiled_int16.tif 100 100 texas_int16_tiled -co TILED=YES -co BLOCKXSIZE=16 -co BLOCKYSIZE=16 -co COMPRESS=DEFLATE
t arenal_aster30m_epsg4326.tif 50 50 arenal_geographic_lzw_pred2 -co COMPRESS=LZW -co PREDICTOR=2
t vinschgau_250m_utm32n.tif 50 50 vinschgau_pixel_is_point -mo AREA_OR_POINT=Point
t zion_srtm_utm12n.tif 200 200 zion_feet_compound -ot Float32 -a_srs EPSG:32612+6360
gdalwarp -q -overwrite -t_srs '+proj=lcc +lat_1=33 +lat_2=45 +lat_0=39 +lon_0=-96 +datum=NAD83 +units=m' \
    "$out/zion_none_strips.tif" "$out/zion_user_defined_lcc.tif"
cp "$out/zion_deflate_tiled_pred2.tif" "$out/zion_with_overviews.tif"
gdaladdo -q -r nearest "$out/zion_with_overviews.tif" 2
ls -l "$out"
