#!/usr/bin/python3
"""Control curve: `demsketch correct` against what GIS users do today.

Today's workflow: burn the curve's heights into the DEM with
`gdal_rasterize -3d`, blank the cells within the influence distance around
it, and fill them back with `gdal_fillnodata.py` (inverse distance from the
hole's edge and the burnt line). Both are measured the same way: the largest
|DEM - z| along the curve (bilinear, every tenth of a cell) and the largest
step of the height change at the edge of the influence (|dz(c) - dz(n)| over
4-neighbour pairs with c inside and n outside the influence distance).

Usage: tools/compare_control_curve.py [DEM] [CURVE.geojson] [DEMSKETCH]
Prints a Markdown table (docs/corrections.md holds the one for the bundled
fixture). Needs GDAL's Python bindings and numpy (/usr/bin/python3).
"""
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from osgeo import gdal

dem = sys.argv[1] if len(sys.argv) > 1 else "fixtures/vinschgau_250m_utm32n.tif"
curve_path = sys.argv[2] if len(sys.argv) > 2 else "fixtures/corrections/vinschgau_embankment.geojson"
exe = sys.argv[3] if len(sys.argv) > 3 else "target/release/demsketch"

feature = json.load(open(curve_path))["features"][0]
influence = feature["properties"]["influence_m"]
coords = feature["geometry"]["coordinates"]

src = gdal.Open(dem)
gt = src.GetGeoTransform()
h0 = src.ReadAsArray().astype(np.float64)
nd = src.GetRasterBand(1).GetNoDataValue()
cell = gt[1]
px = [((x - gt[0]) / gt[1], (y - gt[3]) / gt[5], z) for x, y, z in coords]

# Distance (m) from every cell centre to the curve.
rows, cols = np.mgrid[0 : h0.shape[0], 0 : h0.shape[1]]
cx, cy = cols + 0.5, rows + 0.5
dist = np.full(h0.shape, np.inf)
for (ax, ay, _), (bx, by, _) in zip(px, px[1:]):
    dx, dy = bx - ax, by - ay
    t = np.clip(((cx - ax) * dx + (cy - ay) * dy) / (dx * dx + dy * dy), 0, 1)
    dist = np.minimum(dist, np.hypot(cx - ax - t * dx, cy - ay - t * dy) * cell)
inside = dist <= influence


def bilinear(a, x, y):
    x, y = x - 0.5, y - 0.5
    c, r = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - c, y - r
    return (a[r, c] * (1 - fx) * (1 - fy) + a[r, c + 1] * fx * (1 - fy)
            + a[r + 1, c] * (1 - fx) * fy + a[r + 1, c + 1] * fx * fy)


def measure(path):
    a = gdal.Open(path).ReadAsArray().astype(np.float64)
    worst = 0.0
    for (ax, ay, az), (bx, by, bz) in zip(px, px[1:]):
        n = int(np.ceil(np.hypot(bx - ax, by - ay) / 0.1))
        for k in range(n + 1):
            t = k / n
            worst = max(worst, abs(bilinear(a, ax + t * (bx - ax), ay + t * (by - ay)) - (az + t * (bz - az))))
    dz = a - h0
    step, anywhere = 0.0, 0.0
    for sl_a, sl_b in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                       ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
        edge = inside[sl_a] != inside[sl_b]
        jump = np.abs(dz[sl_a] - dz[sl_b])
        valid = np.isfinite(jump)
        step = max(step, float(np.max(jump[edge & valid])))
        anywhere = max(anywhere, float(np.max(jump[valid & (inside[sl_a] | inside[sl_b])])))
    outside_changed = int(np.count_nonzero((a != h0) & ~inside))
    return worst, step, anywhere, outside_changed


tmp = tempfile.mkdtemp()
ours = os.path.join(tmp, "demsketch.tif")
subprocess.run([exe, "-q", "correct", dem, "--features", curve_path, "--out", ours], check=True)

theirs = os.path.join(tmp, "gdal.tif")
gdal.Translate(theirs, dem, outputType=gdal.GDT_Float32)
ds = gdal.Open(theirs, gdal.GA_Update)
a = ds.ReadAsArray()
a[inside] = nd
ds.GetRasterBand(1).WriteArray(a)
ds = None
subprocess.run(["gdal_rasterize", "-q", "-3d", curve_path, theirs], check=True)
filled = os.path.join(tmp, "gdal_filled.tif")
md = str(int(np.ceil(influence / cell)) + 2)
subprocess.run(["gdal_fillnodata.py", "-q", "-md", md, theirs, filled], check=True)

print(f"Curve {curve_path} on {dem}, influence {influence} m, cells {cell} m.\n")
print("| method | max \\|DEM - z\\| on the curve (m) | max step of dz at the influence edge (m) | max step of dz anywhere (m) | cells changed beyond the influence |")
print("| --- | --- | --- | --- | --- |")
for name, path in (("`demsketch correct`", ours),
                   (f"`gdal_rasterize -3d` + `gdal_fillnodata.py -md {md}`", filled)):
    w, s, m, o = measure(path)
    print(f"| {name} | {w:.3f} | {s:.2f} | {m:.2f} | {o} |")
