//! The candidate cells of ridge detection (the cells that profile recognition
//! marks, see [`super::ridges`]) as a bitmap over the DEM's row-major cell
//! indices with a rank table, so that the `k`-th candidate in row-major order
//! has the compact id `k`. The spanning forest, pruning and tracing keep their
//! per-candidate state in arrays of the candidate count (a tenth of the cells
//! or less) instead of the cell count, find a neighbour's id with one rank
//! lookup, and read a candidate's cell and height from compact arrays.

use rayon::prelude::*;

/// Rows per band of the parallel passes over the candidates (64 rows of
/// cells are whole bitmap words).
pub(super) const BAND: usize = 64;

/// Candidate cells of a `w` x `h` grid.
pub(super) struct CandidateSet {
    /// Bit `c % 64` of word `c / 64` is set when cell `c` is a candidate.
    bits: Vec<u64>,
    /// Number of candidates in the words before each word (one extra entry:
    /// the total).
    rank: Vec<u32>,
    /// Cell index of each candidate id.
    pub(super) cells: Vec<u32>,
    /// Height of each candidate id.
    pub(super) heights: Vec<f32>,
}

/// `s` cut into the consecutive pieces `bounds[i]..bounds[i + 1]`.
pub(super) fn split_at_bounds<'a, T>(mut s: &'a mut [T], bounds: &[u32]) -> Vec<&'a mut [T]> {
    let mut parts = Vec::with_capacity(bounds.len().saturating_sub(1));
    for b in bounds.windows(2) {
        let (part, rest) = std::mem::take(&mut s).split_at_mut((b[1] - b[0]) as usize);
        parts.push(part);
        s = rest;
    }
    parts
}

impl CandidateSet {
    /// The set of the cells whose bits are set in `bits` (bits past the last
    /// cell must be clear), with the cells and heights of the candidates in
    /// order, in consecutive parts.
    pub(super) fn from_parts(bits: Vec<u64>, parts: Vec<(Vec<u32>, Vec<f32>)>) -> Self {
        let rank = Self::rank(&bits);
        let mut bounds = vec![0u32];
        for (cells, _) in &parts {
            bounds.push(bounds[bounds.len() - 1] + cells.len() as u32);
        }
        debug_assert_eq!(rank.last(), bounds.last());
        let n = bounds[bounds.len() - 1] as usize;
        let mut cells = vec![0u32; n];
        let mut heights = vec![0f32; n];
        split_at_bounds(&mut cells, &bounds)
            .into_par_iter()
            .zip(split_at_bounds(&mut heights, &bounds))
            .zip(parts)
            .for_each(|((cells, heights), part)| {
                cells.copy_from_slice(&part.0);
                heights.copy_from_slice(&part.1);
            });
        CandidateSet {
            bits,
            rank,
            cells,
            heights,
        }
    }

    /// Number of set bits before each word, and the total.
    fn rank(bits: &[u64]) -> Vec<u32> {
        let mut rank = Vec::with_capacity(bits.len() + 1);
        let mut n = 0u32;
        for &word in bits {
            rank.push(n);
            n += word.count_ones();
        }
        rank.push(n);
        rank
    }

    /// The set of the cells of a `w` x `h` grid of heights `z` whose bits are
    /// set in `bits` (`(w * h).div_ceil(64)` words; bits past the last cell
    /// must be clear).
    #[cfg(test)]
    pub(super) fn from_bits(bits: Vec<u64>, z: &[f32], w: usize, h: usize) -> Self {
        let mut rank = Vec::with_capacity(bits.len() + 1);
        let mut n = 0u32;
        for &word in &bits {
            rank.push(n);
            n += word.count_ones();
        }
        rank.push(n);
        let mut set = CandidateSet {
            bits,
            rank,
            cells: Vec::new(),
            heights: Vec::new(),
        };
        let bands = h.div_ceil(BAND);
        let bounds = set.band_bounds(w, h);
        let mut cells = vec![0u32; n as usize];
        let mut heights = vec![0f32; n as usize];
        split_at_bounds(&mut cells, &bounds)
            .into_par_iter()
            .zip(split_at_bounds(&mut heights, &bounds))
            .zip(0..bands)
            .for_each(|((cells, heights), b)| {
                let mut k = 0;
                set.for_each(b * BAND * w, ((b + 1) * BAND).min(h) * w, |c, _| {
                    cells[k] = c as u32;
                    heights[k] = z[c];
                    k += 1;
                });
            });
        set.cells = cells;
        set.heights = heights;
        set
    }

