#!/usr/bin/env bash
# Makes the fit cases of issue 5 in fixtures/fit_cases/ (or the directory
# given): for each case a target DEM made from a fixture by a known change (a
# peak raised, a ridge cut, ...), the sketch traced from the target's
# silhouettes and the list of cases (cases.json). See
# examples/make_fit_cases.rs for what is made and how; tests/edit_fit_cases.rs
# checks that editing the fixtures with the sketches reaches the targets.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-fixtures/fit_cases}"
export GDAL_PAM_ENABLED=NO
cargo run --release --locked --example make_fit_cases -- "$out"
echo "wrote $out/cases.json and its sketches and targets"
