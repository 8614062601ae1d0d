//! Native GeoTIFF decoding on the `tiff` crate: the header and image file
//! directories are parsed once at open; blocks (strips or tiles) are decoded
//! on demand, in parallel, from a memory map, each worker with its own
//! `tiff::Decoder` over the shared bytes. Georeferencing follows GDAL:
//! ModelTiepoint + ModelPixelScale or ModelTransformation, PixelIsPoint
//! shifted by half a pixel, `GDAL_NODATA` and `GDAL_METADATA` kept.
//! Reduced-resolution IFDs (overviews) are listed, and opened on demand
//! ([`GeoTiff::overview`]); masks are recognised and skipped.

mod block_decode;
mod file_bytes;
pub mod fuzz;
mod geokeys;
mod ifd_chain;
mod limits;
mod overview;
mod tags;

pub use limits::{decoder_limits, max_decompressed, memory_budget};

use block_decode::BlockCodec;
use file_bytes::{Bytes, FileStamp};

pub use geokeys::{GeoKeys, RasterType};

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

use super::{Crs, GeoTransform, RasterError, SampleType, Vertical};

const TAG_GDAL_METADATA: u16 = 42112;
const TAG_GDAL_NODATA: u16 = 42113;

/// Files up to this size are read into memory at open rather than mapped.
const SMALL_FILE: u64 = 64 << 10;

/// Bytes read before a file's size is asked for (see
/// [`GeoTiff::open_with_budget`]).
const FIRST_READ: usize = 8 << 10;

/// What the open's first read found: a small file, read whole, or a large
/// one's metadata and first bytes (none where it grew while read).
enum FirstRead {
    Whole(Vec<u8>),
    Large {
        meta: std::fs::Metadata,
        head: Vec<u8>,
    },
}

/// How a TIFF's pixels are cut into blocks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BlockLayout {
    pub tiled: bool,
    pub block_width: u32,
    pub block_height: u32,
    pub blocks_across: u32,
    pub blocks_down: u32,
}

impl BlockLayout {
    /// Number of blocks (as u64: a crafted header may claim more than a
    /// TIFF can list).
    pub fn count(&self) -> u64 {
        u64::from(self.blocks_across) * u64::from(self.blocks_down)
    }
}

/// Compression and predictor of the image, with GDAL's names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Encoding {
    pub compression: &'static str,
    pub predictor: u16,
}

/// An open GeoTIFF: parsed metadata and the bytes of the file (a clone
/// shares them).
#[derive(Debug, Clone)]
pub struct GeoTiff {
    pub path: PathBuf,
    bytes: Arc<Bytes>,
    /// Index of the full-resolution IFD.
    pub ifd_index: usize,
    pub width: u32,
    pub height: u32,
    pub sample_type: SampleType,
    pub layout: BlockLayout,
    pub encoding: Encoding,
    pub geotransform: GeoTransform,
    pub raster_type: RasterType,
    pub crs: Crs,
    /// `GDAL_NODATA`, parsed (NaN where the tag says "nan").
    pub nodata: Option<f64>,
    /// The `GDAL_METADATA` XML, kept for write-back.
    pub gdal_metadata: Option<String>,
    /// Band scale, offset, vertical unit and datum (stored value -> metres).
    pub vertical: Vertical,
    /// The reduced-resolution images (overviews): listed at open, or on
    /// first use ([`GeoTiff::overviews`]).
    overview_list: std::sync::OnceLock<OverviewList>,
    /// The memory budget the file was opened under (its decoder's limits).
    budget: u64,
    codec: BlockCodec,
    offsets: Vec<u64>,
    counts: Vec<u64>,
}

fn tiff_err(path: &Path, e: tiff::TiffError) -> RasterError {
    use tiff::TiffError as T;
    match e {
        T::FormatError(tiff::TiffFormatError::TiffSignatureNotFound)
        | T::FormatError(tiff::TiffFormatError::TiffSignatureInvalid) => RasterError::NotTiff {
            path: path.to_path_buf(),
            detail: "no TIFF signature".into(),
        },
        T::UnsupportedError(u) => RasterError::Unsupported {
            path: path.to_path_buf(),
            what: format!("TIFF feature: {u}"),
        },
        T::LimitsExceeded => RasterError::Corrupt {
            path: path.to_path_buf(),
            detail: "a tag claims more data than the file can hold (decoder limits exceeded)"
                .into(),
        },
        T::IoError(io) => RasterError::Corrupt {
            path: path.to_path_buf(),
            detail: io.to_string(),
        },
        other => RasterError::Corrupt {
            path: path.to_path_buf(),
            detail: other.to_string(),
        },
    }
}

