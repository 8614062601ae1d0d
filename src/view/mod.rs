//! Viewpoints and cameras: lon/lat (WGS84) to the DEM's CRS through PROJ,
//! heading from true north, and the pinhole camera of `DESIGN.md`.
