//! Native GeoTIFF decoding on the `tiff` crate: the header and image file
//! directories are parsed once at open; blocks (strips or tiles) are decoded
//! on demand, in parallel, from a memory map, each worker with its own
//! `tiff::Decoder` over the shared bytes. Georeferencing follows GDAL:
//! ModelTiepoint + ModelPixelScale or ModelTransformation, PixelIsPoint
//! shifted by half a pixel, `GDAL_NODATA` and `GDAL_METADATA` kept.
//! Reduced-resolution IFDs (overviews) are listed, and opened on demand
//! ([`GeoTiff::overview`]); masks are recognised and skipped.

mod block_decode;
pub mod fuzz;
mod geokeys;
mod limits;
mod overview;

pub use limits::{decoder_limits, max_decompressed, memory_budget};

use block_decode::BlockCodec;

pub use geokeys::{GeoKeys, RasterType};

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use memmap2::Mmap;
use tiff::decoder::{ChunkType, Decoder, DecodingResult};
use tiff::tags::{CompressionMethod, SampleFormat, Tag};

use super::{Crs, GeoTransform, RasterError, SampleType, Vertical};

const TAG_GDAL_METADATA: u16 = 42112;
const TAG_GDAL_NODATA: u16 = 42113;

/// Files up to this size are read into memory at open rather than mapped.
const SMALL_FILE: u64 = 64 << 10;

/// Bytes read before a file's size is asked for (see
/// [`GeoTiff::open_with_budget`]).
const FIRST_READ: usize = 8 << 10;

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
    /// Sizes of the reduced-resolution images (overviews).
    pub overviews: Vec<(u32, u32)>,
    /// Their images' indices in the file (for [`GeoTiff::overview`]).
    overview_ifds: Vec<usize>,
    codec: BlockCodec,
    offsets: Vec<u64>,
    counts: Vec<u64>,
}

/// The bytes of a GeoTIFF: a read-only map of the file, or a buffer.
#[derive(Debug)]
enum Bytes {
    Map(Mmap),
    Owned(Vec<u8>),
}

