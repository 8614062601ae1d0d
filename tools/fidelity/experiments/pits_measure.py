"""Pit measure of an edit's change field dz = corrected - original.

A pit cell: its dz lies more than T metres under the median of its 8
neighbours' dz (a single cell, or a group of up to 3 of the 8 around it,
or a one-cell-wide notch: the median ignores up to 3 low neighbours; a
step between a raised side and an unraised one is not a pit). Reported
for T = 5 and 10 m, with the deepest. Also (the brief's two measures): cells
under the minimum of their 8 neighbours by more than 3 m, and under their
mean by more than a quarter cell.
Usage: pits.py ORIGINAL CORRECTED [--list]"""
import sys
import numpy as np
from osgeo import gdal


def read(p):
    ds = gdal.Open(p)
    b = ds.GetRasterBand(1)
    a = b.ReadAsArray().astype(np.float64)
    nd = b.GetNoDataValue()
    if nd is not None:
        a[a == nd] = np.nan
    return a, abs(ds.GetGeoTransform()[1])


def neighbours(dz):
    ny, nx = dz.shape
    p = np.pad(dz, 1, mode="edge")
    return np.stack([p[1 + a:1 + a + ny, 1 + b:1 + b + nx]
                     for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)])


def measure(orig, corr, cell):
    dz = corr - orig
    dz[np.isnan(dz)] = 0.0
    nb = neighbours(dz)
    med = np.median(nb, 0)
    under = med - dz
    return {
        "dz": dz, "under": under,
        "pits5": under > 5.0, "pits10": under > 10.0,
        "below_min3": nb.min(0) - dz > 3.0,
        "below_mean_q": nb.mean(0) - dz > cell / 4,
    }


def summary(m, cell):
    u = np.where(m["pits5"], m["under"], 0)
    return (f"pits >5 m under 8-median: {m['pits5'].sum()}, >10 m: {m['pits10'].sum()} "
            f"(deepest {u.max():.1f} m); under 8-min by >3 m: {m['below_min3'].sum()}; "
            f"under 8-mean by > cell/4 ({cell / 4:.1f} m): {m['below_mean_q'].sum()}")


def main():
    orig, cell = read(sys.argv[1])
    corr, _ = read(sys.argv[2])
    m = measure(orig, corr, cell)
    print(summary(m, cell))
    if "--list" in sys.argv:
        for r, c in zip(*np.nonzero(m["pits5"] | m["below_mean_q"] | m["below_min3"])):
            print(f"  ({r},{c}) dz {m['dz'][r, c]:+.1f} under median {m['under'][r, c]:.1f}")


if __name__ == "__main__":
    main()