impl GeoTiff {
    /// Open and parse a GeoTIFF. Fails with a one-line error for files that
    /// are not TIFF, are truncated, lack a georeference or use an encoding
    /// this reader does not decode.
    pub fn open(path: &Path) -> Result<GeoTiff, RasterError> {
        Self::open_with_budget(path, memory_budget())
    }

    /// [`GeoTiff::open`] with the memory budget given ([`memory_budget`]
    /// reads four files of `/proc`: a directory of tiles computes it once).
    pub fn open_with_budget(path: &Path, budget: u64) -> Result<GeoTiff, RasterError> {
        use std::io::Read;
        let mut file = std::fs::File::open(path).map_err(|e| RasterError::io(path, e))?;
        // A small file is read: mapping it, faulting its pages in and
        // unmapping it (a TLB shoot-down on every core) cost several times
        // reading a few pages, and a directory of small tiles opens
        // thousands. The first read says which it is (no stat) for files
        // of a page or two; a larger one is measured before more is read
        // (reading 64 KB of every large tile only to map it copied 64 MB
        // per open of a directory of 1,024 tiles).
        thread_local! {
            static HEAD: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
        }
        // (the whole file where it is small, else its metadata and its
        // first bytes)
        let small = HEAD.with(|head| -> std::io::Result<FirstRead> {
            let mut head = head.borrow_mut();
            head.resize(SMALL_FILE as usize + 1, 0);
            let mut want = FIRST_READ.min(head.len());
            let mut got = 0;
            while got < want {
                match file.read(&mut head[got..want]) {
                    Ok(0) => break,
                    Ok(n) => got += n,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
                if got == want && want < head.len() {
                    // More than the first read: small enough to read whole?
                    let meta = file.metadata()?;
                    if meta.len() > SMALL_FILE {
                        let head = head[..got].to_vec();
                        return Ok(FirstRead::Large { meta, head });
                    }
                    want = head.len();
                }
            }
            if got > SMALL_FILE as usize {
                // (it grew while read: mapped, as a large file)
                let meta = file.metadata()?;
                return Ok(FirstRead::Large {
                    meta,
                    head: Vec::new(),
                });
            }
            Ok(FirstRead::Whole(head[..got].to_vec()))
        });
        let (meta, first) = match small.map_err(|e| RasterError::io(path, e))? {
            FirstRead::Whole(data) => {
                return Self::parse(path, Arc::new(Bytes::Owned(data)), budget)
            }
            FirstRead::Large { meta, head } => (meta, head),
        };
        // A header within the first bytes read is parsed from them, and
        // the file mapped when its blocks are first read
        // ([`Bytes::Deferred`]): every read of the parse lies in those
        // bytes, and every check of a length is against the file's, so
        // what it gives is what parsing the mapped file gives. Where it
        // fails (something lies beyond them), the mapped file is parsed,
        // and its errors are the file's.
        let stamp = FileStamp::of(&meta);
        if !first.is_empty() {
            let deferred = Arc::new(Bytes::deferred(stamp));
            if let Ok(tiff) = Self::parse_from(path, &first, stamp.len(), deferred, budget) {
                return Ok(tiff);
            }
        }
        let map =
            file_bytes::map_whole(&file, stamp.len()).map_err(|e| RasterError::io(path, e))?;
        Self::parse(path, Arc::new(Bytes::Map(map)), budget)
    }

    /// Parse a GeoTIFF held in memory (`label` names it in errors): what
    /// the fuzz harness runs on.
    pub fn from_bytes(label: &Path, data: Vec<u8>) -> Result<GeoTiff, RasterError> {
        Self::parse(label, Arc::new(Bytes::Owned(data)), memory_budget())
    }

    /// Parse the file held in `bytes` (whole: in memory or mapped).
    fn parse(path: &Path, bytes: Arc<Bytes>, budget: u64) -> Result<GeoTiff, RasterError> {
        let data = bytes.data(path)?;
        Self::parse_from(path, data, data.len() as u64, bytes.clone(), budget)
    }

    /// Parse a file of `file_len` bytes from `bytes`, its first bytes
    /// (all of them, or a header's worth: a read beyond them fails), the
    /// GeoTIFF keeping `store` for its blocks.
    fn parse_from(
        path: &Path,
        bytes: &[u8],
        file_len: u64,
        store: Arc<Bytes>,
        budget: u64,
    ) -> Result<GeoTiff, RasterError> {
        if bytes.len() < 8 || !(bytes.starts_with(b"II") || bytes.starts_with(b"MM")) {
            return Err(RasterError::NotTiff {
                path: path.to_path_buf(),
                detail: if bytes.len() < 8 {
                    format!("only {} bytes", bytes.len())
                } else {
                    "no TIFF signature".into()
                },
            });
        }
        let mut dec = Self::decoder(path, bytes, file_len, budget)?;
        let first = subfile_type(&mut dec, path)?;
        // The first image the DEM (as a rule), and a walk over the others
        // that cannot fail (`ifd_chain`): described now, its overviews
        // listed on first use. What the open gives is what the walk would
        // have let it give.
        if first & (SUBFILE_REDUCED | SUBFILE_MASK) == 0 && ifd_chain::subfile_types_readable(bytes)
        {
            let mut tiff = Self::describe(path, (bytes, file_len), store, &mut dec, 0, budget)?;
            tiff.budget = budget;
            return Ok(tiff);
        }
        // Otherwise the walk now, its errors first. The DEM is described
        // where the walk starts on it instead of seeking back to it: its
        // tags read then are the ones read after the walk (the same
        // directory, and limits no tighter than those it was first read
        // under).
        let mut described = None;
        let (ifd_index, list) = walk_images(path, &mut dec, first, |dec| {
            described = Some(Self::describe(
                path,
                (bytes, file_len),
                store.clone(),
                dec,
                0,
                budget,
            ));
        })?;
        let ifd_index = ifd_index.ok_or_else(|| RasterError::Corrupt {
            path: path.to_path_buf(),
            detail: "no full-resolution image in the file".into(),
        })?;
        let mut tiff = match described {
            Some(tiff) => tiff?,
            None => {
                dec.seek_to_image(ifd_index)
                    .map_err(|e| tiff_err(path, e))?;
                Self::describe(path, (bytes, file_len), store, &mut dec, ifd_index, budget)?
            }
        };
        tiff.budget = budget;
        tiff.overview_list = std::sync::OnceLock::from(list);
        Ok(tiff)
    }

    /// A decoder of `bytes` (of a file of `file_len` bytes) on its first
    /// image, with the limits of `budget`.
    fn decoder<'a>(
        path: &Path,
        bytes: &'a [u8],
        file_len: u64,
        budget: u64,
    ) -> Result<Decoder<Cursor<&'a [u8]>>, RasterError> {
        Ok(Decoder::new(Cursor::new(bytes))
            .map_err(|e| tiff_err(path, e))?
            .with_limits(limits::decoder_limits_within(file_len, budget)))
    }

    /// The whole file's bytes (mapped now where the map was put off).
    fn bytes(&self) -> Result<&[u8], RasterError> {
        self.bytes.data(&self.path)
    }

    /// Sizes of the reduced-resolution images (overviews), in the file's
    /// order.
    pub fn overviews(&self) -> &[(u32, u32)] {
        &self.overview_list().sizes
    }

    /// The overviews, listed by the walk over the file's images on first
    /// use where the open put it off (it found that the walk cannot fail).
    fn overview_list(&self) -> &OverviewList {
        self.overview_list.get_or_init(|| {
            let walked = self.bytes().and_then(|bytes| {
                let mut dec = Self::decoder(&self.path, bytes, bytes.len() as u64, self.budget)?;
                let first = subfile_type(&mut dec, &self.path)?;
                walk_images(&self.path, &mut dec, first, |_| {})
            });
            walked.map(|(_, list)| list).unwrap_or_default()
        })
    }

    /// The image `dec` is on (image `ifd_index` of the file) described as
    /// the DEM; its overviews are left for the caller to list.
    fn describe(
        path: &Path,
        (bytes, file_len): (&[u8], u64),
        store: Arc<Bytes>,
        dec: &mut Decoder<Cursor<&[u8]>>,
        ifd_index: usize,
        budget: u64,
    ) -> Result<GeoTiff, RasterError> {
        let p = path;
        let unsupported = |what: String| RasterError::Unsupported {
            path: p.to_path_buf(),
            what,
        };
        // No tag may claim more values than the file has bytes (a crafted
        // count would otherwise make the decoder reserve gigabytes).
        if let Some(ptr) = dec.ifd_pointer() {
            if let Some((tag, count)) = oversized_entry(bytes, file_len, ptr.0) {
                return Err(RasterError::Corrupt {
                    path: p.to_path_buf(),
                    detail: format!(
                        "tag {tag} claims {count} values, more than the file's {file_len} bytes hold"
                    ),
                });
            }
        }
        let (width, height) = dec.dimensions().map_err(|e| tiff_err(p, e))?;
        let samples = dec
            .find_tag_unsigned::<u16>(Tag::SamplesPerPixel)
            .map_err(|e| tiff_err(p, e))?
            .unwrap_or(1);
        if samples != 1 {
            return Err(unsupported(format!(
                "{samples} samples per pixel (a DEM has one band)"
            )));
        }
        let sample_type = tags::sample_type(dec, p)?;
        let (compression, compression_code) = tags::compression(dec, p)?;
        let predictor = tags::predictor(dec, p, sample_type)?;
        // One sample per pixel: both planar configurations are equal, but
        // the tag must be readable.
        dec.find_tag_unsigned::<u16>(Tag::PlanarConfiguration)
            .map_err(|e| tiff_err(p, e))?;
        let layout = tags::block_layout(dec, p, (width, height), sample_type, budget)?;
        let (offsets, counts) = tags::block_extents(dec, p, (width, height), &layout, file_len)?;
        let (geotransform, raster_type, crs, keys) = tags::georeference(dec, p)?;
        let (nodata, gdal_metadata, vertical) = tags::nodata_and_vertical(dec, p, keys.as_ref())?;
        let codec = BlockCodec {
            compression: compression_code,
            predictor,
            sample_type,
            little_endian: bytes.get(..2) == Some(b"II".as_slice()),
        };
        Ok(GeoTiff {
            path: p.to_path_buf(),
            bytes: store,
            ifd_index,
            width,
            height,
            sample_type,
            layout,
            encoding: Encoding {
                compression,
                predictor,
            },
            geotransform,
            raster_type,
            crs,
            nodata,
            gdal_metadata,
            vertical,
            overview_list: std::sync::OnceLock::new(),
            budget,
            codec,
            offsets,
            counts,
        })
    }

    /// Decode block `index` (row-major over the block grid) into its
    /// samples that lie inside the image (`block_extent`), row-major.
    pub fn decode_block(&self, index: u32) -> Result<DecodingResult, RasterError> {
        let i = index as usize;
        let (Some(&off), Some(&len)) = (self.offsets.get(i), self.counts.get(i)) else {
            return Err(RasterError::Corrupt {
                path: self.path.clone(),
                detail: format!("no block {index}"),
            });
        };
        let (_, _, w, h) = self.block_extent(index);
        let (stored_w, stored_h) = if self.layout.tiled {
            (
                self.layout.block_width as usize,
                self.layout.block_height as usize,
            )
        } else {
            (self.width as usize, h as usize)
        };
        // Offsets and lengths were checked against the file size at open
        // (and a deferred map is of the same file).
        let src = &self.bytes()?[off as usize..(off + len) as usize];
        block_decode::decode_block(&self.codec, src, stored_w, stored_h, w as usize, h as usize)
            .map_err(|e| RasterError::Corrupt {
                path: self.path.clone(),
                detail: format!("block {index}: {e}"),
            })
    }

    /// Pixel rectangle `(col, row, width, height)` covered by block `index`
    /// (clipped to the image). Strips are blocks one strip high and the full
    /// image wide.
    pub fn block_extent(&self, index: u32) -> (u32, u32, u32, u32) {
        let l = &self.layout;
        let bx = index % l.blocks_across;
        let by = index / l.blocks_across;
        let col = bx * l.block_width;
        let row = by * l.block_height;
        (
            col,
            row,
            l.block_width.min(self.width - col),
            l.block_height.min(self.height - row),
        )
    }

    /// The width of a decoded block's rows (tiles are padded only on the
    /// right/bottom edges; the decoder returns the clipped data).
    pub fn decoded_row_len(&self, index: u32) -> usize {
        self.block_extent(index).2 as usize
    }
}

