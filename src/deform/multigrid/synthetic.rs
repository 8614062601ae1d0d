//! Deterministic synthetic constraint layouts for the solver's tests,
//! benchmarks and the pyamg comparison (`tools/compare_pyamg.py` reads the
//! layout that `examples/multigrid_bench.rs` writes with this module, so both
//! solve the identical problem).
//!
//! A layout imitates what the deformation step produces: several random
//! polylines rasterised as one-cell-wide 8-connected curves carrying a
//! displacement that varies smoothly along the curve, a few isolated
//! constrained cells, and a few round nodata holes fixed to 0.

/// SplitMix64: a tiny, well-mixed deterministic generator (no dependency).
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A constraint layout on an `nx x ny` grid: `fixed` marks Dirichlet cells,
/// `values` holds their values (0 elsewhere), row-major `i + nx * j`.
#[derive(Debug, Clone)]
pub struct ConstraintLayout {
    pub fixed: Vec<bool>,
    pub values: Vec<f32>,
}

/// Builds the layout for `seed`: `curves` polylines of 3 to 6 vertices each
/// (displacement `20 sin(phase + arc_length / 40 cells) + 5` metres along
/// each), `points` isolated cells with displacements in `[-10, 10)`, and
/// `holes` discs of radius `max(2, min(nx, ny) / 100)` cells fixed to 0.
pub fn scattered_constraints(
    nx: usize,
    ny: usize,
    curves: usize,
    points: usize,
    holes: usize,
    seed: u64,
) -> ConstraintLayout {
    let mut rng = SplitMix64(seed);
    let mut fixed = vec![false; nx * ny];
    let mut values = vec![0.0f32; nx * ny];
    let (fx, fy) = (nx as f64, ny as f64);
    for _ in 0..curves {
        let vertices = 3 + (rng.next_u64() % 4) as usize;
        let phase = rng.unit() * std::f64::consts::TAU;
        let mut prev = (rng.unit() * fx, rng.unit() * fy);
        let mut arc = 0.0;
        for _ in 1..vertices {
            let next = (rng.unit() * fx, rng.unit() * fy);
            // 8-connected rasterisation: one cell per step along the major axis.
            let (dx, dy) = (next.0 - prev.0, next.1 - prev.1);
            let steps = dx.abs().max(dy.abs()).ceil().max(1.0) as usize;
            let len = (dx * dx + dy * dy).sqrt();
            for s in 0..=steps {
                let t = s as f64 / steps as f64;
                let (x, y) = (prev.0 + t * dx, prev.1 + t * dy);
                let (i, j) = (x.floor() as isize, y.floor() as isize);
                if i < 0 || j < 0 || i as usize >= nx || j as usize >= ny {
                    continue;
                }
                let k = j as usize * nx + i as usize;
                fixed[k] = true;
                values[k] = (20.0 * (phase + (arc + t * len) / 40.0).sin() + 5.0) as f32;
            }
            arc += len;
            prev = next;
        }
    }
    for _ in 0..points {
        let i = (rng.unit() * fx) as usize;
        let j = (rng.unit() * fy) as usize;
        let k = j.min(ny - 1) * nx + i.min(nx - 1);
        fixed[k] = true;
        values[k] = (rng.unit() * 20.0 - 10.0) as f32;
    }
    let radius = (nx.min(ny) / 100).max(2) as isize;
    for _ in 0..holes {
        let ci = (rng.unit() * fx) as isize;
        let cj = (rng.unit() * fy) as isize;
        for j in (cj - radius)..=(cj + radius) {
            for i in (ci - radius)..=(ci + radius) {
                let inside = (i - ci) * (i - ci) + (j - cj) * (j - cj) <= radius * radius;
                if inside && i >= 0 && j >= 0 && (i as usize) < nx && (j as usize) < ny {
                    let k = j as usize * nx + i as usize;
                    fixed[k] = true;
                    values[k] = 0.0;
                }
            }
        }
    }
    ConstraintLayout { fixed, values }
}
