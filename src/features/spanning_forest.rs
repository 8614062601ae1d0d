//! The maximum-height spanning forest of the ridge candidates (the step of
//! PPA that replaces polygon breaking, see [`super::ridges`]), computed
//! exactly but strip by strip so that it stays cache-friendly and parallel
//! on DEMs of tens of millions of cells.
//!
//! Segments join 8-adjacent candidate cells (of two crossing diagonals only
//! the higher is kept); a segment's weight is the sum of its two heights and
//! ties are broken by segment id (the id of its first candidate in row-major
//! order times 4 plus its direction), so the forest is unique and equal to
//! what Kruskal's algorithm over all segments (highest first) gives.
//!
//! 1. The rows are cut into strips of 64 rows. Each strip computes the
//!    forest of the segments inside it (in parallel): one Borůvka step (the
//!    best segment of every candidate is in the forest) joins the candidates
//!    into trees, then Kruskal runs on the segments between trees only,
//!    sorted by weight with a stable radix sort (the segments are generated
//!    in id order), with a union-find over the strip's candidates. By the
//!    cycle property, a segment left out of its strip's forest is the lowest
//!    of a cycle and is not in the global forest either.
//! 2. Only segments crossing strip boundaries can close new cycles. Their
//!    end cells are terminals. In each strip forest, branches that hold no
//!    terminal are cut off (they are in no cycle) and the remaining chains
//!    between terminals and branch points are contracted into single edges
//!    carrying their lowest segment.
//! 3. Kruskal on the small contracted graph plus the crossing segments
//!    decides which crossing segments join and which chains lose their
//!    lowest segment.
//!
//! The result is the forest's adjacency mask per candidate id (bit `d` links
//! a candidate to its neighbour `DIRS[d]` of [`super::ridges`]).

use rayon::prelude::*;

use super::candidates::{split_at_bounds, CandidateSet};
use super::ridges::{degree, DIRS};

/// Rows per strip (a multiple of 64 cells per strip keeps strips on whole
/// bitmap words).
const STRIP: usize = 64;

/// Order-preserving map of an `f32` to `u32`.
#[inline]
fn f32_key(v: f32) -> u32 {
    let b = v.to_bits();
    // Negative: all bits flipped; otherwise the sign bit set (no branch).
    let flip = ((b as i32) >> 31) as u32 | 0x8000_0000;
    b ^ flip
}

/// Weight part of a segment's sort key: ascending keys are descending
/// height sums.
#[inline]
fn weight_key(z: &[f32], a: usize, b: usize) -> u32 {
    !f32_key(z[a] + z[b])
}

/// Full sort key of the segment from candidate `id_a` along bit `d` (< 4):
/// higher weight first, then lower segment id.
#[inline]
fn segment_key(weight: u32, id_a: u32, d: usize) -> u64 {
    (weight as u64) << 32 | (id_a as u64 * 4 + d as u64)
}

/// Cell offsets of the eight mask directions.
fn offsets(w: usize) -> [isize; 8] {
    std::array::from_fn(|d| DIRS[d].1 * w as isize + DIRS[d].0)
}

/// Root of `x`, halving the path on the way.
#[inline]
fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[parent[x as usize] as usize];
        parent[x as usize] = p;
        x = p;
    }
    x
}

/// Joins the trees of roots `ra` and `rb` (union by rank).
#[inline]
fn union(parent: &mut [u32], rank: &mut [u8], ra: u32, rb: u32) {
    let (ka, kb) = (rank[ra as usize], rank[rb as usize]);
    if ka < kb {
        parent[ra as usize] = rb;
    } else {
        parent[rb as usize] = ra;
        if ka == kb {
            rank[ra as usize] += 1;
        }
    }
}

/// End of a row's list of candidate cells.
const SENTINEL: u32 = u32::MAX;

/// The candidates of a row and of the row below it.
struct RowPair<'a> {
    /// Cells of the row's candidates followed by [`SENTINEL`], and the id of
    /// the first.
    cur: &'a [u32],
    cur_id0: u32,
    /// The same for the row below (only the sentinel below the last row).
    next: &'a [u32],
    next_id0: u32,
}

