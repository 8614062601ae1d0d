#!/usr/bin/env python3
"""Browser tests of `demsketch serve` (issue 13), run by tools/test.sh.

Drives Debian's Chromium through chromedriver (Python selenium, in the
virtual environment tools/setup.sh makes):

- edit_flow: open the page, place the viewpoint on the map (click, drag for
  the heading), set the camera, draw two strokes over silhouettes with pointer
  actions, over-sketch one, undo/redo, delete, move one (and undo), run the dry run, download the sketch, accept;
  then `demsketch edit` on the downloaded sketch must give a GeoTIFF with
  the same `gdalinfo -checksum` as the one the app wrote.
- hostile: bad JSON, a 100 MB body, paths in parameters, oversized or
  malformed photo-EXIF and job-wait requests, 10 concurrent
  edits: 4xx answers (or queued and completed), the server keeps serving,
  no file outside OUT touched.
- photo_trace: a render of a changed DEM saved as JPEG with EXIF (GPS
  position, bearing, focal length and sensor width, written by exiftool) is
  loaded under the view: the viewpoint, heading and field of view come from
  the EXIF; the camera aligned to it by dragging, its skyline traced, edited.
- underlay: `--underlay` with bad files (missing, not a raster, no
  georeference: exit 1, one line naming the file); with the fixture RGB
  GeoTIFF in EPSG:4326: the underlay served at the map's size, its colours
  those of the file at given lon/lat, drawn with its opacity control.

Usage: run.py --bin target/release/demsketch [--screenshots docs/serve] [TEST...]
Prints "browser: N passed, M failed" last; exit code 1 when any failed.
"""

import argparse
import hashlib
import http.client
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import urllib.error
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEM = os.path.join(ROOT, "fixtures", "zion_srtm_utm12n.tif")
SKETCH = os.path.join(ROOT, "fixtures", "sketches", "zion_dome.json")


