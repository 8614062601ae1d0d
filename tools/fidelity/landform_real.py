#!/usr/bin/python3
"""Landforms from silhouettes on the real fixtures (issue 14 item 5): the
judge's fit of each landform's silhouette, DEM by DEM and stroke by stroke.

    /usr/bin/python3 tools/fidelity/landform_real.py [--md TABLE.md] [--json OUT.json]
        [--only DEM_SUBSTRING] [--styles S,...] [--keep DIR] [--pictures DIR]

For each fixture a viewpoint and heading are chosen automatically (the
first candidate cell, scanned in a fixed order, from which the judge sees
the ground at every stroke distance over the stroke's columns), then for
each stroke style and distance D (1-3 km) a stroke is drawn in image space:
its end points on the ground the judge sees at depth D, its body a bump of
the style's shape, raised until it clears the nearer terrain by 3 px (so
the landform can be seen at all). `demsketch correct DEM --features F
--sketch S` builds the landform (default shadow and boundary) and
`landform_fit.py`'s measure (judge.fit, 1 px) is taken on the after-DEM.
The DEM used for tuning is listed in TUNED; the others are held out.

--feet hillside (the original cases) puts the strokes' ends 4 rows inside
a run of ground; --feet crest on a visible crest (the row above shows sky
or terrain at least 5% and a cell farther), as a person adds a peak or a
ridge on a ridge line. Besides the judge's fit over all the stroke's
columns, each case reports the fit over the columns the stroke can show
(showable_fit), the landform's roughness on the DEM (roughness) and the
wavelet energy ratio of its crest measured on the DEM (dem_energy_ratio);
the Markdown ends with the jagged styles' ratios against their smooth
counterparts (JAGGED_PAIRS). docs/landform_real.md says what each means.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import judge  # noqa: E402
from run import spike_stats  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BIN = os.environ.get("DEMSKETCH", os.path.join(ROOT, "target/release/demsketch"))
W, H, HFOV = 640, 360, 60.0
FIXTURES = [
    "zion_srtm_utm12n.tif",
    "zion_srtm90m_epsg4326.tif",
    "arenal_aster30m_epsg4326.tif",
    "texas_srtm90m_tiled_int16.tif",
    "vinschgau_250m_utm32n.tif",
]
TUNED = {"zion_srtm_utm12n.tif"}
# where the strokes' feet stand (--feet): "hillside" or "crest", see ground_rows
FEET = "hillside"
# style: (column span px, bump height px, shape)
STYLES = {
    "smooth": (120, 40, "bump"),
    "jagged": (120, 40, "jag"),
    "long": (300, 30, "ridge"),
    "short": (50, 25, "bump"),
    "asym": (140, 45, "asym"),
    "dome": (160, 40, "dome"),
    # teeth spanning several DEM cells at the landform's distance (what a
    # person drawing rough terrain at that range means): see cell_teeth
    "jagged_cells": (120, 40, "bump_teeth"),
    "long_jagged_cells": (300, 30, "ridge_teeth"),
}
ORIGINAL_STYLES = ("smooth", "jagged", "long", "short", "asym", "dome")
# jagged style -> its smooth counterpart, for the roughness ratios
JAGGED_PAIRS = {"jagged": "smooth", "jagged_cells": "smooth", "long_jagged_cells": "long"}
# cell teeth: period in DEM cells at the landform's distance, and the
# teeth's amplitude as a share of the period (0.25: flanks at 45 degrees)
TOOTH_PERIOD_CELLS = 4.0
TOOTH_AMPLITUDE = 0.25
DISTANCES = [1000.0, 2000.0, 3000.0]


def shape(kind, t):
    """Height share at t in [0, 1] (0 at both ends)."""
    if kind in ("bump", "jag", "bump_teeth"):
        return 1.0 - (2 * t - 1) ** 2
    if kind in ("ridge", "ridge_teeth"):
        return min(1.0, 4 * t, 4 * (1 - t))
    if kind == "dome":
        return math.sqrt(max(0.0, 1.0 - (2 * t - 1) ** 2))
    if kind == "asym":
        return (t / 0.3) if t < 0.3 else (1 - t) / 0.7
    raise ValueError(kind)


def ground_rows(depth, D, feet="hillside", cell_m=0.0):
    """Per column: a row (centre) where the judge sees terrain at depth
    D..1.25 D, inside a run of at least 9 such rows, NaN if none; and the
    top of the nearer terrain (depth < 0.8 D). feet "hillside" (the
    original cases): 4 rows from the run's ends (not on an occlusion
    boundary), at the depth nearest 1.1 D. feet "crest": the bottom edge
    of the run's top row (so the end pixel shows the ground in any
    renderer), where the row above shows sky or terrain at least 5% and a
    cell farther (a foot on a visible crest, so the stroke can show from
    its first column), NaN if the run's top is not such a crest."""
    at = np.full(W, np.nan)
    near_top = np.full(W, float(H))
    for c in range(W):
        col = depth[:, c]
        run = []
        above = math.inf
        for y in range(H - 1, -1, -1):
            d = col[y]
            if d < 0.8 * D:
                near_top[c] = y
            if D <= d <= 1.25 * D:
                run.append(y)
            elif run:
                above = d
                break
            if math.isinf(d):
                break
        if len(run) < 9:
            continue
        if feet == "crest":
            top = col[run[-1]]
            if above >= max(1.05 * top, top + cell_m):
                at[c] = run[-1] + 1.0
            continue
        inner = run[4:-4]
        y = min(inner, key=lambda yy: abs(col[yy] - 1.1 * D))
        at[c] = y + 0.5
    return at, near_top


