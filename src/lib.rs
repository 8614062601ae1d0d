//! demsketch: correct real digital elevation models (DEMs) by sketching the
//! silhouettes the terrain should show from ground-level viewpoints.
//!
//! The modules follow the pipeline of `DESIGN.md`:
//!
//! - [`raster`]: GeoTIFF decoding, georeferencing, the tile layer that gives
//!   seamless windows across tiles, and atomic write-back of corrected tiles.
//! - [`view`]: viewpoints (lon/lat through PROJ to the DEM's CRS) and the
//!   pinhole camera with earth curvature and refraction.
//! - [`render`]: first-person depth buffer, shaded images, viewsheds.
//! - [`features`]: the terrain features a sketch is matched to: visible
//!   silhouettes and ridge lines.
//! - [`sketch`]: sketch files, stroke depth ordering and stroke-feature matching.
//! - [`deform`]: displacement constraints, the multigrid diffusion solver and
//!   lowering of protruding silhouettes.
//! - [`edit`]: one edit end to end: load, features, matching, deformation,
//!   lowering, write-back, report and pictures.
//! - [`batch`]: many edits on one DEM, planned into independent groups of
//!   tiles, run in parallel or as an array job, with a journal to resume.
//! - [`export`]: the DEM to web-map tiles, COG, GeoJSON, STAC and glTF.
//!
//! [`buffer_pool`] keeps the large per-view and per-solve buffers warm
//! between views and solves.

// Errors are values: nothing that comes from a file, a user, the environment
// or the OS is unwrapped. A true invariant is an `expect("why it holds")`;
// tests may unwrap.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]
// `!(a < b)` is deliberate throughout: it is true for NaN, which is what the
// checks want (a NaN depth, distance or bound is rejected). Rewriting it as
// `a >= b` would let NaN through, so the lint stays off.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod batch;
pub mod buffer_pool;
pub mod correct;
pub mod deform;
pub mod edit;
pub mod export;
pub mod features;
pub mod num;
pub mod raster;
pub mod render;
pub mod serve;
pub mod sketch;
pub mod view;
