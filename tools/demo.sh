#!/usr/bin/env bash
# The main job on a bundled real DEM: installs what is missing, builds the
# release binary and runs demsketch on Zion National Park (SRTM, UTM 12N).
# Results go to out/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/setup.sh
export GDAL_PAM_ENABLED=NO
cargo build --release --locked
bin=target/release/demsketch
mkdir -p out/demo
$bin info fixtures/zion_srtm_utm12n.tif
$bin info fixtures/zion_srtm_utm12n.tif --json > out/demo/info.json
echo "wrote out/demo/info.json"
