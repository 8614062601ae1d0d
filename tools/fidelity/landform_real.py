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
# style: (column span px, bump height px, shape)
STYLES = {
    "smooth": (120, 40, "bump"),
    "jagged": (120, 40, "jag"),
    "long": (300, 30, "ridge"),
    "short": (50, 25, "bump"),
    "asym": (140, 45, "asym"),
    "dome": (160, 40, "dome"),
}
DISTANCES = [1000.0, 2000.0, 3000.0]


def shape(kind, t):
    """Height share at t in [0, 1] (0 at both ends)."""
    if kind in ("bump", "jag"):
        return 1.0 - (2 * t - 1) ** 2
    if kind == "ridge":
        return min(1.0, 4 * t, 4 * (1 - t))
    if kind == "dome":
        return math.sqrt(max(0.0, 1.0 - (2 * t - 1) ** 2))
    if kind == "asym":
        return (t / 0.3) if t < 0.3 else (1 - t) / 0.7
    raise ValueError(kind)


def ground_rows(depth, D):
    """Per column: a row (centre) where the judge sees terrain at depth
    D..1.25 D, inside a run of at least 9 such rows and 4 rows from its ends
    (not on an occlusion boundary), NaN if none; and the top of the nearer
    terrain (depth < 0.8 D)."""
    at = np.full(W, np.nan)
    near_top = np.full(W, float(H))
    for c in range(W):
        col = depth[:, c]
        run = []
        for y in range(H - 1, -1, -1):
            d = col[y]
            if d < 0.8 * D:
                near_top[c] = y
            if D <= d <= 1.25 * D:
                run.append(y)
            elif run:
                break
            if math.isinf(d):
                break
        if len(run) >= 9:
            inner = run[4:-4]
            y = min(inner, key=lambda yy: abs(col[yy] - 1.1 * D))
            at[c] = y + 0.5
    return at, near_top


def draw(style, D, rows, near_top, c_mid):
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
    # raise the bump until it clears the nearer terrain by 3 px
    need = hpx
    for x, b, s in zip(xs, base, sh):
        if s > 0.2:
            top = near_top[int(x)] - 3.0
            if b - hpx * s > top:
                need = max(need, (b - top) / s)
    hpx = min(need, 150.0)
    ys = base - hpx * sh
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
    rows, near_top = ground_rows(depth, D)
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
    drawn = draw(style, D, rows, near_top, cm)
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
    res.update(misses(dem, depth, pts, res.pop("dev_by_column", {})))
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
    a = ap.parse_args()
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
                res.update({"dem": name, "style": style, "distance_m": D,
                            "held_out": name not in TUNED})
                rows.append(res)
                print(json.dumps(res), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    if a.md:
        measured = [r for r in rows if "fit_after" in r]
        fits = [r["fit_after"] for r in measured]
        normal = [r["fit_after"] for r in measured if r["status"] == "ok"]
        with open(a.md, "w") as f:
            f.write("| DEM | held out | stroke | distance | view (lon, lat, heading) | bump px | "
                    "fit before | fit after | median dev px | silhouette share | cells across | "
                    "missed columns: terrain above / end cell / interior | wavelet energy ratio | status |\n")
            f.write("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n")
            for r in rows:
                ll = r.get("lonlat", ["", ""])
                f.write(f"| {r['dem'][:-4]} | {'yes' if r['held_out'] else 'no (tuned)'} | {r['style']} | "
                        f"{r['distance_m'] / 1000:.0f} km | {ll[0]}, {ll[1]}, {r.get('heading', '')} | "
                        f"{r.get('bump_px', '')} | {r.get('fit_before', float('nan')):.2f} | "
                        f"{r.get('fit_after', float('nan')):.3f} | {r.get('median_dev_px') or float('nan'):.2f} | "
                        f"{r.get('silhouette_share', float('nan')):.2f} | "
                        f"{r.get('cells_across', float('nan')):.1f} | {miss_cell(r)} | {energy_cell(r)} | {r['status']} |\n")
            if fits:
                f.write(f"\n{sum(x >= 0.95 for x in fits)} of {len(fits)} measured landforms fitted "
                        f">= 0.95 (min {min(fits):.2f}, median {sorted(fits)[len(fits) // 2]:.2f}); "
                        f"{len(rows) - len(fits)} not measured.\n")
                if normal:
                    f.write(f"Of the {len(normal)} with status ok (the stroke over sky or farther "
                            f"terrain in >= 95% of its columns): {sum(x >= 0.95 for x in normal)} "
                            f">= 0.95 (min {min(normal):.2f}, median "
                            f"{sorted(normal)[len(normal) // 2]:.2f}).\n")


if __name__ == "__main__":
    main()
