#!/usr/bin/python3
"""Pictures of `demsketch correct --renders` for the user guide, one per
tool: docs/guide/corrections_{lake,river,control_curve,breakline}.png, each
the map before, the map after (hillshade, feature drawn) and the height
change side by side. The lake, river and control curve are the features of
fixtures/corrections/vinschgau_example.geojson, one at a time, on the
bundled 250 m fixture; the breakline is the blurred roof of
tests/correct_breakline.rs with a hard breakline along its ridge.

    /usr/bin/python3 tools/correct_pictures.py   # after cargo build --release
"""
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
from osgeo import gdal, osr

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.environ.get("DEMSKETCH", os.path.join(ROOT, "target/release/demsketch"))
FIXTURE = os.path.join(ROOT, "fixtures/vinschgau_250m_utm32n.tif")
OUT = os.path.join(ROOT, "docs/guide")


def roof_case(tmp):
    """The blurred roof (as the test builds it) and its ridge breakline."""
    n, cell, th = 80, 10.0, math.radians(70)
    u, c = (math.cos(th), math.sin(th)), n / 2

    def frame(px, py):
        dx, dy = px - c, py - c
        return (dx * u[0] + dy * u[1]) * cell, (u[0] * dy - u[1] * dx) * cell

    def roof(px, py):
        t, d = frame(px, py)
        return 1500 + 0.08 * t - (0.35 if d < 0 else 0.6) * abs(d)

    z = np.zeros((n, n), np.float32)
    for r in range(n):
        for cc in range(n):
            p = (cc + 0.5, r + 0.5)
            if abs(frame(*p)[1]) < 25:
                z[r, cc] = np.mean([roof(p[0] + a, p[1] + b)
                                    for a in range(-2, 3) for b in range(-2, 3)])
            else:
                z[r, cc] = roof(*p)
    dem = os.path.join(tmp, "roof.tif")
    ds = gdal.GetDriverByName("GTiff").Create(dem, n, n, 1, gdal.GDT_Float32)
    gt = [600000, cell, 0, 5200000, 0, -cell]
    ds.SetGeoTransform(gt)
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32632)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(z)
    ds = None
    coords = []
    for k in (-1, 0, 1):
        px, py = c + k * 40 * u[0], c + k * 40 * u[1]
        coords.append([gt[0] + px * cell, gt[3] - py * cell, roof(px, py)])
    fc = {"type": "FeatureCollection",
          "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32632"}},
          "features": [{"type": "Feature",
                        "properties": {"kind": "breakline", "name": "ridge", "influence_m": 30},
                        "geometry": {"type": "LineString", "coordinates": coords}}]}
    features = os.path.join(tmp, "breakline.geojson")
    with open(features, "w") as f:
        json.dump(fc, f)
    return dem, features


def read_rgb(path):
    ds = gdal.Open(path)
    return np.dstack([ds.GetRasterBand(i + 1).ReadAsArray() for i in range(3)])


def compose(renders, out):
    ims = [read_rgb(os.path.join(renders, n + ".png"))
           for n in ("map_before", "map_after", "height_change")]
    gap = 12
    h = max(i.shape[0] for i in ims)
    w = sum(i.shape[1] for i in ims) + gap * (len(ims) - 1)
    canvas = np.full((h, w, 3), 255, np.uint8)
    x = 0
    for i in ims:
        canvas[:i.shape[0], x:x + i.shape[1]] = i
        x += i.shape[1] + gap
    mem = gdal.GetDriverByName("MEM").Create("", w, h, 3, gdal.GDT_Byte)
    for b in range(3):
        mem.GetRasterBand(b + 1).WriteArray(canvas[:, :, b])
    gdal.GetDriverByName("PNG").CreateCopy(out, mem)
    aux = out + ".aux.xml"
    if os.path.exists(aux):
        os.remove(aux)


def main():
    with tempfile.TemporaryDirectory() as tmp:
        with open(os.path.join(ROOT, "fixtures/corrections/vinschgau_example.geojson")) as f:
            example = json.load(f)
        cases = []
        for feat in example["features"]:
            kind = feat["properties"]["kind"]
            one = dict(example, features=[feat])
            path = os.path.join(tmp, kind + ".geojson")
            with open(path, "w") as f:
                json.dump(one, f)
            cases.append((kind, FIXTURE, path))
        cases.append(("breakline",) + roof_case(tmp))
        for kind, dem, features in cases:
            renders = os.path.join(tmp, "r_" + kind)
            subprocess.run([BIN, "correct", dem, "--features", features,
                            "--out", os.path.join(tmp, kind + ".tif"),
                            "--renders", renders], check=True)
            out = os.path.join(OUT, "corrections_%s.png" % kind)
            compose(renders, out)
            print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