def cell_px(dem, D):
    """A DEM cell's width in the image at 1.1 D (where the stroke's ends
    stand), pixels."""
    f = (W / 2.0) / math.tan(math.radians(HFOV) / 2.0)
    return f * dem.cell_m / (1.1 * D)


def cell_teeth(xs, sh, dem, D):
    """Teeth spanning several cells at the landform's distance: a triangle
    wave of period TOOTH_PERIOD_CELLS cells (at least 12 px, the old
    jagged stroke's), amplitude TOOTH_AMPLITUDE of the period, tapered in
    with the shape over its lower half so the feet stay on the ground
    (image px, positive down)."""
    period = max(12.0, TOOTH_PERIOD_CELLS * cell_px(dem, D))
    amp = TOOTH_AMPLITUDE * period
    u = (xs - xs[0]) / period
    tri = 1.0 - 4.0 * np.abs(u - np.floor(u) - 0.5)
    return amp * tri * np.minimum(1.0, sh / 0.5)


def draw(style, D, rows, near_top, c_mid, dem):
    span, hpx, kind = STYLES[style]
    c0, c1 = c_mid - span // 2, c_mid + span // 2
    if c0 < 5 or c1 > W - 5 or math.isnan(rows[c0]) or math.isnan(rows[c1]):
        return None
    y0, y1 = rows[c0], rows[c1]
    xs = np.arange(c0, c1 + 1, 2.0) + 0.5
    xs[-1] = c1 + 0.5
    ts = (xs - c0) / (c1 - c0)
    base = y0 + ts * (y1 - y0)
    sh = np.array([shape(kind, t) for t in ts])
    teeth = cell_teeth(xs, sh, dem, D) if kind.endswith("_teeth") else np.zeros_like(xs)
    # raise the bump until it clears the nearer terrain by 3 px
    need = hpx
    for x, b, s, tooth in zip(xs, base, sh, teeth):
        if s > 0.2:
            top = near_top[int(x)] - 3.0
            if b + tooth - hpx * s > top:
                need = max(need, (b + tooth - top) / s)
    hpx = min(need, 150.0)
    ys = base - hpx * sh + teeth
    if FEET == "crest":
        # the first and last points (half a pixel in from the end columns)
        # on the foot row: the dome, steep at its feet, starts 4.4 px
        # above it, on the hillside with hillside feet but in the sky
        # above a crest
        ys[0], ys[-1] = base[0], base[-1]
    if kind == "jag":
        for k in range(1, len(ys) - 1):
            ys[k] += 3.0 if (k // 3) % 2 else -3.0
    return [[float(x), float(y)] for x, y in zip(xs, ys)], hpx


def choose_view(dem):
    """A viewpoint and heading from which the ground is seen at every
    distance over the middle columns: candidates on a grid of cells in a
    fixed order, headings every 45 degrees."""
    ny, nx = dem.ny, dem.nx
    best = None
    for fy in (0.5, 0.35, 0.65, 0.25, 0.75):
        for fx in (0.5, 0.35, 0.65, 0.25, 0.75):
            px, py = nx * fx, ny * fy
            lon, lat = dem.pixel_to_ll(px, py)
            g = dem.height_ll(lon, lat)
            if not math.isfinite(g):
                continue
            for heading in range(0, 360, 45):
                r = judge.render(dem, lon, lat, g + 1.7, heading, HFOV, W, H)
                depth = judge.depth_image(r)
                score = 0
                for D in DISTANCES:
                    rows, _ = ground_rows(depth, D)
                    score += int(np.isfinite(rows[150:490]).sum())
                if best is None or score > best[0]:
                    best = (score, lon, lat, heading, depth)
            if best and best[0] > 0.9 * 340 * len(DISTANCES):
                return best
    return best


def save_pictures(dem, out, pts, view, prefix):
    """The judge's renders of the DEM before and after (PREFIX_before.png,
    PREFIX_after.png), the stroke drawn in yellow."""
    score, lon, lat, heading, depth = view
    alt = dem.height_ll(lon, lat) + 1.7
    for name, d in (("before", dem), ("after", judge.Dem(out))):
        r = judge.render(d, lon, lat, alt, heading, HFOV, W, H)
        judge.save_picture(r, f"{prefix}_{name}.png", strokes=[pts])


def run_case(dem_path, dem, view, style, D, tmp, pictures=None):
    score, lon, lat, heading, depth = view
    rows, near_top = ground_rows(depth, D, FEET, dem.cell_m)
    ok = np.isfinite(rows)
    # the stroke's middle column: the most central one with both ends on ground
    span = STYLES[style][0]
    for off in sorted(range(-200, 201, 4), key=abs):
        cm = W // 2 + off
        c0, c1 = cm - span // 2, cm + span // 2
        if 5 <= c0 and c1 < W - 5 and ok[c0] and ok[c1]:
            break
    else:
        return {"status": "no ground at this distance"}
    drawn = draw(style, D, rows, near_top, cm, dem)
    if drawn is None:
        return {"status": "no ground at this distance"}
    pts, hpx = drawn
    sketch = {"views": [{"name": "v", "viewpoint": {"lon": lon, "lat": lat, "eye_height_m": 1.7},
                         "camera": {"heading_deg": float(heading), "hfov_deg": HFOV,
                                    "width": W, "height": H},
                         "strokes": [{"id": "s", "points": pts}]}]}
    sk = os.path.join(tmp, "sketch.json")
    with open(sk, "w") as f:
        json.dump(sketch, f)
    feats = os.path.join(tmp, "f.geojson")
    with open(feats, "w") as f:
        json.dump({"type": "FeatureCollection", "features": [
            {"type": "Feature", "properties": {"kind": "landform", "name": "lf",
                                               "silhouette": {"view": "v", "stroke": "s"}},
             "geometry": None}]}, f)
    out, rep = os.path.join(tmp, "out.tif"), os.path.join(tmp, "rep.json")
    for p in (out, rep):
        if os.path.exists(p):
            os.remove(p)
    o = subprocess.run([BIN, "correct", dem_path, "--features", feats, "--sketch", sk,
                        "--out", out, "--report", rep], capture_output=True, text=True)
    res = {"lonlat": [round(lon, 5), round(lat, 5)], "heading": heading, "cols": [pts[0][0], pts[-1][0]],
           "bump_px": round(hpx, 1)}
    if o.returncode != 0:
        res["status"] = "correct failed: " + o.stderr.strip()[-200:]
        return res
    with open(rep) as f:
        lf = json.load(f)["corrections"][0]
    res["peak_m"] = lf.get("landform", {}).get("peak_m")
    res["energy_ratio"] = (lf.get("noise") or {}).get("detail_energy_ratio")
    res["curve_error_m"] = lf.get("max_curve_error_m", lf.get("landform", {}).get("max_curve_error_m"))
    fo = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "tools/fidelity/landform_fit.py"),
                         dem_path, out, sk, "v", "s", "--columns"], capture_output=True, text=True)
    if fo.returncode != 0:
        res["status"] = "judge failed: " + fo.stderr.strip()[-200:]
        return res
    res.update(json.loads(fo.stdout))
    res.update(resolvable(dem, depth, pts, D))
    dev = res.pop("dev_by_column", {})
    res.update(misses(dem, depth, pts, dev))
    res.update(showable_fit(dem, depth, pts, dev))
    after = judge.Dem(out)
    res["roughness_m"] = roughness(dem, after)
    res["spikes"] = spike_stats(after.h - dem.h, dem.cell_m)[0]
    res["dem_energy_ratio"] = dem_energy_ratio(after, lf.get("landform", {}).get("shadow"))
    if pictures:
        save_pictures(dem, out, pts, view,
                      os.path.join(pictures, f"{os.path.basename(dem_path)[:-4]}_{style}_{int(D)}"))
    res["status"] = "ok" if res["silhouette_share"] >= 0.95 else (
        f"stroke over terrain in {100 * (1 - res['silhouette_share']):.0f}% of its columns")
    if res["cells_across"] < 6:
        res["status"] += f"; sub-cell: {res['cells_across']:.1f} cells across"
    return res


