#!/usr/bin/python3
"""Validates the judge against things that do not share its code.

1. gdal_viewshed (GDAL's own line-of-sight, curvature coefficient 0.85714 =
   1 - 1/7): along every judge ray, the cells the judge sees should be the
   cells gdal_viewshed marks visible.  Projected DEMs only (gdal_viewshed
   measures distance in CRS units).
2. `demsketch view --depth` (a sanity check, not the definition): the
   skyline row per column, the depth just under it, and whether demsketch's
   depth image shows a depth step at the rows of the judge's traced robust
   boundaries.

Writes tools/fidelity/validation.md (run.py includes it in docs/fidelity.md).
"""
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np
from osgeo import gdal

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
import cases  # noqa: E402
import judge  # noqa: E402
import trace  # noqa: E402

gdal.UseExceptions()


def demsketch():
    return os.environ.get("DEMSKETCH", os.path.join(ROOT, "target", "release", "demsketch"))


def viewshed_check(dem, v, work):
    # both stand on the centre of the viewpoint's cell (where the bilinear surface equals the
    # cell value gdal_viewshed uses), 1.7 m above it
    X, Y = dem.ll_to_crs(np.array([v["lon"]]), np.array([v["lat"]]))
    px, py = dem.crs_to_pixel(X, Y)
    i, j = int(px[0]), int(py[0])
    Xc, Yc = dem.pixel_to_crs(i + 0.5, j + 0.5)
    lon, lat = dem.pixel_to_ll(i + 0.5, j + 0.5)
    v = dict(v, lon=lon, lat=lat, alt=float(dem.h[j, i]) + cases.EYE_HEIGHT)
    X, Y = np.array([Xc]), np.array([Yc])
    oz = cases.EYE_HEIGHT
    out = os.path.join(work, "vs.tif")
    subprocess.run(["gdal_viewshed", "-q", "-ox", repr(float(X[0])), "-oy", repr(float(Y[0])), "-oz", repr(float(oz)),
                    "-cc", "0.85714", "-md", "50000", dem.path, out], check=True, stdout=subprocess.DEVNULL)
    ds = gdal.Open(out)
    vs = ds.GetRasterBand(1).ReadAsArray()
    vgt = ds.GetGeoTransform()
    ds = None
    # the viewshed's grid may be a window of the DEM's: map DEM cells onto it
    oi = int(round((vgt[0] - dem.gt[0]) / dem.gt[1]))
    oj = int(round((vgt[3] - dem.gt[3]) / dem.gt[5]))
    r = cases.render_view(dem, v, keep_samples=True)
    valid = np.isfinite(r.a)
    # skip the first 3 cells (cell-centre vs ray-sample geometry differs most there)
    far = r.s[None, :] > 3 * dem.cell_m
    m = valid & far
    ci = np.clip(np.floor(r.px[m]).astype(int), 0, dem.nx - 1)
    cj = np.clip(np.floor(r.py[m]).astype(int), 0, dem.ny - 1)
    jv = r.vis[m]
    vi, vj = ci - oi, cj - oj
    inwin = (vi >= 0) & (vj >= 0) & (vi < vs.shape[1]) & (vj < vs.shape[0])
    gv = np.zeros(len(ci), bool)
    gv[inwin] = vs[vj[inwin], vi[inwin]] == 255
    # a ray's visible sample in a cell the viewshed calls hidden, or vice versa; one sample
    # per (column, cell) to weigh cells, not samples
    key = np.stack([np.nonzero(m)[0], cj * dem.nx + ci], axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    agree = float(np.mean(jv[first] == gv[first]))
    # the same, leaving out grazing samples (within 1 px of the running maximum's line of sight)
    prev = np.concatenate([np.full((r.width, 1), -np.inf), r.run_max[:, :-1]], axis=1)
    margin = np.abs(r.a - prev) * r.rowscale[:, None]
    clear = margin[m][first] > 1.0
    agree_clear = float(np.mean((jv[first] == gv[first])[clear])) if clear.any() else float("nan")
    jvis_share = float(np.mean(jv[first]))
    gvis_share = float(np.mean(gv[first]))
    # cells any judge sample sees vs cells gdal sees, within the judge's wedge
    return {"agree": agree, "agree_clear": agree_clear, "clear_share": float(np.mean(clear)), "judge_visible": jvis_share, "viewshed_visible": gvis_share, "n": int(len(first))}


def demsketch_check(dem, v, work):
    png, dep = os.path.join(work, "v.png"), os.path.join(work, "d.tif")
    cam = cases.CAMERA
    subprocess.run([demsketch(), "view", dem.path, "--lon", repr(v["lon"]), "--lat", repr(v["lat"]),
                    "--alt", repr(v["alt"]), "--heading", repr(v["heading"]), "--pitch", "0", "--roll", "0",
                    "--hfov", repr(cam["hfov_deg"]), "--size", "%dx%d" % (cam["width"], cam["height"]),
                    "--max-distance", "50000", "--out", png, "--depth", dep], check=True, capture_output=True)
    ds = gdal.Open(dep)
    d = ds.GetRasterBand(1).ReadAsArray().astype(float)
    nd = ds.GetRasterBand(1).GetNoDataValue()
    ds = None
    sky = ~np.isfinite(d) | (d <= 0)
    if nd is not None:
        sky |= d == nd
    r = cases.render_view(dem, v)
    H, W = d.shape
    has = (~sky).any(axis=0)
    first = np.argmax(~sky, axis=0).astype(float)  # first terrain row from the top
    ok = has & np.isfinite(r.sky_row) & r.sky_robust & (r.sky_row > 1) & (r.sky_row < H - 1)
    # the judge's skyline row y is continuous; the first terrain pixel row is the one whose
    # centre lies below it: floor(y - 0.5) + 1 ... compare y with the row's top edge.
    diff = first[ok] - r.sky_row[ok]
    dd = d[np.minimum(first.astype(int) + 1, H - 1), np.arange(W)]
    q = (dd[ok] / r.sky_depth[ok])
    # traced boundaries: does demsketch's depth image step there?
    chs = trace.chains(r)
    n_b, n_step = 0, 0
    for ch in chs:
        for c, row, fr in zip(ch["col"], ch["row"], ch["depth"]):
            y = int(math.floor(row))
            lo, hi = max(0, y - 2), min(H, y + 3)
            col = d[lo:hi, c]
            colsky = sky[lo:hi, c]
            n_b += 1
            above = np.where(colsky, np.inf, col)
            if (np.max(above) >= 1.15 * np.min(col[~colsky])) if (~colsky).any() else False:
                n_step += 1
    return {"sky_cols": int(ok.sum()), "sky_within_1px": float(np.mean(np.abs(diff) <= 1.0)) if ok.any() else None,
            "sky_diff_median": float(np.median(diff)) if ok.any() else None,
            "sky_depth_ratio_p5_p50_p95": [float(x) for x in np.percentile(q, [5, 50, 95])] if ok.any() else None,
            "traced_cols": n_b, "traced_with_depth_step": (n_step / n_b) if n_b else None}


def main():
    rows = []
    work = tempfile.mkdtemp(prefix="fidelity-val-")
    for g in cases.groups():
        if g["kind"] != "identity":
            continue
        gg = cases.build_group(dict(g, styles=[]), os.path.join(ROOT, "fixtures"), work)
        if "error" in gg:
            continue
        dem = judge.Dem(gg["base_path"])
        row = {"group": g["id"], "dem": g["dem"]}
        if not dem.geographic:
            row["viewshed"] = viewshed_check(dem, gg["view"], work)
        row["demsketch"] = demsketch_check(dem, gg["view"], work)
        rows.append(row)
        sys.stderr.write("validate: %s\n" % g["id"])
    json.dump(rows, open(os.path.join(HERE, "validation.json"), "w"), indent=1)
    L = ["## Validation of the judge\n",
         "Generated by `tools/fidelity/validate.py` on the identity viewpoints.\n",
         "**gdal_viewshed** (`-cc 0.85714`; both stand 1.7 m above the centre of the viewpoint's cell, where the "
         "bilinear surface equals the cell value gdal_viewshed uses): for every "
         "(judge ray, DEM cell) pair beyond 3 cells, does the judge's visibility of the ray sample equal the "
         "viewshed's? Projected DEMs only.\n",
         "| viewpoint | agreement | agreement, non-grazing | non-grazing share | judge visible | viewshed visible | pairs |",
         "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if "viewshed" in r:
            v = r["viewshed"]
            L.append("| %s | %.1f%% | %.1f%% | %.1f%% | %.1f%% | %.1f%% | %d |" % (
                r["group"], 100 * v["agree"], 100 * v["agree_clear"], 100 * v["clear_share"], 100 * v["judge_visible"],
                                                            100 * v["viewshed_visible"], v["n"]))
    L += ["", "**demsketch view --depth** (sanity check only): skyline row of the judge vs the first terrain pixel "
          "row of demsketch's depth image (robust skyline columns), depth under the skyline (demsketch / judge), "
          "and the share of the judge's traced robust boundary columns where demsketch's depth image has a "
          ">= 15% depth step within +-2 rows.\n",
          "| viewpoint | skyline cols | within 1 px | median diff px | depth ratio p5 / p50 / p95 | traced cols | with depth step |",
          "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        d = r["demsketch"]
        L.append("| %s | %d | %s | %s | %s | %d | %s |" % (
            r["group"], d["sky_cols"], "-" if d["sky_within_1px"] is None else "%.1f%%" % (100 * d["sky_within_1px"]),
            "-" if d["sky_diff_median"] is None else "%.2f" % d["sky_diff_median"],
            "-" if d["sky_depth_ratio_p5_p50_p95"] is None else " / ".join("%.3f" % x for x in d["sky_depth_ratio_p5_p50_p95"]),
            d["traced_cols"], "-" if d["traced_with_depth_step"] is None else "%.1f%%" % (100 * d["traced_with_depth_step"])))
    L += ["", "What this says (hand-written, 2026-12-01):", "",
          "- Visibility agrees with gdal_viewshed on 80 to 99.9 % of (ray, cell) pairs, 92 to 99.9 % once grazing "
          "samples (within 1 px of the line of sight over the nearer terrain) are left out. The disagreements were "
          "traced on Zion edge1: a uniform slope seen from just above a plateau edge, where the judge's bilinear "
          "ray rises 0.003 in tan elevation above the running maximum and GDAL's cell-centre interpolation calls "
          "it hidden; on NZ 1 km half of all pairs are grazing. The visible shares differ most on those views "
          "(judge 9 %, viewshed 2 %): GDAL's viewshed is the more conservative one on grazing slopes.",
          "- Skylines agree with demsketch's renderer (two triangles per cell) to a median of -0.5 to 0 px; the "
          "share within 1 px is lowest on jagged coarse skylines (Vinschgau 250 m: 64 to 82 %), where triangles "
          "and bilinear patches differ between cell centres. At 93 to 100 % of the judge's traced robust boundary "
          "columns demsketch's depth image has a depth step, so the traced strokes are on silhouettes both "
          "renderers show. Low p5 depth ratios (Texas, NZ edge) are the measurement: the pixel under a flat "
          "skyline shows much nearer ground.",
          "- Found on the way: `demsketch view` without `--max-distance` sees farther than the 50 km `edit` "
          "reads by default (NZ: skylines 6 px apart until both were given 50 km), so the check passes "
          "`--max-distance 50000` and the suite passes it to `edit` too. A viewpoint put 1.7 m above the "
          "bilinear ground can be below the cell value at a summit's edge (Zion edge1: 1.1 m under), which is "
          "why the viewshed check stands on the cell centre.",
          ""]
    open(os.path.join(HERE, "validation.md"), "w").write("\n".join(L) + "\n")
    print("\n".join(L))
    subprocess.run(["rm", "-rf", work])


if __name__ == "__main__":
    main()
