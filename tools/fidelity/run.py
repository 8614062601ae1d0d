#!/usr/bin/python3
"""Runs the fidelity suite of `demsketch edit` (tools/fidelity).

    /usr/bin/python3 tools/fidelity/run.py [--subset ci] [--report-only]
        [--json results.json] [--md docs/fidelity.md] [--save-pictures DIR]
        [--jobs 2] [--only SUBSTRING]

demsketch is a black box: the binary named by $DEMSKETCH (default
target/release/demsketch), nothing else from src/.
"""
import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from osgeo import gdal

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))

import cases  # noqa: E402
import judge  # noqa: E402
import trace  # noqa: E402

FIT_MIN = 0.95
IDENTITY_MAX_DZ = 3.0
GROUND_MAX = 0.5
IDEMPOTENT_MAX = 0.5
DEPTH_TOL = 0.15
RMSE_FALL = 0.5

# the CI subset: a few cases over four DEMs and all kinds of check (well under a minute on 2 cores)
CI_STYLES = {
    "zion_srtm_utm12n-identity-interior0": ["dense", "hand"],
    "vinschgau_250m_utm32n-identity-edge1": ["long", "border"],
    "nz_1km_nan_nodata-identity-interior0": ["rtl"],
    "zion_srtm_utm12n-peak_raised-toward-change0": ["dense", "hand"],
    "vinschgau_250m_utm32n-peak_raised-toward-change0": ["dense"],
    "texas_srtm90m_tiled_int16-new_hill-interior0": ["dense"],
    "arenal_aster30m_epsg4326-void_fill-toward-change0": ["dense"],
}
CI_GROUPS = list(CI_STYLES) + ["demo-zion_dome"]


def demsketch():
    return os.environ.get("DEMSKETCH", os.path.join(ROOT, "target", "release", "demsketch"))


_ALLOW_PARTIAL = None


def allow_partial_flag():
    global _ALLOW_PARTIAL
    if _ALLOW_PARTIAL is None:
        try:
            h = subprocess.run([demsketch(), "edit", "--help"], capture_output=True, text=True, timeout=30).stdout
        except Exception:
            h = ""
        _ALLOW_PARTIAL = "--allow-partial" in h
    return ["--allow-partial"] if _ALLOW_PARTIAL else []


def run_edit(dem_path, sketch_path, out_path, report_path):
    cmd = [demsketch(), "edit", dem_path, "--sketch", sketch_path, "--out", out_path,
           "--report", report_path, "--max-distance", str(cases.MAX_DIST)] + allow_partial_flag()
    t = time.time()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        rc, err = p.returncode, (p.stderr.strip().splitlines() or [""])[-1]
    except subprocess.TimeoutExpired:
        rc, err = -1, "timeout 300 s"
    return rc, err, time.time() - t


def sketch_json(g, strokes):
    v = g["view"]
    return {
        "views": [{
            "name": "fidelity",
            "viewpoint": {"lon": v["lon"], "lat": v["lat"], "alt_m": round(v["alt"], 3)},
            "camera": {"heading_deg": round(v["heading"], 4), "pitch_deg": 0.0, "roll_deg": 0.0,
                       "hfov_deg": cases.CAMERA["hfov_deg"], "width": cases.CAMERA["width"],
                       "height": cases.CAMERA["height"]},
            "strokes": [{"id": "s%d" % i, "points": s["points"]} for i, s in enumerate(strokes)],
        }],
        "options": {"influence_m": g["influence_m"]},
    }


def spike_stats(dz, cell):
    """Cells whose change exceeds (or falls below) all 8 neighbours' changes
    by more than half a cell size."""
    H, W = dz.shape
    if H < 3 or W < 3:
        return 0, 0.0
    c = dz[1:-1, 1:-1]
    nb = np.stack([dz[1 + dj:H - 1 + dj, 1 + di:W - 1 + di]
                   for dj in (-1, 0, 1) for di in (-1, 0, 1) if (di, dj) != (0, 0)])
    ok = np.isfinite(c) & np.isfinite(nb).all(axis=0)
    with np.errstate(invalid="ignore"):
        hi = np.where(ok, c - nb.max(axis=0), -np.inf)
        lo = np.where(ok, nb.min(axis=0) - c, -np.inf)
    ex = np.maximum(hi, lo)
    n = int((ex > cell / 2).sum())
    return n, float(ex.max()) if np.isfinite(ex).any() else 0.0


def depth_of_report(rs):
    m = rs.get("matched") or rs.get("match") or {}
    d = m.get("depth_m")
    if d is None:
        return None
    if isinstance(d, (int, float)):
        return float(d), float(d)
    return float(min(d)), float(max(d))