/// `cells` followed by [`SENTINEL`], into `out`.
fn with_sentinel(cells: &[u32], out: &mut Vec<u32>) {
    out.clear();
    out.extend_from_slice(cells);
    out.push(SENTINEL);
}

/// The segments from the candidates of a row to their east / south-east /
/// south / south-west neighbours, as `f(bit, (id a, id b))`,
/// in segment-id order. Of two crossing diagonals only the higher is kept
/// (ties to the south-west one). `z` holds the heights by candidate id.
#[inline]
fn row_segments(z: &[f32], w: usize, rows: &RowPair, mut f: impl FnMut(usize, (u32, u32))) {
    let (cur, next) = (rows.cur, rows.next);
    let mut j = 0usize;
    for i in 0..cur.len() - 1 {
        // Cells of other rows never match: the lists hold one row each.
        let a = cur[i];
        let ida = rows.cur_id0 + i as u32;
        let east = cur[i + 1] == a + 1;
        let west = i > 0 && cur[i - 1] + 1 == a;
        let s = a as usize + w;
        if east {
            f(0, (ida, ida + 1));
        }
        // Candidates below at s - 1, s, s + 1 (the sentinel ends the scans).
        while (next[j] as usize) + 1 < s {
            j += 1;
        }
        let south_west = next[j] as usize + 1 == s;
        let k = j + south_west as usize;
        let south = next[k] as usize == s;
        let k_east = k + south as usize;
        let south_east = next[k_east] as usize == s + 1;
        let id = |k: usize| rows.next_id0 + k as u32;
        // Heights of the candidates by id: a, east, west, south, south-east
        // and south-west (read only when they are candidates).
        let za = |o: isize| z[(ida as isize + o) as usize];
        let zb = |k: usize| z[id(k) as usize];
        if south_east && !(east && south && za(1) + zb(k) > za(0) + zb(k_east)) {
            f(1, (ida, id(k_east)));
        }
        if south {
            f(2, (ida, id(k)));
        }
        if south_west && !(west && south && za(-1) + zb(k) >= za(0) + zb(j)) {
            f(3, (ida, id(j)));
        }
    }
}

/// The segment lists of a strip under construction: sort items (weight key
/// above, index into `segs` below), segments as `[a << 2 | bit, b]` by
/// strip-local ids, and the best (first in Kruskal order) item of each
/// candidate (and one spare entry after them).
struct StripLists<'a> {
    items: &'a mut Vec<u64>,
    segs: &'a mut Vec<[u32; 2]>,
    best: &'a mut [u64],
    /// Id of the strip's first candidate.
    id0: u32,
}

