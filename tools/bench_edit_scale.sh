#!/usr/bin/env bash
# The same edit on a 32 x 32 set of 1024^2 tiles and on a 3 x 3 set, at 15,
# 50 and 100 km view distance (issue 15, item 1: "time within 1.3 times
# across all six, and peak memory under 600 MB"), side by side for two
# builds, interleaved; medians of RUNS. The tile sets
# (tools/make_edit_scale_tiles.py: the Zion fixture at 15 m cells, repeated
# mirrored; the small set is the big one's central 3 x 3 tiles, so the eye's
# surroundings are the same cells) and the sketch (three strokes traced from
# `demsketch view --features` silhouettes 2 to 2.7 km from the eye, raised
# by up to 7 px) are made once under $DEMSKETCH_BENCH_DIR (default
# /tmp/demsketch-bench-edit-scale, 2.2 GB). Each run is `demsketch edit
# --dry-run` (the whole edit, nothing written) under /usr/bin/time.
#
#   bash tools/bench_edit_scale.sh OLD_DEMSKETCH NEW_DEMSKETCH [RUNS]
set -euo pipefail
cd "$(dirname "$0")/.."
old=$1
new=$2
runs=${3:-3}
dir=${DEMSKETCH_BENCH_DIR:-/tmp/demsketch-bench-edit-scale}
mkdir -p "$dir/out"
/usr/bin/python3 tools/make_edit_scale_tiles.py fixtures/zion_srtm_utm12n.tif "$dir" >/dev/null
eye="--lon -113.0462 --lat 37.3225"
if [ ! -f "$dir/sketch.json" ]; then
  # shellcheck disable=SC2086
  "$new" view "$dir/t32" $eye --eye-height 300 --heading 90 --pitch -2 --hfov 60 \
    --size 1024x512 --max-distance 15000 --out "$dir/out/s.png" --features "$dir/out/s.geojson"
  /usr/bin/python3 - "$dir" <<'PY'
import json, math, sys
d = sys.argv[1]
f = json.load(open(f"{d}/out/s.geojson"))
s = [x["properties"] for x in f["features"]
     if x["properties"]["kind"] == "silhouette" and not x["properties"]["skyline"]
     and x["properties"]["depth_max"] < 3000 and x["properties"]["length_px"] > 150]
s.sort(key=lambda p: -p["length_px"])
strokes = []
for k, p in enumerate(s[:3]):
    px = p["pixels"]
    n = len(px)
    pts = [[x, y - 7.0 * math.sin(math.pi * i / (n - 1))] for i, (x, y) in enumerate(px)][::2]
    strokes.append({"id": f"s{k + 1}", "points": [[round(a, 3), round(b, 3)] for a, b in pts]})
sk = {"views": [{"name": "bench",
                 "viewpoint": {"lon": -113.0462, "lat": 37.3225, "eye_height_m": 300.0},
                 "camera": {"heading_deg": 90.0, "pitch_deg": -2.0, "roll_deg": 0.0,
                            "hfov_deg": 60.0, "width": 1024, "height": 512},
                 "strokes": strokes}], "options": {}}
json.dump(sk, open(f"{d}/sketch.json", "w"))
PY
fi
log=$dir/out/runs.txt
: >"$log"
echo "machine: $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
for i in $(seq "$runs"); do
  for d in 15000 50000 100000; do
    for set in t3 t32; do
      for bin in old new; do
        b=$old
        [ $bin = new ] && b=$new
        /usr/bin/time -o "$dir/out/time" -f "%e %M %U %S" "$b" edit "$dir/$set" --sketch "$dir/sketch.json" \
          --max-distance $d --dry-run --out "$dir/out/$set" --report "$dir/out/r_${bin}_${set}_$d.json" -q || true
        echo "$bin $set $d $(cat "$dir/out/time")" >>"$log"
      done
      # Same edit from both builds (timings aside). With a level of detail
      # the features beyond the exact reach differ (ridges are detected on
      # the exact terrain only; far silhouettes come from the coarse rings),
      # so a report that differs is also checked for the same edit: changed
      # cells, largest change, and every stroke's fit, visibility, status.
      /usr/bin/python3 - "$dir/out/r_old_${set}_$d.json" "$dir/out/r_new_${set}_$d.json" "$set $d" <<'PY'
import json, sys
def strip(o):
    if isinstance(o, dict):
        return {k: strip(v) for k, v in o.items() if not k.endswith("_s") and k not in ("timings", "timing")}
    if isinstance(o, list):
        return [strip(v) for v in o]
    return o
a, b = (strip(json.load(open(p))) for p in sys.argv[1:3])
if a != b:
    def edit(r):
        return (r.get("changed_cells"), r.get("max_abs_displacement_m"),
                [[(s.get("fit"), s.get("visible_fraction"), s.get("status")) for s in v.get("strokes", [])]
                 for v in r.get("views", [])])
    same = edit(a) == edit(b)
    print(f"REPORTS DIFFER: {sys.argv[3]} ({'same edit: changed cells, max |dz|, stroke fits' if same else 'THE EDIT DIFFERS'})")
PY
    done
  done
done
echo "load after: $(cut -d' ' -f1-3 /proc/loadavg)"
/usr/bin/python3 - "$log" <<'PY'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1]) if l.strip()]
med = {}
for bin_, s, d, t, kb, user, system in rows:
    # wall s, peak RSS KB, CPU s (user + system: steadier than the wall
    # time on a machine shared with other work)
    med.setdefault((bin_, s, d), []).append((float(t), int(kb), float(user) + float(system)))
print("| tile set | --max-distance | old wall s | new wall s | old CPU s | new CPU s | old peak RSS MB | new peak RSS MB |")
print("|---|---|---|---|---|---|---|---|")
for d in ("15000", "50000", "100000"):
    for s in ("t3", "t32"):
        o, n = med[("old", s, d)], med[("new", s, d)]
        f = lambda v, k: statistics.median(x[k] for x in v)
        print(f"| {'3 x 3' if s == 't3' else '32 x 32'} | {int(d)//1000} km | {f(o,0):.2f} | {f(n,0):.2f} | {f(o,2):.2f} | {f(n,2):.2f} | {f(o,1)/1024:.0f} | {f(n,1)/1024:.0f} |")
for b in ("old", "new"):
    ts = [statistics.median(x[0] for x in v) for k, v in med.items() if k[0] == b]
    cs = [statistics.median(x[2] for x in v) for k, v in med.items() if k[0] == b]
    ms = [statistics.median(x[1] for x in v) for k, v in med.items() if k[0] == b]
    print(f"{b}: slowest / fastest case {max(ts)/min(ts):.2f} (wall), {max(cs)/min(cs):.2f} (CPU), peak RSS max {max(ms)/1024:.0f} MB")
PY
