#!/usr/bin/env bash
# Batch edits at scale (issue 15, items 3 and 4): 200 edits on a 16 x 16
# tile set (the Texas fixture resampled to 2048 x 2048, about 14 m cells,
# 128 x 128 tiles, DEFLATE), each sketch a ridge raised in front of a
# random viewpoint (the strokes of tests/batch_support, --max-distance
# 500). Checks, in one run:
#   1. the reference: the DEM copied to OUT, then the 200 edits one by one
#      with `demsketch edit OUT --in-place` (timed);
#   2. `demsketch batch DEM --jobs M --out OUT` (timed): tiles byte-identical
#      to the reference (SHA-256 of every tile);
#   3. the batch killed with SIGKILL at 20 random moments, then resumed:
#      byte-identical;
#   4. the array-job steps: `batch plan`, every index in a shuffled order,
#      two processes at a time, `batch finish`: byte-identical.
# Prints one line per check and the figures docs/benchmarks.md records.
# Needs GDAL's tools and /usr/bin/python3; run after `cargo build --release`.
# Usage: tools/bench_batch.sh [EXE] [EDITS] [KILLS]
set -euo pipefail
cd "$(dirname "$0")/.."
exe=$(realpath "${1:-target/release/demsketch}")
edits=${2:-200}
kills=${3:-20}
flags=(--max-distance 500 --min-fit 0)
export GDAL_PAM_ENABLED=NO SOURCE_DATE_EPOCH=1764547200
tmp=$(mktemp -d /tmp/bench_batch.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
gdal_translate -q -outsize 2048 2048 -r bilinear fixtures/texas_srtm90m_tiled_int16.tif "$tmp/big.tif"
mkdir "$tmp/dem"
for ty in $(seq 0 15); do
    for tx in $(seq 0 15); do
        gdal_translate -q -srcwin $((tx * 128)) $((ty * 128)) 128 128 -co TILED=YES \
            -co BLOCKXSIZE=64 -co BLOCKYSIZE=64 -co COMPRESS=DEFLATE \
            "$tmp/big.tif" "$tmp/dem/t_$(printf %02d "$ty")_$(printf %02d "$tx").tif"
    done
done
rm "$tmp/big.tif"
/usr/bin/python3 - "$tmp" "$edits" <<'PY'
import json, random, sys
from osgeo import gdal
tmp, n = sys.argv[1], int(sys.argv[2])
ds = gdal.Open(f"{tmp}/dem/t_00_00.tif")
gt = ds.GetGeoTransform()
rng = random.Random(15)
entries = []
import os
os.makedirs(f"{tmp}/sketches")
for k in range(n):
    c, r = rng.uniform(40, 2008), rng.uniform(40, 2008)
    lon, lat = gt[0] + (c + 0.5) * gt[1], gt[3] + (r + 0.5) * gt[5]
    heading = rng.choice([0, 90, 180, 270]) + rng.uniform(-20, 20)
    drop = rng.choice([1.5, 3.0])
    pts = [[60.0, 46.0 + drop], [80.0, 44.5 + drop], [100.0, 44.0 + drop], [120.0, 45.0 + drop]]
    sk = {"views": [{"name": "v", "viewpoint": {"lon": lon, "lat": lat, "eye_height_m": 1.7},
                     "camera": {"heading_deg": heading, "pitch_deg": 0.0, "roll_deg": 0.0,
                                "hfov_deg": 60.0, "width": 200, "height": 100},
                     "strokes": [{"id": "s", "points": pts}]}],
          "options": {"influence_m": 100.0}}
    json.dump(sk, open(f"{tmp}/sketches/e{k:03d}.json", "w"))
    entries.append({"id": f"e{k:03d}", "sketch": f"sketches/e{k:03d}.json"})
json.dump({"edits": entries}, open(f"{tmp}/manifest.json", "w"))
PY
out="$tmp/out"
hashes() { (cd "$1" && sha256sum ./*.tif); }
now() { date +%s.%N; }

# 1. Reference: one by one, in place.
cp -r "$tmp/dem" "$out"
t0=$(now)
for s in "$tmp"/sketches/*.json; do
    "$exe" -q edit "$out" --sketch "$s" --in-place "${flags[@]}" || echo "edit $s: exit $?"
done
t_seq=$(echo "$(now) - $t0" | bc)
hashes "$out" > "$tmp/ref.sha"
rm -rf "$out"
changed=$(cd "$tmp/dem" && sha256sum ./*.tif | diff - "$tmp/ref.sha" | grep -c '^>' || true)
echo "reference: $edits edits one by one in ${t_seq} s; $changed of 256 tiles changed"

# 2. The batch, in one process.
t0=$(now)
"$exe" -q batch "$tmp/dem" --jobs "$tmp/manifest.json" --out "$out" "${flags[@]}" || echo "batch: exit $?"
t_batch=$(echo "$(now) - $t0" | bc)
groups=$(/usr/bin/python3 -c "import json,sys; p=json.load(open(sys.argv[1])); g=[len(x['edits']) for x in p['groups']]; print(len(g), max(g))" "$out/.demsketch_batch/plan.json")
if hashes "$out" | cmp -s - "$tmp/ref.sha"; then same=identical; else same=DIFFERENT; fi
echo "batch: ${t_batch} s, groups (count, largest): $groups; tiles $same to the reference"
echo "throughput: one by one $(echo "scale=2; $edits / $t_seq" | bc) edits/s, batch $(echo "scale=2; $edits / $t_batch" | bc) edits/s, ratio $(echo "scale=2; $t_seq / $t_batch" | bc)"

# 3. Killed at random moments, resumed.
rm -rf "$out"
seed=15
killed=0
for k in $(seq 1 "$kills"); do
    seed=$(( (seed * 1103515245 + 12345) % 2147483648 ))
    # Spread over about one batch's time, so that the kills land in work.
    delay=$(echo "scale=3; 0.3 + ($seed % 1000) / 1000 * 2 * $t_batch / $kills" | bc)
    "$exe" -q batch "$tmp/dem" --jobs "$tmp/manifest.json" --out "$out" "${flags[@]}" --resume \
        2>/dev/null &
    pid=$!
    sleep "$delay"
    # Still running (not a zombie that has ended)?
    if [ "$(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null)" != Z ] && kill -9 "$pid" 2>/dev/null; then
        killed=$((killed + 1))
    fi
    wait "$pid" 2>/dev/null || true
done
"$exe" -q batch "$tmp/dem" --jobs "$tmp/manifest.json" --out "$out" "${flags[@]}" --resume || echo "resume: exit $?"
recovered=$(/usr/bin/python3 -c "import json,sys; s=json.load(open(sys.argv[1])); print(s['recovered'], len(s['records']))" "$out/.demsketch_batch/summary.json")
if hashes "$out" | cmp -s - "$tmp/ref.sha"; then same=identical; else same=DIFFERENT; fi
echo "killed $killed of $kills runs (SIGKILL) before they ended, resumed: tiles $same to the reference; (recovered, records): $recovered"

# 4. Array job: every index, shuffled, two processes at a time.
rm -rf "$out"
"$exe" -q batch plan "$tmp/dem" --jobs "$tmp/manifest.json" --out "$out" --plan "$tmp/plan.json" "${flags[@]}"
n=$(/usr/bin/python3 -c "import json,sys; print(len(json.load(open(sys.argv[1]))['groups']))" "$tmp/plan.json")
t0=$(now)
seq 0 $((n - 1)) | shuf --random-source=<(yes) | xargs -P 2 -I{} "$exe" -q batch run --plan "$tmp/plan.json" --index {}
"$exe" -q batch finish --plan "$tmp/plan.json" || echo "finish: exit $?"
t_array=$(echo "$(now) - $t0" | bc)
if hashes "$out" | cmp -s - "$tmp/ref.sha"; then same=identical; else same=DIFFERENT; fi
echo "array job: $n indices shuffled, 2 at a time, ${t_array} s: tiles $same to the reference"
echo "machine: $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg)"
