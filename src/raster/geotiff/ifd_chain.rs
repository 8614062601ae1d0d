//! A look at a TIFF's chain of image file directories from their raw
//! bytes, without decoding them: whether every directory's
//! NewSubfileType (tag 254), where present, is one value the decoder reads
//! as a number. The walk over the directories that lists a file's
//! overviews fails only on such a tag, so where this holds the walk cannot
//! fail and may be put off until the overviews are asked for
//! ([`super::GeoTiff::overviews`]): opening a directory of a thousand tiles
//! then parses one directory per tile, not five.

/// Most directories looked at; a longer chain is not vouched for.
const MAX_DIRECTORIES: usize = 4096;

/// NewSubfileType.
const TAG_SUBFILE_TYPE: u64 = 254;

/// Whether every directory of `bytes`'s chain (from the header's first
/// offset, each next one after its entries, as the decoder follows them,
/// to an offset of 0) lies within the file and holds no NewSubfileType
/// other than one SHORT or LONG value. `false` where anything is
/// otherwise (a directory out of the file, a cycle, a longer chain than
/// [`MAX_DIRECTORIES`], another type or count): not vouched for.
pub(super) fn subfile_types_readable(bytes: &[u8]) -> bool {
    let Some(raw) = Raw::new(bytes) else {
        return false;
    };
    let mut seen = Vec::new();
    let mut at = raw.first_directory();
    while let Some(offset) = at {
        if offset == 0 {
            return true;
        }
        if seen.len() >= MAX_DIRECTORIES || seen.contains(&offset) {
            return false;
        }
        seen.push(offset);
        at = raw.checked_directory(offset);
    }
    false
}

/// The bytes of a TIFF with its byte order and offset size.
struct Raw<'a> {
    bytes: &'a [u8],
    little: bool,
    big_tiff: bool,
}

impl<'a> Raw<'a> {
    /// The header's byte order and version; `None` for anything else.
    fn new(bytes: &'a [u8]) -> Option<Raw<'a>> {
        let little = match bytes.get(..2)? {
            b"II" => true,
            b"MM" => false,
            _ => return None,
        };
        let mut raw = Raw {
            bytes,
            little,
            big_tiff: false,
        };
        raw.big_tiff = match raw.uint(2, 2)? {
            42 => false,
            43 => true,
            _ => return None,
        };
        Some(raw)
    }

    /// The first directory's offset.
    fn first_directory(&self) -> Option<u64> {
        if self.big_tiff {
            self.uint(8, 8)
        } else {
            self.uint(4, 4)
        }
    }

    /// The next directory's offset after the one at `offset`, when that
    /// one lies within the file and its NewSubfileType (if any) is one
    /// SHORT or LONG value.
    fn checked_directory(&self, offset: u64) -> Option<u64> {
        let at = usize::try_from(offset).ok()?;
        let (count_len, entry_len, value_len) = if self.big_tiff {
            (8, 20, 8)
        } else {
            (2, 12, 4)
        };
        let entries = usize::try_from(self.uint(at, count_len)?).ok()?;
        let first = at.checked_add(count_len)?;
        for i in 0..entries {
            let e = first.checked_add(i.checked_mul(entry_len)?)?;
            if self.uint(e, 2)? == TAG_SUBFILE_TYPE {
                let kind = self.uint(e + 2, 2)?;
                let count = self.uint(e + 4, value_len)?;
                if !matches!(kind, 3 | 4) || count != 1 {
                    return None;
                }
            }
        }
        let next = first.checked_add(entries.checked_mul(entry_len)?)?;
        self.uint(next, value_len)
    }

    /// The unsigned integer of `n` bytes at `at`, in the file's byte order.
    fn uint(&self, at: usize, n: usize) -> Option<u64> {
        let b = self.bytes.get(at..at.checked_add(n)?)?;
        Some(if self.little {
            b.iter().rev().fold(0u64, |v, &x| (v << 8) | u64::from(x))
        } else {
            b.iter().fold(0u64, |v, &x| (v << 8) | u64::from(x))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A classic little-endian TIFF whose directories hold the given
    /// NewSubfileType entries (`(type, count)`, or none), chained in order.
    fn chain(entries: &[Option<(u16, u32)>]) -> Vec<u8> {
        let mut out = b"II*\0".to_vec();
        out.extend_from_slice(&8u32.to_le_bytes());
        for (i, e) in entries.iter().enumerate() {
            let n: u16 = if e.is_some() { 2 } else { 1 };
            out.extend_from_slice(&n.to_le_bytes());
            if let Some((kind, count)) = e {
                out.extend_from_slice(&254u16.to_le_bytes());
                out.extend_from_slice(&kind.to_le_bytes());
                out.extend_from_slice(&count.to_le_bytes());
                out.extend_from_slice(&1u32.to_le_bytes());
            }
            // ImageWidth, one SHORT
            out.extend_from_slice(&256u16.to_le_bytes());
            out.extend_from_slice(&3u16.to_le_bytes());
            out.extend_from_slice(&1u32.to_le_bytes());
            out.extend_from_slice(&16u32.to_le_bytes());
            let next = if i + 1 < entries.len() {
                out.len() as u32 + 4
            } else {
                0
            };
            out.extend_from_slice(&next.to_le_bytes());
        }
        out
    }

    #[test]
    fn a_chain_of_short_or_long_subfile_types_is_vouched_for() {
        assert!(subfile_types_readable(&chain(&[
            None,
            Some((4, 1)),
            Some((3, 1))
        ])));
        assert!(subfile_types_readable(&chain(&[Some((4, 1))])));
    }

    #[test]
    fn anything_else_is_not() {
        // a RATIONAL subfile type, two values, a cut file, a cycle
        assert!(!subfile_types_readable(&chain(&[None, Some((5, 1))])));
        assert!(!subfile_types_readable(&chain(&[None, Some((4, 2))])));
        let whole = chain(&[None, Some((4, 1))]);
        assert!(!subfile_types_readable(&whole[..whole.len() - 2]));
        let mut cycle = chain(&[None]);
        let end = cycle.len() - 4;
        cycle[end..].copy_from_slice(&8u32.to_le_bytes());
        assert!(!subfile_types_readable(&cycle));
        assert!(!subfile_types_readable(b"GIF89a.."));
    }
}
