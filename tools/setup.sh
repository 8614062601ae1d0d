#!/usr/bin/env bash
# Installs what demsketch needs on a fresh Debian machine (GDAL, PROJ, clang
# for the bindings, pkg-config, the GDAL command-line tools the tests compare
# against, and numpy + GDAL's Python bindings for tools/fidelity), only where it is missing. Needs root for apt-get.
set -euo pipefail
pkgs=(libgdal-dev libproj-dev libclang-dev pkg-config gdal-bin proj-bin python3-numpy python3-gdal
      python3-venv chromium chromium-driver libimage-exiftool-perl)
missing=()
for p in "${pkgs[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}" >&2
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
command -v cargo >/dev/null || { echo "setup: cargo (Rust) is required: https://rustup.rs" >&2; exit 1; }
# Python packages the tests use (jsonschema, for the STAC item of `export
# stac`), in a virtual environment of the project's own (.venv, git-ignored),
# never in the system Python.
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
if ! "$ROOT/.venv/bin/python" -c "import jsonschema, referencing" >/dev/null 2>&1; then
  dpkg -s python3-venv >/dev/null 2>&1 || {
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
  }
  echo "setup: creating .venv with jsonschema" >&2
  /usr/bin/python3 -m venv "$ROOT/.venv"
  "$ROOT/.venv/bin/python" -m pip install -q --disable-pip-version-check "jsonschema>=4.18"
fi
# The browser tests' Python environment (tests/browser/run.py).
cd "$(dirname "$0")/.."
if [ ! -x .venv-browser/bin/python ] || ! .venv-browser/bin/python -c "import selenium" 2>/dev/null; then
  echo "setup: creating .venv-browser (selenium)" >&2
  /usr/bin/python3 -m venv .venv-browser
  .venv-browser/bin/pip install -q "selenium>=4.20,<5"
fi
