// demsketch serve: the page. Plain JavaScript, no build step, nothing
// fetched but this server's own API. State: a sketch (views with their
// viewpoint, camera and strokes, as the sketch file of DESIGN.md), the
// current view, undo/redo snapshots, the photo, the last edit job.
"use strict";

const $ = (id) => document.getElementById(id);
const app = {
  info: null,
  overview: null,          // Image of the hillshade
  underlay: null,          // Image of the --underlay on the map's grid (or null)
  viewshed: null,          // Image of the viewshed (or null)
  sketch: { views: [], options: { influence_m: 1500.0 } },
  cur: 0,                  // index of the current view
  selected: null,          // index of the selected stroke
  undo: [], redo: [],
  drawing: null,           // points of the stroke being drawn
  moving: null,            // the stroke being moved: { k, from, points, moved }
  jac: null,               // lon/lat per overview pixel at the viewpoint
  vpPixel: null,           // viewpoint on the overview
  job: null, writeJob: null,
  renderSeq: 0, lastRendered: "",
  photo: null,             // { url, w, h }
};
window.app = app;

// ---------- API ----------
async function api(path, body) {
  const opt = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  const r = await fetch(path, opt);
  if (!r.ok) {
    let m = r.status + "";
    try { m = (await r.json()).error || m; } catch (e) { /* not JSON */ }
    throw new Error(m);
  }
  const ct = r.headers.get("Content-Type") || "";
  return ct.startsWith("image/") ? r.blob() : r.json();
}
function status(msg) { $("status").textContent = msg; }

// ---------- sketch state ----------
function view() { return app.sketch.views[app.cur]; }
function newView(name, from) {
  const v = from ? JSON.parse(JSON.stringify(from)) : {
    name, viewpoint: { lon: 0, lat: 0, eye_height_m: 1.7 },
    camera: { heading_deg: 0, pitch_deg: 0, roll_deg: 0, hfov_deg: 60, width: 1600, height: 900 },
    strokes: [],
  };
  v.name = name; v.strokes = [];
  return v;
}
function snapshot() {
  app.undo.push(JSON.stringify({ s: app.sketch, c: app.cur }));
  if (app.undo.length > 200) app.undo.shift();
  app.redo = [];
}
function restore(text) {
  const o = JSON.parse(text);
  app.sketch = o.s; app.cur = Math.min(o.c, app.sketch.views.length - 1); app.selected = null;
  syncFields(); drawStrokes(); drawMap(); scheduleRender();
}
function undo() { if (!app.undo.length) return; app.redo.push(JSON.stringify({ s: app.sketch, c: app.cur })); restore(app.undo.pop()); }
function redo() { if (!app.redo.length) return; app.undo.push(JSON.stringify({ s: app.sketch, c: app.cur })); restore(app.redo.pop()); }
function nextStrokeId(v) {
  let n = v.strokes.length + 1;
  while (v.strokes.some((s) => s.id === "s" + n)) n++;
  return "s" + n;
}
// The sketch file as DESIGN.md describes it (rounded pixel coordinates).
function sketchJSON() {
  const out = JSON.parse(JSON.stringify(app.sketch));
  for (const v of out.views) {
    for (const s of v.strokes) s.points = s.points.map(([x, y]) => [Math.round(x * 10) / 10, Math.round(y * 10) / 10]);
  }
  return out;
}
app.sketchJSON = sketchJSON;

// ---------- fields ----------
const camFields = [["f-heading", "heading_deg"], ["f-pitch", "pitch_deg"], ["f-roll", "roll_deg"],
  ["f-hfov", "hfov_deg"], ["f-width", "width"], ["f-height", "height"]];
