#!/usr/bin/python3
"""Self-tests of the judge on synthetic DEMs with answers known in closed form.

1. A plateau edge on the central meridian of UTM 32N (no meridian
   convergence): a flat plain at 0 m and, from northing D on, a plateau at
   100 m. Looking true north from 1.7 m, the plateau's near edge is the
   skyline; a point of it on column u lies at ray distance D sqrt(1 + u^2), so
   its row is cy - f (98.3 - drop(D sqrt(1+u^2))) / D in every column.
2. True north off the central meridian: on UTM 32N at 12 deg E (3 deg east of
   the central meridian, grid convergence about 2.2 deg) the centre column of
   a heading-0 camera must follow the meridian (constant longitude), and of a
   heading-90 camera the geodesic east (Vincenty vs the UTM distance / scale).
3. Heading and image orientation: a single hill to the east of the eye with
   heading 80 appears right of the image centre, with heading 100 left of it,
   and above the centre row by f (150 - 1.7 - drop) / 5000 px.
Exit status 1 on any failure.
"""
import math
import os
import sys
import tempfile

import numpy as np
from osgeo import gdal, osr

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import judge  # noqa: E402

gdal.UseExceptions()


def make_dem(path, arr, gt, epsg, nodata=None):
    ds = gdal.GetDriverByName("GTiff").Create(path, arr.shape[1], arr.shape[0], 1, gdal.GDT_Float32)
    ds.SetGeoTransform(gt)
    s = osr.SpatialReference()
    s.ImportFromEPSG(epsg)
    ds.SetProjection(s.ExportToWkt())
    b = ds.GetRasterBand(1)
    if nodata is not None:
        b.SetNoDataValue(nodata)
    b.WriteArray(arr)
    ds = None


def main():
    work = tempfile.mkdtemp(prefix="fidelity-self-")
    fails = []
    # 1. plateau on the central meridian of UTM 32N (x = 500000)
    cell = 50.0
    n = 200
    x0, y0 = 500000.0 - n / 2 * cell, 5200000.0 + n * cell
    gt = (x0, cell, 0, y0, 0, -cell)
    rows_y = y0 - (np.arange(n) + 0.5) * cell  # cell centre northings
    eye_y = 5200000.0 + 40 * cell + 0.3 * cell  # the eye between cell centres
    D_target = 2000.0
    arr = np.zeros((n, n), np.float32)
    first = None
    for j in range(n):
        if rows_y[j] >= eye_y + D_target:
            arr[j, :] = 100.0
    # the plateau's first (southernmost) cell centre row at or beyond eye + D
    plateau_y = rows_y[rows_y >= eye_y + D_target].min()
    D = plateau_y - eye_y
    p = os.path.join(work, "plateau.tif")
    make_dem(p, arr, gt, 32632)
    dem = judge.Dem(p)
    lon, lat, _ = dem.to_ll.TransformPoint(500000.0, eye_y)
    r = judge.render(dem, lon, lat, 1.7, 0.0, 40.0, 320, 180)
    u = (np.arange(320) + 0.5 - r.cx) / r.f
    s_ray = D * np.sqrt(1 + u ** 2)
    R = judge.earth_radius(lat)
    drop = (1 - judge.K_REFRACTION) * s_ray ** 2 / (2 * R)
    expect = r.cy - r.f * (100.0 - drop - 1.7) / D
    err = np.abs(r.sky_row - expect)
    # the ray reaches the plateau between samples; the crest is where the bilinear ramp ends
    tol = r.f * (100.0 / D) * (r.step / D) + 0.05
    print("plateau skyline: max |row - closed form| = %.3f px (tolerance %.3f px), depth %.1f vs %.1f m" % (
        np.nanmax(err), tol, np.nanmedian(r.sky_depth / np.sqrt(1 + u ** 2)), D))
    if not np.nanmax(err) <= tol:
        fails.append("plateau skyline rows")
    if abs(np.nanmedian(r.sky_depth / np.sqrt(1 + u ** 2)) - D) > r.step:
        fails.append("plateau skyline depth")
    if not (r.sky_row < r.cy).all():
        fails.append("plateau not above the image centre (image upside down?)")

    # 2. true north off the central meridian
    x0 = 740000.0  # about 12 deg E at 47 N in zone 32
    gt = (x0, cell, 0, 5230000.0, 0, -cell)
    p = os.path.join(work, "flat.tif")
    make_dem(p, np.zeros((n, n), np.float32), gt, 32632)
    dem = judge.Dem(p)
    lon, lat = dem.pixel_to_ll(n / 2, n / 2)
    for heading in (0.0, 90.0):
        lat2, lon2 = judge.vincenty_direct(lat, lon, heading, 4000.0)
        if heading == 0.0:
            ok = abs(float(lon2) - lon) < 1e-9
            print("heading 0 at %.2f E: the geodesic keeps longitude (dlon %.1e deg)" % (lon, float(lon2) - lon))
        else:
            X1, Y1 = dem.ll_to_crs(np.array([lon]), np.array([lat]))
            X2, Y2 = dem.ll_to_crs(np.array([float(lon2)]), np.array([float(lat2)]))
            # UTM point scale factor at the midpoint
            k0 = 0.9996
            xm = (X1[0] + X2[0]) / 2 - 500000.0
            k = k0 * (1 + xm ** 2 / (2 * (k0 * 6371000.0) ** 2))
            d_utm = math.hypot(X2[0] - X1[0], Y2[0] - Y1[0]) / k
            conv = math.degrees(math.atan2(X2[0] - X1[0], Y2[0] - Y1[0]))
            ok = abs(d_utm - 4000.0) < 0.5 and abs(conv - 90.0) > 1.0
            print("heading 90: UTM distance / scale %.2f m (4000), grid azimuth %.2f deg (grid convergence applied)" % (d_utm, conv))
        if not ok:
            fails.append("geodesic heading %g" % heading)

    # 3. a hill to the east; heading 80 puts it right of centre, heading 100 left
    arr = np.zeros((n, n), np.float32)
    jj, ii = np.mgrid[0:n, 0:n]
    arr += 150.0 * np.exp(-(((ii - 150) * cell) ** 2 + ((jj - 100) * cell) ** 2) / (2 * 300.0 ** 2))
    gt = (500000.0 - 100 * cell, cell, 0, 5300000.0, 0, -cell)
    p = os.path.join(work, "hill.tif")
    make_dem(p, arr, gt, 32632)
    dem = judge.Dem(p)
    lon, lat = dem.pixel_to_ll(50.5, 100.5)
    for heading, side in ((80.0, "right"), (100.0, "left")):
        r = judge.render(dem, lon, lat, dem.height_ll(lon, lat) + 1.7, heading, 60.0, 320, 180)
        c = int(np.nanargmin(r.sky_row))
        ok = (c > 160) if side == "right" else (c < 160)
        # 148 m at 5 km with f = 277 px: atan(148 / 5000) f = 8.2 px above the centre row
        ok = ok and abs((r.cy - r.sky_row[c]) - r.f * (150.0 - 1.7 - (1 - judge.K_REFRACTION) * 5000.0 ** 2 / (2 * judge.earth_radius(lat))) / 5000.0) < 0.6
        print("hill east, heading %g: highest skyline at column %d (%s of centre expected), row %.1f" % (heading, c, side, r.sky_row[c]))
        if not ok:
            fails.append("hill heading %g" % heading)
    os.system("rm -rf " + work)
    if fails:
        print("selftest FAILED: " + ", ".join(fails))
        sys.exit(1)
    print("selftest ok")


if __name__ == "__main__":
    main()
