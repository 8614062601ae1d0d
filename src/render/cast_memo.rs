//! Remembered casts of a far layer. A far layer never changes while it is
//! shared by the terrains of an edit's rounds and passes
//! ([`super::far_layers`]), so a segment cast into it is a function of the
//! ray's direction, start and limit alone; and the silhouettes' bisections
//! ask the same questions of it again and again (each round extracts the
//! silhouettes of its render anew, and the columns the edit does not touch
//! bisect the same brackets with the same rays: on the bench's long view
//! about 29,000 distinct casts of 83,000); so do the walks of a layer's
//! cells from a bisection's near side on it. The answer kept for the same
//! question, bit for bit, is the answer the cast (or walk) would give.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hash, Hasher};
use std::sync::{Mutex, MutexGuard, PoisonError};

use super::terrain::RayHit;

/// Most answers a layer keeps (each about 75 bytes with the table's
/// overhead: under 20 MiB a layer); beyond, casts are made and not kept.
const MAX_KEPT: usize = 1 << 18;

/// A cast's (or walk's) question, bit for bit: the direction's three
/// components, two distances and, for a walk, the triangle it starts in
/// and the most cells it walks.
#[derive(Debug, Clone, Copy, Eq)]
pub(crate) struct CastKey([u64; 7]);

impl PartialEq for CastKey {
    /// Word by word, in line (the derived comparison of the array called
    /// `memcmp` on every probe of the table).
    #[inline]
    fn eq(&self, other: &Self) -> bool {
        self.0.iter().zip(&other.0).fold(0, |d, (a, b)| d | (a ^ b)) == 0
    }
}

impl CastKey {
    /// The question of a cast of unit ray `d` over `[t_start, t_limit]`.
    pub(crate) fn new(d: [f64; 3], t_start: f64, t_limit: f64) -> CastKey {
        CastKey([
            d[0].to_bits(),
            d[1].to_bits(),
            d[2].to_bits(),
            t_start.to_bits(),
            t_limit.to_bits(),
            0,
            0,
        ])
    }

    /// The question of a walk of unit ray `d` from triangle `id`
    /// ([`super::LocalTerrain::walk_cells`]'s arguments).
    pub(crate) fn walk(
        d: [f64; 3],
        id: u32,
        t_start: f64,
        latest_entry: f64,
        max_cells: usize,
    ) -> CastKey {
        CastKey([
            d[0].to_bits(),
            d[1].to_bits(),
            d[2].to_bits(),
            t_start.to_bits(),
            latest_entry.to_bits(),
            u64::from(id),
            max_cells as u64,
        ])
    }
}

impl Hash for CastKey {
    fn hash<H: Hasher>(&self, state: &mut H) {
        for w in self.0 {
            state.write_u64(w);
        }
    }
}

/// A multiply-rotate hash of whole words (the keys are floating-point
/// bits, not chosen by anyone: no need for a keyed hash).
#[derive(Default)]
pub(crate) struct WordHasher(u64);

impl Hasher for WordHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.write_u64(u64::from(*b));
        }
    }

    fn write_u64(&mut self, w: u64) {
        self.0 = (self.0.rotate_left(5) ^ w).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

type Answers = HashMap<CastKey, Option<RayHit>, BuildHasherDefault<WordHasher>>;

/// The answers of one far layer's segment casts (shared by the clones of
/// the layer).
#[derive(Default)]
pub(crate) struct CastMemo(Mutex<Answers>);

impl std::fmt::Debug for CastMemo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "CastMemo({} answers)", self.answers().len())
    }
}

impl CastMemo {
    /// The answer to `key`: the one kept, or `cast()`'s (then kept, while
    /// fewer than [`MAX_KEPT`] are). The lock is not held while casting.
    pub(crate) fn answer(
        &self,
        key: CastKey,
        cast: impl FnOnce() -> Option<RayHit>,
    ) -> Option<RayHit> {
        if let Some(&hit) = self.answers().get(&key) {
            return hit;
        }
        let hit = cast();
        let mut answers = self.answers();
        if answers.len() < MAX_KEPT {
            answers.insert(key, hit);
        }
        hit
    }

    fn answers(&self) -> MutexGuard<'_, Answers> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_question_asked_again_gets_the_first_answer_without_a_cast() {
        let memo = CastMemo::default();
        let key = CastKey::new([0.6, 0.8, 0.0], 10.0, f64::INFINITY);
        let hit = Some(RayHit {
            t: 12.5,
            triangle: 7,
        });
        assert_eq!(memo.answer(key, || hit), hit);
        assert_eq!(memo.answer(key, || panic!("cast again")), hit);
        // another start (one bit) is another question
        let other = CastKey::new(
            [0.6, 0.8, 0.0],
            f64::from_bits(10f64.to_bits() + 1),
            f64::INFINITY,
        );
        assert_eq!(memo.answer(other, || None), None);
        assert_eq!(memo.answer(other, || panic!("cast again")), None);
    }
}