/// [`row_segments`] for a row whose next row lies in the same strip,
/// appending the segments to `lists`: the same segments in the same order,
/// but found with the candidate bitmap and written without branches on the
/// data (whether a segment exists is a coin toss that a branch predictor
/// loses).
#[inline(never)]
fn inside_row_segments(
    cand: &CandidateSet,
    w: usize,
    row: usize,
    rows: &RowPair,
    lists: StripLists,
) {
    let StripLists {
        items,
        segs,
        best,
        id0,
    } = lists;
    let z = &cand.heights[..];
    // (no candidate at all: no row has any, and `zi` is never called)
    let last = z.len().saturating_sub(1);
    let zi = |id: u32| z[(id as usize).min(last)];
    let cur = rows.cur;
    let n = cur.len() - 1;
    let start = items.len();
    // Every candidate writes its four possible segments after the kept
    // ones, into the spare capacity (not cleared first).
    items.reserve(4 * n);
    segs.reserve(4 * n);
    let new_items = &mut items.spare_capacity_mut()[..4 * n];
    let new_segs = &mut segs.spare_capacity_mut()[..4 * n];
    let (row_start, row_end) = (row * w, (row + 1) * w);
    let mut len = 0;
    let spare = (best.len() - 1) as u32;
    for i in 0..n {
        let a = cur[i] as usize;
        let ida = rows.cur_id0 + i as u32;
        let la = ida - id0;
        let east = cur[i + 1] as usize == a + 1;
        let west = i > 0 && cur[i - 1] as usize + 1 == a;
        // Candidates below at s - 1, s and s + 1 (bits 0 to 2 of `below`),
        // and the id of the first candidate at or after s - 1.
        let s = a + w;
        let (has_west, has_east) = (a > row_start, a + 1 < row_end);
        let x = s - has_west as usize;
        let below = cand.three_from(x) << (!has_west) as u32;
        let first = cand.id(x);
        let south_west = below & 1 != 0;
        let south = below & 2 != 0;
        let south_east = has_east && below & 4 != 0;
        let (id_sw, id_s) = (first, first + south_west as u32);
        let id_se = id_s + south as u32;
        let za = z[ida as usize];
        // The best item of `a` stays in a register (no chain of stores and
        // loads through memory).
        let mut best_a = best[la as usize];
        let (z_e, z_w) = (zi(ida + 1), z[(ida as usize).saturating_sub(1)]);
        let (z_s, z_se, z_sw) = (zi(id_s), zi(id_se), zi(id_sw));
        // Of two crossing diagonals only the higher is kept (ties to the
        // south-west one), as in `row_segments`.
        let keep_se = south_east & !(east & south & (z_e + z_s > za + z_se));
        let keep_sw = south_west & !(west & south & (z_w + z_s >= za + z_sw));
        for (keep, bit, idb, zb) in [
            (east, 0u32, ida + 1, z_e),
            (keep_se, 1, id_se, z_se),
            (south, 2, id_s, z_s),
            (keep_sw, 3, id_sw, z_sw),
        ] {
            let weight = !f32_key(za + zb);
            // A missing segment leaves `best` as it is; its `b` is clamped
            // into `best` (the spare last entry at most), never `a`.
            let lb = idb.wrapping_sub(id0).min(spare);
            let item = (weight as u64) << 32 | (start + len) as u64;
            new_items[len].write(item);
            new_segs[len].write([la << 2 | bit, lb]);
            let candidate = if keep { item } else { u64::MAX };
            best_a = best_a.min(candidate);
            best[lb as usize] = best[lb as usize].min(candidate);
            len += keep as usize;
        }
        best[la as usize] = best_a;
    }
    // SAFETY: the first `len` spare entries of both were written above.
    unsafe {
        items.set_len(start + len);
        segs.set_len(start + len);
    }
}

/// Stable LSD radix sort of `items` by their upper 32 bits (11-bit digits;
/// digits equal in all items are skipped).
fn sort_by_high_word(items: &mut Vec<u64>, tmp: &mut Vec<u64>) {
    const DIGITS: [(u32, usize); 3] = [(32, 11), (43, 11), (54, 10)];
    let mut hist = [[0u32; 1 << 11]; 3];
    for &x in items.iter() {
        for (h, &(shift, bits)) in hist.iter_mut().zip(&DIGITS) {
            h[(x >> shift) as usize & ((1 << bits) - 1)] += 1;
        }
    }
    tmp.resize(items.len(), 0);
    for (h, &(shift, bits)) in hist.iter_mut().zip(&DIGITS) {
        if h.iter().any(|&c| c as usize == items.len()) {
            continue;
        }
        let mut sum = 0u32;
        for c in h.iter_mut() {
            let n = *c;
            *c = sum;
            sum += n;
        }
        for &x in items.iter() {
            let slot = &mut h[(x >> shift) as usize & ((1 << bits) - 1)];
            tmp[*slot as usize] = x;
            *slot += 1;
        }
        std::mem::swap(items, tmp);
    }
}

/// A segment by the ids of its two candidates; `bit` (< 4) leads from `a`
/// to `b`.
#[derive(Clone, Copy)]
struct Segment {
    a: u32,
    b: u32,
    bit: u8,
    key: u64,
}

/// A contracted chain of a strip forest (its lowest segment) or a crossing
/// segment, between two vertices of the contracted graph.
#[derive(Clone, Copy)]
struct Link {
    ends: [u32; 2],
    seg: Segment,
    crossing: bool,
}

/// One strip after contraction.
#[derive(Default)]
struct Contracted {
    /// Chains between the strip's key vertices (local vertex numbers).
    chains: Vec<Link>,
    /// Number of key vertices.
    vertices: u32,
    /// Vertex numbers of the `a` ends of the strip's own crossing segments.
    down: Vec<u32>,
    /// Vertex numbers of the `b` ends of the previous strip's crossing segments.
    up: Vec<u32>,
}

