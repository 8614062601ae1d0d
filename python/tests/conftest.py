"""Shared by the Python package's tests: the batch tests' tile set and
sketches (as tests/batch_support/mod.rs makes them: a 4 x 4 set of 48 x 48
tiles cut from the Texas fixture with gdal_translate -srcwin, sketches that
raise a ridge in front of a viewpoint near the set's corners, so that the
plan has independent groups and, at two corners, groups of two edits), the
reference of applying them one by one with `demsketch edit OUT --in-place`,
and the tiles' digests.

The command is target/release/demsketch (or $DEMSKETCH); every process of
the tests (Dask workers included) runs with SOURCE_DATE_EPOCH set, so that
the provenance of an edit is the same bytes whoever writes it.
"""

import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "fixtures"
DEMSKETCH = os.environ.get("DEMSKETCH", str(ROOT / "target" / "release" / "demsketch"))

# Before any worker process starts: they inherit the environment.
os.environ["SOURCE_DATE_EPOCH"] = "1764547200"
os.environ["GDAL_PAM_ENABLED"] = "NO"
for v in ("SLURM_ARRAY_TASK_ID", "JOB_COMPLETION_INDEX"):
    os.environ.pop(v, None)

FLAGS = ["--max-distance", "1000", "--min-fit", "0"]
# The same flags as keyword arguments of the package.
OPTIONS = {"max_distance": 1000.0, "min_fit": 0.0}
TILE, SIDE = 48, 4


def cli(*args, check=True, **kw):
    r = subprocess.run([DEMSKETCH, *map(str, args)], capture_output=True, text=True, **kw)
    if check and r.returncode != 0:
        raise AssertionError(f"demsketch {' '.join(map(str, args))}: {r.stderr}")
    return r


def tile_set(dir_, name="dem"):
    out = Path(dir_) / name
    out.mkdir()
    for ty in range(SIDE):
        for tx in range(SIDE):
            subprocess.run(
                ["gdal_translate", "-q", "-srcwin", str(64 + tx * TILE), str(64 + ty * TILE),
                 str(TILE), str(TILE), "-co", "TILED=YES", "-co", "BLOCKXSIZE=16",
                 "-co", "BLOCKYSIZE=16", "-co", "COMPRESS=DEFLATE",
                 str(FIXTURES / "texas_srtm90m_tiled_int16.tif"), str(out / f"tile_{ty}_{tx}.tif")],
                check=True,
            )
    return out


def lonlat(col, row):
    x0, y0, d = -97.485, 32.82166666666667, 0.000833333333333
    return x0 + (64.0 + col + 0.5) * d, y0 - (64.0 + row + 0.5) * d


def sketch(col, row, heading, drop):
    lon, lat = lonlat(col, row)
    ys = [46.0 + drop, 44.5 + drop, 44.0 + drop, 45.0 + drop]
    pts = ",".join(f"[{x},{y}]" for x, y in zip([60.0, 80.0, 100.0, 120.0], ys))
    return (
        f'{{"views":[{{"name":"v","viewpoint":{{"lon":{lon},"lat":{lat},"eye_height_m":1.7}},'
        f'"camera":{{"heading_deg":{heading},"pitch_deg":0.0,"roll_deg":0.0,"hfov_deg":60.0,'
        f'"width":200,"height":100}},"strokes":[{{"id":"s","points":[{pts}]}}]}}],'
        f'"options":{{"influence_m":200.0}}}}'
    )


PLACEMENTS = [
    (20.0, 20.0, 0.0, 1.5),
    (172.0, 20.0, 180.0, 1.5),
    (20.0, 172.0, 90.0, 0.0),
    (24.0, 18.0, 90.0, 1.5),
    (172.0, 172.0, 270.0, 1.5),
    (18.0, 168.0, 0.0, 1.5),
]


def manifest(dir_, n=6):
    dir_ = Path(dir_)
    (dir_ / "sketches").mkdir()
    paths, entries = [], []
    for k in range(n):
        c, r, h, l = PLACEMENTS[k % len(PLACEMENTS)]
        p = dir_ / "sketches" / f"e{k:02}.json"
        p.write_text(sketch(c, r, h, l))
        entries.append(f'{{"id":"e{k:02}","sketch":"sketches/e{k:02}.json"}}')
        paths.append(p)
    m = dir_ / "manifest.json"
    m.write_text(f'{{"edits":[{",".join(entries)}]}}')
    return m, paths


def digests(dir_):
    """sha256 of every tile (*.tif) of a directory, by name."""
    return {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(Path(dir_).glob("*.tif"))
    }


class Batch:
    """A tile set, a manifest of six edits, and the reference digests of
    applying them one by one with the command at `out` (removed after: the
    provenance records the output's path, so every run under test writes
    at that same path)."""

    def __init__(self, tmp):
        self.tmp = Path(tmp)
        self.dem = tile_set(self.tmp)
        self.manifest, self.sketches = manifest(self.tmp)
        self.out = self.tmp / "out"
        self.plan = self.tmp / "plan.json"
        shutil.copytree(self.dem, self.out)
        for s in self.sketches:
            cli("edit", self.out, "--sketch", s, "--in-place", *FLAGS, "--quiet")
        self.want = digests(self.out)
        shutil.rmtree(self.out)

    def fresh(self):
        """Remove what a previous test left at `out` and `plan`."""
        if self.out.exists():
            shutil.rmtree(self.out)
        if self.plan.exists():
            self.plan.unlink()

    def state(self):
        return self.out / ".demsketch_batch"


@pytest.fixture(scope="session")
def batch(tmp_path_factory):
    return Batch(tmp_path_factory.mktemp("batch"))