/// NewSubfileType bits: a reduced-resolution image, a transparency mask.
const SUBFILE_REDUCED: u32 = 1;
const SUBFILE_MASK: u32 = 4;

/// A file's reduced-resolution images: their sizes and their images'
/// indices in the file (for [`GeoTiff::overview`]).
#[derive(Debug, Clone, Default)]
struct OverviewList {
    sizes: Vec<(u32, u32)>,
    ifds: Vec<usize>,
}

/// The NewSubfileType of the image `dec` is on (0 where absent).
fn subfile_type(dec: &mut Decoder<Cursor<&[u8]>>, path: &Path) -> Result<u32, RasterError> {
    Ok(dec
        .find_tag_unsigned::<u32>(Tag::NewSubfileType)
        .map_err(|e| tiff_err(path, e))?
        .unwrap_or(0))
}

/// Walk the chain of images from the first (`dec` on it, its
/// NewSubfileType `first`): the first full-resolution, non-mask image is
/// the DEM (its index; `at_dem` is run on the decoder when that is the
/// first image), reduced-resolution images are its overviews. An image
/// the decoder cannot describe (e.g. a JPEG mask) is not the DEM: the walk
/// stops there.
fn walk_images(
    path: &Path,
    dec: &mut Decoder<Cursor<&[u8]>>,
    first: u32,
    mut at_dem: impl FnMut(&mut Decoder<Cursor<&[u8]>>),
) -> Result<(Option<usize>, OverviewList), RasterError> {
    let mut ifd_index = None;
    let mut list = OverviewList::default();
    let mut index = 0usize;
    let mut subfile = first;
    loop {
        if subfile & SUBFILE_MASK == 0 {
            if subfile & SUBFILE_REDUCED != 0 {
                let dims = dec.dimensions().map_err(|e| tiff_err(path, e))?;
                list.sizes.push(dims);
                list.ifds.push(index);
            } else if ifd_index.is_none() {
                ifd_index = Some(index);
                if index == 0 {
                    at_dem(dec);
                }
            }
        }
        if !dec.more_images() {
            break;
        }
        index += 1;
        if dec.next_image().is_err() {
            break;
        }
        subfile = subfile_type(dec, path)?;
    }
    Ok((ifd_index, list))
}