def terrain_above_ok(dem, depth, pts):
    """Per stroke column: True where the before render shows sky, or
    terrain at least 5% and a cell farther than the ground the stroke's
    ends stand on, just above the stroke."""
    cols = judge.stroke_columns(pts, W)
    ends = [depth[min(H - 1, int(q[1])), min(W - 1, int(q[0]))] for q in (pts[0], pts[-1])]
    d_end = max([e for e in ends if math.isfinite(e)] or [math.inf])
    out = {}
    for c, ys in cols.items():
        y = int(math.floor(min(ys))) - 1
        d = depth[y, c] if 0 <= y < H else math.inf
        out[c] = bool(d >= max(1.05 * d_end, d_end + dem.cell_m))
    return out


def showable_fit(dem, depth, pts, dev_by_column):
    """The fit over the columns the stroke can show: those where the
    before render shows sky, or terrain at least 5% and a cell farther
    than the stroke's ends' ground, just above the stroke
    (terrain_above_ok). Elsewhere nearer terrain, or ground behind the foot
    too close for the judge to count a boundary, stands just above the
    stroke: a landform that does not lower what the user did not draw
    cannot show a silhouette there. None if no column is showable."""
    ok = terrain_above_ok(dem, depth, pts)
    shown = [c for c, good in ok.items() if good]
    if not shown:
        return {"fit_showable": None, "showable_columns": 0}
    hit = sum(1 for c in shown
              if dev_by_column.get(str(c)) is not None and dev_by_column[str(c)] <= 1.0)
    return {"fit_showable": hit / len(shown), "showable_columns": len(shown)}


