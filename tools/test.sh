#!/usr/bin/env bash
# Runs every test of demsketch: installs what is missing, builds, tests.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export GDAL_PAM_ENABLED=NO
# A clean build gains nothing from incremental state, and it costs disk.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
# No merge left half done: conflict markers in any tracked file fail the run.
if git rev-parse --git-dir >/dev/null 2>&1 && git grep -n -E '^(<<<<<<< |>>>>>>> )' -- . ; then
    echo "tools/test.sh: merge conflict markers in the tracked files above" >&2
    exit 1
fi
echo "disk free before the build: $(df -h --output=avail . | tail -1)"
cargo test --locked --no-fail-fast 2>&1
# The independent fidelity evaluation (tools/fidelity, a second renderer), CI subset.
# Lines of issue 11 the edit meets are required (CI fails on them); the others
# are reported (--report-only) until the edit meets them too. Idempotence and
# the known-change fit are required again since strokes are anchored only
# within the fit's 1 px (2026-12-02: every CI case fits 1.00, re-edits 0.0 m);
# RMSE and depth are reported (issue 11, left).
cargo build --release --locked 2>&1 && DEMSKETCH="${DEMSKETCH:-target/release/demsketch}" /usr/bin/python3 tools/fidelity/run.py --subset ci --report-only \
    --require "identity: max,identity: every stroke,known change: every stroke,ground within 100 m,no change beyond,no spike,idempotence,edit exits 0,bundled demo"
# The browser app (demsketch serve) driven through Chromium: edit flow and
# hostile requests (tests/browser/run.py).
.venv-browser/bin/python tests/browser/run.py --bin target/release/demsketch
# The Python package (python/): wheel built with maturin, tests with Dask
# (tools/test_python.sh installs maturin, dask, distributed from PyPI).
bash tools/test_python.sh
