//! The tags of one image file directory, read into what a DEM needs: the
//! sample type, the encoding (compression, predictor), the block layout
//! and every block's place in the file, the georeference (geotransform,
//! raster type, CRS), the nodata value and the vertical unit and datum.
//! Each function reads one of these and says precisely what is missing,
//! unsupported or corrupt; [`super::GeoTiff`]'s `describe` puts them
//! together.

use std::io::Cursor;
use std::path::Path;

use tiff::decoder::{ChunkType, Decoder};
use tiff::tags::{CompressionMethod, SampleFormat, Tag};

use super::geokeys::{GeoKeys, RasterType};
use super::{parse_nodata, tiff_err, BlockLayout, TAG_GDAL_METADATA, TAG_GDAL_NODATA};
use crate::raster::{Crs, GeoTransform, RasterError, SampleType, Vertical};

/// The decoder over a file's bytes, positioned on one image.
pub(super) type Dec<'a> = Decoder<Cursor<&'a [u8]>>;

fn unsupported(p: &Path, what: String) -> RasterError {
    RasterError::Unsupported {
        path: p.to_path_buf(),
        what,
    }
}

/// The sample type from BitsPerSample and SampleFormat.
pub(super) fn sample_type(dec: &mut Dec, p: &Path) -> Result<SampleType, RasterError> {
    let unsupported = |what: String| unsupported(p, what);
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
    Ok(sample_type)
}

/// The compression, by GDAL's name, and its TIFF code. Compressions the
/// native decoder does not read are [`RasterError::NotNative`] (GDAL reads
/// them).
pub(super) fn compression(dec: &mut Dec, p: &Path) -> Result<(&'static str, u16), RasterError> {
    let code = dec
        .find_tag_unsigned::<u16>(Tag::Compression)
        .map_err(|e| tiff_err(p, e))?
        .unwrap_or(1);
    let name = match code {
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
    Ok((name, code))
}

/// The predictor, refused where it does not suit the sample type.
pub(super) fn predictor(
    dec: &mut Dec,
    p: &Path,
    sample_type: SampleType,
) -> Result<u16, RasterError> {
    let unsupported = |what: String| unsupported(p, what);
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
    Ok(predictor)
}

/// How the image is cut into blocks, refused when one block alone would
/// exceed the memory `budget`.
pub(super) fn block_layout(
    dec: &mut Dec,
    p: &Path,
    (width, height): (u32, u32),
    sample_type: SampleType,
    budget: u64,
) -> Result<BlockLayout, RasterError> {
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
    Ok(layout)
}

/// Every block's offset and byte count, checked to lie inside the file:
/// a truncated file is caught at open, not half-way through a read.
pub(super) fn block_extents(
    dec: &mut Dec,
    p: &Path,
    (width, height): (u32, u32),
    layout: &BlockLayout,
    file_len: u64,
) -> Result<(Vec<u64>, Vec<u64>), RasterError> {
    let tiled = layout.tiled;
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

    Ok((offsets[..expected].to_vec(), counts[..expected].to_vec()))
}

/// The georeference as GDAL reads it: ModelTransformation, or
/// ModelTiepoint with ModelPixelScale, PixelIsPoint shifted by half a
/// pixel; the GeoKeys (kept for the vertical datum), raster type and CRS.
pub(super) fn georeference(
    dec: &mut Dec,
    p: &Path,
) -> Result<(GeoTransform, RasterType, Crs, Option<GeoKeys>), RasterError> {
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
    let scale = f64s(dec, 33550)?;
    let tiepoint = f64s(dec, 33922)?;
    let transform = f64s(dec, 34264)?;
    let keys = match dec
        .find_tag(Tag::GeoKeyDirectoryTag)
        .map_err(|e| tiff_err(p, e))?
    {
        None => None,
        Some(v) => {
            let dir: Vec<u16> = v.into_u16_vec().map_err(|e| tiff_err(p, e))?;
            let doubles = f64s(dec, 34736)?.unwrap_or_default();
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
    Ok((gt, raster_type, crs, keys))
}

/// The nodata value, the GDAL_METADATA text and the vertical unit, scale,
/// offset and datum (from GDAL_METADATA and the vertical GeoKeys).
pub(super) fn nodata_and_vertical(
    dec: &mut Dec,
    p: &Path,
    keys: Option<&GeoKeys>,
) -> Result<(Option<f64>, Option<String>, Vertical), RasterError> {
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
    let gdal_metadata = ascii_tag(dec, TAG_GDAL_METADATA, "GDAL_METADATA")?;
    let (scale, offset, unit) = gdal_metadata
        .as_deref()
        .map(crate::raster::vertical::from_gdal_metadata)
        .unwrap_or_default();
    let vertical = Vertical::of_file(p, scale, offset, &unit, keys.and_then(|k| k.vertical()))?;
    Ok((nodata, gdal_metadata, vertical))
}
