//! The HTTP interface: the page and its files, and a JSON/PNG API over the
//! library. Every body is bounded ([`MAX_BODY_BYTES`]) and parsed here
//! (a malformed one is a 400 with a one-line message as JSON
//! `{"error": ...}`); no parameter is a path; work that reads the DEM or
//! renders runs on blocking threads (at most [`MAX_RENDERS`] at once).
//!
//! | method, path | body | answer |
//! | --- | --- | --- |
//! | GET `/api/info` | | the DEM: size, CRS, bounds, overview size, OUT |
//! | GET `/api/overview.png` | | the map's hillshade |
//! | GET `/api/underlay.png` | | the `--underlay` on the map's grid (404 without one) |
//! | GET `/api/lookup?x=X&y=Y` | | lon, lat, height at overview pixel (X, Y) |
//! | POST `/api/project` | `{"points": [[lon, lat], ...]}` | overview pixels |
//! | POST `/api/render` | view (`viewpoint`, `camera`, `overlays`) | PNG |
//! | POST `/api/features` | view | silhouettes (and ridges) as pixel polylines |
//! | POST `/api/locate` | view with `pixel` | the terrain point, or null |
//! | POST `/api/viewshed` | view | PNG on the overview grid |
//! | POST `/api/photo-exif?width=W&height=H` | the photo's first bytes (at most 1 MiB) | its EXIF GPS position, heading, focal length, hfov |
//! | POST `/api/edit` | `{"sketch": {...}, "allow_partial": false}` | `{"job": id}`, a dry run |
//! | GET `/api/jobs/{id}[?wait_ms=T]` | | state, report, pictures (with `wait_ms`: once finished, or after T ms) |
//! | GET `/api/jobs/{id}/image/{name}` | | a picture of the dry run |
//! | POST `/api/jobs/{id}/accept` | | `{"job": id}`, the real edit to OUT |
//! | POST `/api/jobs/{id}/reject` | | the dry run discarded |

use axum::body::Bytes;
use axum::extract::rejection::QueryRejection;
use axum::extract::{DefaultBodyLimit, Path as UrlPath, Query, State};
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Router;
use serde::Deserialize;
use serde_json::json;

use super::assets;
use super::first_person::{self, ViewRequest};
use super::jobs;
use super::pictures;
use super::state::AppState;
use super::ServeError;
use crate::sketch::SketchFile;

/// Largest request body, bytes.
pub const MAX_BODY_BYTES: usize = 16 * 1024 * 1024;
/// Renders (and other DEM reads) at once; more wait.
pub const MAX_RENDERS: usize = 2;

impl IntoResponse for ServeError {
    fn into_response(self) -> Response {
        let status = match &self {
            ServeError::BadRequest(_) => StatusCode::BAD_REQUEST,
            ServeError::NotFound(_) => StatusCode::NOT_FOUND,
            ServeError::Conflict(_) => StatusCode::CONFLICT,
            ServeError::Busy(_) => StatusCode::TOO_MANY_REQUESTS,
            ServeError::Unprocessable(_) => StatusCode::UNPROCESSABLE_ENTITY,
            ServeError::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        };
        let body = json!({ "error": self.to_string().replace('\n', " ") }).to_string();
        (status, [(header::CONTENT_TYPE, "application/json")], body).into_response()
    }
}

type Answer = Result<Response, ServeError>;

fn json_answer(v: &impl serde::Serialize) -> Answer {
    let body = serde_json::to_string(v).map_err(|e| ServeError::Internal(e.to_string()))?;
    Ok(([(header::CONTENT_TYPE, "application/json")], body).into_response())
}

fn png_answer(png: Vec<u8>) -> Answer {
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        png,
    )
        .into_response())
}

/// Parse a JSON body, naming what is wrong.
fn parse<T: serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, ServeError> {
    serde_json::from_slice(body).map_err(|e| ServeError::BadRequest(format!("request body: {e}")))
}

