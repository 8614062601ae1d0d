//! The bytes of an open GeoTIFF: read into memory (a small file), mapped,
//! or mapped only when first needed.
//!
//! A directory of large tiles is opened whole, but an edit or a view reads
//! the blocks of a few of its tiles: mapping every tile at open, faulting
//! in the pages of its header and unmapping it at the end cost more than
//! parsing the header (about 10 us a tile, and 40 KB of resident pages,
//! for a directory of 1,024 tiles of 1024^2 cells). Where a file's header
//! lies wholly in the bytes the open reads first, the file is parsed from
//! those bytes and mapped on the first read of its blocks or overviews
//! ([`Bytes::Deferred`]). The map is then checked to be of the file that
//! was parsed (same device, inode, length and modification time): a file
//! replaced since is an error, never a mix of one file's header and
//! another's blocks.

use std::path::Path;
use std::sync::OnceLock;

use memmap2::Mmap;

use crate::raster::RasterError;

/// What identifies the file a header was parsed from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct FileStamp {
    len: u64,
    dev: u64,
    ino: u64,
    modified: Option<std::time::SystemTime>,
}

impl FileStamp {
    pub(super) fn of(meta: &std::fs::Metadata) -> FileStamp {
        #[cfg(unix)]
        let (dev, ino) = {
            use std::os::unix::fs::MetadataExt;
            (meta.dev(), meta.ino())
        };
        #[cfg(not(unix))]
        let (dev, ino) = (0, 0);
        FileStamp {
            len: meta.len(),
            dev,
            ino,
            modified: meta.modified().ok(),
        }
    }

    /// The file's length, bytes.
    pub(super) fn len(&self) -> u64 {
        self.len
    }
}

/// The bytes of a GeoTIFF.
#[derive(Debug)]
pub(super) enum Bytes {
    /// A read-only map of the whole file.
    Map(Mmap),
    /// The whole file, read (a small file, or bytes given).
    Owned(Vec<u8>),
    /// A file parsed from its first bytes, mapped on first use.
    Deferred {
        stamp: FileStamp,
        map: OnceLock<Result<Mmap, MapFailure>>,
    },
}

impl Bytes {
    /// A file of `stamp` mapped when its bytes are first asked for.
    pub(super) fn deferred(stamp: FileStamp) -> Bytes {
        Bytes::Deferred {
            stamp,
            map: OnceLock::new(),
        }
    }

    /// The whole file (`path` names it, and is mapped where the map was
    /// put off).
    pub(super) fn data(&self, path: &Path) -> Result<&[u8], RasterError> {
        match self {
            Bytes::Map(m) => Ok(m),
            Bytes::Owned(v) => Ok(v),
            Bytes::Deferred { stamp, map } => match map.get_or_init(|| map_stamped(path, *stamp)) {
                Ok(m) => Ok(m),
                Err(MapFailure::Changed) => Err(RasterError::ChangedSinceOpened {
                    path: path.to_path_buf(),
                }),
                Err(MapFailure::Io(kind, message)) => Err(RasterError::Io {
                    path: path.to_path_buf(),
                    source: std::io::Error::new(*kind, message.clone()),
                }),
            },
        }
    }
}

/// Why a deferred map failed (kept for every later read of the file).
#[derive(Debug)]
pub(super) enum MapFailure {
    /// Not the file that was parsed any more.
    Changed,
    /// Opening, measuring or mapping it failed.
    Io(std::io::ErrorKind, String),
}

impl From<std::io::Error> for MapFailure {
    fn from(e: std::io::Error) -> Self {
        MapFailure::Io(e.kind(), e.to_string())
    }
}

/// Map `path`, which must still be the file of `stamp`.
fn map_stamped(path: &Path, stamp: FileStamp) -> Result<Mmap, MapFailure> {
    let file = std::fs::File::open(path)?;
    if FileStamp::of(&file.metadata()?) != stamp {
        return Err(MapFailure::Changed);
    }
    Ok(map_whole(&file, stamp.len)?)
}

/// A read-only map of the whole of `file`, `len` bytes long (its length as
/// measured already: a map measures the file again otherwise).
pub(super) fn map_whole(file: &std::fs::File, len: u64) -> std::io::Result<Mmap> {
    let len = usize::try_from(len).map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "memory map length overflows usize",
        )
    })?;
    // SAFETY: the map is read-only; a file truncated by another process
    // while mapped is outside what any GIS reader can guard against.
    unsafe { memmap2::MmapOptions::new().len(len).map(file) }
}