impl std::ops::Deref for Bytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Map(m) => m,
            Bytes::Owned(v) => v,
        }
    }
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
        let small = HEAD.with(|head| -> std::io::Result<Option<Vec<u8>>> {
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
                    let len = file.metadata()?.len();
                    if len > SMALL_FILE {
                        return Ok(None);
                    }
                    want = head.len();
                }
            }
            Ok((got <= SMALL_FILE as usize).then(|| head[..got].to_vec()))
        });
        if let Some(data) = small.map_err(|e| RasterError::io(path, e))? {
            return Self::parse(path, Arc::new(Bytes::Owned(data)), budget);
        }
        // SAFETY: the map is read-only; a file truncated by another process
        // while mapped is outside what any GIS reader can guard against.
        let map = unsafe { Mmap::map(&file) }.map_err(|e| RasterError::io(path, e))?;
        Self::parse(path, Arc::new(Bytes::Map(map)), budget)
    }

    /// Parse a GeoTIFF held in memory (`label` names it in errors): what
    /// the fuzz harness runs on.
    pub fn from_bytes(label: &Path, data: Vec<u8>) -> Result<GeoTiff, RasterError> {
        Self::parse(label, Arc::new(Bytes::Owned(data)), memory_budget())
    }

    fn parse(path: &Path, bytes: Arc<Bytes>, budget: u64) -> Result<GeoTiff, RasterError> {
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
        let mut dec = Decoder::new(Cursor::new(&bytes[..]))
            .map_err(|e| tiff_err(path, e))?
            .with_limits(limits::decoder_limits_within(bytes.len() as u64, budget));

        // Walk the IFD chain: the first full-resolution, non-mask image is
        // the DEM; reduced-resolution images are its overviews.
        let mut ifd_index = None;
        let mut overviews = Vec::new();
        let mut overview_ifds = Vec::new();
        let mut index = 0usize;
        loop {
            let subfile = dec
                .find_tag_unsigned::<u32>(Tag::NewSubfileType)
                .map_err(|e| tiff_err(path, e))?
                .unwrap_or(0);
            let is_mask = subfile & 4 != 0;
            let reduced = subfile & 1 != 0;
            if !is_mask {
                if reduced {
                    let dims = dec.dimensions().map_err(|e| tiff_err(path, e))?;
                    overviews.push(dims);
                    overview_ifds.push(index);
                } else if ifd_index.is_none() {
                    ifd_index = Some(index);
                }
            }
            if !dec.more_images() {
                break;
            }
            index += 1;
            if dec.next_image().is_err() {
                // An IFD the decoder cannot describe (e.g. a JPEG mask) is not
                // the DEM; stop the walk there.
                break;
            }
        }
        let ifd_index = ifd_index.ok_or_else(|| RasterError::Corrupt {
            path: path.to_path_buf(),
            detail: "no full-resolution image in the file".into(),
        })?;
        dec.seek_to_image(ifd_index)
            .map_err(|e| tiff_err(path, e))?;
        let mut tiff = Self::describe(path, bytes.clone(), dec, ifd_index, overviews, budget)?;
        tiff.overview_ifds = overview_ifds;
        Ok(tiff)
    }

    fn describe(
        path: &Path,
        bytes: Arc<Bytes>,
        mut dec: Decoder<Cursor<&[u8]>>,
        ifd_index: usize,
        overviews: Vec<(u32, u32)>,
        budget: u64,
    ) -> Result<GeoTiff, RasterError> {
        let p = path;
        let unsupported = |what: String| RasterError::Unsupported {
            path: p.to_path_buf(),
            what,
        };
        // No tag may claim more values than the file has bytes (a crafted
        // count would otherwise make the decoder reserve gigabytes).
        let file_len = bytes.len() as u64;
        if let Some(ptr) = dec.ifd_pointer() {
            if let Some((tag, count)) = oversized_entry(&bytes, ptr.0) {
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
        let bits = dec
            .find_tag_unsigned_vec::<u16>(Tag::BitsPerSample)
            .map_err(|e| tiff_err(p, e))?
            .and_then(|v| v.first().copied())
            .unwrap_or(1);
        let format = dec
            .find_tag_unsigned_vec::<u16>(Tag::SampleFormat)
            .map_err(|e| tiff_err(p, e))?
            .and_then(|v| v.first().copied())
            .map(SampleFormat::from_u16_exhaustive)
            .unwrap_or(SampleFormat::Uint);
        let sample_type = match (format, bits) {
            (SampleFormat::Uint, 8) => SampleType::UInt8,
            (SampleFormat::Int, 8) => SampleType::Int8,
            (SampleFormat::Uint, 16) => SampleType::UInt16,
            (SampleFormat::Int, 16) => SampleType::Int16,
            (SampleFormat::Uint, 32) => SampleType::UInt32,
            (SampleFormat::Int, 32) => SampleType::Int32,
            (SampleFormat::IEEEFP, 32) => SampleType::Float32,
            (SampleFormat::IEEEFP, 64) => SampleType::Float64,
            (f, b) => {
                let kind = match f {
                    SampleFormat::Uint => "unsigned integer".to_string(),
                    SampleFormat::Int => "signed integer".to_string(),
                    SampleFormat::IEEEFP => "floating point".to_string(),
                    SampleFormat::Void => "untyped".to_string(),
                    _ => format!("SampleFormat {}", f.to_u16()),
                };
                return Err(unsupported(format!("sample type {b}-bit {kind}")));
            }
        };
        let compression = match dec
            .find_tag_unsigned::<u16>(Tag::Compression)
            .map_err(|e| tiff_err(p, e))?
            .unwrap_or(1)
        {
            1 => "NONE",
            5 => "LZW",
            8 | 32946 => "DEFLATE",
            32773 => "PACKBITS",
            50000 => "ZSTD",
            c => {
                let name = match c {
                    6 => "old-style JPEG".to_string(),
                    7 => "JPEG".to_string(),
                    34712 => "JPEG 2000".to_string(),
                    34887 => "LERC".to_string(),
                    34925 => "LZMA".to_string(),
                    50001 => "WEBP".to_string(),
                    50002 => "JPEG XL".to_string(),
                    _ => match CompressionMethod::from_u16_exhaustive(c) {
                        CompressionMethod::Unknown(_) => format!("code {c}"),
                        m => format!("{m:?}"),
                    },
                };
                return Err(RasterError::NotNative {
                    path: p.to_path_buf(),
                    what: format!("compression {name}"),
                });
            }
        };
        let predictor = dec
            .find_tag_unsigned::<u16>(Tag::Predictor)
            .map_err(|e| tiff_err(p, e))?
            .unwrap_or(1);
        match (predictor, sample_type.is_integer()) {
            (1, _) | (2, true) | (3, false) => {}
            (2, false) => {} // horizontal differencing of floats is legal, if rare
            (pr, _) => {
                let name = match pr {
                    2 => " (horizontal differencing)",
                    3 => " (floating point)",
                    _ => "",
                };
                return Err(unsupported(format!(
                    "predictor {pr}{name} for {sample_type}"
                )));
            }
        }
        let planar = dec
            .find_tag_unsigned::<u16>(Tag::PlanarConfiguration)
            .map_err(|e| tiff_err(p, e))?
            .unwrap_or(1);
        let _ = planar; // one sample per pixel: both configurations are equal

        let tiled = matches!(dec.get_chunk_type(), ChunkType::Tile);
        let (bw, bh) = dec.chunk_dimensions();
        if bw == 0 || bh == 0 {
            return Err(RasterError::Corrupt {
                path: p.to_path_buf(),
                detail: "zero block size".into(),
            });
        }
        let layout = BlockLayout {
            tiled,
            block_width: bw,
            block_height: bh,
            blocks_across: width.div_ceil(bw),
            blocks_down: height.div_ceil(bh),
        };
        let block_bytes = bw as u64 * bh as u64 * sample_type.bytes() as u64;
        if block_bytes > budget {
            return Err(RasterError::TooLarge {
                path: p.to_path_buf(),
                width: width as u64,
                height: height as u64,
                sample: sample_type.to_string(),
                bytes: block_bytes,
                budget,
            });
        }
        // Every block must lie inside the file: a truncated file is caught
        // here, at open, not half-way through a read.
        let (offsets_tag, counts_tag) = if tiled {
            (Tag::TileOffsets, Tag::TileByteCounts)
        } else {
            (Tag::StripOffsets, Tag::StripByteCounts)
        };
        let offsets = dec
            .get_tag_u64_vec(offsets_tag)
            .map_err(|e| tiff_err(p, e))?;
        let counts = dec
            .get_tag_u64_vec(counts_tag)
            .map_err(|e| tiff_err(p, e))?;
        let listed = offsets.len().min(counts.len());
        if layout.count() > listed as u64 {
            return Err(RasterError::Corrupt {
                path: p.to_path_buf(),
                detail: format!(
                    "{} x {} pixels need {} blocks but the file lists {listed}",
                    width,
                    height,
                    layout.count()
                ),
            });
        }
        let expected = layout.count() as usize;
        if offsets.len() < expected || counts.len() < expected {
            return Err(RasterError::Corrupt {
                path: p.to_path_buf(),
                detail: format!(
                    "{} x {} pixels need {expected} blocks but the file lists {}",
                    width,
                    height,
                    offsets.len().min(counts.len())
                ),
            });
        }
        for (i, (&o, &c)) in offsets.iter().zip(&counts).enumerate().take(expected) {
            if o.checked_add(c).is_none_or(|end| end > file_len) {
                return Err(RasterError::Corrupt {
                    path: p.to_path_buf(),
                    detail: format!(
                        "block {i} ends at byte {} past the end of the file ({file_len} bytes)",
                        o.saturating_add(c)
                    ),
                });
            }
        }

        // Georeference.
        let f64s =
            |dec: &mut Decoder<Cursor<&[u8]>>, tag: u16| -> Result<Option<Vec<f64>>, RasterError> {
                match dec
                    .find_tag(Tag::Unknown(tag))
                    .map_err(|e| tiff_err(p, e))?
                {
                    None => Ok(None),
                    Some(v) => v.into_f64_vec().map(Some).map_err(|e| tiff_err(p, e)),
                }
            };
        let scale = f64s(&mut dec, 33550)?;
        let tiepoint = f64s(&mut dec, 33922)?;
        let transform = f64s(&mut dec, 34264)?;
        let keys = match dec
            .find_tag(Tag::GeoKeyDirectoryTag)
            .map_err(|e| tiff_err(p, e))?
        {
            None => None,
            Some(v) => {
                let dir: Vec<u16> = v.into_u16_vec().map_err(|e| tiff_err(p, e))?;
                let doubles = f64s(&mut dec, 34736)?.unwrap_or_default();
                let ascii = match dec
                    .find_tag(Tag::GeoAsciiParamsTag)
                    .map_err(|e| tiff_err(p, e))?
                {
                    Some(v) => v.into_string().unwrap_or_default(),
                    None => String::new(),
                };
                Some(GeoKeys::parse(p, &dir, &doubles, &ascii)?)
            }
        };
        let raster_type = keys
            .as_ref()
            .map(|k| k.raster_type())
            .unwrap_or(RasterType::PixelIsArea);
        let mut gt = match (&transform, &scale, &tiepoint) {
            (Some(m), _, _) if m.len() >= 16 => GeoTransform([m[3], m[0], m[1], m[7], m[4], m[5]]),
            (_, Some(s), Some(t)) if s.len() >= 2 && t.len() >= 6 => GeoTransform([
                t[3] - t[0] * s[0],
                s[0],
                0.0,
                t[4] + t[1] * s[1],
                0.0,
                -s[1],
            ]),
            _ => {
                return Err(RasterError::NoGeoreference {
                    path: p.to_path_buf(),
                })
            }
        };
        if raster_type == RasterType::PixelIsPoint {
            // GDAL's default (GTIFF_POINT_GEO_IGNORE=FALSE): the tiepoint is
            // the centre of the pixel, so the corner is half a pixel off.
            let g = gt.0;
            gt = GeoTransform([
                g[0] - 0.5 * g[1] - 0.5 * g[2],
                g[1],
                g[2],
                g[3] - 0.5 * g[4] - 0.5 * g[5],
                g[4],
                g[5],
            ]);
        }
        if gt.0.iter().any(|v| !v.is_finite()) || gt.crs_to_pixel(0.0, 0.0).is_none() {
            return Err(RasterError::Corrupt {
                path: p.to_path_buf(),
                detail: format!("degenerate geotransform {:?}", gt.0),
            });
        }
        let crs = match &keys {
            Some(k) => k.crs(p)?,
            None => Crs {
                epsg: None,
                wkt: String::new(),
                proj: None,
                geographic: false,
            },
        };
        // A GDAL tag that is there but cannot be read is an error: silently
        // dropping it would lose the nodata value or the heights' scale.
        let ascii_tag = |dec: &mut Decoder<Cursor<&[u8]>>,
                         tag: u16,
                         name: &str|
         -> Result<Option<String>, RasterError> {
            let unreadable = |e: String| RasterError::Corrupt {
                path: p.to_path_buf(),
                detail: format!("{name} tag cannot be read ({e})"),
            };
            match dec
                .find_tag(Tag::Unknown(tag))
                .map_err(|e| unreadable(e.to_string()))?
            {
                None => Ok(None),
                Some(v) => v
                    .into_string()
                    .map(|s| Some(s.trim_end_matches('\0').to_string()))
                    .map_err(|e| unreadable(e.to_string())),
            }
        };
        // A GDAL_NODATA tag that is there but unreadable (not text, not a
        // number) is an error, never "no nodata": its cells would be read
        // as heights.
        let corrupt = |detail: String| RasterError::Corrupt {
            path: p.to_path_buf(),
            detail,
        };
        let nodata = match dec.find_tag(Tag::Unknown(TAG_GDAL_NODATA)) {
            Ok(None) => None,
            Ok(Some(v)) => {
                let s = v
                    .into_string()
                    .map_err(|_| corrupt("the GDAL_NODATA tag is not text".into()))?;
                let s = s.trim_end_matches('\0');
                Some(parse_nodata(s).ok_or_else(|| {
                    corrupt(format!(
                        "GDAL_NODATA '{}' is not a number",
                        s.escape_debug()
                    ))
                })?)
            }
            Err(e) => return Err(corrupt(format!("the GDAL_NODATA tag is unreadable: {e}"))),
        };
        let gdal_metadata = ascii_tag(&mut dec, TAG_GDAL_METADATA, "GDAL_METADATA")?;
        let (scale, offset, unit) = gdal_metadata
            .as_deref()
            .map(super::vertical::from_gdal_metadata)
            .unwrap_or_default();
        let (datum, crs_unit) = match keys.as_ref().and_then(|k| k.vertical()) {
            Some((name, unit)) => (Some(name), unit),
            None => (None, None),
        };
        let vertical =
            Vertical::from_parts(scale, offset, &unit, crs_unit, datum).map_err(|message| {
                RasterError::Crs {
                    path: p.to_path_buf(),
                    message,
                }
            })?;
        let codec = BlockCodec {
            compression: dec
                .find_tag_unsigned::<u16>(Tag::Compression)
                .map_err(|e| tiff_err(p, e))?
                .unwrap_or(1),
            predictor,
            sample_type,
            little_endian: bytes.get(..2) == Some(b"II".as_slice()),
        };

        Ok(GeoTiff {
            path: p.to_path_buf(),
            bytes,
            ifd_index,
            width,
            height,
            sample_type,
            layout,
            encoding: Encoding {
                compression,
                predictor,
            },
            geotransform: gt,
            raster_type,
            crs,
            nodata,
            gdal_metadata,
            vertical,
            overviews,
            overview_ifds: Vec::new(),
            codec,
            offsets: offsets[..expected].to_vec(),
            counts: counts[..expected].to_vec(),
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
        // Offsets and lengths were checked against the file size at open.
        let src = &self.bytes[off as usize..(off + len) as usize];
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

/// The entry of the image file directory at `offset` that claims the most
/// values beyond the file's size, as `(tag, count)` (the lowest such tag):
/// read from the directory's bytes (its entries' counts), without decoding
/// it again. `None` when every count fits, or the directory cannot be read
/// (the decoder, which read it already, says what is wrong then).
fn oversized_entry(bytes: &[u8], offset: u64) -> Option<(u16, u64)> {
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
    let file_len = bytes.len() as u64;
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
