//! A per-viewpoint horizon index that lets exact ray casting skip the empty
//! space between the eye and the first terrain a ray can possibly touch.
//!
//! Around the eye, the plane is cut into azimuth sectors and distance rings.
//! Every block of the terrain's max-height pyramid (level chosen so that
//! there are at most a few hundred thousand blocks) gives an upper bound of
//! the elevation slope `z / dh` (apparent height over horizontal distance,
//! both relative to the eye) of every point in it: its maximum height over
//! its smallest distance from the eye. The bound is recorded in every sector
//! the block overlaps, at the ring of its smallest distance, and a running
//! maximum along the rings turns each sector into a non-decreasing "horizon
//! so far" function. A ray of slope `m` in a sector cannot touch terrain
//! before the first ring whose running maximum reaches `m`: everything nearer
//! lies below it. Binary search gives that ring, and the exact traversal
//! ([`super::LocalTerrain::cast`]) starts there. A ray steeper than the
//! whole sector's maximum escapes without any traversal.
//!
//! The bound is conservative (rounded up), so casting stays exact. A small
//! disc around the eye (`near_m`) is left out of the index (there `dh` tends
//! to zero and the bound to infinity) and always traversed exactly.

use rayon::prelude::*;

/// The sector x ring horizon bounds of one viewpoint.
#[derive(Debug, Clone)]
pub(crate) struct HorizonIndex {
    sectors: usize,
    rings: usize,
    /// Ring width in metres.
    ring_m: f64,
    /// Radius of the disc around the eye the index leaves out, metres.
    pub near_m: f64,
    /// Sector index per radian of azimuth.
    sectors_per_rad: f64,
    /// Sector-major running maximum of slope bounds over rings:
    /// `prefix[s * rings + r]` bounds `z / dh` of all terrain in sector `s`
    /// with `near_m <= dh < (r + 1) * ring_m`.
    prefix: Vec<f32>,
}

/// One block of the max-height pyramid seen from the eye.
pub(crate) struct Block {
    /// Centre in local (east, north) metres.
    pub centre: (f64, f64),
    /// Radius of a circle around the centre holding the whole block.
    pub radius: f64,
    /// Maximum apparent height of the block (relative to the eye).
    pub zmax: f32,
}

impl HorizonIndex {
    /// Build the index from the blocks produced by `blocks(row)` for block
    /// rows `0..block_rows` (each row yields its blocks), with rings
    /// `ring_m` metres wide out to `max_dh` metres.
    pub fn build<F>(block_rows: usize, blocks: F, ring_m: f64, max_dh: f64, near_m: f64) -> Self
    where
        F: Fn(usize, &mut Vec<Block>) + Sync,
    {
        let rings = ((max_dh / ring_m).ceil() as usize + 2).clamp(2, 1 << 16);
        // About two blocks of arc at the far edge, within bounds.
        let sectors =
            ((std::f64::consts::TAU * max_dh / ring_m / 2.0).ceil() as usize).clamp(64, 4096);
        let sectors_per_rad = sectors as f64 / std::f64::consts::TAU;
        let threads = rayon::current_num_threads().clamp(1, 8);
        let per = block_rows.div_ceil(threads).max(1);
        let grids: Vec<Vec<f32>> = (0..threads)
            .into_par_iter()
            .map(|k| {
                let mut g = vec![f32::NEG_INFINITY; rings * sectors];
                let mut buf = Vec::new();
                for row in (k * per)..((k + 1) * per).min(block_rows) {
                    buf.clear();
                    blocks(row, &mut buf);
                    for b in &buf {
                        if b.zmax == f32::NEG_INFINITY || b.zmax.is_nan() {
                            continue;
                        }
                        let dc = (b.centre.0 * b.centre.0 + b.centre.1 * b.centre.1).sqrt();
                        if dc + b.radius <= near_m {
                            continue;
                        }
                        let dmin = (dc - b.radius).max(near_m);
                        let z = b.zmax as f64;
                        let slope = if z >= 0.0 {
                            z / dmin
                        } else {
                            z / (dc + b.radius)
                        };
                        let slope = (slope + slope.abs() * 1e-5 + 1e-9) as f32;
                        let r = ((dmin / ring_m) as usize).min(rings - 1);
                        let row = &mut g[r * sectors..(r + 1) * sectors];
                        if b.radius >= dc * 0.99 {
                            row.iter_mut().for_each(|v| *v = v.max(slope));
                            continue;
                        }
                        let az = b.centre.0.atan2(b.centre.1);
                        let half = (b.radius / dc).asin() * 1.0001 + 1e-9;
                        let s0 = ((az - half) * sectors_per_rad).floor() as i64;
                        let s1 = ((az + half) * sectors_per_rad).floor() as i64;
                        if s1 - s0 + 1 >= sectors as i64 {
                            row.iter_mut().for_each(|v| *v = v.max(slope));
                            continue;
                        }
                        for s in s0..=s1 {
                            let i = s.rem_euclid(sectors as i64) as usize;
                            row[i] = row[i].max(slope);
                        }
                    }
                }
                g
            })
            .collect();
        let mut prefix = vec![f32::NEG_INFINITY; rings * sectors];
        prefix
            .par_chunks_mut(rings)
            .enumerate()
            .for_each(|(s, out)| {
                let mut run = f32::NEG_INFINITY;
                for (r, o) in out.iter_mut().enumerate() {
                    for g in &grids {
                        run = run.max(g[r * sectors + s]);
                    }
                    *o = run;
                }
            });
        HorizonIndex {
            sectors,
            rings,
            ring_m,
            near_m,
            sectors_per_rad,
            prefix,
        }
    }

    /// For a ray with horizontal direction `(de, dn)` (not both zero) and
    /// slope `m = dz / |(de, dn)|`: the horizontal distance beyond `near_m`
    /// before which it cannot touch terrain, or `None` when it touches no
    /// terrain beyond `near_m` at all.
    #[inline]
    pub fn start_distance(&self, de: f64, dn: f64, m: f64) -> Option<f64> {
        let az = de.atan2(dn);
        // az >= -pi, so the shifted value is positive and truncation is floor
        let s = ((az * self.sectors_per_rad + self.sectors as f64) as usize) % self.sectors;
        let p = &self.prefix[s * self.rings..(s + 1) * self.rings];
        let m = m as f32;
        // first ring whose running maximum reaches m
        let r = p.partition_point(|&v| v < m);
        if r >= self.rings {
            return None;
        }
        Some((r as f64 * self.ring_m).max(self.near_m))
    }
}
