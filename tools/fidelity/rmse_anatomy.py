#!/usr/bin/python3
"""rmse_anatomy.py WORKDIR STYLE [--png OUT.png] [--json OUT.json]

Where the RMSE to the truth in the judge's visible changed region comes
from, for one known-change case kept by `run.py --keep` (WORKDIR holds
truth.tif and STYLE/{sketch.json,report.json,out.tif}).

The region is run.py's: cells a judge ray sample sees in the truth view or
the unedited view, where |truth - base| > 0.5 m. Every cell is put in the
view's own plan frame: its distance r from the eye and its azimuth (true
north, from lon/lat), i.e. its image column. Per azimuth bin (one cell wide
at the change's distance) the script finds where the truth's change and the
edit's change peak along the sight line (the "crest" of each change: the
largest raise for a raised change, the deepest cut for a lowered one) and
where the placed curve (report `placed_curve`) lies, and prints:

- the two changes' size: peak, volume, centroid distance, spread along the
  sight line and across it (second moments of the change of the truth's
  sign, over the whole footprint, not only the region);
- the plan distance between the crest lines, per bin and median, and the
  placed curve's distance from the truth's crest;
- the squared error after the edit split by part of the region, relative
  to the truth's crest in each bin: front (nearer than one cell in front of
  the crest), crest (within a cell), behind (farther than a cell behind);
  and by the truth's change: core (at least half its peak) and fringe;
- what the edit changed outside the truth's footprint (not in the region:
  it does not count in the RMSE, reported for what it says about width);
- three counterfactuals on the region's RMSE: the edit's change scaled by
  its best factor; shifted along the sight lines so that its crest falls on
  the truth's; and the truth's own change (its shape) scaled to the edit's
  peak (what a right shape of the edit's height would give).

With --png: a plan picture (each cell a square of pixels): truth change,
edit change, error (edit - truth), side by side, blue = lowered, red =
raised (same scale in the three), the region outlined in black, the truth's
crest per bin in green, the edit's in magenta, the placed curve in yellow,
the eye's direction to the upper edge.
"""
import argparse
import json
import math
import os
import sys

import numpy as np
from osgeo import gdal

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cases  # noqa: E402
import judge  # noqa: E402


def enu_of_cells(dem, j0, j1, i0, i1, lon0, lat0):
    """East/north metres (local tangent at the eye, true north) of the cell
    centres in rows j0..j1, columns i0..i1."""
    jj, ii = np.mgrid[j0:j1, i0:i1]
    X, Y = dem.pixel_to_crs(ii + 0.5, jj + 0.5)
    return enu_of_crs(dem, X, Y, lon0, lat0)


def enu_of_crs(dem, X, Y, lon0, lat0):
    X = np.asarray(X, float)
    Y = np.asarray(Y, float)
    shape = X.shape
    if dem.geographic:
        lon, lat = X.ravel(), Y.ravel()
    else:
        pts = np.stack([X.ravel(), Y.ravel()], axis=1)
        out = np.array(dem.to_ll.TransformPoints(pts))
        lon, lat = out[:, 0], out[:, 1]
    R = judge.earth_radius(lat0)
    e = np.radians(lon - lon0) * R * math.cos(math.radians(lat0))
    n = np.radians(lat - lat0) * R
    return e.reshape(shape), n.reshape(shape)


def moments(w, r, a):
    """Weighted centroid and spread of a non-negative field w at (r, a)."""
    s = w.sum()
    if s <= 0:
        return None
    rc = (w * r).sum() / s
    ac = (w * a).sum() / s
    sr = math.sqrt(max((w * (r - rc) ** 2).sum() / s, 0.0))
    sa = math.sqrt(max((w * (a - ac) ** 2).sum() / s, 0.0))
    return rc, ac, sr, sa


