#!/usr/bin/env python3
"""Benchmarks of `demsketch serve` (issue 13), figures for docs/benchmarks.md.

1. page load to first view: Chromium (headless) from navigation to the
   first rendered view (the page sets body[data-ready]), on the bundled
   Zion DEM.
2. view re-render, 1600 x 900 on a 4096 x 4096 DEM (the Zion fixture
   resampled to 4096 x 4096 by gdalwarp in a temporary directory): POST
   /api/render with a new heading each time, the terrain of the viewpoint
   already read (the first request, which reads it, is reported apart).
3. stroke to dry-run result, 512 x 512 DEM (the Zion fixture resampled),
   10 strokes (the view's 10 longest silhouettes, each raised by a bump):
   from POST /api/edit to the finished job's report (long-polled, as the
   page does), and to its three pictures fetched (drawn when fetched).

Usage: tools/bench_serve.py [--bin target/release/demsketch] [--runs N]
Needs the browser environment of tools/setup.sh (.venv-browser) for 1.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "browser"))
import run as bt  # noqa: E402  (the browser tests' helpers)

ROOT = bt.ROOT
ZION = bt.DEM
VP = {"lon": -112.90, "lat": 37.40, "eye_height_m": 1.7}


def resample(src, dst, n):
    subprocess.run(["gdalwarp", "-q", "-overwrite", "-ts", str(n), str(n), "-r", "cubicspline",
                    "-co", "TILED=YES", "-co", "COMPRESS=DEFLATE", src, dst], check=True)


def timed(f):
    t0 = time.perf_counter()
    v = f()
    return time.perf_counter() - t0, v


def bench_page_load(binary, tmp, runs):
    srv = bt.Server(binary, ZION, os.path.join(tmp, "o.tif"))
    times = []
    try:
        d = bt.browser(tmp)
        try:
            for _ in range(runs):
                t0 = time.perf_counter()
                d.get(srv.url)
                bt.wait_for(lambda: d.execute_script("return document.body.dataset.ready"), 60, "page")
                times.append(time.perf_counter() - t0)
        finally:
            d.quit()
    finally:
        srv.stop()
    return times


def bench_render(binary, tmp, runs):
    dem = os.path.join(tmp, "zion4096.tif")
    resample(ZION, dem, 4096)
    srv = bt.Server(binary, dem, os.path.join(tmp, "o4096.tif"))
    try:
        cam = {"heading_deg": 200.0, "pitch_deg": -1.0, "roll_deg": 0.0, "hfov_deg": 60.0,
               "width": 1600, "height": 900}
        first, (s, _) = timed(lambda: bt.post_json(srv, "/api/render", {"viewpoint": VP, "camera": cam}))
        assert s == 200, s
        times = []
        for k in range(runs):
            c = dict(cam, heading_deg=180.0 + 4 * k)
            t, (s, _) = timed(lambda: bt.post_json(srv, "/api/render", {"viewpoint": VP, "camera": c}))
            assert s == 200, s
            times.append(t)
        with_sil = []
        for k in range(max(3, runs // 3)):
            c = dict(cam, heading_deg=181.0 + 4 * k)
            t, (s, _) = timed(lambda: bt.post_json(srv, "/api/render", {"viewpoint": VP, "camera": c, "overlays": ["silhouettes"]}))
            assert s == 200, s
            with_sil.append(t)
    finally:
        srv.stop()
    return first, times, with_sil


def bench_dry_run(binary, tmp, runs):
    dem = os.path.join(tmp, "zion512.tif")
    resample(ZION, dem, 512)
    srv = bt.Server(binary, dem, os.path.join(tmp, "o512.tif"))
    try:
        cam = {"heading_deg": 200.0, "pitch_deg": -1.0, "roll_deg": 0.0, "hfov_deg": 60.0,
               "width": 1200, "height": 600}
        s, f = bt.post_json(srv, "/api/features", {"viewpoint": VP, "camera": cam})
        assert s == 200, f
        sils = sorted(f["silhouettes"], key=lambda c: -len(c["pixels"]))[:10]
        strokes = []
        for k, c in enumerate(sils):
            pts = c["pixels"][::3] or c["pixels"]
            n = len(pts)
            bump = [[x, y - 6.0 * max(0.0, 1 - abs(2 * i / max(1, n - 1) - 1) * 2)] for i, (x, y) in enumerate(pts)]
            strokes.append({"id": f"s{k + 1}", "points": bump})
        sketch = {"views": [{"name": "bench", "viewpoint": VP, "camera": cam, "strokes": strokes}],
                  "options": {"influence_m": 1500.0}}
        times = []
        with_pictures = []
        fitted = None
        states = set()
        for _ in range(runs + 1):
            t0 = time.perf_counter()
            s, r = bt.post_json(srv, "/api/edit", {"sketch": sketch, "allow_partial": True})
            assert s == 202, r
            while True:
                # long-polling, as the page does
                j = bt.get_json(srv, f"/api/jobs/{r['job']}?wait_ms=10000")
                if j["state"] in ("done", "failed"):
                    break
            times.append(time.perf_counter() - t0)
            # A failed edit is a result too (its message is shown); the
            # state is reported.
            states.add(j["state"] if j["state"] == "done" else f"{j['state']}: {j.get('message')}")
            # the pictures the page then shows (drawn when fetched)
            for name in j.get("images") or []:
                s, png = bt.request(srv, "GET", f"/api/jobs/{r['job']}/image/{name}")
                assert s == 200, (name, s)
            with_pictures.append(time.perf_counter() - t0)
            if j.get("report"):
                fitted = sum(st["status"] == "fitted" for v in j["report"]["views"] for st in v["strokes"])
    finally:
        srv.stop()
    stages = (j.get("report") or {}).get("timings_s")
    return times[1:], with_pictures[1:], len(strokes), fitted, stages, sorted(states)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "demsketch"))
    ap.add_argument("--runs", type=int, default=10)
    args = ap.parse_args()
    os.environ.setdefault("GDAL_PAM_ENABLED", "NO")
    binary = os.path.abspath(args.bin)
    tmp = tempfile.mkdtemp(prefix="demsketch-bench-serve-")
    load = os.getloadavg()
    pl = bench_page_load(binary, tmp, max(3, args.runs // 2))
    first, rr, rs = bench_render(binary, tmp, args.runs)
    dr, drp, n, fitted, stages, states = bench_dry_run(binary, tmp, max(3, args.runs // 2))
    med = statistics.median
    print(json.dumps({
        "loadavg_before": load,
        "page_load_to_first_view_s": {"median": med(pl), "min": min(pl), "runs": len(pl)},
        "render_4096_1600x900_s": {"first_reads_dem": first, "median": med(rr), "min": min(rr), "max": max(rr), "runs": len(rr),
                                   "with_silhouettes_median": med(rs)},
        "stroke_to_dry_run_512_s": {"median": med(dr), "min": min(dr), "runs": len(dr), "strokes": n,
                                    "fitted": fitted, "edit_stages_s_last": stages, "job_states": states,
                                    "with_pictures_median": med(drp), "with_pictures_min": min(drp)},
        "loadavg_after": os.getloadavg(),
    }, indent=2))


if __name__ == "__main__":
    main()
