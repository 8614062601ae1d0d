#!/bin/sh
# Times `demsketch correct` on one control curve with 5 cross-sections on a
# 4096 x 4096 DEM (the Vinschgau fixture resampled bilinearly, Float32,
# tiled DEFLATE, about 15 x 12 m cells, as tools/bench_correct.sh): the
# curve has 3 vertices over about 4.6 km (heights the terrain's + 20 m), the
# sections cross it at right angles, 30 cells to each side, 0.5 m down per
# cell; influence 600 m. Prints demsketch's own stage times (-v) for three
# runs. Needs GDAL's tools and /usr/bin/python3 with osgeo; run after
# `cargo build --release`. Usage: tools/bench_control_curve.sh [EXE]
set -eu
exe=${1:-target/release/demsketch}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
gdal_translate -q -outsize 4096 4096 -r bilinear -ot Float32 -co TILED=YES \
    -co COMPRESS=DEFLATE fixtures/vinschgau_250m_utm32n.tif "$tmp/big.tif"
/usr/bin/python3 - "$tmp" <<'PY'
import json, math, sys
from osgeo import gdal
tmp = sys.argv[1]
ds = gdal.Open(f"{tmp}/big.tif")
gt = ds.GetGeoTransform()
a = ds.GetRasterBand(1).ReadAsArray()
def crs(c, r):
    return [gt[0] + c * gt[1], gt[3] + r * gt[5]]
px = [[2400.3, 1000.7], [2560.1, 1060.2], [2720.6, 1030.4]]
z = [float(a[int(r), int(c)]) + 20.0 for c, r in px]
feats = [{"type": "Feature", "properties": {"kind": "control_curve", "name": "road", "influence_m": 600},
          "geometry": {"type": "LineString", "coordinates": [crs(*p) + [h] for p, h in zip(px, z)]}}]
for j, (k, t) in enumerate([(0, 0.2), (0, 0.6), (1, 0.3), (1, 0.6), (1, 0.9)]):
    (c0, r0), (c1, r1) = px[k], px[k + 1]
    L = math.hypot(c1 - c0, r1 - r0)
    n = [-(r1 - r0) / L, (c1 - c0) / L]
    c = [c0 + t * (c1 - c0), r0 + t * (r1 - r0)]
    zc = z[k] + t * (z[k + 1] - z[k])
    sec = [crs(c[0] + n[0] * d, c[1] + n[1] * d) + [zc - 0.5 * d] for d in (-30, 0, 30)]
    feats.append({"type": "Feature", "properties": {"kind": "cross_section", "name": f"s{j}", "control_curve": "road"},
                  "geometry": {"type": "LineString", "coordinates": sec}})
json.dump({"type": "FeatureCollection", "features": feats,
           "crs": {"type": "name", "properties": {"name": "EPSG:32632"}}},
          open(f"{tmp}/curve.geojson", "w"))
PY
for i in 1 2 3; do
    "$exe" -v correct "$tmp/big.tif" --features "$tmp/curve.geojson" --out "$tmp/out$i.tif" \
        --report "$tmp/r$i.json" 2>&1 | grep -v '^feature'
    /usr/bin/python3 -c "import json,sys; f=json.load(open(sys.argv[1]))['corrections'][0]; print('curve error', round(f['max_curve_error_m'], 4), 'm, section error', round(f['max_section_error_m'], 4), 'm, cells changed', f['cells_changed'])" "$tmp/r$i.json"
done
