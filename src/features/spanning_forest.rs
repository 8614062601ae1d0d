//! The maximum-height spanning forest of the ridge candidates (the step of
//! PPA that replaces polygon breaking, see [`super::ridges`]), computed
//! exactly but strip by strip so that it stays cache-friendly and parallel
//! on DEMs of tens of millions of cells.
//!
//! Segments join 8-adjacent candidate cells (of two crossing diagonals only
//! the higher is kept); a segment's weight is the sum of its two heights and
//! ties are broken by segment id, so the forest is unique and equal to what
//! Kruskal's algorithm over all segments (highest first) gives.
//!
//! 1. The rows are cut into strips. Each strip runs Kruskal on the segments
//!    inside it with a small union-find (in parallel). By the cycle
//!    property, a segment left out of its strip's forest is the lowest of a
//!    cycle and is not in the global forest either.
//! 2. Only segments crossing strip boundaries can close new cycles. Their
//!    end cells are terminals. In each strip forest, branches that hold no
//!    terminal are cut off (they are in no cycle) and the remaining chains
//!    between terminals and branch points are contracted into single edges
//!    carrying their lowest segment.
//! 3. Kruskal on the small contracted graph plus the crossing segments
//!    decides which crossing segments join and which chains lose their
//!    lowest segment.
//!
//! The result is the forest's adjacency mask (bit `d` links a cell to its
//! neighbour `DIRS[d]` of [`super::ridges`]).

use rayon::prelude::*;
use std::collections::HashMap;

/// Rows per strip.
const STRIP: usize = 64;

use super::ridges::DIRS;