/// Candidate ids of the `b` ends of the segments from row `row` to the row
/// below, in the order in which [`strip_forest`] lists them as crossing.
fn crossing_ends(cand: &CandidateSet, w: usize, row: usize) -> Vec<u32> {
    let ids = |r: usize| cand.before(r * w)..cand.before((r + 1) * w);
    let (cur, next) = (ids(row), ids(row + 1));
    let (mut cur_cells, mut next_cells) = (Vec::new(), Vec::new());
    with_sentinel(
        &cand.cells[cur.start as usize..cur.end as usize],
        &mut cur_cells,
    );
    with_sentinel(
        &cand.cells[next.start as usize..next.end as usize],
        &mut next_cells,
    );
    let rows = RowPair {
        cur: &cur_cells,
        cur_id0: cur.start,
        next: &next_cells,
        next_id0: next.start,
    };
    let mut ends = Vec::new();
    row_segments(&cand.heights, w, &rows, |d, (_, idb)| {
        if d != 0 {
            ends.push(idb);
        }
    });
    ends
}

/// Working memory of one rayon job, reused from strip to strip.
#[derive(Default)]
struct Scratch {
    items: Vec<u64>,
    sorted: Vec<u64>,
    segs: Vec<[u32; 2]>,
    parent: Vec<u32>,
    rank: Vec<u8>,
    best: Vec<u64>,
    row_cur: Vec<u32>,
    row_next: Vec<u32>,
    core: Vec<u8>,
    flags: Vec<u8>,
    number: Vec<u32>,
    stack: Vec<u32>,
}

/// Maximum spanning forest of the candidate segments: the adjacency mask of
/// each candidate id.
#[inline(never)]
pub(super) fn spanning_forest(cand: &CandidateSet, w: usize, h: usize) -> Vec<u8> {
    let mut mask = vec![0u8; cand.len()];
    let strips = h.div_ceil(STRIP);
    let first_id: Vec<u32> = (0..=strips)
        .map(|s| cand.before((s * STRIP).min(h) * w))
        .collect();
    // 1. Forest of each strip, contracted to its terminals and branch
    // points; the crossing segments to the next strip.
    let several = strips > 1;
    let t0 = std::time::Instant::now();
    let (crossing, contracted): (Vec<Vec<Segment>>, Vec<Contracted>) =
        split_at_bounds(&mut mask, &first_id)
            .into_par_iter()
            .enumerate()
            .map_init(Scratch::default, |scratch, (s, smask)| {
                let id0 = first_id[s];
                let down = strip_forest(cand, (w, h), (s, id0), smask, scratch);
                let contracted = if several {
                    let up = if s > 0 {
                        crossing_ends(cand, w, s * STRIP - 1)
                    } else {
                        Vec::new()
                    };
                    contract_strip(cand, w, id0, smask, (&down, &up), scratch)
                } else {
                    Contracted::default()
                };
                (down, contracted)
            })
            .unzip();
    if !several || crossing.iter().all(|c| c.is_empty()) {
        return mask;
    }
    let t1 = std::time::Instant::now();
    // 3. Kruskal on the contracted graph.
    let mut base = Vec::with_capacity(strips + 1);
    let mut n = 0u32;
    for c in &contracted {
        base.push(n);
        n += c.vertices;
    }
    let mut links: Vec<Link> = Vec::new();
    for (s, c) in contracted.iter().enumerate() {
        links.extend(c.chains.iter().map(|l| Link {
            ends: [base[s] + l.ends[0], base[s] + l.ends[1]],
            ..*l
        }));
        if s + 1 < strips {
            let below = &contracted[s + 1];
            links.extend(crossing[s].iter().enumerate().map(|(i, &seg)| Link {
                ends: [base[s] + c.down[i], base[s + 1] + below.up[i]],
                seg,
                crossing: true,
            }));
        }
    }
    links.par_sort_unstable_by_key(|l| l.seg.key);
    let mut parent: Vec<u32> = (0..n).collect();
    let mut rank = vec![0u8; n as usize];
    for l in links {
        let (ra, rb) = (find(&mut parent, l.ends[0]), find(&mut parent, l.ends[1]));
        let Segment { a, b, bit, .. } = l.seg;
        if ra != rb {
            union(&mut parent, &mut rank, ra, rb);
            if l.crossing {
                mask[a as usize] |= 1 << bit;
                mask[b as usize] |= 1 << (bit + 4);
            }
        } else if !l.crossing {
            // The chain's lowest segment closes a cycle: break it there.
            mask[a as usize] &= !(1 << bit);
            mask[b as usize] &= !(1 << (bit + 4));
        }
    }
    if std::env::var_os("RIDGE_TIMING").is_some() {
        eprintln!(
            "forest: strips {:?} contracted graph {:?} ({n} vertices)",
            t1 - t0,
            t1.elapsed()
        );
    }
    mask
}

