#!/usr/bin/env bash
# `demsketch view` with --features on a large DEM (issue 15, item 1: "view
# with features on 8192^2 under 1 s"), side by side with another build,
# interleaved. The DEMs: fixtures/zion_srtm_utm12n.tif resampled (bilinear)
# to 8192 x 8192 and 4096 x 4096 Float32, tiled, Deflate with the
# floating-point predictor, made once. Two views, 800 x 450, hfov 60,
# pitch 1, no --max-distance: from the middle looking north ("centre") and
# from near the south-west corner looking north-east across the DEM
# ("corner", whose wedge's box is most of the DEM).
#
#   bash tools/bench_view_wedge.sh OTHER_DEMSKETCH [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
other=$1
runs=${2:-3}
dir=${DEMSKETCH_BENCH_DIR:-/tmp/demsketch-bench-view}
mkdir -p "$dir/out"
for n in 8192 4096; do
  [ -f "$dir/zion$n.tif" ] || gdal_translate -q -outsize $n $n -r bilinear -ot Float32 \
    -co TILED=YES -co COMPRESS=DEFLATE -co PREDICTOR=3 fixtures/zion_srtm_utm12n.tif "$dir/zion$n.tif"
done
cargo build --release --locked >/dev/null
this=target/release/demsketch
echo "machine: $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
for n in 8192 4096; do
  for vp in "centre|--lon -113.06 --lat 37.32 --heading 0" "corner|--lon -113.23 --lat 37.14 --heading 45"; do
    name=${vp%%|*}
    # shellcheck disable=SC2086
    for i in $(seq "$runs"); do
      for bin in "$other" "$this"; do
        /usr/bin/time -f "zion$n $name $bin: %e s wall, %U s user, %S s sys, %M KB" \
          "$bin" view "$dir/zion$n.tif" ${vp#*|} --pitch 1 --size 800x450 \
          --out "$dir/out/v.png" --features "$dir/out/f.geojson"
      done
    done
  done
done 2>&1
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