function syncFields() {
  const v = view();
  $("view-select").innerHTML = app.sketch.views.map((w, i) => `<option value="${i}">${esc(w.name)}</option>`).join("");
  $("view-select").value = app.cur;
  $("view-name").value = v.name;
  $("f-lon").value = v.viewpoint.lon.toFixed(6);
  $("f-lat").value = v.viewpoint.lat.toFixed(6);
  $("f-eye").value = v.viewpoint.eye_height_m ?? "";
  $("f-alt").value = v.viewpoint.alt_m ?? "";
  for (const [id, k] of camFields) $(id).value = v.camera[k];
  const locked = v.strokes.length > 0;
  for (const id of ["f-lon", "f-lat", "f-eye", "f-alt", ...camFields.map((c) => c[0])]) $(id).disabled = locked;
  $("camera-lock").hidden = !locked;
  sizeView();
  listStrokes();
}
function readFields() {
  const v = view();
  if (v.strokes.length) return;
  const num = (id, d) => { const x = parseFloat($(id).value); return Number.isFinite(x) ? x : d; };
  v.viewpoint.lon = num("f-lon", v.viewpoint.lon);
  v.viewpoint.lat = num("f-lat", v.viewpoint.lat);
  const alt = parseFloat($("f-alt").value);
  if (Number.isFinite(alt)) { v.viewpoint.alt_m = alt; delete v.viewpoint.eye_height_m; }
  else { delete v.viewpoint.alt_m; v.viewpoint.eye_height_m = num("f-eye", 1.7); }
  for (const [id, k] of camFields) v.camera[k] = num(id, v.camera[k]);
  v.camera.width = Math.max(16, Math.min(4096, Math.round(v.camera.width)));
  v.camera.height = Math.max(16, Math.min(4096, Math.round(v.camera.height)));
  sizeView();
}
function setCamera(changes) {
  const v = view();
  if (v.strokes.length) { status("camera locked: the view has strokes"); return; }
  Object.assign(v.camera, changes);
  v.camera.heading_deg = ((v.camera.heading_deg % 360) + 360) % 360;
  v.camera.pitch_deg = Math.max(-89, Math.min(89, v.camera.pitch_deg));
  v.camera.hfov_deg = Math.max(1, Math.min(170, v.camera.hfov_deg));
  for (const k of ["heading_deg", "pitch_deg", "roll_deg", "hfov_deg"]) v.camera[k] = Math.round(v.camera[k] * 100) / 100;
  syncFields(); drawMap(); scheduleRender();
}
function esc(s) { return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" }[c])); }

// ---------- map ----------
async function setupMap() {
  app.info = await api("/api/info");
  $("dem-name").textContent = `${app.info.name} (${app.info.width} x ${app.info.height})` + (app.info.out ? ` -> ${app.info.out}` : " (dry runs only: no --out)");
  const blob = await api("/api/overview.png");
  app.overview = await loadImage(URL.createObjectURL(blob));
  if (app.info.underlay) {
    app.underlay = await loadImage(URL.createObjectURL(await api("/api/underlay.png")));
    $("underlay-name").textContent = app.info.underlay.name;
    $("underlay-ctl").hidden = false;
  }
  const c = $("map");
  c.width = app.info.overview.width; c.height = app.info.overview.height;
  drawMap();
}
function loadImage(url) {
  return new Promise((ok, bad) => { const i = new Image(); i.onload = () => ok(i); i.onerror = bad; i.src = url; });
}
function mapPixel(e) {
  const c = $("map"), r = c.getBoundingClientRect();
  return [(e.clientX - r.left) * c.width / r.width, (e.clientY - r.top) * c.height / r.height];
}
async function lookup(x, y) { return api(`/api/lookup?x=${x}&y=${y}`); }
// Local linear map of overview pixels to lon/lat at the viewpoint.
async function updateJacobian() {
  const v = view();
  const others = app.sketch.views.map((w) => [w.viewpoint.lon, w.viewpoint.lat]);
  const p = await api("/api/project", { points: [[v.viewpoint.lon, v.viewpoint.lat], ...others] });
  app.viewPixels = p.pixels.slice(1);
  if (!p.pixels[0]) { app.vpPixel = null; drawMap(); return; }
  const [x, y] = p.pixels[0];
  app.vpPixel = [x, y];
  const cx = Math.min(Math.max(x, 0), app.info.overview.width - 2), cy = Math.min(Math.max(y, 0), app.info.overview.height - 2);
  const [a, b, c] = await Promise.all([lookup(cx, cy), lookup(cx + 1, cy), lookup(cx, cy + 1)]);
  app.jac = { dlon_dx: b.lon - a.lon, dlat_dx: b.lat - a.lat, dlon_dy: c.lon - a.lon, dlat_dy: c.lat - a.lat };
  drawMap();
}
// East/north metres of an overview pixel step (dx, dy) at the viewpoint.
function pixelToEN(dx, dy) {
  const j = app.jac, lat = view().viewpoint.lat * Math.PI / 180, R = 6371008.8 * Math.PI / 180;
  return [(j.dlon_dx * dx + j.dlon_dy * dy) * R * Math.cos(lat), (j.dlat_dx * dx + j.dlat_dy * dy) * R];
}
function enToPixel(e, n) {
  // invert the 2x2 of pixelToEN
  const [ax, ay] = pixelToEN(1, 0), [bx, by] = pixelToEN(0, 1);
  const det = ax * by - bx * ay;
  return [(e * by - n * bx) / det, (n * ax - e * ay) / det];
}
function drawMap() {
  const c = $("map"), g = c.getContext("2d");
  if (!app.overview) return;
  g.clearRect(0, 0, c.width, c.height);
  g.drawImage(app.overview, 0, 0, c.width, c.height);
  if (app.underlay) {
    g.globalAlpha = +$("underlay-opacity").value;
    g.drawImage(app.underlay, 0, 0, c.width, c.height);
    g.globalAlpha = 1;
  }
  if (app.viewshed) g.drawImage(app.viewshed, 0, 0, c.width, c.height);
  if (!app.vpPixel || !app.jac) return;
  const [x, y] = app.vpPixel, cam = view().camera;
  const s = Math.max(c.width, c.height) / 600;
  // field of view wedge, 1/4 of the map across
  const [ux, uy] = pixelToEN(1, 0);
  const mPerPx = Math.hypot(ux, uy);
  const len = 0.25 * Math.max(c.width, c.height) * mPerPx;
  const h = cam.heading_deg * Math.PI / 180, half = cam.hfov_deg * Math.PI / 360;
  g.beginPath(); g.moveTo(x, y);
  for (let k = 0; k <= 16; k++) {
    const a = h - half + 2 * half * k / 16;
    const [px, py] = enToPixel(len * Math.sin(a), len * Math.cos(a));
    g.lineTo(x + px, y + py);
  }
  g.closePath();
  g.fillStyle = "rgba(255,255,255,0.28)"; g.fill();
  g.lineWidth = 1.5 * s; g.strokeStyle = "#c0158f"; g.stroke();
  // the other views of the sketch
  (app.viewPixels || []).forEach((q, i) => {
    if (!q || i === app.cur) return;
    g.beginPath(); g.arc(q[0], q[1], 3.5 * s, 0, 2 * Math.PI);
    g.fillStyle = "#444"; g.fill(); g.lineWidth = 1.5 * s; g.strokeStyle = "#fff"; g.stroke();
  });
  g.beginPath(); g.arc(x, y, 5 * s, 0, 2 * Math.PI); g.fillStyle = "#c0158f"; g.fill();
  g.lineWidth = 2 * s; g.strokeStyle = "#fff"; g.stroke();
}
function setupMapEvents() {
  const c = $("map");
  let dragging = false, moved = false, lastMove = 0;
  c.addEventListener("pointerdown", async (e) => {
    if (view().strokes.length) { status("camera locked: the view has strokes (add a view to place another)"); return; }
    c.setPointerCapture(e.pointerId);
    dragging = true; moved = false;
    const [x, y] = mapPixel(e);
    try {
      const p = await lookup(x, y);
      if (p.height === null) { status("no data there"); dragging = false; return; }
      const v = view();
      v.viewpoint.lon = Math.round(p.lon * 1e6) / 1e6; v.viewpoint.lat = Math.round(p.lat * 1e6) / 1e6;
      app.viewshed = null;
      syncFields();
      await updateJacobian();
      scheduleRender();
    } catch (err) { status(err.message); dragging = false; }
  });
  c.addEventListener("pointermove", async (e) => {
    const [x, y] = mapPixel(e);
    if (dragging && app.vpPixel && app.jac) {
      const [dx, dy] = [x - app.vpPixel[0], y - app.vpPixel[1]];
      if (Math.hypot(dx, dy) > 3) {
        moved = true;
        const [east, north] = pixelToEN(dx, dy);
        setCamera({ heading_deg: Math.atan2(east, north) * 180 / Math.PI });
      }
      return;
    }
    const now = performance.now();
    if (now - lastMove < 60) return;
    lastMove = now;
    if (x < 0 || y < 0 || x >= c.width || y >= c.height) return;
    try {
      const p = await lookup(x, y);
      $("cursor").textContent = `lon ${p.lon.toFixed(5)}  lat ${p.lat.toFixed(5)}  ` + (p.height === null ? "nodata" : `${p.height.toFixed(1)} m`);
    } catch (err) { /* outside */ }
  });
  c.addEventListener("pointerup", () => { dragging = false; if (moved) scheduleRender(); });
}

// ---------- first-person view ----------
function sizeView() {
  const cam = view().camera, wrap = $("view-wrap");
  wrap.style.aspectRatio = `${cam.width} / ${cam.height}`;
  const cv = $("strokes");
  if (cv.width !== cam.width || cv.height !== cam.height) { cv.width = cam.width; cv.height = cam.height; }
  drawStrokes();
}
function overlays() {
  const o = [];
  if ($("ov-sil").checked) o.push("silhouettes");
  if ($("ov-ridges").checked) o.push("ridges");
  return o;
}
let renderTimer = null;
function scheduleRender() { clearTimeout(renderTimer); renderTimer = setTimeout(render, 120); }
async function render() {
  const v = view();
  const req = { viewpoint: v.viewpoint, camera: v.camera, overlays: overlays() };
  const key = JSON.stringify(req);
  if (key === app.lastRendered) return;
  const seq = ++app.renderSeq;
  status("rendering...");
  const t0 = performance.now();
  try {
    const blob = await api("/api/render", req);
    if (seq !== app.renderSeq) return;
    const img = $("render");
    const old = img.src;
    await new Promise((ok) => { img.onload = ok; img.onerror = ok; img.src = URL.createObjectURL(blob); });
    if (old.startsWith("blob:")) URL.revokeObjectURL(old);
    app.lastRendered = key;
    img.dataset.rendered = key;
    status(`view rendered in ${Math.round(performance.now() - t0)} ms`);
  } catch (err) { if (seq === app.renderSeq) status("render: " + err.message); }
}
function viewPixel(e) {
  const cv = $("strokes"), r = cv.getBoundingClientRect();
  return [(e.clientX - r.left) * cv.width / r.width, (e.clientY - r.top) * cv.height / r.height];
}
function drawStrokes() {
  const cv = $("strokes"), g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  const lw = Math.max(2.5, cv.width / 320);
  const line = (pts, color, w) => {
    if (pts.length < 1) return;
    g.beginPath(); g.moveTo(pts[0][0], pts[0][1]);
    for (const p of pts.slice(1)) g.lineTo(p[0], p[1]);
    g.strokeStyle = color; g.lineWidth = w; g.lineJoin = "round"; g.lineCap = "round"; g.stroke();
  };
  view().strokes.forEach((s, i) => {
    line(s.points, "rgba(255,255,255,0.8)", lw + 2.5);
    line(s.points, i === app.selected ? "#1f6feb" : "#e000c8", lw);
  });
  if (app.drawing) line(app.drawing, "#ff8c00", lw);
}
function listStrokes() {
  const v = view();
  $("stroke-list").innerHTML = v.strokes.map((s, i) =>
    `<li data-i="${i}" class="${i === app.selected ? "sel" : ""}">${esc(s.id)}: ${s.points.length} points</li>`).join("");
}
// Over-sketching (Gain et al. 2009, section 3): a stroke that starts
// and/or ends near an existing stroke replaces the part of it between.
function nearest(points, p) {
  let best = -1, bd = Infinity;
  points.forEach((q, i) => { const d = Math.hypot(q[0] - p[0], q[1] - p[1]); if (d < bd) { bd = d; best = i; } });
  return [best, bd];
}
function addStroke(pts) {
  const v = view();
  const R = Math.max(10, 14 * $("strokes").width / $("strokes").getBoundingClientRect().width);
  const a = pts[0], b = pts[pts.length - 1];
  let best = null;
  v.strokes.forEach((s, k) => {
    const [is, ds] = nearest(s.points, a), [ie, de] = nearest(s.points, b);
    const score = (ds < R ? 1 : 0) + (de < R ? 1 : 0);
    if (score > 0 && (!best || score > best.score || (score === best.score && ds + de < best.d)))
      best = { k, is, ie, ds, de, score, d: ds + de };
  });
  snapshot();
  if (!best) {
    v.strokes.push({ id: nextStrokeId(v), points: pts });
    app.selected = null;
  } else {
    const s = v.strokes[best.k], P = s.points;
    let np;
    if (best.ds < R && best.de < R) {
      let [i, j, q] = [best.is, best.ie, pts];
      if (i > j) { [i, j] = [j, i]; q = pts.slice().reverse(); }
      np = P.slice(0, i).concat(q, P.slice(j + 1));
    } else if (best.ds < R) {
      // replaces from the start point on, towards the side it heads to
      const dirEnd = best.is >= P.length / 2;
      np = dirEnd ? P.slice(0, best.is).concat(pts) : pts.slice().reverse().concat(P.slice(best.is + 1));
    } else {
      const dirEnd = best.ie >= P.length / 2;
      np = dirEnd ? P.slice(0, best.ie).concat(pts.slice().reverse()) : pts.concat(P.slice(best.ie + 1));
    }
    s.points = np;
    app.selected = null;
  }
  syncFields(); drawStrokes();
}
function tool() { return document.querySelector("input[name=tool]:checked").value; }
function setupViewEvents() {
  const cv = $("strokes");
  let look = null;
  cv.addEventListener("pointerdown", (e) => {
    cv.setPointerCapture(e.pointerId);
    $("view-wrap").focus({ preventScroll: true });
    const t = tool();
    if (t === "draw" && e.button === 0) { app.drawing = [viewPixel(e)]; drawStrokes(); }
    else if (t === "move") startMove(viewPixel(e));
    else look = { x: e.clientX, y: e.clientY, cam: { ...view().camera }, shift: e.shiftKey, align: t === "align" };
  });
  cv.addEventListener("pointermove", (e) => {
    if (app.drawing) {
      const p = viewPixel(e), q = app.drawing[app.drawing.length - 1];
      if (Math.hypot(p[0] - q[0], p[1] - q[1]) >= 2) { app.drawing.push(p); drawStrokes(); }
    } else if (app.moving) {
      const p = viewPixel(e), m = app.moving;
      const [dx, dy] = [p[0] - m.from[0], p[1] - m.from[1]];
      view().strokes[m.k].points = m.points.map(([x, y]) => [x + dx, y + dy]);
      m.moved = true;
      drawStrokes();
    } else if (look) {
      const r = cv.getBoundingClientRect();
      const degPerPx = look.cam.hfov_deg / r.width;
      const dx = e.clientX - look.x, dy = e.clientY - look.y;
      // Look: the terrain follows the pointer. Align: the render moves under the photo.
      if (look.shift) setCamera({ roll_deg: look.cam.roll_deg + dx * 0.1 });
      else setCamera({ heading_deg: look.cam.heading_deg - dx * degPerPx, pitch_deg: look.cam.pitch_deg + dy * degPerPx });
    }
  });
  const end = (e) => {
    if (app.drawing) {
      const pts = app.drawing; app.drawing = null;
      if (pts.length >= 2) addStroke(pts); else drawStrokes();
    }
    if (app.moving) {
      // Nothing moved: the snapshot taken for it is dropped.
      if (!app.moving.moved) app.undo.pop();
      app.moving = null; listStrokes();
    }
    look = null;
  };
  cv.addEventListener("pointerup", end);
  cv.addEventListener("pointercancel", end);
  cv.addEventListener("wheel", (e) => {
    if (tool() === "draw" || tool() === "move") return;
    e.preventDefault();
    setCamera({ hfov_deg: view().camera.hfov_deg * (e.deltaY > 0 ? 1.03 : 1 / 1.03) });
  }, { passive: false });
  $("view-wrap").addEventListener("keydown", (e) => {
    const c = view().camera, step = e.shiftKey ? 10 : 2;
    const k = { ArrowLeft: { heading_deg: c.heading_deg - step }, ArrowRight: { heading_deg: c.heading_deg + step },
      ArrowUp: { pitch_deg: c.pitch_deg + step / 2 }, ArrowDown: { pitch_deg: c.pitch_deg - step / 2 } }[e.key];
    if (k) { e.preventDefault(); setCamera(k); }
    if (e.key === "Escape" && app.drawing) { app.drawing = null; drawStrokes(); }
    if ((e.ctrlKey || e.metaKey) && e.key === "z") { e.preventDefault(); e.shiftKey ? redo() : undo(); }
    if (e.key === "Delete" || e.key === "Backspace") { e.preventDefault(); deleteStroke(); }
  });
}
// Move: the stroke nearest the pointer (within a few pixels of the
// screen) is selected and follows it; one undo step.
function startMove(p) {
  const v = view(), cv = $("strokes");
  const R = Math.max(8, 16 * cv.width / cv.getBoundingClientRect().width);
  let best = null;
  v.strokes.forEach((s, k) => {
    const [, d] = nearest(s.points, p);
    if (d < R && (!best || d < best.d)) best = { k, d };
  });
  if (!best) { app.selected = null; listStrokes(); drawStrokes(); return; }
  snapshot();
  app.selected = best.k;
  app.moving = { k: best.k, from: p, points: v.strokes[best.k].points.map((q) => q.slice()), moved: false };
  listStrokes(); drawStrokes();
}
function deleteStroke() {
  const v = view();
  if (app.selected === null || !v.strokes[app.selected]) return;
  snapshot(); v.strokes.splice(app.selected, 1); app.selected = null; syncFields(); drawStrokes();
}

// ---------- photo ----------
function setupPhoto() {
  $("photo-file").addEventListener("change", async (e) => {
    const f = e.target.files[0]; if (!f) return;
    const url = URL.createObjectURL(f);
    const img = await loadImage(url);
    app.photo = { url, w: img.naturalWidth, h: img.naturalHeight };
    for (const id of ["photo-under", "photo-over-img"]) $(id).src = url;
    showPhoto();
    // the view takes the photo's shape (same width)
    const v = view();
    let used = "";
    if (!v.strokes.length) {
      // The photo's size, scaled down to the server's limits if need be.
      const lim = app.info.limits, nw = img.naturalWidth, nh = img.naturalHeight;
      const k = Math.min(1, lim.max_side_px / nw, lim.max_side_px / nh, Math.sqrt(lim.max_pixels / (nw * nh)));
      setCamera({ width: Math.max(16, Math.floor(nw * k)), height: Math.max(16, Math.floor(nh * k)) });
      used = await useExif(f, img);
    }
    $("photo-info").textContent = `${f.name}: ${img.naturalWidth} x ${img.naturalHeight}` + used;
    status(`photo ${f.name}: ${img.naturalWidth} x ${img.naturalHeight}` + used);
  });
  $("photo-opacity").addEventListener("input", showPhoto);
  $("photo-over").addEventListener("change", showPhoto);
}
// The photo's EXIF (read by the server from its first MiB): the GPS
// position places the viewpoint, the focal length sets the field of view,
// a true GPS bearing the heading. Returns what was used, for the status.
async function useExif(file, img) {
  let ex;
  try {
    const r = await fetch(`/api/photo-exif?width=${img.naturalWidth}&height=${img.naturalHeight}`, {
      method: "POST", headers: { "Content-Type": "application/octet-stream" }, body: file.slice(0, 1024 * 1024),
    });
    if (!r.ok) return "";
    ex = await r.json();
  } catch (err) { return ""; }
  app.photoExif = ex;
  const used = [], cam = {};
  const v = view();
  if (ex.lon !== null && ex.lat !== null) {
    v.viewpoint.lon = Math.round(ex.lon * 1e6) / 1e6; v.viewpoint.lat = Math.round(ex.lat * 1e6) / 1e6;
    app.viewshed = null;
    used.push(`GPS ${v.viewpoint.lon.toFixed(5)}, ${v.viewpoint.lat.toFixed(5)}`);
  }
  if (ex.hfov_deg !== null) {
    cam.hfov_deg = ex.hfov_deg;
    used.push(`hfov ${ex.hfov_deg.toFixed(1)} deg from the ${ex.hfov_from === "35mm" ? "35 mm equivalent" : "sensor width"} of ${(ex.focal_35mm ?? ex.focal_mm).toFixed(1)} mm`);
  }
  if (ex.heading_deg !== null) { cam.heading_deg = ex.heading_deg; used.push(`heading ${ex.heading_deg.toFixed(0)} deg`); }
  if (!used.length) return ": no EXIF position or focal length";
  setCamera(cam);
  if (ex.lon !== null) await updateJacobian();
  return ": EXIF " + used.join(", ");
}
function showPhoto() {
  const over = $("photo-over").checked, op = $("photo-opacity").value;
  $("photo-under").hidden = !app.photo || over;
  $("photo-over-img").hidden = !app.photo || !over;
  $("photo-over-img").style.opacity = op;
  // under the render: the render is see-through by the opacity
  $("render").style.opacity = app.photo && !over ? 1 - op : 1;
}

// ---------- sketch file ----------
function download() {
  const text = JSON.stringify(sketchJSON(), null, 2);
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([text], { type: "application/json" }));
  a.download = "sketch.json";
  document.body.appendChild(a); a.click(); a.remove();
}
async function loadSketch(file) {
  try {
    const s = JSON.parse(await file.text());
    if (!Array.isArray(s.views) || !s.views.length) throw new Error("no views");
    snapshot();
    for (const v of s.views) { v.strokes = v.strokes || []; v.camera = Object.assign(newView("x").camera, v.camera || {}); }
    app.sketch = { views: s.views, options: s.options || {} };
    app.cur = 0; app.selected = null;
    syncFields(); await updateJacobian(); scheduleRender();
    status(`loaded ${file.name}: ${s.views.length} view(s)`);
  } catch (err) { status(`${file.name}: not a sketch file: ${err.message}`); }
}

