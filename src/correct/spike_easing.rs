//! No spikes in a landform's change (issue 11 item 5, applied to the
//! landforms of Gain et al.): no cell's change may stand more than half a
//! cell above, or below, the changes of all its 8 neighbours.
//!
//! A landform's silhouette cells (the bilinear stencils its curve lies in)
//! are put on the sight cone through the stroke. At a few kilometres one
//! cell spans many image columns, so where the stroke rises steeply the
//! cone rises steeply across a cell, and a stencil cell can stand alone
//! above neighbours that are held under the sight line (on Zion 83 m, a
//! long ridge at 3 km: +285 m beside neighbours of at most +225 m). The
//! spike is eased the way the edit eases its own ([`crate::edit::spikes`]):
//! a neighbour is raised towards it, but never above the height at which
//! it would show above the stroke (its cap), so the silhouette the user
//! drew is unchanged; only what no neighbour can take up is taken off the
//! cell itself. Pits (a cell far below all its neighbours) are eased by
//! lowering a neighbour, which can only hide terrain, never show it.

use crate::deform::CellSize;
use crate::edit::spikes::NEIGHBOURS;

/// The change field being eased: a window of `width` x `height` cells,
/// row-major. NaN: nodata (neither moved nor compared).
pub struct ChangeField<'a> {
    pub width: usize,
    pub height: usize,
    /// The change of every cell, metres.
    pub change: &'a mut [f64],
    /// Cells that may be raised or lowered as a spike's neighbour (inside
    /// the landform's footprint, not on its silhouette).
    pub movable: &'a [bool],
    /// Cells that may give way themselves when no neighbour can (the
    /// footprint's cells).
    pub own: &'a [bool],
    /// The highest change each cell may take (the sight bound; infinite
    /// where none applies).
    pub cap: &'a [f64],
}

impl ChangeField<'_> {
    fn neighbours(&self, i: usize) -> impl Iterator<Item = usize> + '_ {
        let (c, r) = ((i % self.width) as i64, (i / self.width) as i64);
        NEIGHBOURS.iter().filter_map(move |&(dc, dr)| {
            let (x, y) = (c + dc, r + dr);
            (x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height)
                .then(|| y as usize * self.width + x as usize)
                .filter(|&k| !self.change[k].is_nan())
        })
    }

    /// The smallest and largest change of the valid neighbours of `i`.
    fn range(&self, i: usize) -> Option<(f64, f64)> {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for k in self.neighbours(i) {
            lo = lo.min(self.change[k]);
            hi = hi.max(self.change[k]);
        }
        hi.is_finite().then_some((lo, hi))
    }

    /// Cells standing more than `limit` above or below all their
    /// neighbours, with the signed excess (positive: above).
    fn spikes(&self, limit: f64) -> Vec<(usize, f64)> {
        (0..self.change.len())
            .filter(|&i| !self.change[i].is_nan())
            .filter_map(|i| {
                let (lo, hi) = self.range(i)?;
                let m = self.change[i];
                if m - hi > limit {
                    Some((i, m - hi))
                } else if lo - m > limit {
                    Some((i, m - lo))
                } else {
                    None
                }
            })
            .collect()
    }
}

/// Eases the spikes of `f` (see the module documentation); `cell` gives
/// the limit (half the smaller side). Returns how many cells were
/// changed. Spikes on cells that may not give way stay.
pub fn ease_spikes(f: &mut ChangeField, cell: CellSize) -> usize {
    let limit = 0.5 * cell.hx.min(cell.hy);
    // Within 0.9 of the limit: the written heights are rounded to the
    // DEM's sample type.
    let gap = 0.9 * limit;
    let mut changed = vec![false; f.change.len()];
    // Each pass moves cells towards a spike, which can leave the moved cell
    // standing out from its own neighbours; a few passes settle that.
    for _ in 0..32 {
        let spikes = f.spikes(limit);
        if spikes.is_empty() {
            break;
        }
        for (i, excess) in spikes {
            let m = f.change[i];
            if excess > 0.0 {
                raise_a_neighbour(f, i, m - gap, gap, &mut changed);
            } else {
                lower_a_neighbour(f, i, m + gap, gap, &mut changed);
            }
        }
    }
    changed.iter().filter(|&&c| c).count()
}

/// Brings the neighbour of spike `i` that can come closest to `target`
/// up to it (not above its cap); what is left, the spike itself gives up.
fn raise_a_neighbour(f: &mut ChangeField, i: usize, target: f64, gap: f64, changed: &mut [bool]) {
    let best = f
        .neighbours(i)
        .filter(|&k| f.movable[k])
        .map(|k| (k, f.cap[k].min(target)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    if let Some((k, to)) = best {
        if to > f.change[k] {
            f.change[k] = to;
            changed[k] = true;
        }
    }
    if let Some((_, hi)) = f.range(i) {
        if f.change[i] - hi > gap && f.own[i] {
            f.change[i] = hi + gap;
            changed[i] = true;
        }
    }
}

/// Brings a movable neighbour of pit `i` down to `target`; when none may
/// move, the pit itself comes up (not above its cap).
fn lower_a_neighbour(f: &mut ChangeField, i: usize, target: f64, gap: f64, changed: &mut [bool]) {
    let best = f
        .neighbours(i)
        .filter(|&k| f.movable[k])
        .min_by(|&a, &b| f.change[a].total_cmp(&f.change[b]));
    if let Some(k) = best {
        if target < f.change[k] {
            f.change[k] = target;
            changed[k] = true;
        }
    }
    if let Some((lo, _)) = f.range(i) {
        if lo - f.change[i] > gap && f.own[i] {
            f.change[i] = (lo - gap).min(f.cap[i]);
            changed[i] = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMIT: f64 = 5.0;

    /// Eases a 3 x 3 field whose centre has `centre` and every other cell
    /// 0; returns the changes after.
    fn eased(centre: f64, movable: [bool; 9], cap: [f64; 9]) -> Vec<f64> {
        let mut change = vec![0.0; 9];
        change[4] = centre;
        let own = [true; 9];
        let mut f = ChangeField {
            width: 3,
            height: 3,
            change: &mut change,
            movable: &movable,
            own: &own,
            cap: &cap,
        };
        ease_spikes(&mut f, CellSize { hx: 10.0, hy: 10.0 });
        assert!(f.spikes(LIMIT).is_empty(), "{:?}", f.change);
        change
    }

    #[test]
    fn a_spike_is_eased_by_raising_a_neighbour_under_its_cap() {
        // The centre 20 m above neighbours at 0 (limit 5 m); only the east
        // neighbour may rise.
        let mut cap = [0.0; 9];
        cap[5] = 100.0;
        let change = eased(20.0, [true; 9], cap);
        assert_eq!(change[4], 20.0, "the spike itself stays");
        assert!((change[5] - 15.5).abs() < 1e-9, "{change:?}");
    }

    #[test]
    fn with_no_room_under_the_caps_the_spike_gives_way() {
        let change = eased(20.0, [true; 9], [0.0; 9]);
        assert!((change[4] - 4.5).abs() < 1e-9, "{change:?}");
    }

    #[test]
    fn a_pit_is_eased_by_lowering_a_neighbour() {
        let mut movable = [false; 9];
        movable[1] = true;
        let change = eased(-20.0, movable, [f64::INFINITY; 9]);
        assert_eq!(change[4], -20.0);
        assert!((change[1] + 15.5).abs() < 1e-9, "{change:?}");
    }
}
