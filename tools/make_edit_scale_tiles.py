#!/usr/bin/python3
"""Tile sets for tools/bench_edit_scale.sh (issue 15, item 1): the Zion
fixture (83.5 m, UTM 12N) resampled (cubic) to 15 m cells and repeated
mirrored (period 2W x 2H: seamless, real-looking terrain everywhere) over
a 32 x 32 set of 1024 x 1024 Float32 GeoTIFF tiles (Deflate, floating-point
predictor), and the same set's central 3 x 3 tiles as the small set: the
same cells, the same CRS coordinates, so one viewpoint and one sketch serve
both. The fixture itself (not a mirror) lies under the eye.

With --overviews every tile also gets internal overviews 2, 4, 8 and 16
times coarser whose cells are the maxima of the cells they cover (GDAL 3.6
has no MAX resampling for overviews: they are made NEAREST, then written
with the maxima), the same cells the level of detail's block maxima
compute (src/raster/block_max.rs), so that a view reads the same rings from
either.

    /usr/bin/python3 tools/make_edit_scale_tiles.py FIXTURE OUTDIR [--overviews]
"""
import os
import sys

import numpy as np
from osgeo import gdal

gdal.UseExceptions()
fixture, out = sys.argv[1], sys.argv[2]
overviews = "--overviews" in sys.argv[3:]
LEVELS = [2, 4, 8, 16]
CELL, TILE, N, SMALL = 15.0, 1024, 32, 3
big, small = os.path.join(out, "t32"), os.path.join(out, "t3")
if os.path.exists(os.path.join(out, "done")):
    sys.exit(0)
os.makedirs(big, exist_ok=True)
os.makedirs(small, exist_ok=True)
src = gdal.Open(fixture)
gt0 = src.GetGeoTransform()
w = int(round(src.RasterXSize * gt0[1] / CELL))
h = int(round(src.RasterYSize * -gt0[5] / CELL))
res = gdal.Warp("", src, format="MEM", width=w, height=h, resampleAlg="cubic",
                outputType=gdal.GDT_Float32, dstNodata=None, srcNodata=65535)
z = res.GetRasterBand(1).ReadAsArray().astype(np.float32)
# The fixture's nodata (65535, its reprojected corners) must not pass as
# heights: left in, it stood as 65 km walls along the mirror seams (the
# "vertical lines in the sky" of a 100 km view, which hid everything
# beyond 18 km).
valid = np.isfinite(z) & (z > 0) & (z < 65535)
z = np.where(valid, z, np.median(z[valid])).astype(np.float32)
# One period: the fixture and its mirrors.
top = np.concatenate([z, z[:, ::-1]], axis=1)
period = np.concatenate([top, top[::-1, :]], axis=0)
ph, pw = period.shape
# The small set is tiles 15..17 of the big one; its centre (big cell 16896)
# falls on the fixture's centre.
centre = (N // 2 - 1) * TILE + (SMALL * TILE) // 2
c_off, r_off = centre - w // 2, centre - h // 2
# The CRS: the fixture's centre at the big set's centre cell.
x0 = gt0[0] + gt0[1] * src.RasterXSize / 2 - centre * CELL
y0 = gt0[3] + gt0[5] * src.RasterYSize / 2 + centre * CELL
srs = src.GetProjection()
drv = gdal.GetDriverByName("GTiff")
opts = ["TILED=YES", "COMPRESS=DEFLATE", "PREDICTOR=3", "ZLEVEL=1"]
for tr in range(N):
    rows = (np.arange(tr * TILE, (tr + 1) * TILE) - r_off) % ph
    for tc in range(N):
        cols = (np.arange(tc * TILE, (tc + 1) * TILE) - c_off) % pw
        a = period[np.ix_(rows, cols)]
        name = f"tile_{tr:02d}_{tc:02d}.tif"
        path = os.path.join(big, name)
        ds = drv.Create(path, TILE, TILE, 1, gdal.GDT_Float32, opts)
        ds.SetGeoTransform((x0 + tc * TILE * CELL, CELL, 0, y0 - tr * TILE * CELL, 0, -CELL))
        ds.SetProjection(srs)
        ds.GetRasterBand(1).WriteArray(a)
        if overviews:
            ds.BuildOverviews("NEAREST", LEVELS)
            band = ds.GetRasterBand(1)
            for i, f in enumerate(LEVELS):
                m = a.reshape(TILE // f, f, TILE // f, f).max(axis=(1, 3))
                band.GetOverview(i).WriteArray(m)
        ds = None
        lo, hi = N // 2 - 1, N // 2 - 1 + SMALL
        if lo <= tr < hi and lo <= tc < hi:
            os.link(path, os.path.join(small, name))
open(os.path.join(out, "done"), "w").close()
# The eye: the big set's centre cell, for the bench.
ex, ey = x0 + (centre + 0.5) * CELL, y0 - (centre + 0.5) * CELL
print(f"centre {ex} {ey}")