/// The entry of the image file directory at `offset` that claims the most
/// values beyond the file's size, as `(tag, count)` (the lowest such tag):
/// read from the directory's bytes (its entries' counts), without decoding
/// it again. `None` when every count fits, or the directory cannot be read
/// (the decoder, which read it already, says what is wrong then).
fn oversized_entry(bytes: &[u8], file_len: u64, offset: u64) -> Option<(u16, u64)> {
    let little = bytes.get(..2)? == b"II";
    let big = {
        let v = bytes.get(2..4)?;
        (if little { v[0] } else { v[1] }) == 43
    };
    let uint = |at: usize, n: usize| -> Option<u64> {
        let b = bytes.get(at..at.checked_add(n)?)?;
        Some(if little {
            b.iter().rev().fold(0u64, |v, &x| (v << 8) | u64::from(x))
        } else {
            b.iter().fold(0u64, |v, &x| (v << 8) | u64::from(x))
        })
    };
    let at = usize::try_from(offset).ok()?;
    let (entries, first, size, count_at, count_len) = if big {
        (uint(at, 8)?, at + 8, 20, 4, 8)
    } else {
        (uint(at, 2)?, at + 2, 12, 4, 4)
    };
    let mut worst: Option<(u16, u64)> = None;
    for i in 0..usize::try_from(entries).ok()? {
        let e = first.checked_add(i.checked_mul(size)?)?;
        let tag = u16::try_from(uint(e, 2)?).ok()?;
        let count = uint(e + count_at, count_len)?;
        if count > file_len && worst.is_none_or(|(t, _)| tag < t) {
            worst = Some((tag, count));
        }
    }
    worst
}

/// Parse a `GDAL_NODATA` string the way GDAL does ("nan", "-inf", numbers).
pub fn parse_nodata(s: &str) -> Option<f64> {
    let t = s.trim();
    match t.to_ascii_lowercase().as_str() {
        "nan" | "-nan" | "1.#qnan" | "-1.#ind" => Some(f64::NAN),
        "inf" | "+inf" => Some(f64::INFINITY),
        "-inf" => Some(f64::NEG_INFINITY),
        _ => t.parse::<f64>().ok(),
    }
}
