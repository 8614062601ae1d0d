#!/usr/bin/python3
"""Pictures of landforms from silhouettes and noise regions for the user
guide (issue 14 item 5): on the synthetic plain of tests/correct_landform.rs
(a 500 m plain, 10 m cells, UTM 32N, and a 200 m cone the viewpoint stands
on, looking north), the landform of the smooth silhouette stroke and a
noise region south-west of it.

- docs/guide/corrections_landform.png: `correct --renders` map before, map
  after (boundary green, shadow red) and height change, side by side;
- docs/guide/landform_view.png: the view of the sketch before and after
  (`demsketch view --sketch`, the strokes drawn), one above the other;
- docs/guide/corrections_noise_region.png: as the first, for the region.

    /usr/bin/python3 tools/landform_pictures.py   # after cargo build --release
"""
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
from osgeo import gdal, osr

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from correct_pictures import compose, read_rgb  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.environ.get("DEMSKETCH", os.path.join(ROOT, "target/release/demsketch"))
OUT = os.path.join(ROOT, "docs/guide")
N, CELL, X0, Y0 = 500, 10.0, 600000.0, 5105000.0
VIEW = (2500.0, 4700.0)


def plain(path):
    ys, xs = np.mgrid[0:N, 0:N]
    x, y = (xs + 0.5) * CELL, (ys + 0.5) * CELL
    cone = 200 * np.maximum(0, 1 - np.hypot(x - VIEW[0], y - VIEW[1]) / 400.0)
    h = 500 + 2 * np.sin(x / 700.0) + 2 * np.cos(y / 900.0) + cone
    ds = gdal.GetDriverByName("GTiff").Create(path, N, N, 1, gdal.GDT_Float32)
    ds.SetGeoTransform([X0, CELL, 0, Y0, 0, -CELL])
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32632)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(h.astype(np.float32))


def stroke(jag):
    pts = []
    for k in range(101):
        x = 220.0 + 2 * k
        t = (x - 320.0) / 100.0
        d = 0.0 if k in (0, 100) else (jag if (k // 3) % 2 else -jag)
        pts.append([x, 236.0 - 86.0 * (1 - t * t) + d])
    return pts


def lonlat(x, y):
    src, dst = osr.SpatialReference(), osr.SpatialReference()
    src.ImportFromEPSG(32632)
    dst.ImportFromEPSG(4326)
    for s in (src, dst):
        s.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
    lon, lat, _ = osr.CoordinateTransformation(src, dst).TransformPoint(x, y)
    return lon, lat


def stack(paths, out):
    ims = [read_rgb(p) for p in paths]
    w = max(i.shape[1] for i in ims)
    h = sum(i.shape[0] for i in ims) + 8 * (len(ims) - 1)
    canvas = np.full((h, w, 3), 255, np.uint8)
    y = 0
    for i in ims:
        canvas[y:y + i.shape[0], :i.shape[1]] = i
        y += i.shape[0] + 8
    mem = gdal.GetDriverByName("MEM").Create("", w, h, 3, gdal.GDT_Byte)
    for b in range(3):
        mem.GetRasterBand(b + 1).WriteArray(canvas[:, :, b])
    gdal.GetDriverByName("PNG").CreateCopy(out, mem)
    if os.path.exists(out + ".aux.xml"):
        os.remove(out + ".aux.xml")


def main():
    with tempfile.TemporaryDirectory() as tmp:
        dem = os.path.join(tmp, "plain.tif")
        plain(dem)
        lon, lat = lonlat(X0 + VIEW[0], Y0 - VIEW[1])
        sketch = {"views": [{"name": "hill",
                             "viewpoint": {"lon": lon, "lat": lat, "eye_height_m": 1.7},
                             "camera": {"heading_deg": 0.0, "hfov_deg": 60.0,
                                        "width": 640, "height": 360},
                             "strokes": [{"id": "smooth", "points": stroke(0.0)}]}]}
        sk = os.path.join(tmp, "sketch.json")
        with open(sk, "w") as f:
            json.dump(sketch, f)
        noise_sketch = json.loads(json.dumps(sketch))
        noise_sketch["views"][0]["strokes"] = [{"id": "rough", "points": stroke(4.0)}]
        nsk = os.path.join(tmp, "noise_sketch.json")
        with open(nsk, "w") as f:
            json.dump(noise_sketch, f)
        crs = {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32632"}}
        square = [[X0 + 1000 + dx, Y0 - 1000 - dy] for dx, dy in
                  ((0, 0), (1000, 0), (1000, 1000), (0, 1000), (0, 0))]
        cases = [
            ("landform", sk, {"kind": "landform", "name": "new_hill",
                              "silhouette": {"view": "hill", "stroke": "smooth"}}, None),
            ("noise_region", nsk, {"kind": "noise_region", "name": "rough_patch",
                                   "noise_stroke": {"view": "hill", "stroke": "rough"}},
             {"type": "Polygon", "coordinates": [square]}),
        ]
        for kind, sketch_path, props, geom in cases:
            fc = {"type": "FeatureCollection", "crs": crs,
                  "features": [{"type": "Feature", "properties": props, "geometry": geom}]}
            features = os.path.join(tmp, kind + ".geojson")
            with open(features, "w") as f:
                json.dump(fc, f)
            renders = os.path.join(tmp, "r_" + kind)
            after = os.path.join(tmp, kind + ".tif")
            subprocess.run([BIN, "correct", dem, "--features", features, "--sketch", sketch_path,
                            "--out", after, "--renders", renders], check=True)
            out = os.path.join(OUT, "corrections_%s.png" % kind)
            compose(renders, out)
            print(out)
            if kind == "landform":
                views = []
                for name, d in (("before", dem), ("after", after)):
                    v = os.path.join(tmp, "view_%s.png" % name)
                    subprocess.run([BIN, "view", d, "--sketch", sketch_path, "--out", v, "-q"],
                                   check=True)
                    views.append(v)
                out = os.path.join(OUT, "landform_view.png")
                stack(views, out)
                print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
