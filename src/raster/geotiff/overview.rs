//! Opening a GeoTIFF's overview (a reduced-resolution image of the same
//! file) as a [`GeoTiff`] of its own: the same bytes and encoding, its own
//! block layout, and the georeference scaled. For reading a DEM coarsely
//! without decoding its full-resolution blocks ([`crate::raster::Dem::overview_layer`]).

use std::io::Cursor;

use tiff::decoder::{ChunkType, Decoder};
use tiff::tags::Tag;

use super::{limits, BlockLayout, GeoTiff};
use crate::raster::GeoTransform;

impl GeoTiff {
    /// The overview exactly `k` times coarser than the image (its size
    /// `ceil(width / k) x ceil(height / k)`), opened: `None` where the file
    /// has none, or it is not encoded as the image is (compression,
    /// predictor, sample type) or lists blocks outside the file.
    pub fn overview(&self, k: u32) -> Option<GeoTiff> {
        if k < 2 {
            return None;
        }
        let want = (self.width.div_ceil(k), self.height.div_ceil(k));
        let list = self.overview_list();
        let at = list.sizes.iter().position(|&d| d == want)?;
        let index = *list.ifds.get(at)?;
        let bytes = self.bytes().ok()?;
        let mut dec =
            Decoder::new(Cursor::new(bytes))
                .ok()?
                .with_limits(limits::decoder_limits_within(
                    bytes.len() as u64,
                    limits::memory_budget(),
                ));
        dec.seek_to_image(index).ok()?;
        // Its own compression and predictor (GDAL may encode overviews
        // otherwise), among those the decoder reads.
        let compression = dec
            .find_tag_unsigned::<u16>(Tag::Compression)
            .ok()?
            .unwrap_or(1);
        let predictor = dec
            .find_tag_unsigned::<u16>(Tag::Predictor)
            .ok()?
            .unwrap_or(1);
        let float = !self.sample_type.is_integer();
        if !matches!(compression, 1 | 5 | 8 | 32946 | 32773 | 50000)
            || !matches!((predictor, float), (1, _) | (2, _) | (3, true))
        {
            return None;
        }
        if dec.dimensions().ok()? != want
            || dec
                .find_tag_unsigned_vec::<u16>(Tag::BitsPerSample)
                .ok()?
                .and_then(|v| v.first().copied())
                .unwrap_or(1) as usize
                != 8 * self.sample_type.bytes()
        {
            return None;
        }
        let tiled = matches!(dec.get_chunk_type(), ChunkType::Tile);
        let (bw, bh) = dec.chunk_dimensions();
        if bw == 0 || bh == 0 {
            return None;
        }
        let layout = BlockLayout {
            tiled,
            block_width: bw,
            block_height: bh,
            blocks_across: want.0.div_ceil(bw),
            blocks_down: want.1.div_ceil(bh),
        };
        let (offsets_tag, counts_tag) = if tiled {
            (Tag::TileOffsets, Tag::TileByteCounts)
        } else {
            (Tag::StripOffsets, Tag::StripByteCounts)
        };
        let offsets = dec.get_tag_u64_vec(offsets_tag).ok()?;
        let counts = dec.get_tag_u64_vec(counts_tag).ok()?;
        let n = usize::try_from(layout.count()).ok()?;
        if offsets.len() < n || counts.len() < n {
            return None;
        }
        let file_len = bytes.len() as u64;
        let inside = offsets
            .iter()
            .zip(&counts)
            .take(n)
            .all(|(&o, &c)| o.checked_add(c).is_some_and(|end| end <= file_len));
        if !inside {
            return None;
        }
        let g = self.geotransform.0;
        let (sx, sy) = (
            self.width as f64 / want.0 as f64,
            self.height as f64 / want.1 as f64,
        );
        let mut ov = self.clone();
        ov.codec.compression = compression;
        ov.codec.predictor = predictor;
        ov.encoding.predictor = predictor;
        ov.width = want.0;
        ov.height = want.1;
        ov.layout = layout;
        ov.offsets = offsets[..n].to_vec();
        ov.counts = counts[..n].to_vec();
        ov.geotransform = GeoTransform([g[0], g[1] * sx, g[2] * sy, g[3], g[4] * sx, g[5] * sy]);
        ov.overview_list = std::sync::OnceLock::from(super::OverviewList::default());
        Some(ov)
    }
}
