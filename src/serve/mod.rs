//! The browser app (`demsketch serve`): a local web server over the
//! library, with its page, script and styles built into the binary.
//!
//! It is a thin layer: the map view is a hillshade of decimated reads of
//! the DEM's files ([`overview`]), optionally with any raster warped onto
//! its grid by GDAL ([`underlay`]); first-person views, their silhouettes
//! and ridges and the viewshed come from [`crate::render`] and
//! [`crate::features`] ([`first_person`]); a photo's EXIF gives its
//! viewpoint and field of view ([`photo_exif`]); edits run through
//! [`crate::edit::run`], the code path of `demsketch edit`, as dry runs
//! first, and an accepted edit is written to the `--out` of the command
//! line by the same call with the same sketch, through the edit's atomic
//! write-back ([`jobs`]); a dry run's pictures are drawn from its height
//! change when the page fetches them ([`pictures`]). No path ever comes from the browser: the server
//! only reads the DEM and writes OUT (and its own private working
//! directory). Requests are bounded (body size, image size, queue length);
//! heavy work runs on blocking threads, one edit at a time
//! ([`routes`]). The page ([`assets`]) is plain JavaScript with no build
//! step and nothing fetched from the internet.

pub mod assets;
pub mod first_person;
pub mod jobs;
pub mod overview;
pub mod photo_exif;
pub mod pictures;
pub mod routes;
pub mod state;
pub mod underlay;

pub use routes::router;
pub use state::{AppState, ServeConfig};

use std::net::SocketAddr;

/// Errors of the server, each with the HTTP status it is answered with.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The request is malformed or asks for something impossible (400).
    #[error("{0}")]
    BadRequest(String),
    /// No such job or image (404).
    #[error("{0}")]
    NotFound(String),
    /// The request conflicts with the server's state (409): no --out,
    /// a job not finished.
    #[error("{0}")]
    Conflict(String),
    /// Too many edits queued (429).
    #[error("{0}")]
    Busy(String),
    /// The library failed on valid input (422): viewpoint outside the DEM, ...
    #[error("{0}")]
    Unprocessable(String),
    /// The server's own fault (500).
    #[error("internal error: {0}")]
    Internal(String),
}

/// Start the server on `addr` and serve until the process ends; `on_ready`
/// is called with the bound address (the port may have been 0).
pub fn serve_blocking(
    config: ServeConfig,
    addr: SocketAddr,
    on_ready: impl FnOnce(SocketAddr),
) -> Result<(), ServeError> {
    let state = AppState::new(config)?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .max_blocking_threads(8)
        .enable_all()
        .build()
        .map_err(|e| ServeError::Internal(format!("cannot start the runtime: {e}")))?;
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind(addr)
            .await
            .map_err(|e| ServeError::BadRequest(format!("cannot listen on {addr}: {e}")))?;
        let bound = listener
            .local_addr()
            .map_err(|e| ServeError::Internal(e.to_string()))?;
        on_ready(bound);
        axum::serve(listener, router(state))
            .await
            .map_err(|e| ServeError::Internal(format!("server: {e}")))
    })
}
