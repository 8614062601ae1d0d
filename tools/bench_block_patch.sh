#!/usr/bin/env bash
# Write time of a small edit (750 changed cells) of a 40 M-cell single-file
# tiled GeoTIFF: block patch (only the touched 256 x 256 blocks re-encoded,
# the rest copied as compressed bytes) against a whole re-encode of the same
# file (the write path before issue 12, forced here with -co), best of 3.
# Then checks with GDAL's Python bindings that both outputs hold the same
# pixels, and that they equal the input outside the edit.
#
#   bash tools/bench_block_patch.sh [WORKDIR]   (default /tmp/demsketch-bench-patch)
#
# The DEM: fixtures/zion_srtm_utm12n.tif, gdal_translate -outsize 7300 5480
# (40.0 M cells), Float32, DEFLATE, 256 x 256 tiles.
set -euo pipefail
cd "$(dirname "$0")/.."
W="${1:-/tmp/demsketch-bench-patch}"
mkdir -p "$W"
DEM="$W/dem40m.tif"
if [ ! -f "$DEM" ]; then
  gdal_translate -q -outsize 7300 5480 -r bilinear -ot Float32 \
    -co TILED=YES -co BLOCKXSIZE=256 -co BLOCKYSIZE=256 -co COMPRESS=DEFLATE \
    fixtures/zion_srtm_utm12n.tif "$DEM"
fi
cargo build --release --quiet --example bench_block_patch
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "file: $DEM ($(du -h "$DEM" | cut -f1), $(gdalinfo "$DEM" | grep -m1 'Size is'))"
./target/release/examples/bench_block_patch "$DEM" "$W"
/usr/bin/python3 - "$DEM" "$W/patched.tif" "$W/reencoded.tif" <<'PY'
import sys
import numpy as np
from osgeo import gdal
gdal.UseExceptions()
ds = [gdal.Open(f) for f in sys.argv[1:4]]
a, p, r = (d.GetRasterBand(1).ReadAsArray() for d in ds)
same = np.array_equal(p, r, equal_nan=True)
diff = np.argwhere(~((p == a) | (np.isnan(p) & np.isnan(a))))
print(f"patched == re-encoded (every pixel, GDAL): {same}; cells differing from the input: {len(diff)}"
      + (f" in rows {diff[:,0].min()}..{diff[:,0].max()}, cols {diff[:,1].min()}..{diff[:,1].max()}" if len(diff) else ""))
sys.exit(0 if same else 1)
PY
ls -l "$W/patched.tif" "$W/reencoded.tif" | awk '{print $5, $9}'