/// Kruskal on the segments inside strip `s` (candidate ids from `id0`, mask
/// `smask`); returns the segments from its last row to the next strip.
#[inline(never)]
fn strip_forest(
    cand: &CandidateSet,
    (w, h): (usize, usize),
    (s, id0): (usize, u32),
    smask: &mut [u8],
    scratch: &mut Scratch,
) -> Vec<Segment> {
    let (r0, r1) = (s * STRIP, ((s + 1) * STRIP).min(h));
    let n = smask.len();
    let z = &cand.heights[..];
    // Sort items: weight key above, index into `segs` below.
    let Scratch {
        items,
        sorted,
        segs,
        parent,
        rank,
        best,
        row_cur,
        row_next,
        ..
    } = scratch;
    items.clear();
    segs.clear();
    best.clear();
    // One spare entry at the end for the segments that
    // `inside_row_segments` does not write.
    best.resize(n + 1, u64::MAX);
    let mut crossing = Vec::new();
    let row_ids = |r: usize| cand.before(r * w)..cand.before((r + 1).min(h) * w);
    let mut next_ids = row_ids(r0);
    with_sentinel(
        &cand.cells[next_ids.start as usize..next_ids.end as usize],
        row_next,
    );
    for row in r0..r1 {
        let cur_ids = next_ids;
        next_ids = row_ids(row + 1);
        std::mem::swap(row_cur, row_next);
        with_sentinel(
            &cand.cells[next_ids.start as usize..next_ids.end as usize],
            row_next,
        );
        let rows = RowPair {
            cur: row_cur,
            cur_id0: cur_ids.start,
            next: row_next,
            next_id0: next_ids.start,
        };
        let inside = row + 1 < r1;
        if inside {
            let lists = StripLists {
                items: &mut *items,
                segs: &mut *segs,
                best: &mut best[..],
                id0,
            };
            inside_row_segments(cand, w, row, &rows, lists);
            continue;
        }
        row_segments(z, w, &rows, |d, (ida, idb)| {
            let weight = weight_key(z, ida as usize, idb as usize);
            if d == 0 || inside {
                let item = (weight as u64) << 32 | segs.len() as u64;
                let (la, lb) = ((ida - id0) as usize, (idb - id0) as usize);
                items.push(item);
                segs.push([(la as u32) << 2 | d as u32, lb as u32]);
                best[la] = best[la].min(item);
                best[lb] = best[lb].min(item);
            } else {
                crossing.push(Segment {
                    a: ida,
                    b: idb,
                    bit: d as u8,
                    key: segment_key(weight, ida, d),
                });
            }
        });
    }
    // Borůvka step: the best segment of every candidate (the first of its
    // segments in Kruskal order) is in the forest. These segments form trees
    // whose only cycles are the pairs of candidates that chose the same
    // segment; the lower id of a pair is the root.
    parent.clear();
    for (v, &item) in best[..n].iter().enumerate() {
        if item == u64::MAX {
            parent.push(v as u32);
            continue;
        }
        let [ad, b] = segs[(item & 0xffff_ffff) as usize];
        let (a, d) = (ad >> 2, ad & 3);
        smask[a as usize] |= 1 << d;
        smask[b as usize] |= 1 << (d + 4);
        let other = if a as usize == v { b } else { a };
        let root = best[other as usize] == item && (v as u32) < other;
        parent.push(if root { v as u32 } else { other });
    }
    for v in 0..n as u32 {
        let root = find(parent, v);
        let mut x = v;
        while parent[x as usize] != root {
            (x, parent[x as usize]) = (parent[x as usize], root);
        }
    }
    // Kruskal on the segments between the trees.
    sorted.clear();
    sorted.extend(items.iter().copied().filter(|&item| {
        let [ad, b] = segs[(item & 0xffff_ffff) as usize];
        parent[(ad >> 2) as usize] != parent[b as usize]
    }));
    std::mem::swap(items, sorted);
    sort_by_high_word(items, sorted);
    rank.clear();
    rank.resize(n, 0);
    for &item in items.iter() {
        let [ad, b] = segs[(item & 0xffff_ffff) as usize];
        let (a, d) = (ad >> 2, ad & 3);
        let (ra, rb) = (find(parent, a), find(parent, b));
        if ra != rb {
            union(parent, rank, ra, rb);
            smask[a as usize] |= 1 << d;
            smask[b as usize] |= 1 << (d + 4);
        }
    }
    crossing
}

