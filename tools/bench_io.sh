#!/usr/bin/env bash
# Read and write throughput of demsketch's tile layer against GDAL on the same
# 8192 x 8192 Float32 tiled Deflate (predictor 3) DEM, in one run.
#
#   bash tools/bench_io.sh [WORKDIR]      (default /tmp/demsketch-bench-io)
#
# The DEM is made from fixtures/zion_srtm_utm12n.tif by cubic resampling.
# Read: GDAL = gdal_translate to the in-memory driver (whole raster decoded),
# with and without GDAL_NUM_THREADS=ALL_CPUS; demsketch = Dem::open +
# read_height_map of the full window (examples/raster_io.rs).
# Write: GDAL = gdal_translate to a new tiled Deflate+predictor 3 GeoTIFF;
# demsketch = write_back of the whole window (every cell changed) to a new
# file with the source's layout. Each timing is the best of 3.
set -euo pipefail
cd "$(dirname "$0")/.."
W="${1:-/tmp/demsketch-bench-io}"
mkdir -p "$W"
DEM="$W/dem8k.tif"
if [ ! -f "$DEM" ]; then
  gdal_translate -q -outsize 8192 8192 -r cubic -ot Float32 \
    -co TILED=YES -co COMPRESS=DEFLATE -co PREDICTOR=3 \
    fixtures/zion_srtm_utm12n.tif "$DEM"
fi
cargo build --release --quiet --example raster_io
best() { # best of 3: "wall_s cpu_s" (cpu = user + sys) of a command
  local b="999999 0"
  for _ in 1 2 3; do
    /usr/bin/time -f "%e %U %S" -o "$W/time.txt" "$@" >/dev/null 2>&1
    b=$(python3 -c "w,u,s=map(float,open('$W/time.txt').read().split()[-3:]); bw,bc=map(float,'$b'.split()); print(f'{w} {u+s}' if w<bw else '$b')")
  done
  echo "$b"
}
CO=(-co TILED=YES -co COMPRESS=DEFLATE -co PREDICTOR=3)
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), load $(cut -d' ' -f1-3 /proc/loadavg)"
echo "file: $DEM ($(du -h "$DEM" | cut -f1), $(gdalinfo "$DEM" | grep -m1 'Size is'))"
g1=$(best gdal_translate -q -of MEM "$DEM" /dev/null)
g2=$(best env GDAL_NUM_THREADS=ALL_CPUS gdal_translate -q -of MEM "$DEM" /dev/null)
gw1=$(best gdal_translate -q "${CO[@]}" "$DEM" "$W/gdal_out.tif")
gw2=$(best gdal_translate -q "${CO[@]}" -co NUM_THREADS=ALL_CPUS "$DEM" "$W/gdal_out.tif")
ours=$(./target/release/examples/raster_io "$DEM" "$W/ours_out.tif")
echo "$ours"
oread=$(best ./target/release/examples/raster_io "$DEM" "$W/ours_out.tif" --read-only)
python3 - "$g1" "$g2" "$gw1" "$gw2" "$oread" "$ours" <<'PY'
import json, sys
g1, g2, gw1, gw2, oread = (tuple(map(float, a.split())) for a in sys.argv[1:6])
o = json.loads(sys.argv[6])
mc = o["cells"] / 1e6
# The read-only example process reads 3 times; its CPU time per read is a third.
rows = [
    ("read", "GDAL gdal_translate -of MEM, 1 thread", g1[0], g1[1]),
    ("read", "GDAL gdal_translate -of MEM, GDAL_NUM_THREADS=ALL_CPUS", g2[0], g2[1]),
    ("read", f"demsketch Dem::read_height_map ({o['threads']} threads)", o["read_best_s"], oread[1] / 3),
    ("write", "GDAL gdal_translate, 1 thread", gw1[0], gw1[1]),
    ("write", "GDAL gdal_translate, NUM_THREADS=ALL_CPUS", gw2[0], gw2[1]),
    ("write", "demsketch Dem::write_back, every cell changed", o["write_s"], float("nan")),
]
print("| op | tool | wall s | CPU s | Mcells/s (wall) |")
print("|---|---|---|---|---|")
for op, tool, w, c in rows:
    print(f"| {op} | {tool} | {w:.2f} | {c:.2f} | {mc / w:.0f} |")
PY