    /// First candidate id of each band of `BAND` rows, and the count.
    #[cfg(test)]
    fn band_bounds(&self, w: usize, h: usize) -> Vec<u32> {
        (0..=h.div_ceil(BAND))
            .map(|b| self.before((b * BAND).min(h) * w))
            .collect()
    }

    /// Number of candidates.
    pub(super) fn len(&self) -> usize {
        self.rank.last().copied().unwrap_or(0) as usize
    }

    /// Whether cell `cell` (inside the grid) is a candidate.
    #[inline]
    #[cfg(test)]
    pub(super) fn contains(&self, cell: usize) -> bool {
        (self.bits[cell >> 6] >> (cell & 63)) & 1 != 0
    }

    /// Compact id of the candidate cell `cell`: the number of candidates
    /// before it. `cell` must lie inside the grid.
    #[inline]
    pub(super) fn id(&self, cell: usize) -> u32 {
        let (word, bit) = (cell >> 6, cell & 63);
        self.rank[word] + (self.bits[word] & ((1u64 << bit) - 1)).count_ones()
    }

    /// Candidate flags of the cells `cell`, `cell + 1` and `cell + 2` as bits
    /// 0 to 2 (cells past the grid are no candidates). `cell` must lie
    /// inside the grid.
    #[inline]
    pub(super) fn three_from(&self, cell: usize) -> u32 {
        let (word, bit) = (cell >> 6, cell & 63);
        let low = self.bits[word] >> bit;
        let high = match self.bits.get(word + 1) {
            Some(&next) if bit > 61 => next << (64 - bit),
            _ => 0,
        };
        ((low | high) & 7) as u32
    }

    /// Number of candidates among the cells before `cell` (`cell` may be the
    /// cell count).
    pub(super) fn before(&self, cell: usize) -> u32 {
        let (word, bit) = (cell >> 6, cell & 63);
        if bit == 0 {
            self.rank[word]
        } else {
            self.id(cell)
        }
    }

    /// Calls `f(cell, id)` for the candidates among cells `c0..c1`, in order.
    #[inline]
    #[cfg(test)]
    pub(super) fn for_each(&self, c0: usize, c1: usize, mut f: impl FnMut(usize, u32)) {
        if c0 >= c1 {
            return;
        }
        let mut id = self.before(c0);
        let (w0, w1) = (c0 >> 6, (c1 - 1) >> 6);
        for wi in w0..=w1 {
            let mut word = self.bits[wi];
            if wi == w0 {
                word &= !0u64 << (c0 & 63);
            }
            let end = c1 - (wi << 6);
            if end < 64 {
                word &= (1u64 << end) - 1;
            }
            while word != 0 {
                f((wi << 6) + word.trailing_zeros() as usize, id);
                id += 1;
                word &= word - 1;
            }
        }
    }

    /// The set of the cells of a `w` x `h` grid of heights `z` where `flags`
    /// is true.
    #[cfg(test)]
    pub(super) fn from_flags(flags: &[bool], z: &[f32], w: usize, h: usize) -> Self {
        let mut bits = vec![0u64; flags.len().div_ceil(64)];
        for (c, _) in flags.iter().enumerate().filter(|(_, &f)| f) {
            bits[c >> 6] |= 1 << (c & 63);
        }
        Self::from_bits(bits, z, w, h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_count_the_candidates_before() {
        let flags: Vec<bool> = (0..300).map(|c| c % 3 == 0 || c % 7 == 2).collect();
        let z: Vec<f32> = (0..300).map(|c| c as f32 * 0.5).collect();
        let set = CandidateSet::from_flags(&flags, &z, 20, 15);
        let mut n = 0u32;
        for (c, &f) in flags.iter().enumerate() {
            assert_eq!(set.contains(c), f);
            assert_eq!(set.before(c), n);
            if f {
                assert_eq!(set.id(c), n);
                assert_eq!(set.cells[n as usize] as usize, c);
                assert_eq!(set.heights[n as usize], z[c]);
                n += 1;
            }
        }
        assert_eq!(set.before(300), n);
        assert_eq!(set.len(), n as usize);
        for (c0, c1) in [
            (0, 300),
            (5, 64),
            (64, 128),
            (63, 65),
            (100, 100),
            (129, 257),
        ] {
            let mut got = Vec::new();
            set.for_each(c0, c1, |c, id| got.push((c, id)));
            let want: Vec<(usize, u32)> = (c0..c1)
                .filter(|&c| flags[c])
                .map(|c| (c, set.before(c)))
                .collect();
            assert_eq!(got, want, "cells {c0}..{c1}");
        }
    }
}
