#!/usr/bin/env bash
# Runs every test of demsketch: installs what is missing, builds, tests.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export GDAL_PAM_ENABLED=NO
cargo test --locked --no-fail-fast 2>&1
