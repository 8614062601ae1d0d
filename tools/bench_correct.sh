#!/bin/sh
# Times `demsketch correct` on a 4096 x 4096 DEM (the Vinschgau fixture
# resampled bilinearly, Float32, tiled DEFLATE, about 15 x 12 m cells) with
# 10 lakes (octagons 80 cells across) and a 20 km river (60 m wide, 100
# segments). Prints demsketch's own stage times (-v) for three runs.
# Needs GDAL's tools and /usr/bin/python3 with osgeo; run after
# `cargo build --release`.
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
gt = gdal.Open(f"{tmp}/big.tif").GetGeoTransform()
def crs(c, r):
    return [gt[0] + c * gt[1], gt[3] + r * gt[5]]
feats = []
for k in range(10):
    cx, cy, R = 400 + (k % 5) * 700, 600 + (k // 5) * 1500, 40
    ring = [crs(cx + R * math.cos(a * math.pi / 8), cy + R * math.sin(a * math.pi / 8)) for a in range(16)]
    ring.append(ring[0])
    feats.append({"type": "Feature", "properties": {"kind": "lake", "name": f"lake{k}"},
                  "geometry": {"type": "Polygon", "coordinates": [ring]}})
pts = [crs(1400 + i * 13, 1600 + 200 * math.sin(i / 10)) for i in range(101)]
feats.append({"type": "Feature", "properties": {"kind": "river", "name": "long", "width_m": 60, "flow": "auto"},
              "geometry": {"type": "LineString", "coordinates": pts}})
json.dump({"type": "FeatureCollection", "features": feats,
           "crs": {"type": "name", "properties": {"name": "EPSG:32632"}}},
          open(f"{tmp}/big.geojson", "w"))
PY
for i in 1 2 3; do
    "$exe" -v correct "$tmp/big.tif" --features "$tmp/big.geojson" --out "$tmp/out$i.tif" 2>&1 | grep -v '^feature'
done