/// The chains between key vertices (terminals and branch points) of one
/// strip's forest `smask` (candidate ids from `id0`), after cutting
/// branches that hold no terminal. `down` are the strip's crossing segments
/// to the next strip, `up` those of the previous strip into this one.
#[inline(never)]
fn contract_strip(
    cand: &CandidateSet,
    w: usize,
    id0: u32,
    smask: &[u8],
    (down, up): (&[Segment], &[u32]),
    scratch: &mut Scratch,
) -> Contracted {
    const TERMINAL: u8 = 1;
    if down.is_empty() && up.is_empty() {
        return Contracted::default();
    }
    let z = &cand.heights[id0 as usize..];
    let n = smask.len();
    let off = offsets(w);
    let cells = &cand.cells[id0 as usize..id0 as usize + n];
    let Scratch {
        core,
        flags,
        number,
        stack,
        parent,
        ..
    } = scratch;
    // flags: bit 0 terminal, bits 1.. unused; `done` edges live in `core`'s
    // copy below.
    flags.clear();
    flags.resize(n, 0);
    for s in down {
        flags[(s.a - id0) as usize] = TERMINAL;
    }
    for &b in up {
        flags[(b - id0) as usize] = TERMINAL;
    }
    let term = |i: usize| flags[i] == TERMINAL;
    // Only the trees with two terminals or more can hold a cycle through the
    // crossing segments; the others reduce to their terminal (if any).
    number.clear();
    number.resize(n, 0);
    for i in 0..n {
        if term(i) {
            let r = find(parent, i as u32) as usize;
            number[r] = (number[r] + 1).min(2);
        }
    }
    core.clear();
    core.extend((0..n).map(|i| {
        if smask[i] != 0 && number[find(parent, i as u32) as usize] == 2 {
            smask[i]
        } else {
            0
        }
    }));

    // Cut non-terminal leaves repeatedly.
    stack.clear();
    stack.extend((0..n as u32).filter(|&i| degree(core[i as usize]) == 1 && !term(i as usize)));
    while let Some(i) = stack.pop() {
        let i = i as usize;
        if degree(core[i]) != 1 || term(i) {
            continue;
        }
        let d = core[i].trailing_zeros() as usize;
        let j = (cand.id((cells[i] as isize + off[d]) as usize) - id0) as usize;
        core[i] = 0;
        core[j] &= !(1 << ((d + 4) % 8));
        if degree(core[j]) == 1 && !term(j) {
            stack.push(j as u32);
        }
    }
    // Number the key vertices.
    number.clear();
    number.resize(n, u32::MAX);
    let mut vertices = 0u32;
    for i in 0..n {
        if term(i) || (core[i] != 0 && degree(core[i]) != 2) {
            number[i] = vertices;
            vertices += 1;
        }
    }
    // Trace the chains from key vertices; `done` marks traced edge ends.
    let done = flags;
    done.iter_mut().for_each(|f| *f = 0);
    let mut chains = Vec::new();
    for i in 0..n {
        if core[i] == 0 || number[i] == u32::MAX {
            continue;
        }
        for d0 in 0..8 {
            if core[i] & (1 << d0) == 0 || done[i] & (1 << d0) != 0 {
                continue;
            }
            done[i] |= 1 << d0;
            let (mut c, mut d) = (i, d0);
            // The lowest segment has the largest key.
            let mut low: Option<Segment> = None;
            let end = loop {
                let cell = cells[c] as usize;
                let other = (cell as isize + off[d]) as usize;
                let nb = (cand.id(other) - id0) as usize;
                let (ga, gb) = (id0 + c as u32, id0 + nb as u32);
                let seg = if d < 4 {
                    Segment {
                        a: ga,
                        b: gb,
                        bit: d as u8,
                        key: segment_key(weight_key(z, c, nb), ga, d),
                    }
                } else {
                    Segment {
                        a: gb,
                        b: ga,
                        bit: d as u8 - 4,
                        key: segment_key(weight_key(z, nb, c), gb, d - 4),
                    }
                };
                if low.is_none_or(|l| seg.key > l.key) {
                    low = Some(seg);
                }
                let back = (d + 4) % 8;
                if number[nb] != u32::MAX {
                    done[nb] |= 1 << back;
                    break nb;
                }
                let rest = core[nb] & !(1 << back);
                c = nb;
                d = rest.trailing_zeros() as usize;
            };
            let Some(seg) = low else { continue };
            chains.push(Link {
                ends: [number[i], number[end]],
                seg,
                crossing: false,
            });
        }
    }
    Contracted {
        chains,
        vertices,
        down: down.iter().map(|s| number[(s.a - id0) as usize]).collect(),
        up: up.iter().map(|&b| number[(b - id0) as usize]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Kruskal over all segments at once, on cell indices: the reference.
    fn global_kruskal(z: &[f32], cand: &[bool], w: usize, h: usize) -> Vec<u8> {
        let mut segs = Vec::new();
        for c in 0..w * h {
            if !cand[c] {
                continue;
            }
            let (col, row) = (c % w, c / w);
            let mut add = |d: usize, o: usize| segs.push((z[c] + z[o], c, d, o));
            let east = col + 1 < w && cand[c + 1];
            if east {
                add(0, c + 1);
            }
            if row + 1 < h {
                let s = c + w;
                if col + 1 < w
                    && cand[s + 1]
                    && !(east && cand[s] && z[c + 1] + z[s] > z[c] + z[s + 1])
                {
                    add(1, s + 1);
                }
                if cand[s] {
                    add(2, s);
                }
                if col > 0
                    && cand[s - 1]
                    && !(cand[c - 1] && cand[s] && z[c - 1] + z[s] >= z[c] + z[s - 1])
                {
                    add(3, s - 1);
                }
            }
        }
        // Highest first, then by cell and direction.
        segs.sort_by(|p, q| q.0.total_cmp(&p.0).then((p.1, p.2).cmp(&(q.1, q.2))));
        let mut parent: Vec<u32> = (0..(w * h) as u32).collect();
        let mut mask = vec![0u8; w * h];
        for (_, a, d, b) in segs {
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
            (1, 150, 0.8),
            (200, 1, 0.8),
        ] {
            let z: Vec<f32> = (0..w * h).map(|_| (rnd() * 50.0).round() as f32).collect();
            let flags: Vec<bool> = (0..w * h).map(|_| rnd() < density).collect();
            let set = CandidateSet::from_flags(&flags, &z, w, h);
            let by_id = spanning_forest(&set, w, h);
            let want = global_kruskal(&z, &flags, w, h);
            let got: Vec<u8> = (0..w * h)
                .map(|c| {
                    if flags[c] {
                        by_id[set.id(c) as usize]
                    } else {
                        0
                    }
                })
                .collect();
            assert!(got == want, "{w} x {h} at {density}: forests differ");
        }
    }

    #[test]
    fn radix_sort_is_stable_by_the_high_word() {
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut items: Vec<u64> = (0..5000u64)
            .map(|i| {
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                ((seed >> 32) & 0xff00_07ff) << 32 | i
            })
            .collect();
        let mut want = items.clone();
        want.sort_by_key(|x| x >> 32);
        sort_by_high_word(&mut items, &mut Vec::new());
        assert_eq!(items, want);
    }
}
