//! Deformation: turns placed 3D curve constraints into a displacement field
//! `M` and the corrected DEM `H' = H + M` (section 6 of Tassé et al. 2014).
//! The displacement is diffused by a multigrid solver ([`multigrid`]) so that
//! the terrain's own small-scale detail is preserved.

pub mod multigrid;