// ---------- edit ----------
async function dryRun() {
  $("accept").disabled = true; $("reject").disabled = true;
  try {
    const r = await api("/api/edit", { sketch: sketchJSON(), allow_partial: $("allow-partial").checked });
    app.job = r.job;
    const j = await poll(r.job);
    showJob(j);
  } catch (err) { $("edit-status").textContent = "dry run: " + err.message; }
}
async function poll(id) {
  for (;;) {
    const j = await api(`/api/jobs/${id}?wait_ms=1000`);
    const what = j.kind === "write" ? "writing" : "dry run";
    if (j.state === "queued") $("edit-status").textContent = `${what} ${id}: queued (${j.queued_ahead} ahead)`;
    else if (j.state === "running") $("edit-status").textContent = `${what} ${id}: running ${j.elapsed_s.toFixed(1)} s${j.stage ? ": " + j.stage : ""}`;
    else return j;
  }
}
function showJob(j) {
  const el = $("edit-status");
  if (j.state === "failed") { el.textContent = `dry run ${j.id} failed: ${j.message}`; $("reject").disabled = false; return; }
  const r = j.report;
  el.textContent = (j.writable ? `dry run ${j.id}: a real run would change ${r.changed_cells} cells (max |dz| ${r.max_abs_displacement_m.toFixed(1)} m), ${j.elapsed_s.toFixed(2)} s`
    : `dry run ${j.id}: would not write: ${j.message}`);
  el.dataset.job = j.id; el.dataset.state = j.writable ? "writable" : "not-writable";
  $("accept").disabled = !(j.writable && app.info.out);
  $("reject").disabled = false;
  const box = $("compare-images");
  box.innerHTML = "";
  const order = (n) => (n.endsWith("_before.png") ? 0 : n.endsWith("_after.png") ? 1 : 2) + n;
  for (const n of j.images.slice().sort((a, b) => order(a).localeCompare(order(b)))) {
    const label = n === "height_change.png" ? "height change (new - old)" : n.replace(/_before\.png$/, ": before").replace(/_after\.png$/, ": after");
    box.insertAdjacentHTML("beforeend", `<figure class="${n === "height_change.png" ? "dz" : ""}"><img src="/api/jobs/${j.id}/image/${encodeURIComponent(n)}" alt="${esc(n)}"><figcaption>${esc(label)}</figcaption></figure>`);
  }
  const rows = [];
  for (const v of r.views) for (const s of v.strokes) {
    const bad = s.status !== "fitted";
    rows.push(`<tr class="${bad ? "bad" : "ok"}"><td>${esc(v.name)}</td><td>${esc(s.id)}</td><td>${esc(s.status)}</td><td>${esc(s.match.kind)}</td>
      <td>${s.fit.fitted_fraction.toFixed(2)}</td><td>${s.visible_fraction.toFixed(2)}</td><td>${s.fit.mean_px.toFixed(2)}</td>
      <td>${esc(placementText(s.placement))}</td><td>${esc(s.reason || "")}</td></tr>`);
  }
  $("stroke-table").querySelector("tbody").innerHTML = rows.join("");
  $("compare-title").textContent = `dry run ${j.id}`;
  $("compare-summary").textContent = `${r.changed_cells} cells would change, max |dz| ${r.max_abs_displacement_m.toFixed(1)} m; ` +
    `stages: ` + Object.entries(r.timings_s).map(([k, t]) => `${k} ${t.toFixed(2)} s`).join(", ");
  $("compare").hidden = false;
}
function placementText(p) {
  if (!p || typeof p !== "object") return "";
  return Object.entries(p).filter(([, v]) => typeof v !== "object").map(([k, v]) => `${k} ${typeof v === "number" ? +v.toFixed(2) : v}`).join(", ");
}
async function accept() {
  if (!app.job) return;
  $("accept").disabled = true; $("reject").disabled = true;
  try {
    const r = await api(`/api/jobs/${app.job}/accept`, {});
    const j = await poll(r.job);
    app.writeJob = j;
    const el = $("edit-status");
    el.dataset.state = j.written ? "written" : "failed";
    el.textContent = j.written ? `written to ${app.info.out}: ${j.report.changed_cells} cells changed in ${j.report.tiles_written.length} file(s)`
      : `not written: ${j.message}`;
  } catch (err) { $("edit-status").textContent = "accept: " + err.message; }
}
async function reject() {
  if (!app.job) return;
  try { await api(`/api/jobs/${app.job}/reject`, {}); } catch (err) { /* gone */ }
  app.job = null; $("compare").hidden = true; $("accept").disabled = true; $("reject").disabled = true;
  $("edit-status").textContent = "rejected: nothing written";
}