# ---------------------------------------------------------------- helpers
class Server:
    """`demsketch serve DEM --out OUT --port 0`, its URL read from stdout."""

    def __init__(self, binary, dem, out, extra=()):
        self.proc = subprocess.Popen(
            [binary, "serve", dem, "--out", out, "--port", "0", *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline()
        m = re.search(r"(http://\S+/)", line)
        if not m:
            err = self.proc.stderr.read()
            raise RuntimeError(f"serve did not print its URL: {line!r} {err!r}")
        self.url = m.group(1)
        self.host, self.port = self.url[len("http://"):-1].split(":")

    def alive(self):
        return self.proc.poll() is None

    def stop(self):
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def request(srv, method, path, body=None, headers=None, timeout=60):
    """(status, bytes) of one request."""
    c = http.client.HTTPConnection(srv.host, int(srv.port), timeout=timeout)
    h = {"Content-Type": "application/json"} if body is not None else {}
    h.update(headers or {})
    c.request(method, path, body=body, headers=h)
    r = c.getresponse()
    data = r.read()
    c.close()
    return r.status, data


def get_json(srv, path):
    s, d = request(srv, "GET", path)
    assert s == 200, (path, s, d)
    return json.loads(d)


def post_json(srv, path, obj):
    s, d = request(srv, "POST", path, json.dumps(obj).encode())
    return s, (json.loads(d) if d[:1] in (b"{", b"[") else d)


def wait_job(srv, job, timeout=120):
    t0 = time.time()
    while time.time() - t0 < timeout:
        j = get_json(srv, f"/api/jobs/{job}?wait_ms=2000")
        if j["state"] in ("done", "failed"):
            return j
    raise AssertionError(f"job {job} did not finish in {timeout} s")


def checksum(path):
    out = subprocess.run(["gdalinfo", "-checksum", path], capture_output=True, text=True, check=True).stdout
    return re.findall(r"Checksum=(\d+)", out)


def tree_state(root):
    """{path: (size, mtime_ns, sha256)} of every file under root."""
    st = {}
    for d, _, files in os.walk(root):
        for f in files:
            p = os.path.join(d, f)
            s = os.stat(p)
            with open(p, "rb") as fh:
                st[p] = (s.st_size, s.st_mtime_ns, hashlib.sha256(fh.read()).hexdigest())
    return st


def browser(download_dir):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    for a in ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
              "--disable-background-networking", "--disable-component-update", "--disable-sync",
              "--disable-dev-shm-usage", "--window-size=1720,1180", "--hide-scrollbars",
              f"--user-data-dir={tempfile.mkdtemp(prefix='demsketch-chrome-')}"]:
        opts.add_argument(a)
    opts.binary_location = shutil.which("chromium") or "/usr/bin/chromium"
    opts.add_experimental_option("prefs", {
        "download.default_directory": download_dir,
        "download.prompt_for_download": False,
    })
    driver_path = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    d = webdriver.Chrome(service=Service(driver_path), options=opts)
    d.set_page_load_timeout(30)
    return d


def wait_for(fn, timeout=60, what="condition"):
    t0 = time.time()
    while time.time() - t0 < timeout:
        v = fn()
        if v:
            return v
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def set_field(d, fid, value):
    d.execute_script(
        "const e = document.getElementById(arguments[0]); e.value = arguments[1];"
        "e.dispatchEvent(new Event('change'));", fid, str(value))


def rendered_for_camera(d):
    """True once the picture shown is the render of the current camera."""
    return d.execute_script(
        "const v = app.sketch.views[app.cur];"
        "const img = document.getElementById('render');"
        "return img.dataset.rendered && JSON.parse(img.dataset.rendered).camera.heading_deg === v.camera.heading_deg"
        " && JSON.parse(img.dataset.rendered).viewpoint.lon === v.viewpoint.lon;")


def draw(d, element, points, size):
    """Draw a stroke on `element` through image pixel `points` of an image `size`."""
    from selenium.webdriver.common.action_chains import ActionChains
    rect = d.execute_script("const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", element)
    sx, sy = rect[0] / size[0], rect[1] / size[1]
    off = [(round(x * sx - rect[0] / 2), round(y * sy - rect[1] / 2)) for x, y in points]
    a = ActionChains(d, duration=5)
    a.move_to_element_with_offset(element, *off[0]).click_and_hold()
    prev = off[0]
    for p in off[1:]:
        # several pointer moves per segment, as a hand gives
        n = max(1, int(max(abs(p[0] - prev[0]), abs(p[1] - prev[1])) // 6))
        for k in range(1, n + 1):
            a.move_to_element_with_offset(element, round(prev[0] + (p[0] - prev[0]) * k / n),
                                          round(prev[1] + (p[1] - prev[1]) * k / n))
        prev = p
    a.release().perform()


def shot(el, path):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    el.screenshot(path)


# ---------------------------------------------------------------- tests
def test_edit_flow(binary, shots, tmp):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.action_chains import ActionChains
    out = os.path.join(tmp, "served.tif")
    dl = os.path.join(tmp, "downloads")
    os.makedirs(dl)
    sketch = json.load(open(SKETCH))
    v0 = sketch["views"][0]
    srv = Server(binary, DEM, out)
    d = browser(dl)
    try:
        t0 = time.time()
        d.get(srv.url)
        wait_for(lambda: d.execute_script("return document.body.dataset.ready"), 30, "the page")
        print(f"  page load to first view: {time.time() - t0:.2f} s")
        # Place the viewpoint by clicking the map where the sketch's viewpoint is,
        # dragging towards the south-south-west sets the heading.
        px = post_json(srv, "/api/project", {"points": [[v0["viewpoint"]["lon"], v0["viewpoint"]["lat"]]]})[1]["pixels"][0]
        info = get_json(srv, "/api/info")
        m = d.find_element(By.ID, "map")
        rect = d.execute_script("const r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", m)
        ow, oh = info["overview"]["width"], info["overview"]["height"]
        ox, oy = round(px[0] * rect[0] / ow - rect[0] / 2), round(px[1] * rect[1] / oh - rect[1] / 2)
        a = ActionChains(d, duration=20)
        a.move_to_element_with_offset(m, ox, oy).click_and_hold().pause(0.6)
        for k in range(1, 6):
            a.move_to_element_with_offset(m, ox - 4 * k, oy + 10 * k)
        a.release().perform()
        vp = wait_for(lambda: d.execute_script("return app.sketch.views[0].viewpoint"), 10, "viewpoint")
        wait_for(lambda: abs(d.execute_script("return app.sketch.views[0].viewpoint.lon") - v0["viewpoint"]["lon"]) < 0.01, 10, "viewpoint")
        heading = d.execute_script("return app.sketch.views[0].camera.heading_deg")
        assert 180 < heading < 230, f"heading set by dragging: {heading}"
        print(f"  viewpoint placed on the map at {vp['lon']:.4f}, {vp['lat']:.4f}, heading {heading:.0f} by dragging")
        # The exact camera of the bundled sketch, typed into the fields.
        for fid, val in [("f-lon", v0["viewpoint"]["lon"]), ("f-lat", v0["viewpoint"]["lat"]),
                         ("f-heading", v0["camera"]["heading_deg"]), ("f-pitch", v0["camera"]["pitch_deg"]),
                         ("f-hfov", v0["camera"]["hfov_deg"]), ("f-width", v0["camera"]["width"]),
                         ("f-height", v0["camera"]["height"])]:
            set_field(d, fid, val)
        set_field(d, "view-name", v0["name"])
        wait_for(lambda: rendered_for_camera(d), 30, "the render of the camera")
        # The silhouettes of this view, as the page overlays them.
        s, feats = post_json(srv, "/api/features", {"viewpoint": v0["viewpoint"], "camera": v0["camera"]})
        assert s == 200 and feats["silhouettes"], feats
        canvas = d.find_element(By.ID, "strokes")
        size = (v0["camera"]["width"], v0["camera"]["height"])
        dome = v0["strokes"][0]["points"]
        peak = v0["strokes"][1]["points"]
        # The dome drawn first with a wrong middle, then over-sketched there.
        rough = [[x, y + (14 if 1000 <= x <= 1080 else 0)] for x, y in dome]
        draw(d, canvas, rough, size)
        draw(d, canvas, peak, size)
        fix = [p for p in dome if 960 <= p[0] <= 1100]
        draw(d, canvas, fix, size)
        strokes = d.execute_script("return app.sketchJSON().views[0].strokes")
        assert len(strokes) == 2, f"over-sketching made a third stroke: {len(strokes)}"
        mid = [p for p in strokes[0]["points"] if 1010 <= p[0] <= 1070]
        assert mid and all(abs(p[1] - min(q[1] for q in dome if abs(q[0] - p[0]) < 45)) < 12 for p in mid), \
            f"the over-sketched part was not replaced: {mid}"
        print(f"  two strokes drawn, one over-sketched: {[len(s['points']) for s in strokes]} points")
        # undo takes the over-sketch back, redo makes it again; delete and undo
        js_strokes = "return app.sketchJSON().views[0].strokes"
        d.find_element(By.ID, "undo").click()
        assert d.execute_script(js_strokes)[0]["points"] != strokes[0]["points"], "undo did nothing"
        d.find_element(By.ID, "redo").click()
        assert d.execute_script(js_strokes) == strokes, "redo did not restore the over-sketch"
        d.find_element(By.CSS_SELECTOR, "#stroke-list li[data-i='1']").click()
        d.find_element(By.ID, "del-stroke").click()
        assert len(d.execute_script(js_strokes)) == 1, "delete"
        d.find_element(By.ID, "undo").click()
        assert d.execute_script(js_strokes) == strokes, "undo of delete"
        # Move: drag the second stroke by (40, 25) image pixels; undo, redo, undo.
        d.find_element(By.CSS_SELECTOR, "input[name=tool][value=move]").click()
        grab = strokes[1]["points"][len(strokes[1]["points"]) // 2]
        draw(d, canvas, [grab, [grab[0] + 40, grab[1] + 25]], size)
        moved = d.execute_script(js_strokes)
        assert moved[0] == strokes[0], "moving one stroke changed the other"
        shifts = {(round(b[0] - a[0]), round(b[1] - a[1])) for a, b in zip(strokes[1]["points"], moved[1]["points"])}
        assert len(moved[1]["points"]) == len(strokes[1]["points"]) and \
            all(abs(sx - 40) <= 3 and abs(sy - 25) <= 3 for sx, sy in shifts) and \
            max(s[0] for s in shifts) - min(s[0] for s in shifts) <= 1, f"move: shifts {shifts}"
        assert d.execute_script("return app.selected") == 1, "the moved stroke is selected"
        d.find_element(By.ID, "undo").click()
        assert d.execute_script(js_strokes) == strokes, "undo of move"
        d.find_element(By.ID, "redo").click()
        assert d.execute_script(js_strokes) == moved, "redo of move"
        d.find_element(By.ID, "undo").click()
        d.find_element(By.CSS_SELECTOR, "input[name=tool][value=draw]").click()
        print(f"  stroke moved by {sorted(shifts)[0]} px, undone, redone, undone")
        d.execute_script("app.selected = null; drawStrokes(); listStrokes();")
        d.find_element(By.ID, "viewshed-btn").click()
        wait_for(lambda: d.execute_script("return app.viewshed !== null"), 30, "the viewshed")
        if shots:
            shot(d.find_element(By.ID, "map-pane"), os.path.join(shots, "map_view.png"))
            shot(d.find_element(By.ID, "view-wrap"), os.path.join(shots, "first_person_strokes.png"))
            d.save_screenshot(os.path.join(shots, "app.png"))
        # Dry run, compare, download, accept.
        d.find_element(By.ID, "dry-run").click()
        state = wait_for(lambda: d.execute_script("return document.getElementById('edit-status').dataset.state"), 90, "the dry run")
        assert state == "writable", d.find_element(By.ID, "edit-status").text
        assert not os.path.exists(out), "the dry run wrote OUT"
        rows = d.find_elements(By.CSS_SELECTOR, "#stroke-table tbody tr")
        assert len(rows) == 2, len(rows)
        wait_for(lambda: d.execute_script(
            "return [...document.querySelectorAll('#compare-images img')].every(i => i.complete && i.naturalWidth > 0)"), 20, "pictures")
        print("  dry run: " + d.find_element(By.ID, "edit-status").text)
        if shots:
            d.execute_script("document.getElementById('compare').scrollIntoView()")
            shot(d.find_element(By.ID, "compare"), os.path.join(shots, "compare.png"))
            d.execute_script("document.querySelector('main').scrollTop = 0")
        d.find_element(By.ID, "download").click()
        dl_file = os.path.join(dl, "sketch.json")
        wait_for(lambda: os.path.exists(dl_file) and os.path.getsize(dl_file) > 0, 20, "the download")
        d.find_element(By.ID, "accept").click()
        state = wait_for(lambda: (lambda s: s if s in ("written", "failed") else None)(
            d.execute_script("return document.getElementById('edit-status').dataset.state")), 90, "the write")
        assert state == "written", d.find_element(By.ID, "edit-status").text
        print("  accepted: " + d.find_element(By.ID, "edit-status").text)
        # the downloaded file loads back as the same sketch
        d.find_element(By.ID, "load-file").send_keys(dl_file)
        wait_for(lambda: d.execute_script("return app.sketchJSON()") == json.load(open(dl_file)), 10, "the loaded sketch")
    finally:
        d.quit()
        srv.stop()
    cli_out = os.path.join(tmp, "cli.tif")
    subprocess.run([binary, "edit", DEM, "--sketch", dl_file, "--out", cli_out, "-q"], check=True)
    a, b = checksum(out), checksum(cli_out)
    assert a and a == b, f"checksums differ: app {a}, edit {b}"
    assert a != checksum(DEM), "the written DEM equals the input"
    print(f"  gdalinfo -checksum: app {a[0]} == demsketch edit {b[0]}")


def test_hostile(binary, shots, tmp):
    work = os.path.join(tmp, "work")
    os.makedirs(work)
    dem = os.path.join(work, "dem.tif")
    shutil.copy(DEM, dem)
    out = os.path.join(work, "out.tif")
    before = tree_state(work)
    fixtures_before = tree_state(os.path.join(ROOT, "fixtures"))
    srv = Server(binary, dem, out)
    try:
        sketch = json.load(open(SKETCH))
        view = {"viewpoint": sketch["views"][0]["viewpoint"], "camera": sketch["views"][0]["camera"]}
        cases = [
            ("bad JSON", "POST", "/api/render", b"{not json", (400,)),
            ("JSON of the wrong shape", "POST", "/api/edit", b'{"sketch": 3}', (400,)),
            ("unknown key (a path)", "POST", "/api/edit", json.dumps({"sketch": sketch, "out": "/tmp/evil.tif"}).encode(), (400,)),
            ("path inside the sketch", "POST", "/api/edit",
             json.dumps({"sketch": dict(sketch, dem="/etc/passwd")}).encode(), (400,)),
            ("path in a query", "GET", "/api/lookup?x=1&y=1&path=/etc/passwd", None, (400,)),
            ("path as job id", "GET", "/api/jobs/..%2F..%2Fetc%2Fpasswd", None, (400, 404)),
            ("path as picture name", "GET", "/api/jobs/1/image/..%2F..%2F..%2Fetc%2Fpasswd", None, (400, 404)),
            ("dot-dot path", "GET", "/../../etc/passwd", None, (400, 404)),
            ("huge image", "POST", "/api/render", json.dumps(dict(view, camera=dict(view["camera"], width=100000))).encode(), (400,)),
            ("NaN camera", "POST", "/api/render", json.dumps(view).replace('"heading_deg": 200.0', '"heading_deg": NaN').encode(), (400,)),
            ("viewpoint outside the DEM", "POST", "/api/render", json.dumps(dict(view, viewpoint={"lon": 10, "lat": 10})).encode(), (422,)),
            ("lookup outside", "GET", "/api/lookup?x=-5&y=1e9", None, (400,)),
            ("accept without a dry run", "POST", "/api/jobs/999/accept", b"{}", (404,)),
            ("unknown overlay", "POST", "/api/render", json.dumps(dict(view, overlays=["/etc/passwd"])).encode(), (400,)),
            ("photo EXIF of 2 MB", "POST", "/api/photo-exif?width=10&height=10", b"\xff" * (2 * 1024 * 1024), (400,)),
            ("photo EXIF, a path for a size", "POST", "/api/photo-exif?width=/etc/passwd&height=1", b"x", (400,)),
            ("photo EXIF of no size", "POST", "/api/photo-exif?width=0&height=0", b"x", (400,)),
            ("job wait, not a number", "GET", "/api/jobs/1?wait_ms=forever", None, (400,)),
            ("no underlay", "GET", "/api/underlay.png", None, (404,)),
        ]
        for name, method, path, body, want in cases:
            s, data = request(srv, method, path, body)
            assert s in want, f"{name}: HTTP {s} {data[:200]!r}, wanted {want}"
            assert s == 404 or b"error" in data, f"{name}: no message: {data[:200]!r}"
            print(f"  {name}: {s} {data[:90].decode(errors='replace')}")
        # A 100 MB body: refused (413) without the server reading it all.
        c = http.client.HTTPConnection(srv.host, int(srv.port), timeout=60)
        status = None
        try:
            c.putrequest("POST", "/api/edit")
            c.putheader("Content-Type", "application/json")
            c.putheader("Content-Length", str(100 * 1024 * 1024))
            c.endheaders()
            chunk = b" " * (1024 * 1024)
            for _ in range(100):
                c.send(chunk)
            status = c.getresponse().status
        except (BrokenPipeError, ConnectionResetError):
            try:
                status = c.getresponse().status
            except Exception:
                status = "closed"
        c.close()
        assert status in (413, "closed"), f"100 MB body: {status}"
        print(f"  100 MB body: {status}")
        assert get_json(srv, "/api/info")["width"] > 0
        # 10 concurrent edits: each is queued (202) or refused (429); every
        # queued one completes.
        results = []

        def submit(k):
            sk = json.loads(json.dumps(sketch))
            sk["views"][0]["strokes"] = sk["views"][0]["strokes"][k % 2:k % 2 + 1]
            results.append(post_json(srv, "/api/edit", {"sketch": sk}))
        threads = [threading.Thread(target=submit, args=(k,)) for k in range(10)]
        t0 = time.time()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        codes = sorted(s for s, _ in results)
        assert all(s in (202, 429) for s in codes), codes
        jobs = [r["job"] for s, r in results if s == 202]
        assert jobs, codes
        # meanwhile the server answers
        s, _ = request(srv, "GET", "/api/info")
        assert s == 200
        for j in jobs:
            v = wait_job(srv, j, 180)
            assert v["state"] == "done", v
        print(f"  10 concurrent edits: {codes.count(202)} queued and completed, {codes.count(429)} refused, {time.time() - t0:.1f} s")
        assert srv.alive(), "the server died"
        assert get_json(srv, "/api/info")["width"] > 0
    finally:
        srv.stop()
    after = tree_state(work)
    assert after == before, f"files in the DEM's directory changed: {set(after) ^ set(before)}"
    assert not os.path.exists(out), "OUT written without an accept"
    assert tree_state(os.path.join(ROOT, "fixtures")) == fixtures_before, "fixtures changed"
    print("  no file outside OUT touched")


PHOTO_SKYLINE_JS = """
const img = arguments[0], x0 = arguments[1], x1 = arguments[2], step = arguments[3];
const c = document.createElement('canvas');
c.width = img.naturalWidth; c.height = img.naturalHeight;
const g = c.getContext('2d'); g.drawImage(img, 0, 0);
const d = g.getImageData(0, 0, c.width, c.height).data;
const out = [];
const px = (x, y) => { const k = (y * c.width + x) * 4; return [d[k], d[k + 1], d[k + 2]]; };
const dist = (p, q) => Math.abs(p[0] - q[0]) + Math.abs(p[1] - q[1]) + Math.abs(p[2] - q[2]);
const W = 8;
for (let x = x0; x <= x1; x += step) {
  // The sky's colour changes slowly down a column; the skyline is near the
  // first row that differs from the row W above by a clear step (a sunlit
  // summit fades into the sky over a few rows of the JPEG, so a step
  // between neighbouring rows can miss it), at the steepest change of the
  // W rows above it.
  for (let y = W; y < c.height; y++) {
    if (dist(px(x, y), px(x, y - W)) <= 24) continue;
    let best = y, most = -1;
    for (let r = y - W + 1; r <= y; r++) {
      const s = dist(px(x, r), px(x, r - 1));
      if (s > most) { most = s; best = r; }
    }
    out.push([x, best - 0.5]);
    break;
  }
}
return out;
"""


def skyline_error(binary, tmp, dems, vp, cols):
    """Mean |skyline row of each DEM - skyline row of the last| over image
    columns `cols`, in the photo's camera (depth buffers read by the system
    Python's GDAL and numpy)."""
    depths = []
    for k, dem in enumerate(dems):
        dp = os.path.join(tmp, f"depth{k}.tif")
        subprocess.run([binary, "view", dem, "--lon", str(vp["lon"]), "--lat", str(vp["lat"]),
                        "--heading", "203", "--pitch", "0", "--hfov", "35", "--size", "1200x600",
                        "--out", os.path.join(tmp, f"v{k}.png"), "--depth", dp, "-q"], check=True)
        depths.append(dp)
    code = ("import sys, json, numpy as np\nfrom osgeo import gdal\n"
            "cols = json.loads(sys.argv[1])\n"
            "def sky(p):\n"
            "    d = gdal.Open(p).ReadAsArray()\n"
            "    return np.array([np.argmax(d[:, c] != -9999) for c in cols], float)\n"
            "s = [sky(p) for p in sys.argv[2:]]\n"
            "print(json.dumps([float(np.abs(x - s[-1]).mean()) for x in s[:-1]]))\n")
    out = subprocess.run(["/usr/bin/python3", "-c", code, json.dumps(cols), *depths],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out)


def test_photo_trace(binary, shots, tmp):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.action_chains import ActionChains
    sketch = json.load(open(SKETCH))
    v0 = sketch["views"][0]
    # The "photo": a render of a changed DEM (the bundled sketch applied),
    # from a camera 3 degrees to the right and 1 degree higher than the
    # app's starting camera, saved as JPEG.
    target = os.path.join(tmp, "target.tif")
    subprocess.run([binary, "edit", DEM, "--sketch", SKETCH, "--out", target, "-q"], check=True)
    png = os.path.join(tmp, "photo.png")
    photo = os.path.join(tmp, "photo.jpg")
    vp = v0["viewpoint"]
    subprocess.run([binary, "view", target, "--lon", str(vp["lon"]), "--lat", str(vp["lat"]),
                    "--heading", "203", "--pitch", "0", "--hfov", "35", "--size", "1200x600",
                    "--out", png, "-q"], check=True)
    subprocess.run(["gdal_translate", "-q", "-of", "JPEG", "-co", "QUALITY=90", png, photo], check=True)
    # EXIF as a camera writes it: the GPS position of the viewpoint, a true
    # bearing 3 degrees off, and a 57.088 mm lens on a 36 mm wide sensor
    # (1200 px at 33.3333 px/mm): 35 degrees across.
    lon, lat = vp["lon"], vp["lat"]
    subprocess.run(["exiftool", "-q", "-overwrite_original",
                    f"-GPSLatitude={abs(lat)}", f"-GPSLatitudeRef={'N' if lat >= 0 else 'S'}",
                    f"-GPSLongitude={abs(lon)}", f"-GPSLongitudeRef={'E' if lon >= 0 else 'W'}",
                    "-GPSImgDirection=200", "-GPSImgDirectionRef=T", "-FocalLength=57.088",
                    "-FocalPlaneXResolution=33.3333", "-FocalPlaneResolutionUnit=mm",
                    "-ExifImageWidth=1200", "-ExifImageHeight=600", photo], check=True)
    out = os.path.join(tmp, "traced.tif")
    srv = Server(binary, DEM, out)
    d = browser(tmp)
    try:
        d.get(srv.url)
        wait_for(lambda: d.execute_script("return document.body.dataset.ready"), 30, "the page")
        # Only the pitch is typed: the viewpoint, heading and field of view
        # come from the photo's EXIF.
        set_field(d, "f-pitch", -1)
        set_field(d, "view-name", "photo")
        d.find_element(By.ID, "photo-file").send_keys(photo)
        wait_for(lambda: d.execute_script("return app.photo && app.sketch.views[0].camera.width === 1200"
                                          " && app.sketch.views[0].camera.height === 600"
                                          " && app.photoExif !== undefined"), 20, "the photo")
        got = d.execute_script("return app.sketch.views[0]")
        assert abs(got["viewpoint"]["lon"] - vp["lon"]) < 2e-6 and abs(got["viewpoint"]["lat"] - vp["lat"]) < 2e-6, got
        assert abs(got["camera"]["hfov_deg"] - 35) < 0.02 and got["camera"]["heading_deg"] == 200, got["camera"]
        note = d.find_element(By.ID, "photo-info").text
        assert "EXIF GPS" in note and "hfov 35.0" in note and "heading 200" in note, note
        print("  " + note)
        set_field(d, "photo-opacity", 0.5)
        d.execute_script("document.getElementById('photo-opacity').dispatchEvent(new Event('input'))")
        # Align: drag the render under the photo (3 degrees right, 1 up),
        # once the render for the photo's camera is in (a drag while the
        # page lays out a render arriving was lost once in CI: the camera
        # stayed where it was).
        wait_for(lambda: rendered_for_camera(d), 30, "the render for the photo's camera")
        d.find_element(By.CSS_SELECTOR, "input[name=tool][value=align]").click()
        canvas = d.find_element(By.ID, "strokes")
        rw = d.execute_script("return arguments[0].getBoundingClientRect().width", canvas)
        px_per_deg = rw / 35.0
        dx, dy = round(-3 * px_per_deg), round(1 * px_per_deg)
        # The pointer moves on the screen, as a mouse does: offsets from
        # where it is, not from the canvas, which may move under a drag
        # while the page lays out (a render arriving); the app follows the
        # pointer's screen movement.
        a = ActionChains(d, duration=20)
        a.move_to_element(canvas).click_and_hold()
        at = (0, 0)
        for k in range(1, 11):
            to = (round(dx * k / 10), round(dy * k / 10))
            a.move_by_offset(to[0] - at[0], to[1] - at[1])
            at = to
        a.release().perform()
        cam = d.execute_script("return app.sketch.views[0].camera")
        assert abs(cam["heading_deg"] - 203) < 0.6 and abs(cam["pitch_deg"] - 0) < 0.6, cam
        print(f"  aligned by dragging: heading {cam['heading_deg']:.2f}, pitch {cam['pitch_deg']:.2f}")
        # fine-tuned in the fields, as a user does once close
        set_field(d, "f-heading", 203)
        set_field(d, "f-pitch", 0)
        wait_for(lambda: rendered_for_camera(d), 30, "the aligned render")
        if shots:
            shot(d.find_element(By.ID, "view-wrap"), os.path.join(shots, "photo_aligned.png"))
        # Trace the photo's skyline where the photo shows the changed hills.
        img = d.find_element(By.ID, "photo-under")
        d.find_element(By.CSS_SELECTOR, "input[name=tool][value=draw]").click()
        traced = []
        for x0, x1 in [(820, 1036), (220, 286)]:
            pts = d.execute_script(PHOTO_SKYLINE_JS, img, x0, x1, 8)
            assert len(pts) > 5, pts
            draw(d, canvas, pts, (1200, 600))
            traced.append(pts)
        strokes = d.execute_script("return app.sketchJSON().views[0].strokes")
        assert len(strokes) == 2, len(strokes)
        print(f"  traced the photo's skyline: {[len(s['points']) for s in strokes]} points")
        if shots:
            shot(d.find_element(By.ID, "view-wrap"), os.path.join(shots, "photo_traced.png"))
        d.find_element(By.ID, "allow-partial").click()
        d.find_element(By.ID, "dry-run").click()
        state = wait_for(lambda: d.execute_script("return document.getElementById('edit-status').dataset.state"), 90, "the dry run")
        assert state == "writable", d.find_element(By.ID, "edit-status").text
        print("  dry run: " + d.find_element(By.ID, "edit-status").text)
        for row in d.find_elements(By.CSS_SELECTOR, "#stroke-table tbody tr"):
            print("    " + row.text.replace("\n", " "))
        d.find_element(By.ID, "accept").click()
        state = wait_for(lambda: (lambda s: s if s in ("written", "failed") else None)(
            d.execute_script("return document.getElementById('edit-status').dataset.state")), 90, "the write")
        assert state == "written", d.find_element(By.ID, "edit-status").text
    finally:
        d.quit()
        srv.stop()
    cols = [int(x) for pts in traced for x, _ in pts]
    before, after = skyline_error(binary, tmp, [DEM, out, target], vp, cols)
    print(f"  skyline in the photo's camera, mean distance to the photo's over the traced columns: "
          f"{before:.1f} px before, {after:.1f} px after the edit")
    assert after < before, (before, after)


def png_size(data):
    """(width, height) from a PNG's IHDR."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n", data[:16]
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_underlay(binary, shots, tmp):
    from selenium.webdriver.common.by import By
    underlay = os.path.join(ROOT, "fixtures", "underlay", "zion_rgb_epsg4326.tif")
    out = os.path.join(tmp, "o.tif")
    # Bad files: one line naming the file, exit code 1, nothing written, no URL.
    text = os.path.join(tmp, "notes.txt")
    open(text, "w").write("not a raster\n")
    nogeo = os.path.join(tmp, "nogeo.png")
    subprocess.run(["gdal_translate", "-q", "-of", "PNG", underlay, nogeo], check=True)
    for f in [p for p in os.listdir(tmp) if p.endswith(".aux.xml")]:
        os.remove(os.path.join(tmp, f))
    for bad, why in [(os.path.join(tmp, "missing.tif"), "no such file"), (text, "not a raster"),
                     (nogeo, "no georeference")]:
        r = subprocess.run([binary, "serve", DEM, "--out", out, "--port", "0", "--underlay", bad],
                           capture_output=True, text=True, timeout=60)
        lines = [l for l in r.stderr.splitlines() if l.strip()]
        assert r.returncode == 1, (bad, r.returncode, r.stderr)
        assert len(lines) == 1 and bad in lines[0] and why in lines[0], (bad, r.stderr)
        assert "http://" not in r.stdout and not os.path.exists(out), (bad, r.stdout)
        print(f"  --underlay {os.path.basename(bad)}: exit 1, {lines[0]}")
    srv = Server(binary, DEM, out, ["--underlay", underlay])
    try:
        info = get_json(srv, "/api/info")
        ow, oh = info["overview"]["width"], info["overview"]["height"]
        assert info["underlay"] == {"name": "zion_rgb_epsg4326.tif", "width": ow, "height": oh}, info["underlay"]
        s, png = request(srv, "GET", "/api/underlay.png")
        assert s == 200 and png_size(png) == (ow, oh), (s, png[:40])
        path = os.path.join(tmp, "underlay.png")
        open(path, "wb").write(png)
        # Mostly opaque (the file covers the DEM), transparent where it does not.
        stats = subprocess.run(["gdalinfo", "-stats", path], capture_output=True, text=True, check=True).stdout
        means = [float(m) for m in re.findall(r"STATISTICS_MEAN=([-\d.e+]+)", stats)]
        assert len(means) == 4 and means[3] > 200, stats
        # Reprojected to the map's grid: the colour at a lon/lat is the file's there.
        for lon, lat in [(-112.95, 37.25), (-113.05, 37.40), (-112.90, 37.45)]:
            px = post_json(srv, "/api/project", {"points": [[lon, lat]]})[1]["pixels"][0]
            got = subprocess.run(["gdallocationinfo", "-valonly", path, str(int(px[0])), str(int(px[1]))],
                                 capture_output=True, text=True, check=True).stdout.split()
            want = subprocess.run(["gdallocationinfo", "-valonly", "-wgs84", underlay, str(lon), str(lat)],
                                  capture_output=True, text=True, check=True).stdout.split()
            assert int(got[3]) == 255, got
            assert all(abs(int(g) - int(w)) <= 24 for g, w in zip(got[:3], want)), (lon, lat, got, want)
        print(f"  underlay {ow} x {oh} RGBA, alpha mean {means[3]:.0f}; colours match the file at 3 points")
        d = browser(tmp)
        try:
            d.get(srv.url)
            wait_for(lambda: d.execute_script("return document.body.dataset.ready"), 30, "the page")
            assert d.execute_script("return app.underlay && app.underlay.naturalWidth") == ow
            assert d.find_element(By.ID, "underlay-ctl").is_displayed()
            pixel = "const g = document.getElementById('map').getContext('2d'); return [...g.getImageData(arguments[0], arguments[1], 1, 1).data];"
            x, y = ow // 4, 2 * oh // 3  # away from the viewpoint and its wedge
            set_field(d, "underlay-opacity", 0)
            d.execute_script("document.getElementById('underlay-opacity').dispatchEvent(new Event('input'))")
            bare = d.execute_script(pixel, x, y)
            set_field(d, "underlay-opacity", 1)
            d.execute_script("document.getElementById('underlay-opacity').dispatchEvent(new Event('input'))")
            full = d.execute_script(pixel, x, y)
            assert bare != full, (bare, full)
            if shots:
                set_field(d, "underlay-opacity", 0.6)
                d.execute_script("document.getElementById('underlay-opacity').dispatchEvent(new Event('input'))")
                shot(d.find_element(By.ID, "map-pane"), os.path.join(shots, "map_underlay.png"))
            print(f"  map pixel at opacity 0: {bare[:3]}, at 1: {full[:3]}")
        finally:
            d.quit()
    finally:
        srv.stop()


TESTS = {"edit_flow": test_edit_flow, "hostile": test_hostile, "photo_trace": test_photo_trace,
         "underlay": test_underlay}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "demsketch"))
    ap.add_argument("--screenshots", help="save the screenshots here (docs/serve)")
    ap.add_argument("--keep", action="store_true", help="keep each test's temporary directory (printed)")
    ap.add_argument("tests", nargs="*")
    args = ap.parse_args()
    os.environ.setdefault("GDAL_PAM_ENABLED", "NO")
    names = args.tests or list(TESTS)
    passed = failed = 0
    for n in names:
        tmp = tempfile.mkdtemp(prefix=f"demsketch-browser-{n}-")
        t0 = time.time()
        print(f"browser test {n}:", flush=True)
        try:
            TESTS[n](os.path.abspath(args.bin), args.screenshots and os.path.abspath(args.screenshots), tmp)
            passed += 1
            print(f"browser test {n}: ok ({time.time() - t0:.1f} s)", flush=True)
        except Exception:
            failed += 1
            traceback.print_exc()
            print(f"browser test {n}: FAILED ({time.time() - t0:.1f} s)", flush=True)
        finally:
            if args.keep:
                print(f"  kept {tmp}", flush=True)
            else:
                shutil.rmtree(tmp, ignore_errors=True)
    print(f"browser: {passed} passed, {failed} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