/// Order-preserving map of an `f32` to `u32`.
#[inline]
fn f32_key(v: f32) -> u32 {
    let b = v.to_bits();
    if b >> 31 == 1 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Sort key of the segment from cell `a` along mask bit `d` (`d` < 4, the
/// other cell lies to the east or below): higher weight first, then lower
/// id. The id is `a * 4 + d`.
#[inline]
fn key(z: &[f32], a: usize, b: usize, d: usize) -> u64 {
    ((!f32_key(z[a] + z[b])) as u64) << 32 | (a * 4 + d) as u64
}

/// Key of the segment between `c` and its neighbour along any mask bit `d`.
#[inline]
fn key_any(z: &[f32], w: usize, c: usize, d: usize) -> u64 {
    let n = neighbour(c, d, w);
    if d < 4 {
        key(z, c, n, d)
    } else {
        key(z, n, c, d - 4)
    }
}

#[inline]
fn neighbour(c: usize, d: usize, w: usize) -> usize {
    let (dx, dy) = DIRS[d];
    (c as isize + dy * w as isize + dx) as usize
}

/// The segments from candidate cell `c` (row `row`, column `col`) to its
/// east / south-east / south / south-west neighbours, as `(bit, other)`.
#[inline]
fn segments(
    cand: &[bool],
    z: &[f32],
    w: usize,
    h: usize,
    c: usize,
    mut f: impl FnMut(usize, usize),
) {
    let (col, row) = (c % w, c / w);
    if col + 1 < w && cand[c + 1] {
        f(0, c + 1);
    }
    if row + 1 >= h {
        return;
    }
    let s = c + w;
    if cand[s] {
        f(2, s);
    }
    if col + 1 < w && cand[s + 1] {
        let crossing = cand[c + 1] && cand[s];
        if !(crossing && z[c + 1] + z[s] > z[c] + z[s + 1]) {
            f(1, s + 1);
        }
    }
    if col > 0 && cand[s - 1] {
        let crossing = cand[c - 1] && cand[s];
        if !(crossing && z[c - 1] + z[s] >= z[c] + z[s - 1]) {
            f(3, s - 1);
        }
    }
}

fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

/// A contracted chain of a strip forest, or a crossing segment.
#[derive(Clone, Copy)]
struct Link {
    a: u32,
    b: u32,
    /// Key of the lowest segment (the link's weight).
    key: u64,
    /// That segment: cell and mask bit.
    cell: u32,
    bit: u8,
    crossing: bool,
}

/// Maximum spanning forest of the candidate segments; returns the mask.
pub(crate) fn spanning_forest(z: &[f32], cand: &[bool], w: usize, h: usize) -> Vec<u8> {
    let mut mask = vec![0u8; w * h];
    let strips = h.div_ceil(STRIP);
    // 1. Kruskal inside each strip; collect the crossing segments.
    let crossing: Vec<Vec<Link>> = mask
        .par_chunks_mut(STRIP * w)
        .enumerate()
        .map(|(s, mask)| {
            let (r0, r1) = (s * STRIP, ((s + 1) * STRIP).min(h));
            let base = r0 * w;
            let mut keys = Vec::new();
            let mut cross = Vec::new();
            for c in base..r1 * w {
                if !cand[c] {
                    continue;
                }
                segments(cand, z, w, h, c, |d, o| {
                    let k = key(z, c, o, d);
                    if o < r1 * w {
                        keys.push(k);
                    } else {
                        cross.push(Link {
                            a: c as u32,
                            b: o as u32,
                            key: k,
                            cell: c as u32,
                            bit: d as u8,
                            crossing: true,
                        });
                    }
                });
            }
            keys.sort_unstable();
            let mut parent: Vec<u32> = (0..((r1 - r0) * w) as u32).collect();
            for k in keys {
                let id = (k & 0xffff_ffff) as usize;
                let (a, d) = (id / 4, id % 4);
                let b = neighbour(a, d, w);
                let (la, lb) = ((a - base) as u32, (b - base) as u32);
                let (ra, rb) = (find(&mut parent, la), find(&mut parent, lb));
                if ra != rb {
                    parent[ra as usize] = rb;
                    mask[a - base] |= 1 << d;
                    mask[b - base] |= 1 << (d + 4);
                }
            }
            cross
        })
        .collect();
    let crossing: Vec<Link> = crossing.into_iter().flatten().collect();
    if crossing.is_empty() || strips < 2 {
        return mask;
    }
    // 2. Terminals and contracted chains per strip.
    let mut terminal = vec![false; w * h];
    for l in &crossing {
        terminal[l.a as usize] = true;
        terminal[l.b as usize] = true;
    }
    let chains: Vec<Vec<Link>> = mask
        .par_chunks(STRIP * w)
        .enumerate()
        .map(|(s, smask)| {
            let base = s * STRIP * w;
            contract_strip(z, w, base, smask, &terminal[base..base + smask.len()])
        })
        .collect();
    // 3. Kruskal on the contracted graph.
    let mut links: Vec<Link> = chains.into_iter().flatten().collect();
    links.extend_from_slice(&crossing);
    links.sort_unstable_by_key(|l| l.key);
    let mut ids: HashMap<u32, u32> = HashMap::with_capacity(2 * links.len());
    let mut parent: Vec<u32> = Vec::with_capacity(2 * links.len());
    let mut id_of = |c: u32, parent: &mut Vec<u32>| -> u32 {
        *ids.entry(c).or_insert_with(|| {
            parent.push(parent.len() as u32);
            parent.len() as u32 - 1
        })
    };
    for l in links {
        let (a, b) = (id_of(l.a, &mut parent), id_of(l.b, &mut parent));
        let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
        let (c, d) = (l.cell as usize, l.bit as usize);
        let n = neighbour(c, d, w);
        if ra != rb {
            parent[ra as usize] = rb;
            if l.crossing {
                mask[c] |= 1 << d;
                mask[n] |= 1 << ((d + 4) % 8);
            }
        } else if !l.crossing {
            // The chain's lowest segment closes a cycle: break it there.
            mask[c] &= !(1 << d);
            mask[n] &= !(1 << ((d + 4) % 8));
        }
    }
    mask
}

/// The chains between terminals and branch points of one strip's forest
/// (`smask`, cells `base..base + smask.len()`), after cutting branches that
/// hold no terminal.
fn contract_strip(z: &[f32], w: usize, base: usize, smask: &[u8], term: &[bool]) -> Vec<Link> {
    let n = smask.len();
    let mut core = smask.to_vec();
    // Cut non-terminal leaves repeatedly.
    let mut stack: Vec<usize> = (0..n)
        .filter(|&i| core[i].count_ones() == 1 && !term[i])
        .collect();
    while let Some(i) = stack.pop() {
        if core[i].count_ones() != 1 || term[i] {
            continue;
        }
        let d = core[i].trailing_zeros() as usize;
        let j = neighbour(base + i, d, w) - base;
        core[i] = 0;
        core[j] &= !(1 << ((d + 4) % 8));
        if core[j].count_ones() == 1 && !term[j] {
            stack.push(j);
        }
    }
    let is_key = |i: usize| term[i] || core[i].count_ones() != 2;
    let mut out = Vec::new();
    let mut done = vec![0u8; n];
    for i in 0..n {
        if core[i] == 0 || !is_key(i) {
            continue;
        }
        for d0 in 0..8 {
            if core[i] & (1 << d0) == 0 || done[i] & (1 << d0) != 0 {
                continue;
            }
            done[i] |= 1 << d0;
            let (mut c, mut d) = (i, d0);
            // The lowest segment has the largest key.
            let mut low: Option<(u64, usize, usize)> = None;
            let end = loop {
                let g = base + c;
                let k = key_any(z, w, g, d);
                if low.is_none_or(|l| k > l.0) {
                    low = Some((k, g, d));
                }
                let nb = neighbour(g, d, w) - base;
                let back = (d + 4) % 8;
                if is_key(nb) {
                    done[nb] |= 1 << back;
                    break nb;
                }
                let rest = core[nb] & !(1 << back);
                c = nb;
                d = rest.trailing_zeros() as usize;
            };
            let Some((k, cell, bit)) = low else { continue };
            let (cell, bit) = if bit < 4 {
                (cell, bit)
            } else {
                (neighbour(cell, bit, w), bit - 4)
            };
            out.push(Link {
                a: (base + i) as u32,
                b: (base + end) as u32,
                key: k,
                cell: cell as u32,
                bit: bit as u8,
                crossing: false,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Kruskal over all segments at once: the reference.
    fn global_kruskal(z: &[f32], cand: &[bool], w: usize, h: usize) -> Vec<u8> {
        let mut keys = Vec::new();
        for c in 0..w * h {
            if cand[c] {
                segments(cand, z, w, h, c, |d, o| keys.push(key(z, c, o, d)));
            }
        }
        keys.sort_unstable();
        let mut parent: Vec<u32> = (0..(w * h) as u32).collect();
        let mut mask = vec![0u8; w * h];
        for k in keys {
            let id = (k & 0xffff_ffff) as usize;
            let (a, d) = (id / 4, id % 4);
            let b = neighbour(a, d, w);
            let (ra, rb) = (find(&mut parent, a as u32), find(&mut parent, b as u32));
            if ra != rb {
                parent[ra as usize] = rb;
                mask[a] |= 1 << d;
                mask[b] |= 1 << (d + 4);
            }
        }
        mask
    }

    #[test]
    fn strips_give_the_global_forest() {
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for (w, h, density) in [
            (37, 200, 0.5),
            (100, 300, 0.7),
            (64, 129, 0.9),
            (5, 400, 0.6),
        ] {
            let z: Vec<f32> = (0..w * h).map(|_| (rnd() * 50.0).round() as f32).collect();
            let cand: Vec<bool> = (0..w * h).map(|_| rnd() < density).collect();
            let a = spanning_forest(&z, &cand, w, h);
            let b = global_kruskal(&z, &cand, w, h);
            assert!(a == b, "{w} x {h} at {density}: forests differ");
        }
    }
}