// ---------- wiring ----------
async function main() {
  app.sketch.views.push(newView("view-1"));
  setupMapEvents(); setupViewEvents(); setupPhoto();
  for (const id of ["f-lon", "f-lat", "f-eye", "f-alt", ...camFields.map((c) => c[0])]) {
    $(id).addEventListener("change", async () => {
      readFields(); syncFields();
      if (id === "f-lon" || id === "f-lat") await updateJacobian();
      drawMap(); scheduleRender();
    });
  }
  $("view-name").addEventListener("change", () => { snapshot(); view().name = $("view-name").value || `view-${app.cur + 1}`; syncFields(); });
  $("view-select").addEventListener("change", async () => { app.cur = +$("view-select").value; app.selected = null; syncFields(); await updateJacobian(); scheduleRender(); });
  $("view-add").addEventListener("click", () => {
    snapshot();
    let n = app.sketch.views.length + 1;
    while (app.sketch.views.some((v) => v.name === `view-${n}`)) n++;
    app.sketch.views.push(newView(`view-${n}`, view()));
    app.cur = app.sketch.views.length - 1; syncFields(); updateJacobian(); scheduleRender();
  });
  $("view-del").addEventListener("click", () => {
    if (app.sketch.views.length < 2) return;
    snapshot(); app.sketch.views.splice(app.cur, 1); app.cur = 0; syncFields(); updateJacobian(); scheduleRender();
  });
  $("underlay-opacity").addEventListener("input", drawMap);
  $("ov-sil").addEventListener("change", scheduleRender);
  $("ov-ridges").addEventListener("change", scheduleRender);
  $("viewshed-btn").addEventListener("click", async () => {
    status("viewshed...");
    try {
      const v = view();
      app.viewshed = await loadImage(URL.createObjectURL(await api("/api/viewshed", { viewpoint: v.viewpoint, camera: v.camera })));
      drawMap(); status("viewshed: visible ground in yellow");
    } catch (err) { status("viewshed: " + err.message); }
  });
  $("stroke-list").addEventListener("click", (e) => {
    const li = e.target.closest("li"); if (!li) return;
    app.selected = +li.dataset.i; listStrokes(); drawStrokes();
  });
  $("undo").addEventListener("click", undo);
  $("redo").addEventListener("click", redo);
  $("del-stroke").addEventListener("click", deleteStroke);
  $("download").addEventListener("click", download);
  $("load-file").addEventListener("change", (e) => { if (e.target.files[0]) loadSketch(e.target.files[0]); });
  $("dry-run").addEventListener("click", dryRun);
  $("accept").addEventListener("click", accept);
  $("reject").addEventListener("click", reject);
  window.addEventListener("resize", drawStrokes);
  try {
    await setupMap();
    // start at the DEM's centre, looking north
    const p = await lookup(app.info.overview.width / 2, app.info.overview.height / 2);
    view().viewpoint.lon = Math.round(p.lon * 1e6) / 1e6; view().viewpoint.lat = Math.round(p.lat * 1e6) / 1e6;
    syncFields(); await updateJacobian(); await render();
    document.body.dataset.ready = "1";
  } catch (err) { status(err.message); document.body.dataset.ready = "error"; }
}
main();
