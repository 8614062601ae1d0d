#!/usr/bin/env python3
"""Side-by-side timing of demsketch's multigrid solver and pyamg (smoothed
aggregation) on the identical problem.

The Rust example `multigrid_bench` writes the synthetic scattered-curve layout
(fixed.u8, values.f32; row-major, cell size 30 m) and times our solver; this
script builds the same 5-point matrix on the free cells (fixed cells
eliminated into the right-hand side b, M = 0 outside the grid), solves with
pyamg to the same relative residual ||b - A x|| / ||b|| (zero initial guess),
and prints both timings as JSON.

    pip install -r tools/requirements-bench.txt
    python3 tools/compare_pyamg.py --n 4096 --tol 1e-4
"""
import argparse
import json
import os
import subprocess
import tempfile
import time

import numpy as np
import pyamg
import scipy.sparse as sp


def build_system(n, fixed, values, h=30.0):
    """Free-cell matrix A (scaled by h^2: 4 on the diagonal) and rhs b."""
    free = ~fixed
    index = -np.ones(n * n, dtype=np.int64)
    index[free.ravel()] = np.arange(free.sum())
    idx = index.reshape(n, n)
    vals = np.where(fixed, values, 0.0).astype(np.float64)
    rows, cols = [], []
    b = np.zeros(free.sum())
    fr = idx >= 0
    # Neighbour shifts: (dj, di).
    for dj, di in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        src = np.zeros((n, n), dtype=bool)
        js = slice(max(0, -dj), n - max(0, dj))
        is_ = slice(max(0, -di), n - max(0, di))
        jd = slice(max(0, dj), n - max(0, -dj) if max(0, -dj) else n)
        id_ = slice(max(0, di), n - max(0, -di) if max(0, -di) else n)
        me = idx[js, is_]
        nb = idx[jd, id_]
        nbv = vals[jd, id_]
        m = me >= 0
        both = m & (nb >= 0)
        rows.append(me[both]); cols.append(nb[both])
        # Fixed neighbour: its value goes to b.
        fixed_nb = m & (nb < 0)
        np.add.at(b, me[fixed_nb], nbv[fixed_nb])
        del src
    r = np.concatenate(rows); c = np.concatenate(cols)
    nfree = int(free.sum())
    off = sp.csr_matrix((-np.ones(len(r)), (r, c)), shape=(nfree, nfree))
    A = (off + 4.0 * sp.identity(nfree, format="csr")).tocsr()
    return A, b


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=4096)
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--bench-bin", default=None,
                    help="prebuilt multigrid_bench binary (default: cargo run --release)")
    args = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    with tempfile.TemporaryDirectory() as tmp:
        if args.bench_bin:
            cmd = [args.bench_bin]
        else:
            cmd = ["cargo", "run", "--release", "--quiet", "--example", "multigrid_bench", "--"]
        cmd += [str(args.n), str(args.seed), str(args.tol), tmp, "3"]
        out = subprocess.run(cmd, cwd=root, check=True, capture_output=True, text=True)
        ours = json.loads(out.stdout.strip().splitlines()[-1])
        fixed = np.fromfile(os.path.join(tmp, "fixed.u8"), dtype=np.uint8).reshape(args.n, args.n) != 0
        values = np.fromfile(os.path.join(tmp, "values.f32"), dtype="<f4").reshape(args.n, args.n)
    A, b = build_system(args.n, fixed, values)
    t0 = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(A, max_coarse=500)
    t1 = time.perf_counter()
    residuals = []
    x = ml.solve(b, x0=np.zeros_like(b), tol=args.tol, residuals=residuals, accel=None)
    t2 = time.perf_counter()
    rel = float(np.linalg.norm(b - A @ x) / np.linalg.norm(b))
    pyamg_result = {
        "solver": f"pyamg {pyamg.__version__} smoothed_aggregation_solver (V-cycles, no Krylov)",
        "setup_s": t1 - t0, "solve_s": t2 - t1, "total_s": t2 - t0,
        "iterations": len(residuals) - 1, "relative_residual": rel,
        "unknowns": int(A.shape[0]),
    }
    print(json.dumps({"n": args.n, "tolerance": args.tol, "demsketch": ours, "pyamg": pyamg_result,
                      "speedup_total": pyamg_result["total_s"] / ours["seconds_best"],
                      "load_average": os.getloadavg()}, indent=1))


if __name__ == "__main__":
    main()