/// Run `f` on a blocking thread, at most [`MAX_RENDERS`] at once.
async fn blocking<T: Send + 'static>(
    state: &AppState,
    f: impl FnOnce(&AppState) -> Result<T, ServeError> + Send + 'static,
) -> Result<T, ServeError> {
    let _permit = state
        .render_gate
        .acquire()
        .await
        .map_err(|e| ServeError::Internal(e.to_string()))?;
    let st = state.clone();
    tokio::task::spawn_blocking(move || f(&st))
        .await
        .map_err(|e| ServeError::Internal(format!("the work stopped: {e}")))?
}

/// The router of the app over `state`.
pub fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(|| async { asset("index.html") }))
        .route("/app.js", get(|| async { asset("app.js") }))
        .route("/style.css", get(|| async { asset("style.css") }))
        .route("/api/info", get(info))
        .route("/api/overview.png", get(overview_png))
        .route("/api/underlay.png", get(underlay_png))
        .route("/api/lookup", get(lookup))
        .route("/api/project", post(project))
        .route("/api/render", post(render))
        .route("/api/features", post(features))
        .route("/api/locate", post(locate))
        .route("/api/viewshed", post(viewshed))
        .route("/api/photo-exif", post(photo_exif))
        .route("/api/edit", post(edit))
        .route("/api/jobs/{id}", get(job))
        .route("/api/jobs/{id}/image/{name}", get(job_image))
        .route("/api/jobs/{id}/accept", post(accept))
        .route("/api/jobs/{id}/reject", post(reject))
        .fallback(|| async { ServeError::NotFound("no such page".into()) })
        .layer(DefaultBodyLimit::max(MAX_BODY_BYTES))
        .with_state(state)
}

fn asset(name: &str) -> Answer {
    let (body, mime) =
        assets::get(name).ok_or_else(|| ServeError::NotFound(format!("no file {name}")))?;
    Ok(([(header::CONTENT_TYPE, mime)], body).into_response())
}

async fn info(State(st): State<AppState>) -> Answer {
    let dem = &st.dem;
    let bounds = crate::raster::lonlat_bounds(&dem.crs, &dem.geotransform, dem.width, dem.height);
    let name = st
        .config
        .dem
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let nodata = match dem.nodata {
        Some(v) if v.is_nan() => json!("nan"),
        Some(v) => json!(v),
        None => json!(null),
    };
    json_answer(&json!({
        "name": name,
        "width": dem.width,
        "height": dem.height,
        "geotransform": dem.geotransform.0,
        "epsg": dem.crs.epsg,
        "nodata": nodata,
        "tiles": dem.tiles.len(),
        "bounds_lonlat": bounds,
        "min_max": st.overview.min_max,
        "overview": {"width": st.overview.width, "height": st.overview.height,
                     "sx": st.overview.sx, "sy": st.overview.sy},
        "out": st.config.out.as_ref().map(|p| p.display().to_string()),
        "underlay": st.underlay.as_ref().map(|u| json!({"name": u.name, "width": u.width, "height": u.height})),
        "max_distance_m": st.config.max_distance_m,
        "min_fit": st.config.min_fit,
        "limits": {"max_body_bytes": MAX_BODY_BYTES, "max_side_px": first_person::MAX_SIDE_PX,
                   "max_pixels": first_person::MAX_PIXELS},
    }))
}

async fn overview_png(State(st): State<AppState>) -> Answer {
    png_answer(st.overview.png.clone())
}

