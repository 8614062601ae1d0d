//! Fallible allocation of the large buffers of the raster layer (windows,
//! decoded blocks): a request the allocator refuses is an error value the
//! caller turns into a one-line message, never an abort.

/// A vector of `n` copies of `v`, or `None` when the memory cannot be had.
pub(crate) fn try_filled<T: Clone>(n: usize, v: T) -> Option<Vec<T>> {
    let mut out = Vec::new();
    out.try_reserve_exact(n).ok()?;
    out.resize(n, v);
    Some(out)
}
