"""demsketch: correct real digital elevation models by sketching, from Python.

A thin layer over the Rust library (the native module ``demsketch._demsketch``,
built from the same crate as the ``demsketch`` command): nothing here computes
on rasters itself, and every call does what the command of the same name does,
with the same bytes.

- :class:`Dem` (or :func:`open`): a GeoTIFF, a directory of GeoTIFF tiles or
  any raster GDAL opens; :meth:`Dem.read_window` gives heights in metres as a
  float32 numpy array (NaN for nodata), :meth:`Dem.view` the first-person view
  ``demsketch view`` renders, as an RGB uint8 array (optionally a PNG).
- :func:`edit`: ``demsketch edit DEM --sketch S (--out OUT | --in-place)``;
  returns the report (a dict).
- :func:`batch_plan`, :func:`batch_run`, :func:`batch_finish`: the array-job
  steps ``demsketch batch plan / run --index N / finish``;
  :mod:`demsketch.dask` runs every index of a plan on a ``dask.distributed``
  cluster.

Errors raise :class:`DemsketchError` with the library's one-line message; an
edit whose fit is below ``min_fit`` raises :class:`BelowMinFitError` (nothing
written but the report). The GIL is released while the library works.
"""

import json as _json
import os as _os

from . import _demsketch
from ._demsketch import BelowMinFitError, Dem, DemsketchError

__version__ = _demsketch.__version__

__all__ = [
    "Dem",
    "DemsketchError",
    "BelowMinFitError",
    "open",
    "edit",
    "batch_plan",
    "batch_groups",
    "batch_run",
    "batch_finish",
]


def open(path):  # noqa: A001 (the name users expect: demsketch.open)
    """Open a DEM (a GeoTIFF, a directory of GeoTIFF tiles, or any raster GDAL opens)."""
    return Dem(_os.fspath(path))


def _opt(p):
    return None if p is None else _os.fspath(p)


def edit(dem, sketch, out=None, *, in_place=False, report=None, renders=None, **options):
    """Run ``demsketch edit DEM --sketch SKETCH --out OUT`` (or ``in_place=True``).

    Options (the command's flags): ``max_distance`` (m, 50000), ``refraction``,
    ``max_lowering_iterations``, ``max_contour_iterations``, ``min_fit``,
    ``allow_partial``, ``dry_run``, ``lock_timeout`` (s). Returns the edit's
    report as a dict (the JSON ``demsketch edit --json`` prints).
    """
    text = _demsketch.edit(
        _os.fspath(dem),
        _os.fspath(sketch),
        _opt(out),
        in_place=in_place,
        report=_opt(report),
        renders=_opt(renders),
        **options,
    )
    return _json.loads(text)


def batch_plan(dem, jobs, out, plan, **options):
    """``demsketch batch plan DEM --jobs JOBS --out OUT --plan PLAN``.

    Plans the batch into independent groups, copies the DEM to ``out`` (which
    must not exist) and writes the plan; returns the plan (a dict; its
    ``groups`` are the indices to run). Options as :func:`edit`'s, less
    ``dry_run`` and ``lock_timeout``.
    """
    text = _demsketch.batch_plan(
        _os.fspath(dem), _os.fspath(jobs), _os.fspath(out), _os.fspath(plan), **options
    )
    return _json.loads(text)


def batch_groups(plan):
    """The number of groups (array-job indices 0 to n - 1) of the plan file."""
    return _demsketch.batch_groups(_os.fspath(plan))


def batch_run(plan, index, *, lock_timeout=300.0):
    """``demsketch batch run --plan PLAN --index INDEX``: run one group.

    Edits recorded done by an earlier run are skipped, and one applied by a
    run killed before it was recorded is not applied again (the batch
    journal), so running an index twice is harmless. Returns
    ``{"group", "skipped", "done": [record per edit]}``.
    """
    return _json.loads(_demsketch.batch_run(_os.fspath(plan), int(index), lock_timeout=lock_timeout))


def batch_finish(plan, *, lock_timeout=300.0):
    """``demsketch batch finish --plan PLAN``: the batch summary (a dict).

    Finishes the interrupted edit journals, removes temporary files of dead
    runs and writes ``summary.json`` into the output's state directory. The
    summary's ``incomplete`` lists edits not done (their groups must run
    again); ``failed`` and ``below_min_fit`` count edits that wrote nothing.
    """
    return _json.loads(_demsketch.batch_finish(_os.fspath(plan), lock_timeout=lock_timeout))