def analyse(wd, style):
    sk = json.load(open(os.path.join(wd, style, "sketch.json")))
    rep = json.load(open(os.path.join(wd, style, "report.json")))
    v = sk["views"][0]
    vp, cam = v["viewpoint"], v["camera"]
    view = dict(lon=vp["lon"], lat=vp["lat"], alt=vp["alt_m"], heading=cam["heading_deg"])
    base = judge.Dem(rep["dem"])
    truth = judge.Dem(os.path.join(wd, "truth.tif"))
    out = judge.Dem(os.path.join(wd, style, "out.tif"))
    r_t = cases.render_view(base, view, h=truth.h)
    r_b = cases.render_view(base, view, h=base.h)
    vis = np.zeros(base.h.size, bool)
    vis[r_t.visible_cells] = True
    vis[r_b.visible_cells] = True
    vis = vis.reshape(base.h.shape)
    dt_full = truth.h - base.h
    de_full = out.h - base.h
    fin = np.isfinite(dt_full) & np.isfinite(de_full)
    foot_t = fin & (np.abs(dt_full) > 0.5)
    foot_e = fin & (np.abs(de_full) > 0.5)
    region = vis & foot_t
    # a window around everything that changed
    any_ = foot_t | foot_e
    js, is_ = np.nonzero(any_)
    pad = 3
    j0, j1 = max(js.min() - pad, 0), min(js.max() + pad + 1, base.ny)
    i0, i1 = max(is_.min() - pad, 0), min(is_.max() + pad + 1, base.nx)
    sl = (slice(j0, j1), slice(i0, i1))
    dt, de, reg = np.where(fin, dt_full, 0.0)[sl], np.where(fin, de_full, 0.0)[sl], region[sl]
    ft, fe = foot_t[sl], foot_e[sl]
    e, n = enu_of_cells(base, j0, j1, i0, i1, view["lon"], view["lat"])
    r = np.hypot(e, n)
    az = np.degrees(np.arctan2(e, n))
    rel = (az - view["heading"] + 180.0) % 360.0 - 180.0
    f = (cases.CAMERA["width"] / 2) / math.tan(math.radians(cases.CAMERA["hfov_deg"] / 2))
    col = cases.CAMERA["width"] / 2 + f * np.tan(np.radians(rel))
    cell = base.cell_m
    sign = 1.0 if dt[ft].sum() >= 0 else -1.0
    # the changes of the truth's sign, in the (along = r, across = r * angle) frame
    rc_t = (np.abs(dt) * ft * r).sum() / max((np.abs(dt) * ft).sum(), 1e-9)
    across = np.radians(rel) * rc_t
    wt = np.clip(sign * dt, 0, None)
    we = np.clip(sign * de, 0, None)
    mt, me = moments(wt, r, across), moments(we, r, across)
    res = {"case": os.path.basename(wd.rstrip("/")), "style": style, "cell_m": round(cell, 1),
           "sign": "raise" if sign > 0 else "lower", "region_cells": int(reg.sum()),
           "truth_cells": int(ft.sum()), "edit_cells": int(fe.sum())}
    area = cell * cell
    res["truth"] = {"peak": round(float((sign * dt).max()), 1), "volume_Mm3": round(float(wt.sum() * area / 1e6), 3)}
    res["edit"] = {"peak": round(float((sign * de).max()), 1), "volume_Mm3": round(float(we.sum() * area / 1e6), 3),
                   "opposite_volume_Mm3": round(float(np.clip(-sign * de, 0, None).sum() * area / 1e6), 3)}
    for k, m in (("truth", mt), ("edit", me)):
        if m:
            res[k].update(centroid_r=round(m[0]), centroid_across=round(m[1]), sd_along=round(m[2]), sd_across=round(m[3]))
    # placed curves
    pcs = []
    for s in rep["views"][0]["strokes"]:
        pc = np.array(s.get("placed_curve") or [], float)
        if len(pc):
            pe, pn = enu_of_crs(base, pc[:, 0], pc[:, 1], view["lon"], view["lat"])
            paz = np.degrees(np.arctan2(pe, pn))
            prel = (paz - view["heading"] + 180.0) % 360.0 - 180.0
            pcs.append((np.hypot(pe, pn), prel, pc[:, 0], pc[:, 1]))
    # azimuth bins one cell wide at the truth's centroid distance
    bw = math.degrees(cell / rc_t)
    rel_reg = rel[ft]
    lo, hi = rel_reg.min(), rel_reg.max()
    edges = np.arange(lo - 1e-9, hi + bw, bw)
    bins = []
    crest_t = np.full(dt.shape, np.nan)
    for a0, a1 in zip(edges[:-1], edges[1:]):
        m = (rel >= a0) & (rel < a1)
        mt_ = m & ft
        if not mt_.any():
            continue
        k = np.argmax(np.where(mt_, sign * dt, -np.inf))
        rt = r.flat[k]
        crest_t[m] = rt
        me_ = m & fe
        re_ = float(r.flat[np.argmax(np.where(me_, sign * de, -np.inf))]) if me_.any() and (sign * de[me_]).max() > 0.5 else None
        rp = None
        for pr, prel, _, _ in pcs:
            pm = (prel >= a0) & (prel < a1)
            if pm.any():
                rp = float(np.median(pr[pm])) if rp is None else min(rp, float(np.median(pr[pm])))
        bins.append({"col": round(float(cases.CAMERA["width"] / 2 + f * math.tan(math.radians((a0 + a1) / 2))), 1),
                     "truth_crest_r": round(float(rt)), "truth_peak": round(float(sign * dt.flat[k]), 1),
                     "edit_crest_r": None if re_ is None else round(re_),
                     "edit_peak": round(float((sign * de[m]).max()), 1),
                     "placed_r": None if rp is None else round(rp),
                     "region_cells": int((m & reg).sum())})
    res["bins"] = bins
    offs = [b["edit_crest_r"] - b["truth_crest_r"] for b in bins if b["edit_crest_r"] is not None and b["region_cells"]]
    poffs = [b["placed_r"] - b["truth_crest_r"] for b in bins if b["placed_r"] is not None and b["region_cells"]]
    res["crest_offset_m_median"] = round(float(np.median(offs))) if offs else None
    res["placed_minus_truth_crest_m_median"] = round(float(np.median(poffs))) if poffs else None
    res["placed_bins"] = len(poffs)
    # squared error by part
    a, b = dt[reg], de[reg]
    err2 = (b - a) ** 2
    tot = err2.sum()
    res["rmse_before"] = round(float(np.sqrt((a ** 2).mean())), 2)
    res["rmse_after"] = round(float(np.sqrt(err2.mean())), 2)
    ct = crest_t[reg]
    rr = r[reg]
    peak = np.abs(dt[ft]).max()
    parts = {
        "front": rr < ct - cell,
        "crest": np.abs(rr - ct) <= cell,
        "behind": rr > ct + cell,
    }
    core = np.abs(a) >= 0.5 * peak
    out_p = {}
    for name, m in list(parts.items()) + [("core", core), ("fringe", ~core)]:
        if m.any():
            out_p[name] = {"cells": int(m.sum()), "truth_mean": round(float(a[m].mean()), 1),
                           "edit_mean": round(float(b[m].mean()), 1),
                           "err_share": round(float(err2[m].sum() / max(tot, 1e-9)), 2),
                           "rmse": round(float(np.sqrt(err2[m].mean())), 1)}
    res["parts"] = out_p
    # relative to the placed curve (per bin: the nearest placed distance) and
    # to the strokes' lines of sight: the sketch bounds the terrain along
    # each stroke column's sight line (nothing in front of the silhouette
    # rises above it, and behind it only a farther landform may)
    rp_map = np.full(dt.shape, np.nan)
    for bn in bins:
        if bn["placed_r"] is None:
            continue
        a_ = math.degrees(math.atan((bn["col"] - cases.CAMERA["width"] / 2) / f))
        m = np.abs(rel - a_) <= 0.5 * bw + 1e-9
        rp_map[m] = bn["placed_r"]
    rpl = rp_map[reg]
    sight = np.full(rr.shape, np.nan)
    colr = col[reg]
    rows = np.full(rr.shape, np.inf)
    for st in v["strokes"]:
        pts = np.array(st["points"], float)
        o = np.argsort(pts[:, 0])
        xs, ys = pts[o, 0], pts[o, 1]
        inside = (colr >= xs[0]) & (colr <= xs[-1])
        yy = np.interp(colr, xs, ys)
        rows = np.where(inside, np.minimum(rows, yy), rows)
    has = np.isfinite(rows)
    u = (colr - cases.CAMERA["width"] / 2) / f
    tan_el = (cases.CAMERA["height"] / 2 - rows) / (f * np.sqrt(1 + u * u))
    R = judge.earth_radius(view["lat"])
    drop = (1 - 1 / 7.0) * rr ** 2 / (2 * R)
    sight[has] = (view["alt"] + tan_el * rr + drop)[has]
    bh = base.h[sl][reg]
    th, eh = bh + a, bh + b
    rel_parts = {"before_curve": np.isfinite(rpl) & (rr < rpl - cell),
                 "at_curve": np.isfinite(rpl) & (np.abs(rr - rpl) <= cell),
                 "behind_curve": np.isfinite(rpl) & (rr > rpl + cell),
                 "no_curve_in_bin": ~np.isfinite(rpl)}
    out_c = {}
    for name, m in rel_parts.items():
        if m.any():
            mm = m & has
            out_c[name] = {"cells": int(m.sum()), "truth_mean": round(float(a[m].mean()), 1),
                           "edit_mean": round(float(b[m].mean()), 1),
                           "err_share": round(float(err2[m].sum() / max(tot, 1e-9)), 2),
                           "rmse": round(float(np.sqrt(err2[m].mean())), 1),
                           "in_stroke_cols": int(mm.sum())}
            if mm.any():
                # how far under the stroke's sight line each surface is there (m; negative: above it)
                out_c[name].update(sight_minus_base=round(float(np.median(sight[mm] - bh[mm])), 1),
                                   sight_minus_truth=round(float(np.median(sight[mm] - th[mm])), 1),
                                   sight_minus_edit=round(float(np.median(sight[mm] - eh[mm])), 1))
    res["parts_by_curve"] = out_c
    outside = fe & ~ft
    res["edit_outside_truth_footprint"] = {"cells": int(outside.sum()),
                                           "visible_cells": int((outside & vis[sl]).sum()),
                                           "rms": round(float(np.sqrt((de[outside] ** 2).mean())), 1) if outside.any() else 0.0}
    # counterfactuals
    k = float(np.dot(a, b) / max(np.dot(b, b), 1e-9))
    res["cf_best_scale"] = {"k": round(k, 2), "rmse": round(float(np.sqrt(((a - k * b) ** 2).mean())), 2)}
    if offs:
        dsh = float(np.median(offs))
        # shift the edit's change by -dsh along each sight line: sample de at (r + dsh, same azimuth)
        s = (r[reg] + dsh) / np.maximum(r[reg], 1e-9)
        ee, nn = e[reg] * s, n[reg] * s
        # back to pixel coordinates through the window's own ENU (nearest cell by least squares of the local affine)
        A = np.stack([e.ravel(), n.ravel(), np.ones(e.size)], 1)
        jj, ii = np.mgrid[0:e.shape[0], 0:e.shape[1]]
        cx, *_ = np.linalg.lstsq(A, ii.ravel() + 0.5, rcond=None)
        cy, *_ = np.linalg.lstsq(A, jj.ravel() + 0.5, rcond=None)
        px = cx[0] * ee + cx[1] * nn + cx[2]
        py = cy[0] * ee + cy[1] * nn + cy[2]
        bsh = bilinear(de, px, py)
        res["cf_shift_to_truth_crest"] = {"shift_m": round(dsh), "rmse": round(float(np.sqrt(((a - bsh) ** 2).mean())), 2)}
    ep = (sign * de).max()
    tp = (sign * dt).max()
    res["cf_truth_shape_at_edit_peak"] = round(float(np.sqrt(((a - a * ep / max(tp, 1e-9)) ** 2).mean())), 2)
    res["_maps"] = (dt, de, reg, ft, bins, rel, r, pcs, (j0, i0), base)
    return res


