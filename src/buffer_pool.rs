//! Large buffers recycled between views and solves.
//!
//! Buffers of megabytes come straight from the kernel: every page costs a
//! fault and a clear when first written, and is unmapped again when the
//! buffer is freed. A 4096 x 4096 terrain's heights (64 MB) or a multigrid
//! solve's levels (about 150 MB) paid that on every view and every solve:
//! about 50 ms of CPU per terrain, a fifth of a solve. The terrain and the
//! solver's levels take their large arrays from here and give them back
//! when they are dropped, so every view or solve after the first one in a
//! process (the rounds of an edit, a batch of tiles, a benchmark) reuses
//! warm memory.
//!
//! A buffer is handed out only for a request of at least half its size,
//! and at most [`KEEP_BYTES`] of idle buffers are kept per element type;
//! [`release`] frees them.

use rayon::prelude::*;
use std::sync::Mutex;

/// Most bytes of idle buffers kept for the next solve (per element type).
pub const KEEP_BYTES: usize = 1 << 30;

/// Buffers shorter than this are allocated and freed normally (the
/// allocator keeps them warm itself).
const MIN_RECYCLED_BYTES: usize = 1 << 20;

/// Entries per parallel task when a recycled buffer is zeroed.
const ZERO_CHUNK: usize = 1 << 16;

static F32: Mutex<Vec<Vec<f32>>> = Mutex::new(Vec::new());
static U32: Mutex<Vec<Vec<u32>>> = Mutex::new(Vec::new());

/// Takes the smallest idle buffer of at least `len` entries, if any.
fn take<T>(pool: &Mutex<Vec<Vec<T>>>, len: usize) -> Option<Vec<T>> {
    if len * std::mem::size_of::<T>() < MIN_RECYCLED_BYTES {
        return None;
    }
    let mut idle = pool.lock().unwrap_or_else(|e| e.into_inner());
    let best = idle
        .iter()
        .enumerate()
        .filter(|(_, v)| v.capacity() >= len && v.capacity() <= 2 * len)
        .min_by_key(|(_, v)| v.capacity())
        .map(|(k, _)| k)?;
    Some(idle.swap_remove(best))
}

/// Keeps `v` for a later [`take`], dropping the largest idle buffers while
/// more than [`KEEP_BYTES`] would be kept.
fn give<T>(pool: &Mutex<Vec<Vec<T>>>, v: Vec<T>) {
    let size = std::mem::size_of::<T>();
    if v.capacity() * size < MIN_RECYCLED_BYTES || v.capacity() * size > KEEP_BYTES {
        return;
    }
    let mut idle = pool.lock().unwrap_or_else(|e| e.into_inner());
    idle.push(v);
    while idle.iter().map(|v| v.capacity() * size).sum::<usize>() > KEEP_BYTES {
        let Some((k, _)) = idle.iter().enumerate().max_by_key(|(_, v)| v.capacity()) else {
            break;
        };
        idle.swap_remove(k);
    }
}

/// A buffer of `len` zeros, recycled where possible.
pub(crate) fn zeroed_f32(len: usize) -> Vec<f32> {
    match take(&F32, len) {
        Some(mut v) => {
            v.clear();
            v.resize(len, 0.0);
            v.par_chunks_mut(ZERO_CHUNK).for_each(|c| c.fill(0.0));
            v
        }
        None => vec![0.0; len],
    }
}

/// A buffer of `len` entries whose values are unspecified (the caller
/// writes every entry), recycled where possible.
pub(crate) fn overwritten_f32(len: usize) -> Vec<f32> {
    match take(&F32, len) {
        Some(mut v) => {
            // Keeps the old values where the buffer was that long already.
            v.resize(len, 0.0);
            v
        }
        None => vec![0.0; len],
    }
}

/// As [`overwritten_f32`].
pub(crate) fn overwritten_u32(len: usize) -> Vec<u32> {
    match take(&U32, len) {
        Some(mut v) => {
            // Keeps the old values where the buffer was that long already.
            v.resize(len, 0);
            v
        }
        None => vec![0; len],
    }
}

/// Gives a buffer back for the next view or solve.
pub(crate) fn recycle_f32(v: Vec<f32>) {
    give(&F32, v);
}

/// Gives a buffer back for the next view or solve.
pub(crate) fn recycle_u32(v: Vec<u32>) {
    give(&U32, v);
}

/// Frees every idle buffer kept for later views and solves (up to
/// [`KEEP_BYTES`] per element type are kept).
pub fn release() {
    F32.lock().unwrap_or_else(|e| e.into_inner()).clear();
    U32.lock().unwrap_or_else(|e| e.into_inner()).clear();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recycled_buffers_come_back_zeroed_and_sized() {
        let len = MIN_RECYCLED_BYTES; // 4 MB of f32
        let mut a = zeroed_f32(len);
        a.iter_mut().for_each(|v| *v = 7.0);
        let ptr = a.as_ptr();
        recycle_f32(a);
        let b = zeroed_f32(len - 5);
        assert_eq!(b.len(), len - 5);
        assert!(b.iter().all(|&v| v == 0.0));
        // Another test may have taken it in between; only check when reused.
        if b.as_ptr() == ptr {
            assert!(b.capacity() >= len);
        }
        recycle_f32(b);
        let c = overwritten_u32(len);
        assert_eq!(c.len(), len);
        recycle_u32(c);
        release();
    }
}