async fn underlay_png(State(st): State<AppState>) -> Answer {
    match &st.underlay {
        Some(u) => png_answer(u.png.clone()),
        None => Err(ServeError::NotFound(
            "no underlay (start the server with --underlay FILE)".into(),
        )),
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LookupQuery {
    x: f64,
    y: f64,
}

async fn lookup(
    State(st): State<AppState>,
    q: Result<Query<LookupQuery>, QueryRejection>,
) -> Answer {
    let Query(q) = q.map_err(|e| ServeError::BadRequest(format!("query: {}", e.body_text())))?;
    let ov_w = st.overview.width as f64;
    let ov_h = st.overview.height as f64;
    if !(q.x.is_finite()
        && q.y.is_finite()
        && (0.0..ov_w).contains(&q.x)
        && (0.0..ov_h).contains(&q.y))
    {
        return Err(ServeError::BadRequest(format!(
            "lookup: ({}, {}) lies outside the map (0..{ov_w} x 0..{ov_h})",
            q.x, q.y
        )));
    }
    let v = blocking(&st, move |st| {
        let (px, py) = st.overview.to_dem_pixel(q.x, q.y);
        let (x, y) = st.dem.geotransform.pixel_to_crs(px, py);
        let (lon, lat) = st.with_georef(|g| {
            g.crs_to_lonlat(x, y)
                .map_err(|e| ServeError::Unprocessable(e.to_string()))
        })?;
        let (col, row) = (px.floor() as i64, py.floor() as i64);
        let win = crate::raster::Window::new(col, row, 1, 1);
        let cell = st
            .dem
            .read_window::<f32>(win)
            .map_err(|e| ServeError::Internal(e.to_string()))?;
        let h = cell.data.first().copied().filter(|v| v.is_finite());
        Ok(json!({"lon": lon, "lat": lat, "height": h, "col": col, "row": row}))
    })
    .await?;
    json_answer(&v)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ProjectRequest {
    points: Vec<[f64; 2]>,
}

async fn project(State(st): State<AppState>, body: Bytes) -> Answer {
    let req: ProjectRequest = parse(&body)?;
    if req.points.len() > 10_000 {
        return Err(ServeError::BadRequest(
            "project: at most 10000 points".into(),
        ));
    }
    let v = blocking(&st, move |st| {
        st.with_georef(|g| {
            let pixels: Vec<Option<[f64; 2]>> = req
                .points
                .iter()
                .map(|&[lon, lat]| {
                    let (x, y) = g.lonlat_to_crs(lon, lat).ok()?;
                    let (px, py) = st.dem.geotransform.crs_to_pixel(x, y)?;
                    let (ox, oy) = st.overview.from_dem_pixel(px, py);
                    (ox.is_finite() && oy.is_finite()).then_some([ox, oy])
                })
                .collect();
            Ok(json!({ "pixels": pixels }))
        })
    })
    .await?;
    json_answer(&v)
}

fn view_request(body: &[u8]) -> Result<ViewRequest, ServeError> {
    let req: ViewRequest = parse(body)?;
    first_person::camera_of(&req.camera)?;
    Ok(req)
}

async fn render(State(st): State<AppState>, body: Bytes) -> Answer {
    let req = view_request(&body)?;
    let (png, times) = blocking(&st, move |st| first_person::render_png(st, &req)).await?;
    let timing: Vec<String> = times
        .iter()
        .map(|(name, s)| format!("{name};dur={:.1}", s * 1000.0))
        .collect();
    let mut r = png_answer(png)?;
    if let Ok(v) = axum::http::HeaderValue::from_str(&timing.join(", ")) {
        r.headers_mut().insert("server-timing", v);
    }
    Ok(r)
}

async fn features(State(st): State<AppState>, body: Bytes) -> Answer {
    let req = view_request(&body)?;
    let f = blocking(&st, move |st| first_person::features(st, &req)).await?;
    json_answer(&f)
}

async fn locate(State(st): State<AppState>, body: Bytes) -> Answer {
    let req = view_request(&body)?;
    let v = blocking(&st, move |st| first_person::locate_pixel(st, &req)).await?;
    json_answer(&v)
}

async fn viewshed(State(st): State<AppState>, body: Bytes) -> Answer {
    let req = view_request(&body)?;
    png_answer(blocking(&st, move |st| first_person::viewshed_png(st, &req)).await?)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PhotoSize {
    width: u32,
    height: u32,
}

async fn photo_exif(q: Result<Query<PhotoSize>, QueryRejection>, body: Bytes) -> Answer {
    let Query(q) = q.map_err(|e| ServeError::BadRequest(format!("query: {}", e.body_text())))?;
    json_answer(&super::photo_exif::read(&body, q.width, q.height)?)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct EditRequest {
    sketch: serde_json::Value,
    #[serde(default)]
    allow_partial: bool,
}

async fn edit(State(st): State<AppState>, body: Bytes) -> Answer {
    let req: EditRequest = parse(&body)?;
    let text = serde_json::to_string_pretty(&req.sketch)
        .map_err(|e| ServeError::BadRequest(format!("sketch: {e}")))?;
    let sketch = SketchFile::from_json_str(&text, "sketch")
        .map_err(|e| ServeError::BadRequest(e.to_string()))?;
    for v in &sketch.views {
        first_person::camera_of(&v.camera)
            .map_err(|e| ServeError::BadRequest(format!("view \"{}\": {e}", v.name)))?;
    }
    let id = jobs::submit_dry_run(&st, text, req.allow_partial)?;
    Ok((StatusCode::ACCEPTED, json_answer(&json!({ "job": id }))?).into_response())
}

fn job_id(s: &str) -> Result<u64, ServeError> {
    s.parse()
        .map_err(|_| ServeError::BadRequest(format!("'{s}' is not a job number")))
}

/// Longest wait of a long-polling job request, milliseconds.
pub const MAX_WAIT_MS: u64 = 10_000;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JobQuery {
    /// Answer once the job has finished or after this many milliseconds
    /// (at most [`MAX_WAIT_MS`]), whichever comes first.
    #[serde(default)]
    wait_ms: u64,
}

async fn job(
    State(st): State<AppState>,
    UrlPath(id): UrlPath<String>,
    q: Result<Query<JobQuery>, QueryRejection>,
) -> Answer {
    let Query(q) = q.map_err(|e| ServeError::BadRequest(format!("query: {}", e.body_text())))?;
    let id = job_id(&id)?;
    let deadline =
        tokio::time::Instant::now() + std::time::Duration::from_millis(q.wait_ms.min(MAX_WAIT_MS));
    loop {
        // Registered before the look, so that a job finishing in between wakes it.
        let woken = st.jobs.finished.notified();
        let v = st.jobs.view(id)?;
        let open = matches!(v.state, jobs::JobState::Queued | jobs::JobState::Running);
        if !open || tokio::time::Instant::now() >= deadline {
            return json_answer(&v);
        }
        tokio::select! {
            _ = woken => {}
            _ = tokio::time::sleep_until(deadline) => {}
        }
    }
}

async fn job_image(
    State(st): State<AppState>,
    UrlPath((id, name)): UrlPath<(String, String)>,
) -> Answer {
    let id = job_id(&id)?;
    let (sketch, dz, window) = match st.jobs.picture_source(id, &name)? {
        jobs::PictureSource::Drawn(png) => return png_answer(png.to_vec()),
        jobs::PictureSource::ToDraw { sketch, dz, window } => (sketch, dz, window),
    };
    let n = name.clone();
    let png = blocking(&st, move |st| {
        let sketch = SketchFile::from_json_str(&sketch, "sketch")
            .map_err(|e| ServeError::Internal(e.to_string()))?;
        let change = pictures::HeightChange::read(&dz, window)?;
        pictures::draw(st, &sketch, &change, &n)
    })
    .await?;
    let png = std::sync::Arc::new(png);
    st.jobs.keep_picture(id, &name, png.clone());
    png_answer(png.to_vec())
}

async fn accept(State(st): State<AppState>, UrlPath(id): UrlPath<String>) -> Answer {
    let new = jobs::submit_accept(&st, job_id(&id)?)?;
    Ok((StatusCode::ACCEPTED, json_answer(&json!({ "job": new }))?).into_response())
}

async fn reject(State(st): State<AppState>, UrlPath(id): UrlPath<String>) -> Answer {
    st.jobs.reject(job_id(&id)?)?;
    json_answer(&json!({ "rejected": true }))
}