def bilinear(h, px, py):
    fx, fy = px - 0.5, py - 0.5
    i0 = np.clip(np.floor(fx).astype(int), 0, h.shape[1] - 2)
    j0 = np.clip(np.floor(fy).astype(int), 0, h.shape[0] - 2)
    tx, ty = np.clip(fx - i0, 0, 1), np.clip(fy - j0, 0, 1)
    return ((h[j0, i0] * (1 - tx) + h[j0, i0 + 1] * tx) * (1 - ty)
            + (h[j0 + 1, i0] * (1 - tx) + h[j0 + 1, i0 + 1] * tx) * ty)


def colour(x, scale):
    """Diverging: blue (negative) - white - red (positive)."""
    t = np.clip(x / max(scale, 1e-9), -1, 1)
    rgb = np.empty(x.shape + (3,), np.uint8)
    p, q = np.clip(t, 0, 1), np.clip(-t, 0, 1)
    rgb[..., 0] = (255 * (1 - q)).astype(np.uint8)
    rgb[..., 1] = (255 * (1 - np.maximum(p, q))).astype(np.uint8)
    rgb[..., 2] = (255 * (1 - p)).astype(np.uint8)
    return rgb


def picture(res, path):
    dt, de, reg, ft, bins, rel, r, pcs, (j0, i0), base = res["_maps"]
    H, W = dt.shape
    k = max(2, min(12, 400 // max(H, W)))
    scale = max(np.abs(dt).max(), np.abs(de).max())
    panels = []
    for fld in (dt, de, de - dt):
        img = colour(fld, scale)
        # region outline: region cells' borders darkened
        edge = reg & ~(np.roll(reg, 1, 0) & np.roll(reg, -1, 0) & np.roll(reg, 1, 1) & np.roll(reg, -1, 1))
        img[edge] = (img[edge] * 0.45).astype(np.uint8)
        big = np.repeat(np.repeat(img, k, 0), k, 1)
        panels.append(big)

    def mark(big, px, py, col):
        x, y = int(px * k), int(py * k)
        if 1 <= x < big.shape[1] - 1 and 1 <= y < big.shape[0] - 1:
            big[y - 1:y + 2, x - 1:x + 2] = col

    # crest lines: the cell of each bin's crest; placed curve points
    for b in bins:
        for key, colr in (("truth_crest_r", (0, 160, 0)), ("edit_crest_r", (200, 0, 200))):
            if b[key] is None:
                continue
            a = math.degrees(math.atan((b["col"] - cases.CAMERA["width"] / 2)
                                       / ((cases.CAMERA["width"] / 2) / math.tan(math.radians(cases.CAMERA["hfov_deg"] / 2)))))
            m = (np.abs(rel - a) < 0.5 * math.degrees(base.cell_m / max(b[key], 1))) & (np.abs(r - b[key]) < 0.6 * base.cell_m)
            for yy, xx in zip(*np.nonzero(m)):
                for pnl in panels:
                    mark(pnl, xx + 0.5, yy + 0.5, colr)
    for _, _, X, Y in pcs:
        px, py = base.crs_to_pixel(X, Y)
        for x, y in zip(px - i0, py - j0):
            for pnl in panels:
                mark(pnl, x, y, (230, 200, 0))
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    full = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], 1)
    drv = gdal.GetDriverByName("MEM")
    ds = drv.Create("", full.shape[1], full.shape[0], 3, gdal.GDT_Byte)
    for c in range(3):
        ds.GetRasterBand(c + 1).WriteArray(full[..., c])
    gdal.GetDriverByName("PNG").CreateCopy(str(path), ds)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("workdir")
    ap.add_argument("style")
    ap.add_argument("--png")
    ap.add_argument("--json")
    ap.add_argument("--bins", action="store_true", help="print every azimuth bin")
    a = ap.parse_args()
    res = analyse(a.workdir, a.style)
    if a.png:
        picture(res, a.png)
    res.pop("_maps")
    t, e_ = res["truth"], res["edit"]
    print("%s %s: %s, cell %.0f m; region %d cells (truth footprint %d, edit %d)" % (
        res["case"], res["style"], res["sign"], res["cell_m"], res["region_cells"], res["truth_cells"], res["edit_cells"]))
    print("  RMSE %.1f -> %.1f m" % (res["rmse_before"], res["rmse_after"]))
    for nm, d in (("truth", t), ("edit", e_)):
        print("  %-5s peak %6.1f m  volume %.3f Mm3  centroid r %s m  across %s  sd along %s  across %s%s" % (
            nm, d["peak"], d["volume_Mm3"], d.get("centroid_r"), d.get("centroid_across"), d.get("sd_along"), d.get("sd_across"),
            ("  (opposite sign %.3f Mm3)" % d["opposite_volume_Mm3"]) if nm == "edit" else ""))
    print("  crest offset edit - truth (median over bins): %s m; placed curve - truth crest: %s m (%d bins)" % (
        res["crest_offset_m_median"], res["placed_minus_truth_crest_m_median"], res["placed_bins"]))
    for nm, p in res["parts"].items():
        print("  %-7s %4d cells  truth %7.1f  edit %7.1f  rmse %6.1f  share of sq err %.2f" % (
            nm, p["cells"], p["truth_mean"], p["edit_mean"], p["rmse"], p["err_share"]))
    for nm, p in res["parts_by_curve"].items():
        print("  %-15s %4d cells  truth %7.1f  edit %7.1f  rmse %6.1f  share %.2f  | %d in stroke columns, under the sight line: base %s truth %s edit %s" % (
            nm, p["cells"], p["truth_mean"], p["edit_mean"], p["rmse"], p["err_share"], p["in_stroke_cols"],
            p.get("sight_minus_base"), p.get("sight_minus_truth"), p.get("sight_minus_edit")))
    o = res["edit_outside_truth_footprint"]
    print("  edit outside the truth footprint: %d cells (%d visible), rms %.1f m (not in the RMSE)" % (o["cells"], o["visible_cells"], o["rms"]))
    print("  counterfactual RMSE: best scale k=%.2f -> %.1f; shifted to truth crest %s; truth shape at edit peak -> %.1f" % (
        res["cf_best_scale"]["k"], res["cf_best_scale"]["rmse"],
        ("%+d m -> %.1f" % (res["cf_shift_to_truth_crest"]["shift_m"], res["cf_shift_to_truth_crest"]["rmse"])) if "cf_shift_to_truth_crest" in res else "-",
        res["cf_truth_shape_at_edit_peak"]))
    if a.bins:
        for b in res["bins"]:
            print("    col %6.1f  truth crest r %6d (%.1f)  edit crest r %s (%.1f)  placed r %s  region %d" % (
                b["col"], b["truth_crest_r"], b["truth_peak"], b["edit_crest_r"], b["edit_peak"], b["placed_r"], b["region_cells"]))
    if a.json:
        json.dump(res, open(a.json, "w"), indent=1)


if __name__ == "__main__":
    main()
