#!/bin/sh
# Tile export throughput: `demsketch export tiles` against `gdal2tiles.py`
# (Debian's gdal-bin) on the same DEM and zooms, same resampling (bilinear),
# both with 2 processes/threads, one run after the other. DEM: the
# Vinschgau fixture resampled to 2016 x 1552 (31 m cells, Float32, UTM
# 32N), zooms 8-13. Prints tiles written and tiles/s of each. gdal2tiles.py
# gets the DEM scaled to Byte (it tiles nothing else).
# Run after `cargo build --release`.
set -eu
exe=${1:-target/release/demsketch}
zooms=${ZOOMS:-8-13}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
gdal_translate -q -outsize 800% 800% -r bilinear -ot Float32 -co TILED=YES \
    -co COMPRESS=DEFLATE fixtures/vinschgau_250m_utm32n.tif "$tmp/dem.tif"
count() { find "$1" -name '*.png' | wc -l; }
now() { date +%s.%N; }
for enc in terrain-rgb terrarium; do
    t0=$(now)
    RAYON_NUM_THREADS=2 "$exe" -q export tiles "$tmp/dem.tif" --encoding $enc --zoom "$zooms" --out "$tmp/ds_$enc"
    t1=$(now)
    n=$(count "$tmp/ds_$enc")
    echo "demsketch export tiles ($enc): $n tiles in $(echo "$t1 - $t0" | bc) s: $(echo "scale=1; $n / ($t1 - $t0)" | bc) tiles/s"
done
if command -v gdal2tiles.py >/dev/null; then
    # gdal2tiles.py tiles Byte rasters only: the same DEM scaled to Byte
    # on the fly by a VRT, as its own message advises.
    gdal_translate -q -of VRT -ot Byte -scale "$tmp/dem.tif" "$tmp/dem_byte.vrt"
    t0=$(now)
    gdal2tiles.py -q --xyz -z "$zooms" -r bilinear -w none --processes=2 "$tmp/dem_byte.vrt" "$tmp/g2t" >/dev/null 2>&1
    t1=$(now)
    n=$(count "$tmp/g2t")
    echo "gdal2tiles.py --xyz -r bilinear --processes=2: $n tiles in $(echo "$t1 - $t0" | bc) s: $(echo "scale=1; $n / ($t1 - $t0)" | bc) tiles/s"
else
    echo "gdal2tiles.py not installed"
fi
