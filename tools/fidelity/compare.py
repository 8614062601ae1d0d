#!/usr/bin/env python3
"""Compare fidelity runs (results JSON of `run.py --json`) of two builds.

    compare.py lines A1.json A2.json ... -- B1.json B2.json ...
        acceptance-line totals summed over the sets, A against B
    compare.py cases A.json B.json
        the cases whose per-line outcome differs between two runs of one set

A line's total is the sum of its `ok` / `total` over the files given (one
file per case set: the tuned suite and the hold-outs). Used to decide
whether a change is kept: every line that held must still hold, and the
net count of lines gained is reported.
"""
import json
import sys


def load(p):
    with open(p) as f:
        return json.load(f)


def totals(paths):
    out = {}
    order = []
    for p in paths:
        for l in load(p)["summary"]:
            k = l["line"]
            if k not in out:
                out[k] = [0, 0]
                order.append(k)
            out[k][0] += l["ok"]
            out[k][1] += l["total"]
    return order, out


def case_flags(r):
    """Per-case outcome of each line (True = holds), for the cases table."""
    f = {}
    if r.get("status") in ("n/a", None) or "fit_min" not in r:
        return {"edited": r.get("status") != "fail"}
    f["fit"] = r["fit_min"] >= 0.95
    if r["kind"] == "identity":
        f["identity_dz"] = r["max_abs_dz"] <= 3.0
    else:
        fall = r.get("rmse_fall")
        f["rmse"] = fall is not None and fall >= 0.5
        w = r.get("depth_within", [])
        f["depth"] = "%d/%d" % (sum(w), len(w))
        f["influence"] = r.get("beyond_influence", 0) == 0
    f["ground"] = r["ground_dz_100m"] < 0.5
    f["spike"] = r["spikes"] == 0
    idem = r.get("idempotence_max_dz")
    f["idem"] = idem is not None and idem <= 0.5
    return f


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    mode = sys.argv[1]
    if mode == "lines":
        rest = sys.argv[2:]
        if "--" not in rest:
            order, t = totals(rest)
            for k in order:
                print("%5d / %-5d %s" % (t[k][0], t[k][1], k))
            return
        i = rest.index("--")
        oa, ta = totals(rest[:i])
        _, tb = totals(rest[i + 1:])
        net = 0
        for k in oa:
            a, b = ta[k], tb.get(k, [0, 0])
            d = b[0] - a[0]
            net += d
            mark = "" if d == 0 else ("  +%d" % d if d > 0 else "  %d" % d)
            print("%5d / %-5d -> %5d / %-5d %s%s" % (a[0], a[1], b[0], b[1], k, mark))
        print("net %+d" % net)
    elif mode == "cases":
        a, b = load(sys.argv[2]), load(sys.argv[3])
        key = lambda r: (r["group"], r.get("style"))
        ma = {key(r): r for r in a["cases"]}
        n = 0
        for r in b["cases"]:
            ra = ma.get(key(r))
            if ra is None:
                print("new case", key(r))
                continue
            fa, fb = case_flags(ra), case_flags(r)
            diff = {k: (fa.get(k), fb.get(k)) for k in set(fa) | set(fb) if fa.get(k) != fb.get(k)}
            dz = (ra.get("max_abs_dz"), r.get("max_abs_dz"))
            if diff or (dz[0] is not None and dz[1] is not None and abs(dz[0] - dz[1]) > 0.5):
                n += 1
                print("%s/%s: %s  max|dz| %s -> %s" % (r["group"], r.get("style"),
                      ", ".join("%s %s->%s" % (k, v[0], v[1]) for k, v in sorted(diff.items())),
                      dz[0] and round(dz[0], 1), dz[1] and round(dz[1], 1)))
        print("%d cases differ" % n)
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