def evaluate(g, style, work, pictures):
    """One case: edit, judge, measure."""
    res = {"group": g["id"], "dem": g["dem"], "kind": g["kind"], "vp_class": g["vp_class"],
           "style": style, "view": g["view"]}
    strokes = g["strokes"].get(style)
    if not strokes:
        res.update(status="n/a", reason="no robust boundary for this style")
        return res
    dem = judge.Dem(g["base_path"])
    res["n_strokes"] = len(strokes)
    sk = sketch_json(g, strokes)
    d = os.path.join(work, style)
    os.makedirs(d, exist_ok=True)
    sp = os.path.join(d, "sketch.json")
    with open(sp, "w") as f:
        json.dump(sk, f)
    out1, rep1 = os.path.join(d, "out.tif"), os.path.join(d, "report.json")
    rc, err, dt = run_edit(g["base_path"], sp, out1, rep1)
    res.update(rc=rc, edit_s=round(dt, 2))
    if rc != 0 or not os.path.exists(out1):
        res.update(status="fail", reason="edit exit %s: %s" % (rc, err[:160]))
        return res
    report = json.load(open(rep1))
    edited = judge.Dem(out1)
    base_h = dem.h
    dz = edited.h - base_h
    both = np.isfinite(dz)
    res["nodata_changed"] = int((np.isfinite(edited.h) != np.isfinite(base_h)).sum())
    res["max_abs_dz"] = float(np.abs(dz[both]).max()) if both.any() else 0.0
    res["changed_cells"] = int((np.abs(dz[both]) > 0.01).sum())
    v = g["view"]
    eye = v["alt"]
    rv = (report.get("views") or [{}])[0]
    if rv.get("eye_alt_m") is not None:
        eye = float(rv["eye_alt_m"])
    res["eye_alt_judge"], res["eye_alt_report"] = v["alt"], rv.get("eye_alt_m")
    # observer's ground
    gx = edited.height_ll(v["lon"], v["lat"]) - dem.height_ll(v["lon"], v["lat"])
    res["ground_dz_vp"] = float(gx)
    ex, ny_ = dem.local_xy_m(v["lon"], v["lat"])
    near = np.hypot(ex, ny_) <= 100.0
    px, py = dem.ll_to_pixel(np.array([v["lon"]]), np.array([v["lat"]]))
    i0, j0 = int(math.floor(px[0] - 0.5)), int(math.floor(py[0] - 0.5))
    near[max(j0, 0):j0 + 2, max(i0, 0):i0 + 2] = True
    res["ground_dz_100m"] = float(np.nanmax(np.abs(dz[near]))) if np.isfinite(dz[near]).any() else 0.0
    # spikes
    n_sp, ex_sp = spike_stats(dz, dem.cell_m)
    res["spikes"], res["spike_excess_m"] = n_sp, round(ex_sp, 2)
    res["spike_excess_half_cells"] = round(ex_sp / (dem.cell_m / 2), 3)
    # judge the after-view
    v2 = dict(v, alt=eye)
    r_after = cases.render_view(dem, v2, h=edited.h)
    fits, ratios_near, ratios_far, within = [], [], [], []
    rep_strokes = {s.get("id"): s for s in rv.get("strokes", [])}
    per_stroke = []
    far_max = 0.0
    for i, s in enumerate(strokes):
        fr, after_depth, _ = judge.fit(r_after, s["points"])
        fits.append(fr)
        cols = judge.stroke_columns(s["points"], r_after.width)
        tc = np.array(s["truth_cols"])
        td = np.array(s["truth_depth"])
        m = np.isin(tc, list(cols.keys()))
        t_near, t_far = (float(td[m].min()), float(td[m].max())) if m.any() else (np.nan, np.nan)
        far_max = max(far_max, t_far if np.isfinite(t_far) else 0.0)
        # the judge's own reading of where the stroke ended up: depth of the edited terrain's
        # boundary under the stroke / the truth boundary's depth, column by column
        tmap = dict(zip(tc.tolist(), td.tolist()))
        jq = [after_depth[c] / tmap[c] for c in after_depth if c in tmap and tmap[c] > 0]
        rs = rep_strokes.get("s%d" % i, {})
        pd = depth_of_report(rs)
        entry = {"id": "s%d" % i, "judge_fit": round(fr, 3), "truth_depth_m": [round(t_near, 1), round(t_far, 1)],
                 "report_fit": (rs.get("fit") or {}).get("fitted_fraction"),
                 "match_kind": (rs.get("match") or rs.get("matched") or {}).get("kind"),
                 "report_on_silhouette": rs.get("on_silhouette"),
                 "judge_depth_ratio_median": round(float(np.median(jq)), 3) if jq else None}
        if pd is not None and np.isfinite(t_near):
            qn, qf = pd[0] / t_near, pd[1] / t_far
            entry["placed_depth_m"] = [round(pd[0], 1), round(pd[1], 1)]
            entry["depth_ratio"] = [round(qn, 3), round(qf, 3)]
            ratios_near.append(qn)
            ratios_far.append(qf)
            within.append(abs(qn - 1) <= DEPTH_TOL and abs(qf - 1) <= DEPTH_TOL)
            far_max = max(far_max, pd[1])
        else:
            within.append(False)
        per_stroke.append(entry)
    res["strokes"] = per_stroke
    res["fit_min"] = float(min(fits))
    res["depth_within"] = [bool(w) for w in within]
    # beyond the influence distance: changed cells farther than influence (+1.5 cells)
    # from the wedge of the strokes' columns out to the farthest depth (x1.2)
    chg = both & (np.abs(dz) > 0.05)
    res["beyond_influence"] = 0
    if chg.any():
        allc = sorted({c for s in strokes for c in judge.stroke_columns(s["points"], r_after.width)})
        allc = allc[::max(1, len(allc) // 40)]
        dmax = max(far_max, 1.0) * 1.2
        ds_ = np.arange(0, dmax + dem.cell_m, dem.cell_m / 2)
        az = np.radians(v["heading"] + np.degrees(np.arctan((np.array(allc) + 0.5 - r_after.cx) / r_after.f)))
        qx = (np.sin(az)[:, None] * ds_[None, :]).ravel()
        qy = (np.cos(az)[:, None] * ds_[None, :]).ravel()
        cx_, cy_ = ex[chg], ny_[chg]
        lim = g["influence_m"] + 1.5 * dem.cell_m
        beyond = 0
        for a0 in range(0, len(cx_), 2000):
            dd = np.min((cx_[a0:a0 + 2000, None] - qx[None, :]) ** 2 + (cy_[a0:a0 + 2000, None] - qy[None, :]) ** 2, axis=1)
            beyond += int((dd > lim * lim).sum())
        res["beyond_influence"] = beyond
    # known change: RMSE to the truth in the visible changed region
    if g["kind"] != "identity":
        truth = judge.Dem(g["truth_path"])
        r_t = cases.render_view(dem, v, h=truth.h)
        r_b = cases.render_view(dem, v, h=base_h)
        vis = np.zeros(dem.h.size, bool)
        vis[r_t.visible_cells] = True
        vis[r_b.visible_cells] = True
        vis = vis.reshape(dem.h.shape)
        region = vis & np.isfinite(truth.h) & np.isfinite(base_h) & (np.abs(truth.h - base_h) > 0.5)
        res["region_cells"] = int(region.sum())
        if region.any():
            before = float(np.sqrt(np.mean((base_h[region] - truth.h[region]) ** 2)))
            after = float(np.sqrt(np.nanmean((edited.h[region] - truth.h[region]) ** 2)))
            res["rmse_before"], res["rmse_after"] = round(before, 2), round(after, 2)
            res["rmse_fall"] = round(1 - after / before, 3) if before > 0 else None
    # idempotence
    out2, rep2 = os.path.join(d, "out2.tif"), os.path.join(d, "report2.json")
    rc2, err2, _ = run_edit(out1, sp, out2, rep2)
    if rc2 == 0 and os.path.exists(out2):
        e2 = judge.Dem(out2)
        dd = e2.h - edited.h
        res["idempotence_max_dz"] = float(np.nanmax(np.abs(dd))) if np.isfinite(dd).any() else 0.0
    else:
        res["idempotence_max_dz"] = None
        res["idempotence_error"] = "exit %s: %s" % (rc2, err2[:120])
    if NOISE_M > 0:
        res.update(noise_stability(g, style, sp, d))
    if pictures:
        os.makedirs(pictures, exist_ok=True)
        pts = [s["points"] for s in strokes]
        tag = "%s-%s" % (g["id"], style)
        r_tr = cases.render_view(dem, v, h=(judge.Dem(g["truth_path"]).h if g["kind"] != "identity" else base_h))
        judge.save_picture(r_tr, os.path.join(pictures, tag + "-truth.png"), pts)
        judge.save_picture(r_after, os.path.join(pictures, tag + "-after.png"), pts)
    verdict(res)
    return res


# --noise M: every case is edited again on a copy of its DEM with uniform
# noise of +-M m added to each valid cell (seeded by the case), both as
# Float32, and the largest difference of the two edits' changes is
# recorded: an edit a user can trust does not turn centimetres of input
# into metres of output. Off (0) by default: it adds two edits per case.
NOISE_M = 0.0


def write_f32(path, like, h):
    """h (NaN = nodata) as a Float32 GeoTIFF on like's grid."""
    src = gdal.Open(like)
    ds = gdal.GetDriverByName("GTiff").Create(path, src.RasterXSize, src.RasterYSize, 1, gdal.GDT_Float32)
    ds.SetGeoTransform(src.GetGeoTransform())
    ds.SetProjection(src.GetProjection())
    b = ds.GetRasterBand(1)
    b.SetNoDataValue(-32768.0)
    b.WriteArray(np.where(np.isfinite(h), h, -32768.0).astype(np.float32))
    b = None
    ds = None
    src = None


def noisy_heights(h, gid, style, noise_m):
    """h plus uniform noise of +-noise_m, seeded by the case (group id and style)."""
    rng = np.random.default_rng(seed_of_case(gid, style))
    return h + rng.uniform(-noise_m, noise_m, h.shape)


def noise_stability(g, style, sketch_path, d):
    dem = judge.Dem(g["base_path"])
    h = dem.h.astype(np.float64)
    noisy = noisy_heights(h, g["id"], style, NOISE_M)
    dz = {}
    for name, hh in (("plain", h), ("noisy", noisy)):
        inp = os.path.join(d, "stab-%s.tif" % name)
        write_f32(inp, g["base_path"], hh)
        hin = judge.Dem(inp).h
        out, rep = os.path.join(d, "stab-%s-out.tif" % name), os.path.join(d, "stab-%s.json" % name)
        rc, err, _ = run_edit(inp, sketch_path, out, rep)
        if rc != 0 or not os.path.exists(out):
            return {"noise_max_ddz": None, "noise_error": "%s edit exit %s: %s" % (name, rc, err[:120])}
        dz[name] = judge.Dem(out).h - hin
    dd = np.abs(dz["noisy"] - dz["plain"])
    dd = dd[np.isfinite(dd)]
    return {"noise_max_ddz": float(dd.max()) if dd.size else 0.0, "noise_cells_1m": int((dd > 1.0).sum())}


def seed_of_case(gid, style):
    return int.from_bytes(hashlib.sha256(("noise:%s:%s" % (gid, style)).encode()).digest()[:8], "little")


def verdict(res):
    reasons = []
    if res["fit_min"] < FIT_MIN:
        reasons.append("fit %.2f < %.2f" % (res["fit_min"], FIT_MIN))
    if res["kind"] == "identity" and res["max_abs_dz"] > IDENTITY_MAX_DZ:
        reasons.append("identity max|dz| %.1f m" % res["max_abs_dz"])
    if res["ground_dz_100m"] >= GROUND_MAX:
        reasons.append("ground within 100 m moved %.1f m" % res["ground_dz_100m"])
    if res["spikes"]:
        reasons.append("%d spike cells (+%.0f m)" % (res["spikes"], res["spike_excess_m"]))
    idem = res.get("idempotence_max_dz")
    if idem is None:
        reasons.append("re-edit failed")
    elif idem > IDEMPOTENT_MAX:
        reasons.append("re-edit moves %.1f m" % idem)
    if res.get("nodata_changed"):
        reasons.append("%d cells changed validity" % res["nodata_changed"])
    if res["kind"] != "identity":
        if res.get("beyond_influence"):
            reasons.append("%d cells changed beyond influence" % res["beyond_influence"])
        fall = res.get("rmse_fall")
        if fall is None or fall < RMSE_FALL:
            reasons.append("RMSE fall %s" % (("%.0f%%" % (100 * fall)) if fall is not None else "n/a"))
        w = res.get("depth_within", [])
        if w and not all(w):
            reasons.append("depth off >15%% on %d/%d strokes" % (len(w) - sum(w), len(w)))
    res["status"] = "pass" if not reasons else "fail"
    res["reason"] = "; ".join(reasons)


DEMO = {"id": "demo-zion_dome", "dem": "zion_srtm_utm12n", "kind": "demo", "vp_class": "bundled",
        "sketch": os.path.join(ROOT, "fixtures", "sketches", "zion_dome.json")}


def evaluate_demo(work):
    """The bundled demo (tools/demo.sh): its sketch as it is (pitch -1, eye height 1.7 m, which the
    judge does not render), checked for exit status, spikes, the observer's ground and idempotence."""
    g = DEMO
    res = {"group": g["id"], "dem": g["dem"], "kind": "demo", "vp_class": "bundled", "style": "bundled sketch"}
    base = judge.Dem(os.path.join(ROOT, "fixtures", g["dem"] + ".tif"))
    out1, rep1 = os.path.join(work, "demo.tif"), os.path.join(work, "demo.json")
    rc, err, dt = run_edit(base.path, g["sketch"], out1, rep1)
    res.update(rc=rc, edit_s=round(dt, 2))
    if rc != 0 or not os.path.exists(out1):
        res.update(status="fail", reason="edit exit %s: %s" % (rc, err[:160]))
        return res
    ed = judge.Dem(out1)
    dz = ed.h - base.h
    res["max_abs_dz"] = float(np.nanmax(np.abs(dz)))
    n_sp, ex_sp = spike_stats(dz, base.cell_m)
    res["spikes"], res["spike_excess_m"] = n_sp, round(ex_sp, 2)
    res["spike_excess_half_cells"] = round(ex_sp / (base.cell_m / 2), 3)
    sk = json.load(open(g["sketch"]))
    vp = sk["views"][0]["viewpoint"]
    ex, ny_ = base.local_xy_m(vp["lon"], vp["lat"])
    near = np.hypot(ex, ny_) <= 100.0
    res["ground_dz_vp"] = ed.height_ll(vp["lon"], vp["lat"]) - base.height_ll(vp["lon"], vp["lat"])
    res["ground_dz_100m"] = float(np.nanmax(np.abs(dz[near]))) if near.any() else abs(res["ground_dz_vp"])
    out2, rep2 = os.path.join(work, "demo2.tif"), os.path.join(work, "demo2.json")
    rc2, err2, _ = run_edit(out1, g["sketch"], out2, rep2)
    res["idempotence_max_dz"] = float(np.nanmax(np.abs(judge.Dem(out2).h - ed.h))) if rc2 == 0 and os.path.exists(out2) else None
    reasons = []
    if n_sp:
        reasons.append("%d spike cells (+%.0f m)" % (n_sp, ex_sp))
    if res["ground_dz_100m"] >= GROUND_MAX:
        reasons.append("ground within 100 m moved %.1f m" % res["ground_dz_100m"])
    if res["idempotence_max_dz"] is None or res["idempotence_max_dz"] > IDEMPOTENT_MAX:
        reasons.append("re-edit %s" % ("failed" if res["idempotence_max_dz"] is None else "moves %.1f m" % res["idempotence_max_dz"]))
    res["status"] = "pass" if not reasons else "fail"
    res["reason"] = "; ".join(reasons)
    return res


def run_group(args):
    g, styles, pictures, keep = args
    if g.get("kind") == "demo":
        work = tempfile.mkdtemp(prefix="fidelity-demo-")
        try:
            return [evaluate_demo(work)]
        finally:
            subprocess.run(["rm", "-rf", work])
    work = tempfile.mkdtemp(prefix="fidelity-")
    t = time.time()
    g0 = g
    try:
        g = cases.build_group(dict(g), os.path.join(ROOT, "fixtures"), work)
    except Exception as e:  # the suite reports, it does not stop
        return [{"group": g["id"], "dem": g["dem"], "kind": g["kind"], "vp_class": g["vp_class"],
                 "style": "-", "status": "n/a", "reason": "setup error: %r" % (e,)}]
    if "error" in g:
        return [{"group": g0["id"], "dem": g0["dem"], "kind": g0["kind"], "vp_class": g0["vp_class"],
                 "style": "-", "status": "n/a", "reason": g["error"]}]
    out = []
    for style in styles or g["styles"]:
        try:
            r = evaluate(g, style, work, pictures)
        except Exception as e:
            import traceback
            r = {"group": g["id"], "dem": g["dem"], "kind": g["kind"], "vp_class": g["vp_class"], "style": style,
                 "status": "error", "reason": "judge error: %r" % (e,), "trace": traceback.format_exc()[-800:]}
        out.append(r)
    if not keep:
        subprocess.run(["rm", "-rf", work])
    else:
        for r in out:
            r["workdir"] = work
    sys.stderr.write("fidelity: %s done in %.0f s\n" % (g["id"], time.time() - t))
    return out


def summary(results):
    ev = [r for r in results if r.get("status") in ("pass", "fail") and r.get("kind") != "demo"]
    ident = [r for r in ev if r["kind"] == "identity"]
    known = [r for r in ev if r["kind"] != "identity"]
    edited = [r for r in ev if "fit_min" in r]
    lines = []

    def line(name, ok, total, detail=""):
        lines.append({"line": name, "ok": ok, "total": total, "pass": total > 0 and ok == total, "detail": detail})

    idn = [r for r in ident if "fit_min" in r]
    line("identity: max|dz| <= 3 m", sum(r["max_abs_dz"] <= IDENTITY_MAX_DZ for r in idn), len(ident),
         "max|dz| median %.1f m, max %.1f m" % (np.median([r["max_abs_dz"] for r in idn]), max(r["max_abs_dz"] for r in idn)) if idn else "")
    line("identity: every stroke judge-fitted >= 0.95", sum(r["fit_min"] >= FIT_MIN for r in idn), len(ident),
         "min fit median %.2f" % np.median([r["fit_min"] for r in idn]) if idn else "")
    kn = [r for r in known if "fit_min" in r]
    line("known change: every stroke judge-fitted >= 0.95", sum(r["fit_min"] >= FIT_MIN for r in kn), len(known),
         "min fit median %.2f" % np.median([r["fit_min"] for r in kn]) if kn else "")
    falls = [r.get("rmse_fall") for r in kn if r.get("rmse_fall") is not None]
    line("known change: RMSE to truth in visible changed region falls >= 50%",
         sum(f >= RMSE_FALL for f in falls), len(known),
         "fall median %.0f%%, min %.0f%%, max %.0f%%" % (100 * np.median(falls), 100 * min(falls), 100 * max(falls)) if falls else "")
    dw = [w for r in kn for w in r.get("depth_within", [])]
    share = (sum(dw) / len(dw)) if dw else 0.0
    lines.append({"line": "known change: >= 90% of strokes placed within 15% of the true depth",
                  "ok": sum(dw), "total": len(dw), "pass": bool(dw) and share >= 0.9,
                  "detail": "%.0f%% of %d strokes" % (100 * share, len(dw))})
    line("ground within 100 m of the viewpoint unchanged (< 0.5 m), all cases", sum(r["ground_dz_100m"] < GROUND_MAX for r in edited),
         len(ev), "max %.1f m" % max(r["ground_dz_100m"] for r in edited) if edited else "")
    line("known change: no change beyond the influence distance", sum(r.get("beyond_influence", 0) == 0 for r in kn), len(known))
    line("no spike, all cases", sum(r["spikes"] == 0 for r in edited), len(ev),
         "largest excess over all 8 neighbours: %.2f half-cells" % max(r["spike_excess_half_cells"] for r in edited) if edited else "")
    idm = [r for r in edited if r.get("idempotence_max_dz") is not None]
    line("idempotence (re-edit moves <= 0.5 m), all cases", sum(r["idempotence_max_dz"] <= IDEMPOTENT_MAX for r in idm), len(ev),
         "max %.1f m" % max(r["idempotence_max_dz"] for r in idm) if idm else "")
    line("edit exits 0 and writes", len(edited), len(ev))
    nz = [r for r in edited if "noise_max_ddz" in r]
    if nz:
        vals = [r["noise_max_ddz"] for r in nz if r["noise_max_ddz"] is not None]
        line("reported: +-%g m input noise moves the edit's change by <= 1 m (not an issue line)" % NOISE_M,
             sum(v <= 1.0 for v in vals), len(nz),
             "median %.2f m, max %.1f m, %d over 10 m" % (np.median(vals), max(vals), sum(v > 10 for v in vals)) if vals else "")
    demo = [r for r in results if r.get("kind") == "demo"]
    if demo:
        d = demo[0]
        lines.append({"line": "bundled demo (zion_dome.json): no spike, observer's ground fixed, idempotent",
                      "ok": int(d.get("status") == "pass"), "total": 1, "pass": d.get("status") == "pass",
                      "detail": "max|dz| %s m, spikes %s, re-edit %s m%s" % (
                          fmt(d.get("max_abs_dz"), 1), d.get("spikes", "-"), fmt(d.get("idempotence_max_dz"), 1),
                          ("; " + d["reason"]) if d.get("reason") else "")})
    return lines


def fmt(x, p=2):
    if x is None:
        return "-"
    if isinstance(x, float):
        if not math.isfinite(x):
            return str(x)
        return ("%%.%df" % p) % x
    return str(x)


def esc(x):
    return str(x).replace("|", "\\|")


def write_md(path, results, lines, meta):
    L = []
    L.append("# Fidelity of `demsketch edit`: an evaluation nobody tuned to\n")
    L.append("Generated by `tools/fidelity/run.py` (%s). Binary: `%s` (%s). %d cases in %d groups, %d evaluated, %.0f s.\n" % (
        meta["when"], meta["binary"], meta["binary_info"], len(results), meta["groups"],
        sum(r.get("status") in ("pass", "fail") for r in results), meta["elapsed_s"]))
    L.append(open(os.path.join(HERE, "README.md")).read().split("<!-- table -->")[0].split("\n", 1)[1])
    L.append("## Summary per acceptance line\n")
    L.append("| acceptance line | cases meeting it | of | met | detail |")
    L.append("| --- | --- | --- | --- | --- |")
    for l in lines:
        L.append("| %s | %d | %d | %s | %s |" % (esc(l["line"]), l["ok"], l["total"], "yes" if l["pass"] else "**no**", esc(l["detail"])))
    n_pass = sum(r.get("status") == "pass" for r in results)
    L.append("\nCases passing every line: **%d of %d** (n/a: %d).\n" % (
        n_pass, len(results), sum(r.get("status") in ("n/a", "error") for r in results)))
    ev = [r for r in results if "fit_min" in r]
    for key, title in (("kind", "kind"), ("style", "stroke style"), ("dem", "DEM"), ("vp_class", "viewpoint class")):
        L.append("| %s | cases | pass | every stroke judge-fitted >= 0.95 | median max\\|dz\\| m | re-edit <= 0.5 m |" % title)
        L.append("| --- | --- | --- | --- | --- | --- |")
        for val in sorted({r[key] for r in ev}):
            cs = [r for r in ev if r[key] == val]
            L.append("| %s | %d | %d | %d | %.1f | %d |" % (
                val, len(cs), sum(r["status"] == "pass" for r in cs), sum(r["fit_min"] >= FIT_MIN for r in cs),
                float(np.median([r["max_abs_dz"] for r in cs])),
                sum((r.get("idempotence_max_dz") is not None and r["idempotence_max_dz"] <= IDEMPOTENT_MAX) for r in cs)))
        L.append("")
    q = [s["depth_ratio"] for r in ev if r["kind"] != "identity" for s in r["strokes"] if "depth_ratio" in s]
    if q:
        qn = np.array([a for a, b in q])
        qf = np.array([b for a, b in q])
        L.append("Known change, placed / true depth over %d strokes: near end p10 / p50 / p90 = %.2f / %.2f / %.2f, "
                 "far end %.2f / %.2f / %.2f.\n" % ((len(q),) + tuple(np.percentile(qn, [10, 50, 90])) + tuple(np.percentile(qf, [10, 50, 90]))))
    jq = [s["judge_depth_ratio_median"] for r in ev if r["kind"] != "identity" for s in r["strokes"]
          if s.get("judge_depth_ratio_median") is not None]
    if jq:
        L.append("Known change, the judge's own reading (depth of the edited boundary under each fitted stroke / true "
                 "depth, median per stroke): within 15%% on %d of %d strokes with fitted columns.\n" % (
                     sum(abs(x - 1) <= DEPTH_TOL for x in jq), len(jq)))
    ons = [(r, s) for r in ev if r["kind"] == "identity" for s in r["strokes"] if s.get("report_on_silhouette") is not None]
    if ons:
        L.append("Identity strokes (traced by the judge on robust boundaries of the unedited DEM) that the report says lie "
                 "on one of demsketch's own silhouettes before the edit (`on_silhouette` >= 0.95): %d of %d; median "
                 "`on_silhouette` %.2f; on the NZ 1 km DEM %s.\n" % (
                     sum(s["report_on_silhouette"] >= 0.95 for r, s in ons), len(ons),
                     float(np.median([s["report_on_silhouette"] for r, s in ons])),
                     ("%.2f" % float(np.median([s["report_on_silhouette"] for r, s in ons if r["dem"].startswith("nz")])))
                     if any(r["dem"].startswith("nz") for r, s in ons) else "-"))
    d = [(s["report_fit"], s["judge_fit"]) for r in ev for s in r["strokes"] if s.get("report_fit") is not None]
    if d:
        L.append("The report's own `fit.fitted_fraction` against the judge's, over %d strokes: report >= 0.95 but judge < 0.95 "
                 "on %d, report < 0.95 but judge >= 0.95 on %d.\n" % (
                     len(d), sum(a >= FIT_MIN and b < FIT_MIN for a, b in d), sum(a < FIT_MIN and b >= FIT_MIN for a, b in d)))
    L.append("## Every case\n")
    L.append("Columns: judge fit = the judge's fitted fraction of the worst stroke (1 px, any boundary); "
             "max|dz| over the DEM; ground: change at the viewpoint (bilinear) / max within 100 m; depth ratio = "
             "placed / true depth of each stroke ([near, far], report `match.depth_m` vs the judge's boundary "
             "depths on the truth); judge depth ratio = median over the fitted columns of the depth of the edited "
             "terrain's boundary under the stroke / the truth boundary's depth (the judge's own reading of the placement); RMSE: before -> after (fall) in the visible changed region; "
             "spike: cells; idem: max change on re-editing the output.\n")
    L.append("| case | DEM | kind | viewpoint | style | strokes | judge fit min | max\\|dz\\| m | ground vp / 100 m | depth ratios | judge depth ratio | RMSE m | beyond infl. | spike | idem m | result |")
    L.append("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for n, r in enumerate(results):
        if r.get("kind") == "demo":
            L.append("| %d | %s | demo | bundled | zion_dome.json | 2 | (pitch -1: not rendered) | %s | %.2f / %.2f | - | - | - | - | %s | %s | %s |" % (
                n + 1, r["dem"], fmt(r.get("max_abs_dz"), 1), r.get("ground_dz_vp", float("nan")), r.get("ground_dz_100m", float("nan")),
                r.get("spikes", "-"), fmt(r.get("idempotence_max_dz"), 2),
                "pass" if r["status"] == "pass" else "fail: " + esc(r.get("reason", ""))))
            continue
        if r.get("status") not in ("pass", "fail") or "fit_min" not in r:
            L.append("| %d | %s | %s | %s | %s | %s | - | - | - | - | - | - | - | - | - | %s: %s |" % (
                n + 1, r["dem"], r["kind"], r["vp_class"], r["style"], r.get("n_strokes", "-"), r.get("status"), esc(r.get("reason", ""))))
            continue
        dr = ", ".join("%.2f/%.2f" % tuple(s["depth_ratio"]) for s in r["strokes"] if "depth_ratio" in s) or "-"
        jr = ", ".join("%.2f" % s["judge_depth_ratio_median"] for s in r["strokes"]
                       if s.get("judge_depth_ratio_median") is not None) or "-"
        rm = "-"
        if r.get("rmse_before") is not None:
            rm = "%.1f -> %.1f (%+.0f%%)" % (r["rmse_before"], r["rmse_after"], -100 * r["rmse_fall"])
        L.append("| %d | %s | %s | %s | %s | %d | %.2f | %.1f | %.2f / %.2f | %s | %s | %s | %s | %d | %s | %s |" % (
            n + 1, r["dem"], r["kind"], r["vp_class"], r["style"], r["n_strokes"], r["fit_min"], r["max_abs_dz"],
            r["ground_dz_vp"], r["ground_dz_100m"], dr, jr, rm,
            r.get("beyond_influence", "-") if r["kind"] != "identity" else "-", r["spikes"],
            fmt(r.get("idempotence_max_dz"), 2), "pass" if r["status"] == "pass" else "fail: " + esc(r["reason"])))
    L.append("")
    tail = open(os.path.join(HERE, "README.md")).read().split("<!-- table -->")
    if len(tail) > 1:
        L.append(tail[1])
    fpath = os.path.join(HERE, "findings.md")
    if os.path.exists(fpath):
        L.append(open(fpath).read())
    if meta.get("validation"):
        L.append(meta["validation"])
    with open(path, "w") as f:
        f.write("\n".join(L) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--subset", choices=["all", "ci"], default="all")
    ap.add_argument("--report-only", action="store_true", help="always exit 0 (CI before the edit meets the lines)")
    ap.add_argument("--require", default="",
                    help="comma-separated parts of line names that must pass even with --report-only")
    ap.add_argument("--json", default=None, help="results JSON (default: tools/fidelity/results[-ci].json)")
    ap.add_argument("--md", default=None, help="table (default docs/fidelity.md for the whole suite, none for ci)")
    ap.add_argument("--save-pictures", default=None, metavar="DIR")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--only", default=None, help="run only groups whose id contains this")
    ap.add_argument("--keep", action="store_true", help="keep the work directories")
    ap.add_argument("--noise", type=float, default=0.0, metavar="M",
                    help="also edit each case's DEM plus uniform +-M m noise and record how far the change moves")
    ap.add_argument("--from-json", default=None, metavar="FILE",
                    help="do not run: rewrite the table (--md, default docs/fidelity.md) from a results JSON")
    a = ap.parse_args()
    global NOISE_M
    NOISE_M = a.noise
    if a.from_json:
        j = json.load(open(a.from_json))
        meta = j["meta"]
        vpath = os.path.join(HERE, "validation.md")
        if os.path.exists(vpath):
            meta["validation"] = open(vpath).read()
        if not a.md and cases.SEED_SALT:
            sys.exit("run.py: --from-json with FIDELITY_SEED set needs --md (docs/fidelity.md is the tuned suite's)")
        write_md(a.md or os.path.join(ROOT, "docs", "fidelity.md"), j["cases"], summary(j["cases"]), meta)
        return
    if not os.path.exists(demsketch()):
        sys.exit("fidelity: no demsketch binary at %s (set DEMSKETCH)" % demsketch())
    gs = cases.groups() + [DEMO]
    styles = {}
    if a.subset == "ci":
        # the judge itself first: a broken judge fails CI even with --report-only
        st = subprocess.run(["/usr/bin/python3", os.path.join(HERE, "selftest.py")], capture_output=True, text=True)
        sys.stdout.write(st.stdout)
        if st.returncode != 0:
            sys.stderr.write(st.stderr)
            sys.exit(2)
        gs = [g for g in gs if g["id"] in CI_GROUPS]
        styles = CI_STYLES
    if a.only:
        gs = [g for g in gs if a.only in g["id"]]
    t0 = time.time()
    jobs = [(g, styles.get(g["id"]), a.save_pictures, a.keep) for g in gs]
    results = []
    if a.jobs > 1:
        with ProcessPoolExecutor(max_workers=a.jobs) as ex:
            for out in ex.map(run_group, jobs):
                results.extend(out)
    else:
        for j in jobs:
            results.extend(run_group(j))
    lines = summary(results)
    binfo = subprocess.run(["git", "-C", ROOT, "log", "-1", "--format=%h %cI"], capture_output=True, text=True).stdout.strip()
    meta = {"when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "binary": demsketch(),
            "binary_info": "built %s" % time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(os.path.getmtime(demsketch()))),
            "checkout": binfo, "groups": len(gs), "elapsed_s": time.time() - t0, "subset": a.subset}
    jpath = a.json or os.path.join(HERE, "results%s.json" % ("-ci" if a.subset == "ci" else ""))
    with open(jpath, "w") as f:
        json.dump({"meta": meta, "summary": lines, "cases": results}, f, indent=1, default=float)
    # The default table is the tuned suite's: a hold-out run (FIDELITY_SEED
    # set) writes a table only where --md names one.
    default_md = a.subset == "all" and not a.only and not cases.SEED_SALT
    md = a.md if a.md else (os.path.join(ROOT, "docs", "fidelity.md") if default_md else None)
    if md:
        vpath = os.path.join(HERE, "validation.md")
        if os.path.exists(vpath):
            meta["validation"] = open(vpath).read()
        write_md(md, results, lines, meta)
    for l in lines:
        print("%-4s %4d/%-4d %s  %s" % ("ok" if l["pass"] else "FAIL", l["ok"], l["total"], l["line"], l["detail"]))
    print("fidelity: %d cases, %d pass, %.0f s" % (len(results), sum(r.get("status") == "pass" for r in results), time.time() - t0))
    failed = not all(l["pass"] for l in lines)
    required = [q.strip() for q in (a.require or "").split(",") if q.strip()]
    missed = [l["line"] for l in lines if not l["pass"] and any(q in l["line"] for q in required)]
    if missed:
        print("fidelity: required lines failed: " + "; ".join(missed))
        sys.exit(1)
    if failed and not a.report_only:
        sys.exit(1)


if __name__ == "__main__":
    main()
