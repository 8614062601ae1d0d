#!/usr/bin/env bash
# Opening a directory of 128 x 128 GeoTIFF tiles of 16 x 16 cells (issue 15,
# item 1: "opening 16,384 tiles under 0.2 s"), side by side: `demsketch info
# --no-stats` of two builds, interleaved (the whole process: start-up, the
# open, the listing it prints), and `Dem::open` alone in this build
# (examples/open_dem.rs). The directory is made once by GDAL.
#
#   bash tools/bench_tile_open.sh [OTHER_DEMSKETCH] [RUNS]
#
# OTHER_DEMSKETCH: the build to compare with (e.g. main's
# target/release/demsketch copied aside); without it only this build runs.
set -euo pipefail
cd "$(dirname "$0")/.."
other=${1:-}
runs=${2:-5}
dir=${DEMSKETCH_BENCH_DIR:-/tmp/demsketch-bench-tiles128}
if [ ! -f "$dir/t_127_127.tif" ]; then
  mkdir -p "$dir"
  /usr/bin/python3 - "$dir" <<'PY'
import os, sys
import numpy as np
from osgeo import gdal, osr
out = sys.argv[1]
srs = osr.SpatialReference(); srs.ImportFromEPSG(32612)
drv = gdal.GetDriverByName("GTiff")
for r in range(128):
    for c in range(128):
        ds = drv.Create(os.path.join(out, f"t_{r:03d}_{c:03d}.tif"), 16, 16, 1, gdal.GDT_Float32)
        ds.SetGeoTransform([300000 + c * 480.0, 30, 0, 4200000 - r * 480.0, 0, -30])
        ds.SetProjection(srs.ExportToWkt())
        b = ds.GetRasterBand(1); b.SetNoDataValue(-9999)
        b.WriteArray(np.full((16, 16), 1000 + 10 * r + c, np.float32))
        ds = None
PY
fi
cargo build --release --locked --example open_dem >/dev/null
this=target/release/demsketch
echo "machine: $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
for i in $(seq "$runs"); do
  for bin in $other $this; do
    /usr/bin/time -f "$bin: info --no-stats %e s wall, %U s user, %S s sys, %M KB" \
      "$bin" info --no-stats "$dir" >/dev/null
  done
done 2>&1
target/release/examples/open_dem "$dir" "$runs"
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
