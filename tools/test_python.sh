#!/usr/bin/env bash
# The Python package (python/, issue 15 item 4): creates .venv-py (git-
# ignored; with the system site packages, for GDAL's Python bindings that
# the tests compare against), installs maturin, dask, distributed, numpy and
# pytest from PyPI, builds the wheel from the same crate with maturin into
# the root's target directory (the library and its dependencies are
# compiled there already by `cargo build --release`), installs it and runs
# python/tests/ (reading against GDAL, view and edit against the command,
# a batch plan on a Dask LocalCluster of two worker processes, a worker
# killed mid-edit, array-job indices in a shuffled order).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$PWD"
t0=$(date +%s)
if ! .venv-py/bin/python -c "import maturin, dask, distributed, numpy, pytest, osgeo" >/dev/null 2>&1; then
  echo "test_python: creating .venv-py" >&2
  rm -rf .venv-py
  /usr/bin/python3 -m venv --system-site-packages .venv-py
  .venv-py/bin/python -m pip install -q --disable-pip-version-check \
    "maturin>=1.9,<2" "dask>=2024.1" "distributed>=2024.1" "numpy>=1.21" "pytest>=7"
fi
export CARGO_TARGET_DIR="$ROOT/target"
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
export GDAL_PAM_ENABLED=NO
# python/ has its own Cargo.lock: a dependency added to the root crate must
# be added there too.
if ! cargo metadata --locked --format-version 1 --manifest-path python/Cargo.toml >/dev/null 2>&1; then
  echo "test_python: python/Cargo.lock is out of date with the crates it builds; run: (cd python && cargo update -p demsketch) and commit it" >&2
  exit 1
fi
rm -rf target/wheels
# A plain linux wheel linked against the system's GDAL and PROJ (no
# auditwheel repair: it is installed here, not uploaded), stripped.
.venv-py/bin/maturin build --release --locked --strip -m python/Cargo.toml \
  -i .venv-py/bin/python --compatibility linux --auditwheel skip --out target/wheels 2>&1 \
  | grep -v '^ *Compiling' || true
[ -n "$(ls target/wheels/demsketch-*.whl 2>/dev/null)" ] || { echo "test_python: the wheel was not built" >&2; exit 1; }
.venv-py/bin/python -m pip install -q --disable-pip-version-check --force-reinstall --no-deps target/wheels/demsketch-*.whl
t1=$(date +%s)
echo "test_python: venv and wheel $((t1 - t0)) s"
DEMSKETCH="${DEMSKETCH:-$ROOT/target/release/demsketch}" .venv-py/bin/python -m pytest -q -p no:cacheprovider python/tests
echo "test_python: total $(( $(date +%s) - t0 )) s"
