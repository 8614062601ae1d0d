//! The noise of a stroke (Gain et al. 2009, section 4, "Noise
//! Propagation"): the stroke's height profile is decomposed by an à-trous
//! (undecimated) binomial pyramid into detail bands `D_i = I_i - I_{i+1}`
//! ([`spectrum`]), whose deviations are fitted by an exponential decay as
//! the paper fits the sketched variances; a [`NoiseField`] turns the bands
//! a DEM's cells can carry into layers of smooth value noise of the same
//! scale and deviation, a function of the DEM's global cell indices (so a
//! tile set gets the single file's noise). Used by the landforms and
//! noise regions of [`super::landform`].

use crate::deform::CellSize;

use super::grid::Grid;

/// Binomial smoothing `[1, 4, 6, 4, 1] / 16` with taps `step` apart (one
/// level of the à-trous pyramid). Beyond the ends the profile is extended
/// by point reflection through the end value (`v(-i) = 2 v(0) - v(i)`),
/// which keeps straight ramps straight: a silhouette rising from the
/// ground keeps its end heights at every level instead of being lifted
/// (the paper's "ends require special attention").
pub fn smooth(v: &[f64], step: usize) -> Vec<f64> {
    let n = v.len() as i64;
    let at = |i: i64| -> f64 {
        if n == 1 {
            return v[0];
        }
        if i < 0 {
            let j = (-i).min(n - 1);
            2.0 * v[0] - v[j as usize]
        } else if i >= n {
            let j = (2 * (n - 1) - i).max(0);
            2.0 * v[(n - 1) as usize] - v[j as usize]
        } else {
            v[i as usize]
        }
    };
    let s = step as i64;
    (0..n)
        .map(|i| {
            (at(i - 2 * s) + 4.0 * at(i - s) + 6.0 * at(i) + 4.0 * at(i + s) + at(i + 2 * s)) / 16.0
        })
        .collect()
}

/// One detail band of a profile's decomposition.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Band {
    /// Scale of the band (twice the taps' spacing), metres.
    pub scale_m: f64,
    /// Standard deviation of the band's detail `D_i`, metres.
    pub sigma_m: f64,
    /// The exponential-decay fit of the deviations at this band, metres.
    pub fitted_sigma_m: f64,
}

/// The noise spectrum of a stroke: its detail bands and how much of its
/// variance they hold.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Spectrum {
    /// Finest first.
    pub bands: Vec<Band>,
    /// Energy of the detail bands over the energy (variance) of the
    /// smoothest level: the wavelet energy ratio.
    pub detail_energy_ratio: f64,
}

/// The noise bands of a stroke reach scales up to its map-view length
/// over this: coarser detail is the landform's shape, which the
/// deformation gives (eqn 3); as noise it would come back as random lumps.
pub const NOISE_SCALE_DIVISOR: f64 = 16.0;

