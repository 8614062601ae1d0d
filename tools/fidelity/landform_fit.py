#!/usr/bin/python3
"""The judge's fit of a landform's silhouette (issue 14 item 5).

    /usr/bin/python3 tools/fidelity/landform_fit.py DEM_BEFORE DEM_AFTER SKETCH VIEW STROKE [--columns]

Renders DEM_BEFORE and DEM_AFTER with the independent judge (judge.py) from
view VIEW of the sketch file SKETCH and prints, as one JSON line, the
judge's fit (judge.fit: share of the stroke's columns with a boundary within
1 px) of stroke STROKE on both: the landform `demsketch correct --sketch`
built from that stroke should be fitted on the after-DEM. With --columns,
also the deviation (px) of each of the stroke's columns on the after-DEM
(dev_by_column; null where the judge sees no boundary in the column). The eye is the
sketch's alt_m, else the before-DEM's bilinear ground + eye_height_m (1.7 m
by default), the same absolute eye for both renders.
"""
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import judge  # noqa: E402


def main(argv):
    columns = "--columns" in argv
    argv = [a for a in argv if a != "--columns"]
    if len(argv) != 6:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    before_path, after_path, sketch_path, view_name, stroke_id = argv[1:]
    with open(sketch_path) as f:
        sketch = json.load(f)
    view = next((v for v in sketch["views"] if v["name"] == view_name), None)
    if view is None:
        print(f"{sketch_path}: no view {view_name!r}", file=sys.stderr)
        return 1
    stroke = next((s for s in view.get("strokes", []) if s["id"] == stroke_id), None)
    if stroke is None:
        print(f"{sketch_path}: view {view_name!r} has no stroke {stroke_id!r}", file=sys.stderr)
        return 1
    vp, cam = view["viewpoint"], view["camera"]
    before, after = judge.Dem(before_path), judge.Dem(after_path)
    alt = vp.get("alt_m")
    if alt is None:
        alt = before.height_ll(vp["lon"], vp["lat"]) + vp.get("eye_height_m", 1.7)
    out = {}
    for name, dem in (("before", before), ("after", after)):
        r = judge.render(dem, vp["lon"], vp["lat"], alt, cam.get("heading_deg", 0.0),
                         cam.get("hfov_deg", 60.0), cam.get("width", 640), cam.get("height", 360))
        fit, _, dev = judge.fit(r, stroke["points"])
        out["fit_" + name] = fit
        if name == "after":
            finite = [d for d in dev.values() if d == d and d != float("inf")]
            out["median_dev_px"] = sorted(finite)[len(finite) // 2] if finite else None
            out["columns"] = len(dev)
            if columns:
                out["dev_by_column"] = {str(c): (d if d == d and d != float("inf") else None)
                                        for c, d in sorted(dev.items())}
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
