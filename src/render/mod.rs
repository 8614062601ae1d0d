//! First-person rendering of a DEM: depth buffer, shaded image and viewshed.
