"""Strokes traced the way people draw them, from the judge's own render.

Only robust boundaries are traced: the skyline where real terrain continues
behind the crest, and occlusion boundaries whose farther terrain is at least
ROBUST_RATIO times farther.  Boundaries are linked into chains across
columns; a chain is split where the row jumps by more than MAX_JUMP_PX or the
depth jumps by more than 30 %, and chains shorter than MIN_LEN columns are
dropped (a boundary stable over several columns).
"""
import math

import numpy as np

ROBUST_RATIO = 1.3
MAX_JUMP_PX = 2.0
MIN_LEN = 24
TRIM = 2


def robust_candidates(r, min_depth):
    """Per column: list of (row, front_depth, kind) of robust boundaries."""
    out = []
    for c in range(r.width):
        a0, a1 = r.b_start[c], r.b_start[c + 1]
        cand = []
        for j in range(a0, a1):
            kind = r.b_kind[j]
            row, fr, be = r.b_row[j], r.b_front[j], r.b_behind[j]
            if not (3.0 <= row <= r.height - 3.0) or fr < min_depth:
                continue
            if kind == 1:
                if r.sky_robust[c]:
                    cand.append((row, fr, 1))
            elif kind == 0 and be >= ROBUST_RATIO * fr and be - fr >= 3 * r.cell_m:
                cand.append((row, fr, 0))
        out.append(cand)
    return out


def chains(r, min_depth=None, skyline_only=False, depth_continuity=True):
    """Chains of robust boundaries: list of dicts with arrays col, row, depth,
    kind (columns consecutive)."""
    min_depth = min_depth if min_depth is not None else max(5 * r.cell_m, 150.0)
    cands = robust_candidates(r, min_depth)
    active = []  # chains ending at the previous column
    done = []
    for c in range(r.width):
        cand = [x for x in cands[c] if (x[2] == 1 or not skyline_only)]
        new_active = []
        used = set()
        # each active chain takes its nearest candidate (greedy by distance)
        pairs = []
        for ai, ch in enumerate(active):
            for ci, (row, fr, kind) in enumerate(cand):
                dr = abs(row - ch["row"][-1])
                if dr > MAX_JUMP_PX:
                    continue
                if depth_continuity:
                    q = fr / ch["depth"][-1]
                    if q > 1.3 or q < 1 / 1.3:
                        continue
                pairs.append((dr, ai, ci))
        pairs.sort()
        taken_a = set()
        for dr, ai, ci in pairs:
            if ai in taken_a or ci in used:
                continue
            taken_a.add(ai)
            used.add(ci)
            ch = active[ai]
            row, fr, kind = cand[ci]
            ch["col"].append(c)
            ch["row"].append(row)
            ch["depth"].append(fr)
            ch["kind"].append(kind)
            new_active.append(ch)
        for ai, ch in enumerate(active):
            if ai not in taken_a:
                done.append(ch)
        for ci, (row, fr, kind) in enumerate(cand):
            if ci not in used:
                new_active.append({"col": [c], "row": [row], "depth": [fr], "kind": [kind]})
        active = new_active
    done.extend(active)
    out = []
    for ch in done:
        n = len(ch["col"])
        lo, hi = 0, n
        # keep the image border if the chain touches it; trim fragile ends elsewhere
        if ch["col"][0] != 0:
            lo = TRIM
        if ch["col"][-1] != r.width - 1:
            hi = n - TRIM
        if hi - lo < MIN_LEN:
            continue
        d = {k: np.array(v[lo:hi]) for k, v in ch.items()}
        d["skyline_share"] = float(np.mean(d["kind"] == 1))
        out.append(d)
    out.sort(key=lambda d: -len(d["col"]))
    return out


def sub_chain(ch, c_lo, c_hi):
    m = (ch["col"] >= c_lo) & (ch["col"] <= c_hi)
    d = {k: (v[m] if isinstance(v, np.ndarray) else v) for k, v in ch.items()}
    return d


def _dp(x, y, tol):
    """Douglas-Peucker indices keeping the polyline within tol of (x, y)."""
    keep = np.zeros(len(x), bool)
    keep[0] = keep[-1] = True
    stack = [(0, len(x) - 1)]
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        xs, ys = x[i:j + 1], y[i:j + 1]
        t = (xs - x[i]) / (x[j] - x[i]) if x[j] != x[i] else np.zeros_like(xs)
        err = np.abs(ys - (y[i] + t * (y[j] - y[i])))
        k = int(np.argmax(err))
        if err[k] > tol:
            keep[i + k] = True
            stack.append((i, i + k))
            stack.append((i + k, j))
    return np.nonzero(keep)[0]


def style_points(ch, style, rng, width):
    """Strokes (list of point lists) of one chain in a style."""
    x = ch["col"] + 0.5
    y = ch["row"]
    n = len(x)
    if style in ("dense", "long", "rtl", "border"):
        idx = list(range(0, n, 3))
        if idx[-1] != n - 1:
            idx.append(n - 1)
        pts = [[float(x[i]), float(y[i])] for i in idx]
        if style == "border":
            if ch["col"][0] == 0:
                pts.insert(0, [0.0, float(y[0])])
            if ch["col"][-1] == width - 1:
                pts.append([float(width), float(y[-1])])
        if style == "rtl":
            pts = pts[::-1]
        return [pts]
    if style == "hand":
        # a careful person: a vertex every so often, within about a pixel.
        keep = _dp(x, y, 0.25)
        strokes = []
        # split into pieces of at most 40 vertices, at least 8
        pieces = []
        if len(keep) <= 40:
            pieces = [keep]
        else:
            m = int(math.ceil(len(keep) / 36))
            bounds = np.linspace(0, len(keep) - 1, m + 1).round().astype(int)
            pieces = [keep[bounds[i]:bounds[i + 1] + 1] for i in range(m)]
        for kp in pieces:
            kp = list(kp)
            while len(kp) < 8:
                gaps = np.diff(kp)
                g = int(np.argmax(gaps))
                if gaps[g] < 2:
                    break
                kp.insert(g + 1, (kp[g] + kp[g + 1]) // 2)
            if len(kp) < 8:
                continue
            pts = []
            for i in kp:
                jx = rng.uniform(-1.0, 1.0)
                jy = rng.uniform(-1.0, 1.0)
                xx = float(np.clip(x[i] + jx, x[0], x[-1]))
                yb = float(np.interp(xx, x, y))
                yy = float(y[i] + jy)
                # keep the drawn vertex within 0.7 px of the boundary it traces
                yy = float(np.clip(yy, yb - 0.7, yb + 0.7))
                pts.append([round(xx, 2), round(yy, 2)])
            strokes.append(pts)
        return strokes
    raise ValueError(style)


STYLES = ("dense", "hand", "long", "rtl", "border")
