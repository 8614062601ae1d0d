#!/usr/bin/env bash
# Runs the fidelity suite with one binary on several case sets, one after
# another: results in $FIDELITY_OUT (default /tmp/fidelity-runs) as
# TAG-SET.json / .md / .log. SET is `tuned` (the suite as drawn) or a
# hold-out seed (holdout1 .. holdout5). Compare two tags with compare.py.
#
#   bash tools/fidelity/runsets.sh BIN TAG tuned holdout1 holdout2 ...
set -euo pipefail
cd "$(dirname "$0")/../.."
bin=$1
tag=$2
shift 2
out=${FIDELITY_OUT:-/tmp/fidelity-runs}
mkdir -p "$out"
for set in "$@"; do
  seed=""
  [ "$set" = tuned ] || seed=$set
  FIDELITY_SEED=$seed DEMSKETCH=$bin /usr/bin/python3 tools/fidelity/run.py \
    --json "$out/$tag-$set.json" --md "$out/$tag-$set.md" >"$out/$tag-$set.log" 2>&1 || true
  tail -1 "$out/$tag-$set.log"
done