/// The spectrum of the height profile of `curve` (DEM CRS, absolute
/// heights) resampled every `ds` metres along its map-view arc length.
pub fn spectrum(curve: &[[f64; 3]], ds: f64, crs_to_m: [f64; 2]) -> Spectrum {
    let mut s = vec![0.0];
    for w in curve.windows(2) {
        let d = ((w[1][0] - w[0][0]) * crs_to_m[0]).hypot((w[1][1] - w[0][1]) * crs_to_m[1]);
        s.push(s.last().copied().unwrap_or(0.0) + d);
    }
    let len = s.last().copied().unwrap_or(0.0);
    let n = (len / ds).floor() as usize + 1;
    let mut prof = Vec::with_capacity(n);
    let mut j = 0;
    for k in 0..n {
        let t = k as f64 * ds;
        while j + 2 < s.len() && s[j + 1] < t {
            j += 1;
        }
        let (a, b) = (s[j], s.get(j + 1).copied().unwrap_or(s[j]));
        let f = if b > a {
            ((t - a) / (b - a)).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let z1 = curve.get(j + 1).map_or(curve[j][2], |p| p[2]);
        prof.push(curve[j][2] + f * (z1 - curve[j][2]));
    }
    let mut bands = Vec::new();
    let mut level = prof.clone();
    let mut step = 1usize;
    let mut detail_energy = 0.0;
    while prof.len() >= 8 && (2 * step) as f64 * ds <= len / NOISE_SCALE_DIVISOR {
        let next = smooth(&level, step);
        let var = level
            .iter()
            .zip(&next)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            / level.len() as f64;
        detail_energy += var;
        bands.push(Band {
            scale_m: 2.0 * step as f64 * ds,
            sigma_m: var.sqrt(),
            fitted_sigma_m: var.sqrt(),
        });
        level = next;
        step *= 2;
    }
    let mean = level.iter().sum::<f64>() / level.len().max(1) as f64;
    let smooth_energy =
        level.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / level.len().max(1) as f64;
    fit_decay(&mut bands);
    Spectrum {
        bands,
        detail_energy_ratio: if smooth_energy > 0.0 {
            detail_energy / smooth_energy
        } else {
            0.0
        },
    }
}

/// Least-squares fit of `ln sigma = a + b i` over the bands with a
/// deviation (the paper's exponential decay of the sketched variances).
fn fit_decay(bands: &mut [Band]) {
    let pts: Vec<(f64, f64)> = bands
        .iter()
        .enumerate()
        .filter(|(_, b)| b.sigma_m > 1e-9)
        .map(|(i, b)| (i as f64, b.sigma_m.ln()))
        .collect();
    if pts.len() < 2 {
        return;
    }
    let n = pts.len() as f64;
    let (sx, sy) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
    let (mx, my) = (sx / n, sy / n);
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let b = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let a = my - b * mx;
    for (i, band) in bands.iter_mut().enumerate() {
        band.fitted_sigma_m = (a + b * i as f64).exp();
    }
}

/// SplitMix64's finaliser.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The value of a lattice node, in `[-1, 1]`: the seed, band and node
/// indices mixed in turn (SplitMix64), so no direction of the lattice is
/// correlated.
fn node_value(i: i64, j: i64, band: u64, seed: u64) -> f64 {
    let z = mix(mix(mix(seed ^ band) ^ i as u64) ^ j as u64);
    (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Standard deviation of one value-noise layer (uniform node values,
/// quintic fade), averaged over the lattice square: the layers are
/// divided by it to unit deviation.
fn value_noise_sd() -> f64 {
    let n = 1000;
    let mut s = 0.0;
    for k in 0..n {
        let f = fade((k as f64 + 0.5) / n as f64);
        s += (1.0 - f) * (1.0 - f) + f * f;
    }
    let e = s / n as f64;
    (e * e / 3.0).sqrt()
}

/// Smooth value noise of lattice spacing `spacing_m` at `(x, y)` metres
/// (global: the DEM's cell indices times the cell size), unit deviation.
fn value_noise(x: f64, y: f64, spacing_m: f64, band: u64, seed: u64, sd: f64) -> f64 {
    let (u, v) = (x / spacing_m, y / spacing_m);
    let (i, j) = (u.floor(), v.floor());
    let (fx, fy) = (fade(u - i), fade(v - j));
    let (i, j) = (i as i64, j as i64);
    let n00 = node_value(i, j, band, seed);
    let n10 = node_value(i + 1, j, band, seed);
    let n01 = node_value(i, j + 1, band, seed);
    let n11 = node_value(i + 1, j + 1, band, seed);
    let a = n00 + fx * (n10 - n00);
    let b = n01 + fx * (n11 - n01);
    (a + fy * (b - a)) / sd
}

/// The noise of `spec` at window cell `(c, r)` of `grid`: the sum over
/// the bands the cells can carry (scale at least two cells) of the
/// fitted deviation times a unit value-noise layer, times `gain`.
pub struct NoiseField {
    layers: Vec<(f64, f64)>,
    seed: u64,
    sd: f64,
}

impl NoiseField {
    pub fn new(spec: &Spectrum, cell: CellSize, gain: f64, seed: u64) -> NoiseField {
        let min_scale = 2.0 * cell.hx.max(cell.hy);
        NoiseField {
            layers: spec
                .bands
                .iter()
                .filter(|b| b.scale_m >= min_scale)
                .map(|b| (b.scale_m, b.fitted_sigma_m * gain))
                .collect(),
            seed,
            sd: value_noise_sd(),
        }
    }

    /// Deviation of the field, metres.
    pub fn sigma(&self) -> f64 {
        self.layers.iter().map(|l| l.1 * l.1).sum::<f64>().sqrt()
    }

    /// Largest scale it carries, metres.
    pub fn coarsest_m(&self) -> f64 {
        self.layers.iter().map(|l| l.0).fold(0.0, f64::max)
    }

    /// At window cell `(c, r)` of `grid`.
    pub fn at(&self, grid: &Grid, c: usize, r: usize) -> f64 {
        let x = (grid.window.col as f64 + c as f64 + 0.5) * grid.cell.hx;
        let y = (grid.window.row as f64 + r as f64 + 0.5) * grid.cell.hy;
        self.layers
            .iter()
            .enumerate()
            .map(|(k, &(s, a))| a * value_noise(x, y, s, k as u64, self.seed, self.sd))
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize, f: impl Fn(f64) -> f64) -> Vec<[f64; 3]> {
        (0..n)
            .map(|k| {
                let x = k as f64;
                [x, 0.0, f(x)]
            })
            .collect()
    }
    #[test]
    fn a_jagged_profile_has_more_detail_energy_than_a_smooth_one() {
        let smooth = line(401, |x| 100.0 * (std::f64::consts::PI * x / 400.0).sin());
        let jagged = line(401, |x| {
            100.0 * (std::f64::consts::PI * x / 400.0).sin()
                + if (x as usize / 4) % 2 == 0 { 3.0 } else { -3.0 }
        });
        let (a, b) = (
            spectrum(&smooth, 1.0, [1.0, 1.0]),
            spectrum(&jagged, 1.0, [1.0, 1.0]),
        );
        assert!(!a.bands.is_empty());
        assert!(
            b.detail_energy_ratio > 20.0 * a.detail_energy_ratio,
            "jagged {} smooth {}",
            b.detail_energy_ratio,
            a.detail_energy_ratio
        );
        let fine = |s: &Spectrum| s.bands[..3].iter().map(|b| b.sigma_m).sum::<f64>();
        assert!(fine(&b) > 10.0 * fine(&a));
    }

    #[test]
    fn a_flat_profile_has_no_detail() {
        let s = spectrum(&line(200, |_| 5.0), 1.0, [1.0, 1.0]);
        assert!(s.bands.iter().all(|b| b.sigma_m < 1e-9));
        assert_eq!(s.detail_energy_ratio, 0.0);
    }

    #[test]
    fn value_noise_has_about_unit_deviation_and_is_a_function_of_position() {
        let sd = value_noise_sd();
        let mut s2 = 0.0;
        let n = 200;
        for i in 0..n {
            for j in 0..n {
                let v = value_noise(i as f64 * 3.7, j as f64 * 2.9, 10.0, 0, 7, sd);
                s2 += v * v;
            }
        }
        let rms = (s2 / (n * n) as f64).sqrt();
        assert!((rms - 1.0).abs() < 0.1, "rms {rms}");
        assert_eq!(
            value_noise(123.0, 45.0, 10.0, 1, 7, sd),
            value_noise(123.0, 45.0, 10.0, 1, 7, sd)
        );
    }
}