def blur(a, sigma):
    """Gaussian blur of a 2D array (NaN-free), separable, reflecting edges."""
    r = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        b = np.pad(a, pad, mode="reflect")
        a = sum(k[i] * np.take(b, range(i, i + a.shape[axis]), axis=axis)
                for i in range(2 * r + 1))
    return a


ROUGH_SIGMA_CELLS = 1.5


def roughness(before, after):
    """Terrain roughness of a landform, measured on the DEM: the RMS over
    the cells it changed of its height change minus that change blurred
    by a Gaussian of ROUGH_SIGMA_CELLS cells (the detail at 1-4 cells, the
    scales a cell-teeth stroke draws), metres. None if nothing changed."""
    dz = after.h - before.h
    changed = np.isfinite(dz) & (dz != 0)
    if not changed.any():
        return None
    ys, xs = np.nonzero(changed)
    pad = int(4 * ROUGH_SIGMA_CELLS) + 2
    y0, y1 = max(0, ys.min() - pad), min(dz.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(dz.shape[1], xs.max() + pad + 1)
    w = np.nan_to_num(dz[y0:y1, x0:x1])
    hp = w - blur(w, ROUGH_SIGMA_CELLS)
    m = changed[y0:y1, x0:x1]
    return float(np.sqrt(np.mean(hp[m] ** 2)))


DEM_BAND_STEPS = (1, 2, 4)


def atrous(v, step):
    """One level of the binomial a-trous pyramid, [1, 4, 6, 4, 1] / 16 with
    taps step apart, the ends extended by point reflection (as
    src/correct/wavelet_noise.rs smooth does)."""
    n = len(v)
    idx = np.arange(n)

    def at(i):
        i = np.asarray(i)
        lo = np.clip(-i, 0, n - 1)
        hi = np.clip(2 * (n - 1) - i, 0, n - 1)
        return np.where(i < 0, 2 * v[0] - v[lo],
                        np.where(i >= n, 2 * v[-1] - v[hi], v[np.clip(i, 0, n - 1)]))
    return (at(idx - 2 * step) + 4 * at(idx - step) + 6 * at(idx) + 4 * at(idx + step)
            + at(idx + 2 * step)) / 16.0


def dem_energy_ratio(after, shadow):
    """The wavelet energy ratio of the landform's crest measured on the
    DEM: the after-DEM's bilinear heights along the report's shadow (the
    silhouette's ground track; the landform passes through the placed
    silhouette there), every half cell, decomposed by the a-trous pyramid
    into detail bands of 1, 2 and 4 cells (DEM_BAND_STEPS); their energy
    over the variance of what is left (the landform's shape). Unlike the
    report's noise.detail_energy_ratio it is not limited to a sixteenth
    of the stroke's length. None without a shadow or with under 16
    samples."""
    if not shadow or len(shadow.get("coordinates", [])) < 2:
        return None
    gt = after.gt
    px = [((x - gt[0]) / gt[1], (y - gt[3]) / gt[5]) for x, y in shadow["coordinates"]]
    seg = [math.hypot((b[0] - a[0]) * after.cell_x_m, (b[1] - a[1]) * after.cell_y_m)
           for a, b in zip(px[:-1], px[1:])]
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    ds = 0.5 * after.cell_m
    ss = np.arange(0.0, cum[-1], ds)
    if len(ss) < 16:
        return None
    xs = np.interp(ss, cum, [p[0] for p in px]) - 0.5
    ys = np.interp(ss, cum, [p[1] for p in px]) - 0.5
    x0 = np.clip(np.floor(xs).astype(int), 0, after.nx - 2)
    y0 = np.clip(np.floor(ys).astype(int), 0, after.ny - 2)
    fx, fy = xs - x0, ys - y0
    h = after.h
    z = ((1 - fx) * (1 - fy) * h[y0, x0] + fx * (1 - fy) * h[y0, x0 + 1]
         + (1 - fx) * fy * h[y0 + 1, x0] + fx * fy * h[y0 + 1, x0 + 1])
    if not np.isfinite(z).all():
        return None
    level, detail = z, 0.0
    for step in DEM_BAND_STEPS:
        nxt = atrous(level, step)
        detail += float(np.mean((level - nxt) ** 2))
        level = nxt
    shape_var = float(np.var(level))
    return detail / shape_var if shape_var > 0 else None


def misses(dem, depth, pts, dev_by_column):
    """Where the judge missed the stroke (deviation over 1 px): in columns
    where the before render shows nearer terrain just above the stroke
    (terrain_above_ok false: no boundary there unless the ground behind is
    dug), within one DEM cell's width in the image of either end (where
    the stroke's corner with the ground falls between cell centres), or
    elsewhere."""
    ok = terrain_above_ok(dem, depth, pts)
    f = (W / 2.0) / math.tan(math.radians(HFOV) / 2.0)
    ends = [depth[min(H - 1, int(q[1])), min(W - 1, int(q[0]))] for q in (pts[0], pts[-1])]
    cell_px = [f * dem.cell_m / e if math.isfinite(e) and e > 0 else 0.0 for e in ends]
    n = {"miss_terrain_above": 0, "miss_end_cell": 0, "miss_interior": 0}
    for key, d in dev_by_column.items():
        c = int(key)
        if d is not None and d <= 1.0:
            continue
        if not ok.get(c, True):
            n["miss_terrain_above"] += 1
        elif c + 0.5 - pts[0][0] <= cell_px[0] or pts[-1][0] - (c + 0.5) <= cell_px[1]:
            n["miss_end_cell"] += 1
        else:
            n["miss_interior"] += 1
    return n


def resolvable(dem, depth, pts, D):
    """What the DEM and the view allow before any code runs: the share of
    the stroke's columns where the before render shows sky, or terrain at
    least 5% and a cell farther than the ground the stroke's ends stand on,
    just above the stroke (where else the judge cannot count a boundary
    unless the ground behind the landform is dug), and how many cells
    across the landform is at that distance."""
    cols = judge.stroke_columns(pts, W)
    ends = [depth[min(H - 1, int(q[1])), min(W - 1, int(q[0]))] for q in (pts[0], pts[-1])]
    d_end = max([e for e in ends if math.isfinite(e)] or [1.25 * D])
    good = 0
    for c, ys in cols.items():
        y = int(math.floor(min(ys))) - 1
        d = depth[y, c] if 0 <= y < H else math.inf
        good += d >= max(1.05 * d_end, d_end + dem.cell_m)
    f = (W / 2.0) / math.tan(math.radians(HFOV) / 2.0)
    across = (pts[-1][0] - pts[0][0]) / f * 1.1 * D / dem.cell_m
    return {"silhouette_share": good / max(1, len(cols)), "cells_across": across}


def miss_cell(r):
    """The table's missed-columns cell: counts by place, of the stroke's
    columns."""
    if "miss_interior" not in r:
        return ""
    return (f"{r['miss_terrain_above']} / {r['miss_end_cell']} / {r['miss_interior']} "
            f"of {r.get('columns', '?')}")


def energy_cell(r):
    """The stroke's wavelet energy ratio (the report's
    noise.detail_energy_ratio: detail bands' energy over the smoothest
    level's), as the table shows it."""
    e = r.get("energy_ratio")
    return "" if e is None else f"{e:.2e}"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--md")
    ap.add_argument("--json")
    ap.add_argument("--only")
    ap.add_argument("--styles")
    ap.add_argument("--keep")
    ap.add_argument("--pictures", help="save the judge's before/after renders of each case here")
    ap.add_argument("--from-json", help="write --md from an earlier --json run")
    ap.add_argument("--feet", choices=("hillside", "crest"), default="hillside",
                    help="where the strokes' feet stand (see ground_rows)")
    a = ap.parse_args()
    global FEET
    FEET = a.feet
    rows = []
    if a.from_json:
        with open(a.from_json) as f:
            rows = json.load(f)
    styles = a.styles.split(",") if a.styles else list(STYLES)
    for name in [] if a.from_json else FIXTURES:
        if a.only and a.only not in name:
            continue
        path = os.path.join(ROOT, "fixtures", name)
        dem = judge.Dem(path)
        view = choose_view(dem)
        for D in DISTANCES:
            for style in styles:
                tmp = a.keep or tempfile.mkdtemp(prefix="lfreal")
                if a.keep:
                    tmp = os.path.join(a.keep, f"{name[:-4]}_{style}_{int(D)}")
                    os.makedirs(tmp, exist_ok=True)
                res = run_case(path, dem, view, style, D, tmp, a.pictures)
                res.update({"dem": name, "style": style, "distance_m": D, "feet": FEET,
                            "held_out": name not in TUNED})
                rows.append(res)
                print(json.dumps(res), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    if a.md:
        with open(a.md, "w") as f:
            write_md(f, rows)


def fmt(v, spec, missing=""):
    """v formatted with spec, or missing when None or NaN."""
    return missing if v is None or v != v else format(v, spec)


def write_md(f, rows):
    """The table, its summary lines and the jagged/smooth ratios."""
    measured = [r for r in rows if "fit_after" in r]
    f.write("| DEM | held out | stroke | distance | view (lon, lat, heading) | bump px | "
            "fit before | fit after | fit where showable (columns) | median dev px | "
            "silhouette share | cells across | "
            "missed columns: terrain above / end cell / interior | wavelet energy ratio | "
            "roughness m | status |\n")
    f.write("|" + " --- |" * 16 + "\n")
    for r in rows:
        ll = r.get("lonlat", ["", ""])
        shown = (f"{fmt(r.get('fit_showable'), '.3f', '-')} ({r['showable_columns']})"
                 if "showable_columns" in r else "")
        f.write(f"| {r['dem'][:-4]} | {'yes' if r['held_out'] else 'no (tuned)'} | {r['style']} | "
                f"{r['distance_m'] / 1000:.0f} km | {ll[0]}, {ll[1]}, {r.get('heading', '')} | "
                f"{r.get('bump_px', '')} | {fmt(r.get('fit_before'), '.2f')} | "
                f"{fmt(r.get('fit_after'), '.3f')} | {shown} | {fmt(r.get('median_dev_px'), '.2f')} | "
                f"{fmt(r.get('silhouette_share'), '.2f')} | "
                f"{fmt(r.get('cells_across'), '.1f')} | {miss_cell(r)} | {energy_cell(r)} | "
                f"{fmt(r.get('roughness_m'), '.2f')} | {r['status']} |\n")
    summary(f, measured, rows)
    jagged_ratios(f, rows)


def summary(f, measured, rows):
    """Counts of landforms fitted >= 0.95, by the old measure (all the
    stroke's columns) and over the showable columns, all styles and the
    original six."""
    for label, sel in (("the original six styles", [r for r in measured
                                                     if r["style"] in ORIGINAL_STYLES]),
                       ("all styles", measured)):
        if not sel:
            continue
        fits = [r["fit_after"] for r in sel]
        shows = [r["fit_showable"] for r in sel if r.get("fit_showable") is not None]
        ok = [r["fit_after"] for r in sel if r["status"] == "ok"]
        f.write(f"\n{label}: {sum(x >= 0.95 for x in fits)} of {len(fits)} measured landforms fitted "
                f">= 0.95 over all the stroke's columns (min {min(fits):.2f}, median "
                f"{sorted(fits)[len(fits) // 2]:.2f}); over the showable columns "
                f"{sum(x >= 0.95 for x in shows)} of {len(shows)} (median "
                f"{sorted(shows)[len(shows) // 2]:.2f}); {len(ok)} with status ok "
                f"(showable >= 95%): {sum(x >= 0.95 for x in ok)} >= 0.95.\n")
    spiked = [r for r in measured if r.get("spikes")]
    if any("spikes" in r for r in measured):
        f.write(f"\nSpikes (a cell's change more than half a cell above or below all 8 "
                f"neighbours'): {sum(r['spikes'] for r in spiked)} cells in {len(spiked)} of "
                f"{len(measured)} landforms"
                + "".join(f"; {r['dem'][:-4]} {r['style']} {r['distance_m'] / 1000:.0f} km"
                          for r in spiked) + ".\n")
    unmeasured = [r for r in rows if "fit_after" not in r]
    no_ground = sum(r["status"] == "no ground at this distance" for r in unmeasured)
    f.write(f"{len(unmeasured)} cases not measured: {no_ground} with no ground at that distance "
            f"in the chosen view, {len(unmeasured) - no_ground} refused by demsketch (status).\n")


def jagged_ratios(f, rows):
    """Per DEM and distance, each jagged style against its smooth
    counterpart (JAGGED_PAIRS): both wavelet energy ratios and the
    roughness ratio on the DEM."""
    by = {(r["dem"], r["distance_m"], r["style"]): r for r in rows if "fit_after" in r}
    f.write("\n| DEM | distance | jagged style | cells across | wavelet energy ratio (report) jagged / smooth | "
            "wavelet energy ratio on the DEM jagged / smooth | "
            "roughness m jagged / smooth | roughness ratio |\n")
    f.write("|" + " --- |" * 8 + "\n")
    for (dem, D, style), r in by.items():
        if style not in JAGGED_PAIRS:
            continue
        s = by.get((dem, D, JAGGED_PAIRS[style]))
        if s is None:
            continue
        rj, rs = r.get("roughness_m"), s.get("roughness_m")
        ratio = rj / rs if rj is not None and rs else None
        f.write(f"| {dem[:-4]} | {D / 1000:.0f} km | {style} vs {JAGGED_PAIRS[style]} | "
                f"{r['cells_across']:.1f} | {energy_cell(r)} / {energy_cell(s)} | "
                f"{fmt(r.get('dem_energy_ratio'), '.2e')} / {fmt(s.get('dem_energy_ratio'), '.2e')} | "
                f"{fmt(rj, '.2f')} / {fmt(rs, '.2f')} | {fmt(ratio, '.2f')} |\n")

if __name__ == "__main__":
    main()
