#!/usr/bin/env bash
# The main job on a bundled real DEM: installs what is missing, builds the
# release binary and runs `demsketch edit` on Zion National Park (SRTM,
# UTM 12N) with the bundled sketch fixtures/sketches/zion_dome.json.
# Results go to out/demo/: corrected.tif, report.json, renders/.
# With --serve: starts the browser app (`demsketch serve`) on the same DEM
# instead, accepted edits written to out/demo/served.tif (open the URL it
# prints; --open asks the desktop's browser to open it).
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export GDAL_PAM_ENABLED=NO
cargo build --release --locked
bin=target/release/demsketch
dem=fixtures/zion_srtm_utm12n.tif
sketch=fixtures/sketches/zion_dome.json
if [ "${1:-}" = "--serve" ]; then
  mkdir -p out/demo
  shift
  exec $bin serve "$dem" --out out/demo/served.tif "$@"
fi
rm -rf out/demo
mkdir -p out/demo
$bin info "$dem"
$bin edit "$dem" --sketch "$sketch" --out out/demo/corrected.tif \
    --report out/demo/report.json --renders out/demo/renders
echo "wrote out/demo/corrected.tif, out/demo/report.json and out/demo/renders/"
