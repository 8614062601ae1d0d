//! Multigrid solver for the diffusion of displacements (placeholder).
