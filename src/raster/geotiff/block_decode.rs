//! Decoding one block (strip or tile) of a GeoTIFF straight from the file's
//! bytes: decompression (none, LZW, Deflate, PackBits, ZSTD), the TIFF
//! predictors (horizontal differencing, floating-point byte shuffling) and
//! byte order. The `tiff` crate parses the directories; this module does the
//! per-block work itself so that it can run on many blocks at once without
//! a decoder per thread, and with predictor loops that compile to tight code
//! (the floating-point predictor dominates reading of Copernicus-style
//! DEMs).

use tiff::decoder::DecodingResult;

use super::super::SampleType;

/// Why a block could not be decoded.
#[derive(Debug)]
pub enum BlockError {
    Decompress(String),
    Short { expected: usize, got: usize },
}

impl std::fmt::Display for BlockError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BlockError::Decompress(e) => write!(f, "decompression failed: {e}"),
            BlockError::Short { expected, got } => {
                write!(f, "decompresses to {got} bytes, {expected} expected")
            }
        }
    }
}

/// How blocks of one image are encoded.
#[derive(Debug, Clone, Copy)]
pub struct BlockCodec {
    pub compression: u16,
    pub predictor: u16,
    pub sample_type: SampleType,
    pub little_endian: bool,
}

/// Room for `n` more bytes in `v`, or an error (never an abort).
fn reserve(v: &mut Vec<u8>, n: usize) -> Result<(), BlockError> {
    v.try_reserve(n)
        .map_err(|_| BlockError::Decompress(format!("cannot allocate {n} bytes")))
}

/// A zlib stream `src` that inflates to exactly `expected` bytes, inflated
/// in one call; `None` for any other stream (longer, shorter or damaged)
/// or where the buffer cannot be had (the streaming inflate then decides).
fn inflate_whole(src: &[u8], expected: usize) -> Option<Vec<u8>> {
    let mut out = scratch(expected)?;
    let mut d = libdeflater::Decompressor::new();
    match d.zlib_decompress(src, &mut out) {
        Ok(n) if n == expected => Some(out),
        _ => None,
    }
}

thread_local! {
    /// The bytes of the last block this thread decoded, kept for the next
    /// one ([`scratch`], [`recycle`]): a block's bytes are read once, into
    /// its samples, and a buffer taken again needs no zeroing (a fresh one
    /// is zeroed, and its pages mapped, for every block).
    static SCRATCH: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The largest buffer [`recycle`] keeps (bytes).
const SCRATCH_MAX: usize = 1 << 24;

/// A buffer of `expected` bytes for a decompression to overwrite whole:
/// this thread's kept one where there is one (its old bytes left in place,
/// only growth zeroed), else a new zeroed one. `None`: no memory.
fn scratch(expected: usize) -> Option<Vec<u8>> {
    let mut out = SCRATCH.with(|s| std::mem::take(&mut *s.borrow_mut()));
    if out.len() >= expected {
        out.truncate(expected);
    } else {
        out.try_reserve_exact(expected - out.len()).ok()?;
        out.resize(expected, 0);
    }
    Some(out)
}

/// Keep `bytes` (a block's bytes, read) for this thread's next
/// [`scratch`], unless a larger one is kept or it is over [`SCRATCH_MAX`].
fn recycle(bytes: Vec<u8>) {
    if bytes.capacity() <= SCRATCH_MAX {
        SCRATCH.with(|s| {
            let mut s = s.borrow_mut();
            if s.capacity() < bytes.capacity() {
                *s = bytes;
            }
        });
    }
}

/// Decompress `src` into exactly `expected` bytes (longer output is cut,
/// shorter output is an error). Output buffers grow with the data that
/// actually arrives (starting from a small multiple of the input), so a
/// block that claims a huge size but holds little costs little memory.
fn decompress(compression: u16, src: &[u8], expected: usize) -> Result<Vec<u8>, BlockError> {
    let initial = expected.min(src.len().saturating_mul(8).saturating_add(4096));
    let mut out = Vec::new();
    reserve(&mut out, initial)?;
    match compression {
        1 => out.extend_from_slice(&src[..src.len().min(expected)]),
        5 => {
            let mut dec = weezl::decode::Decoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8);
            let mut buf = [0u8; 1 << 14];
            let mut input = src;
            // Truncated LZW streams without an end code are common and GDAL
            // accepts them when the data is complete.
            while out.len() < expected {
                let r = dec.decode_bytes(input, &mut buf);
                input = &input[r.consumed_in..];
                let n = r.consumed_out.min(expected - out.len());
                reserve(&mut out, n)?;
                out.extend_from_slice(&buf[..n]);
                match r.status {
                    Ok(weezl::LzwStatus::Ok) if r.consumed_in > 0 || r.consumed_out > 0 => {}
                    Ok(_) => break,
                    Err(e) => {
                        if out.len() < expected {
                            return Err(BlockError::Decompress(format!("LZW: {e}")));
                        }
                        break;
                    }
                }
            }
        }
        8 | 32946 => {
            // A whole block in one call (libdeflate, about twice as fast as
            // a streaming inflate) where the stream holds exactly the
            // block; anything else (a longer or short stream, a damaged
            // one) streams as below, which cuts or refuses it.
            if let Some(whole) = inflate_whole(src, expected) {
                return Ok(whole);
            }
            let mut d = flate2::Decompress::new(true);
            loop {
                if out.len() == out.capacity() {
                    let more = out.capacity().max(4096).min(expected - out.len());
                    reserve(&mut out, more)?;
                }
                let before = (d.total_in(), d.total_out());
                let status = d
                    .decompress_vec(
                        &src[d.total_in() as usize..],
                        &mut out,
                        flate2::FlushDecompress::Finish,
                    )
                    .map_err(|e| BlockError::Decompress(format!("Deflate: {e}")))?;
                let progressed = (d.total_in(), d.total_out()) != before;
                if status == flate2::Status::StreamEnd || out.len() >= expected || !progressed {
                    break;
                }
            }
        }
        50000 => {
            use std::io::Read;
            let dec = zstd::stream::read::Decoder::with_buffer(src)
                .map_err(|e| BlockError::Decompress(format!("ZSTD: {e}")))?;
            let mut chunk = [0u8; 1 << 16];
            let mut dec = dec.take(expected as u64);
            loop {
                let n = dec
                    .read(&mut chunk)
                    .map_err(|e| BlockError::Decompress(format!("ZSTD: {e}")))?;
                if n == 0 {
                    break;
                }
                reserve(&mut out, n)?;
                out.extend_from_slice(&chunk[..n]);
            }
        }
        32773 => {
            let mut i = 0;
            while i < src.len() && out.len() < expected {
                let n = src[i] as i8;
                i += 1;
                if n >= 0 {
                    let len = n as usize + 1;
                    let end = (i + len).min(src.len());
                    reserve(&mut out, end - i)?;
                    out.extend_from_slice(&src[i..end]);
                    i = end;
                } else if n != -128 {
                    let len = (-(n as isize)) as usize + 1;
                    if let Some(&b) = src.get(i) {
                        reserve(&mut out, len)?;
                        out.extend(std::iter::repeat_n(b, len));
                    }
                    i += 1;
                }
            }
        }
        c => return Err(BlockError::Decompress(format!("compression {c}"))),
    }
    if out.len() < expected {
        return Err(BlockError::Short {
            expected,
            got: out.len(),
        });
    }
    out.truncate(expected);
    Ok(out)
}

/// The `w` x `h` `f32` samples of a block of `stored_w`-sample rows stored
/// with the floating-point predictor, on a little-endian machine: each of
/// the first `h` rows undone as [`undo_float_predictor_row`] does and its
/// first `w` samples gathered straight into the samples (the same bits as
/// undoing every row into bytes and reading them as `f32`, without the
/// intermediate bytes, their second pass and the padding rows).
fn float32_predicted(
    bytes: &mut [u8],
    stored_w: usize,
    w: usize,
    h: usize,
) -> Result<Vec<f32>, BlockError> {
    let mut v: Vec<f32> = Vec::new();
    v.try_reserve_exact(w * h)
        .map_err(|_| BlockError::Decompress(format!("cannot allocate {} samples", w * h)))?;
    for row in bytes.chunks_exact_mut(stored_w * 4).take(h) {
        prefix_sum_bytes(row);
        let (p0, rest) = row.split_at(stored_w);
        let (p1, rest) = rest.split_at(stored_w);
        let (p2, p3) = rest.split_at(stored_w);
        gather_be_planes(&mut v, [&p0[..w], &p1[..w], &p2[..w], &p3[..w]]);
    }
    Ok(v)
}

/// The running wrapping sums of `row`'s bytes, in place (`row[i]` becomes
/// `row[0] + ... + row[i]`, modulo 256): the predictor's differencing
/// undone. Sixteen bytes at a time with SSE2 (part of every x86-64 CPU):
/// the same sums, since wrapping addition is associative.
fn prefix_sum_bytes(row: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    let (acc, rest) = {
        let split = row.len() - row.len() % 16;
        let (whole, rest) = row.split_at_mut(split);
        // SAFETY: SSE2 is in the x86-64 baseline.
        (unsafe { prefix_sum_bytes_sse2(whole) }, rest)
    };
    #[cfg(not(target_arch = "x86_64"))]
    let (acc, rest) = (0u8, row);
    let mut acc = acc;
    for b in rest.iter_mut() {
        acc = acc.wrapping_add(*b);
        *b = acc;
    }
}

/// [`prefix_sum_bytes`] over `row` (a whole number of 16-byte lanes),
/// returning the last sum: in each lane the sums by four shifted adds
/// (1, 2, 4 and 8 bytes), then the lane before's last sum added to every
/// byte.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
unsafe fn prefix_sum_bytes_sse2(row: &mut [u8]) -> u8 {
    use std::arch::x86_64::*;
    let mut carry = _mm_setzero_si128();
    for lane in row.chunks_exact_mut(16) {
        let p = lane.as_mut_ptr() as *mut __m128i;
        let mut x = _mm_loadu_si128(p);
        x = _mm_add_epi8(x, _mm_slli_si128::<1>(x));
        x = _mm_add_epi8(x, _mm_slli_si128::<2>(x));
        x = _mm_add_epi8(x, _mm_slli_si128::<4>(x));
        x = _mm_add_epi8(x, _mm_slli_si128::<8>(x));
        x = _mm_add_epi8(x, carry);
        _mm_storeu_si128(p, x);
        // the lane's last byte in every byte
        let t = _mm_srli_si128::<15>(x);
        let t = _mm_unpacklo_epi8(t, t);
        let t = _mm_unpacklo_epi16(t, t);
        carry = _mm_shuffle_epi32::<0>(t);
    }
    _mm_cvtsi128_si32(carry) as u8
}

/// Append to `v` the samples whose big-endian bytes are `planes` (most
/// significant first, all of one length): sample `i` has the bits
/// `planes[0][i] << 24 | ... | planes[3][i]`. Sixteen samples at a time
/// by SSE2 byte interleaving on x86-64.
fn gather_be_planes(v: &mut Vec<f32>, planes: [&[u8]; 4]) {
    let n = planes[0].len();
    debug_assert!(planes.iter().all(|p| p.len() == n));
    #[cfg(target_arch = "x86_64")]
    let done = {
        let whole = n - n % 16;
        v.reserve(n);
        // SAFETY: SSE2 is in the x86-64 baseline; `v` has room for `n`
        // more samples, of which the first `whole` are written before
        // the length takes them.
        unsafe {
            let out = v.as_mut_ptr().add(v.len());
            gather_be_planes_sse2(out, planes, whole);
            v.set_len(v.len() + whole);
        }
        whole
    };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    let [p0, p1, p2, p3] = planes;
    v.extend(
        p0[done..]
            .iter()
            .zip(&p1[done..])
            .zip(&p2[done..])
            .zip(&p3[done..])
            .map(|(((a, b), c), d)| f32::from_bits(u32::from_be_bytes([*a, *b, *c, *d]))),
    );
}

/// [`gather_be_planes`]'s first `whole` samples (a multiple of 16) written
/// at `out`: the bytes of each sample interleaved least significant first
/// (little-endian `f32`, as the machine stores it).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
unsafe fn gather_be_planes_sse2(out: *mut f32, planes: [&[u8]; 4], whole: usize) {
    use std::arch::x86_64::*;
    let [p0, p1, p2, p3] = planes;
    let load = |p: &[u8], i: usize| _mm_loadu_si128(p[i..i + 16].as_ptr() as *const __m128i);
    let mut i = 0;
    while i < whole {
        let (a, b, c, d) = (load(p0, i), load(p1, i), load(p2, i), load(p3, i));
        // (d, c) and (b, a) pairs: the low and high halves of each sample
        let dc_lo = _mm_unpacklo_epi8(d, c);
        let dc_hi = _mm_unpackhi_epi8(d, c);
        let ba_lo = _mm_unpacklo_epi8(b, a);
        let ba_hi = _mm_unpackhi_epi8(b, a);
        let o = out.add(i) as *mut __m128i;
        _mm_storeu_si128(o, _mm_unpacklo_epi16(dc_lo, ba_lo));
        _mm_storeu_si128(o.add(1), _mm_unpackhi_epi16(dc_lo, ba_lo));
        _mm_storeu_si128(o.add(2), _mm_unpacklo_epi16(dc_hi, ba_hi));
        _mm_storeu_si128(o.add(3), _mm_unpackhi_epi16(dc_hi, ba_hi));
        i += 16;
    }
}

/// Undo the floating-point predictor (TIFF Technical Note 3) on one row of
/// `n` samples of `size` bytes: byte-wise differencing, then the bytes of
/// each sample gathered from `size` planes, most significant first.
fn undo_float_predictor_row(row: &mut [u8], size: usize, out: &mut [u8]) {
    let mut acc = 0u8;
    for b in row.iter_mut() {
        acc = acc.wrapping_add(*b);
        *b = acc;
    }
    let n = row.len() / size;
    match size {
        4 => {
            let (p0, rest) = row.split_at(n);
            let (p1, rest) = rest.split_at(n);
            let (p2, p3) = rest.split_at(n);
            for ((((o, a), b), c), d) in out.chunks_exact_mut(4).zip(p0).zip(p1).zip(p2).zip(p3) {
                o.copy_from_slice(&u32::from_be_bytes([*a, *b, *c, *d]).to_ne_bytes());
            }
        }
        _ => {
            for (i, o) in out.chunks_exact_mut(size).enumerate() {
                let mut v = [0u8; 8];
                for (k, byte) in v.iter_mut().take(size).enumerate() {
                    *byte = row[k * n + i];
                }
                let x = u64::from_be_bytes(v) >> (8 * (8 - size));
                o.copy_from_slice(&x.to_ne_bytes()[..size]);
            }
        }
    }
}

macro_rules! typed {
    ($bytes:expr, $t:ty, $le:expr, $pred2:expr, $stored_w:expr, $w:expr, $h:expr) => {{
        const S: usize = std::mem::size_of::<$t>();
        let mut v: Vec<$t> = Vec::new();
        v.try_reserve_exact($w * $h)
            .map_err(|_| BlockError::Decompress(format!("cannot allocate {} samples", $w * $h)))?;
        for r in 0..$h {
            let row = &$bytes[r * $stored_w * S..(r + 1) * $stored_w * S];
            let start = v.len();
            v.extend(row.chunks_exact(S).take($w).map(|c| {
                let mut a = [0u8; S];
                a.copy_from_slice(c);
                if $le {
                    <$t>::from_le_bytes(a)
                } else {
                    <$t>::from_be_bytes(a)
                }
            }));
            if $pred2 {
                let row = &mut v[start..];
                for i in 1..row.len() {
                    row[i] = row[i].wrapping_add_bits(row[i - 1]);
                }
            }
        }
        v
    }};
}

/// Addition as the horizontal predictor defines it: on the sample's bits,
/// wrapping (libtiff applies predictor 2 to the raw words of any type).
trait WrappingAddBits: Copy {
    fn wrapping_add_bits(self, other: Self) -> Self;
}

macro_rules! wrapping_int {
    ($($t:ty),*) => {$(
        impl WrappingAddBits for $t {
            #[inline]
            fn wrapping_add_bits(self, other: Self) -> Self {
                self.wrapping_add(other)
            }
        }
    )*};
}
wrapping_int!(u8, i8, u16, i16, u32, i32);

impl WrappingAddBits for f32 {
    #[inline]
    fn wrapping_add_bits(self, other: Self) -> Self {
        f32::from_bits(self.to_bits().wrapping_add(other.to_bits()))
    }
}

impl WrappingAddBits for f64 {
    #[inline]
    fn wrapping_add_bits(self, other: Self) -> Self {
        f64::from_bits(self.to_bits().wrapping_add(other.to_bits()))
    }
}

/// Decode a block stored as `stored_w` x `stored_h` samples (tiles are
/// padded to the full tile size) into the `w` x `h` samples that lie inside
/// the image.
pub fn decode_block(
    codec: &BlockCodec,
    src: &[u8],
    stored_w: usize,
    stored_h: usize,
    w: usize,
    h: usize,
) -> Result<DecodingResult, BlockError> {
    let size = codec.sample_type.bytes();
    let expected = stored_w
        .checked_mul(stored_h)
        .and_then(|n| n.checked_mul(size))
        .ok_or_else(|| BlockError::Decompress("block size overflows".into()))?;
    if let Some(max) = super::max_decompressed(codec.compression, src.len() as u64) {
        if expected as u64 > max {
            return Err(BlockError::Decompress(format!(
                "{} compressed bytes cannot hold the {expected} bytes of a {stored_w} x {stored_h} block",
                src.len()
            )));
        }
    }
    let mut bytes = decompress(codec.compression, src, expected)?;
    let pred2 = codec.predictor == 2;
    if codec.predictor == 3
        && codec.sample_type == SampleType::Float32
        && cfg!(target_endian = "little")
        && w <= stored_w
        && h <= stored_h
    {
        let samples = float32_predicted(&mut bytes, stored_w, w, h).map(DecodingResult::F32);
        recycle(bytes);
        return samples;
    }
    if codec.predictor == 3 {
        // After the float predictor the samples are in native order.
        let mut out = Vec::new();
        reserve(&mut out, expected)?;
        out.resize(expected, 0);
        let row_bytes = stored_w * size;
        for (row, o) in bytes
            .chunks_exact_mut(row_bytes)
            .zip(out.chunks_exact_mut(row_bytes))
        {
            undo_float_predictor_row(row, size, o);
        }
        bytes = out;
        let le = cfg!(target_endian = "little");
        return Ok(match codec.sample_type {
            SampleType::Float32 => {
                DecodingResult::F32(typed!(bytes, f32, le, false, stored_w, w, h))
            }
            _ => DecodingResult::F64(typed!(bytes, f64, le, false, stored_w, w, h)),
        });
    }
    let le = codec.little_endian;
    Ok(match codec.sample_type {
        SampleType::UInt8 => DecodingResult::U8(typed!(bytes, u8, le, pred2, stored_w, w, h)),
        SampleType::Int8 => DecodingResult::I8(typed!(bytes, i8, le, pred2, stored_w, w, h)),
        SampleType::UInt16 => DecodingResult::U16(typed!(bytes, u16, le, pred2, stored_w, w, h)),
        SampleType::Int16 => DecodingResult::I16(typed!(bytes, i16, le, pred2, stored_w, w, h)),
        SampleType::UInt32 => DecodingResult::U32(typed!(bytes, u32, le, pred2, stored_w, w, h)),
        SampleType::Int32 => DecodingResult::I32(typed!(bytes, i32, le, pred2, stored_w, w, h)),
        SampleType::Float32 => DecodingResult::F32(typed!(bytes, f32, le, pred2, stored_w, w, h)),
        SampleType::Float64 => DecodingResult::F64(typed!(bytes, f64, le, pred2, stored_w, w, h)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A row of `f32` samples as the floating-point predictor (TIFF
    /// predictor 3) stores it: each sample's big-endian bytes shuffled
    /// into byte planes, then each byte the difference from the one
    /// before.
    fn float_predicted_row(vals: &[f32]) -> Vec<u8> {
        let n = vals.len();
        let mut planes = vec![0u8; n * 4];
        for (i, v) in vals.iter().enumerate() {
            for (k, b) in v.to_be_bytes().iter().enumerate() {
                planes[k * n + i] = *b;
            }
        }
        for i in (1..planes.len()).rev() {
            planes[i] = planes[i].wrapping_sub(planes[i - 1]);
        }
        planes
    }

    #[test]
    fn float_predictor_round_trip() {
        let vals = [1.5f32, -2.25, 1000.125, 0.0, 3.4e38];
        let n = vals.len();
        let mut planes = float_predicted_row(&vals);
        let mut out = vec![0u8; n * 4];
        undo_float_predictor_row(&mut planes, 4, &mut out);
        let got: Vec<f32> = out
            .chunks_exact(4)
            .map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        assert_eq!(got, vals);
    }

    /// The SSE2 running byte sums and byte gathering give the scalar
    /// loops' bytes and samples, for every length around the 16-byte
    /// lanes (wrapping sums, NaN and negative-zero bit patterns included).
    #[test]
    fn lane_prefix_sums_and_gathers_equal_the_scalar_loops() {
        let mut seed = 0x9e37_79b9_u32;
        let mut byte = || {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 24) as u8
        };
        for n in 0..70usize {
            let row: Vec<u8> = (0..n).map(|_| byte()).collect();
            let mut fast = row.clone();
            prefix_sum_bytes(&mut fast);
            let mut acc = 0u8;
            let slow: Vec<u8> = row
                .iter()
                .map(|b| {
                    acc = acc.wrapping_add(*b);
                    acc
                })
                .collect();
            assert_eq!(fast, slow, "prefix sums of {n} bytes");
            let planes: Vec<Vec<u8>> = (0..4)
                .map(|k| match (k, n) {
                    // a NaN and a negative zero among the samples
                    (0, 3..) => (0..n)
                        .map(|i| {
                            if i == 1 {
                                0x7f
                            } else if i == 2 {
                                0x80
                            } else {
                                byte()
                            }
                        })
                        .collect(),
                    (1, 3..) => (0..n)
                        .map(|i| {
                            if i == 1 {
                                0xc0
                            } else if i == 2 {
                                0
                            } else {
                                byte()
                            }
                        })
                        .collect(),
                    (_, 3..) => (0..n).map(|i| if i == 2 { 0 } else { byte() }).collect(),
                    _ => (0..n).map(|_| byte()).collect(),
                })
                .collect();
            let mut v = vec![1.5f32];
            gather_be_planes(&mut v, [&planes[0], &planes[1], &planes[2], &planes[3]]);
            let want: Vec<u32> = std::iter::once(1.5f32.to_bits())
                .chain((0..n).map(|i| {
                    u32::from_be_bytes([planes[0][i], planes[1][i], planes[2][i], planes[3][i]])
                }))
                .collect();
            let got: Vec<u32> = v.iter().map(|x| x.to_bits()).collect();
            assert_eq!(got, want, "gathered samples of {n}");
        }
    }

    /// The direct `f32` path gives the bits of undoing every row into bytes
    /// and reading the samples inside the image from them (a block padded
    /// on the right and at the bottom, with NaN and negative zero).
    #[test]
    fn float32_predicted_equals_the_bytes_path() {
        let (stored_w, stored_h, w, h) = (6usize, 4usize, 5usize, 3usize);
        let mut raw = Vec::new();
        for r in 0..stored_h {
            let vals: Vec<f32> = (0..stored_w)
                .map(|c| match (r, c) {
                    (0, 1) => f32::NAN,
                    (1, 2) => -0.0,
                    _ => (r * 7 + c) as f32 * -13.375 + 0.1,
                })
                .collect();
            raw.extend(float_predicted_row(&vals));
        }
        let mut a = raw.clone();
        let direct = float32_predicted(&mut a, stored_w, w, h).expect("direct");
        let mut b = raw;
        let mut out = vec![0u8; b.len()];
        for (row, o) in b
            .chunks_exact_mut(stored_w * 4)
            .zip(out.chunks_exact_mut(stored_w * 4))
        {
            undo_float_predictor_row(row, 4, o);
        }
        let mut bytes_path = Vec::new();
        for r in 0..h {
            for c in 0..w {
                let k = (r * stored_w + c) * 4;
                bytes_path.push(f32::from_ne_bytes([
                    out[k],
                    out[k + 1],
                    out[k + 2],
                    out[k + 3],
                ]));
            }
        }
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&direct), bits(&bytes_path));
        assert!(direct[1].is_nan());
    }

    #[test]
    fn packbits_decodes_runs_and_literals() {
        let src = [0xFEu8, 0xAA, 0x02, 0x80, 0x00, 0x2A];
        let out = decompress(32773, &src, 6).expect("packbits");
        assert_eq!(out, vec![0xAA, 0xAA, 0xAA, 0x80, 0x00, 0x2A]);
    }

    /// The one-call inflate gives what the streaming one gives, and leaves
    /// every stream that does not hold exactly the block to it.
    /// Blocks decoded one after another on one thread (reusing the kept
    /// buffer of the block before, larger or smaller) give the samples a
    /// decode on a fresh thread gives.
    #[test]
    fn blocks_decoded_in_turn_equal_blocks_decoded_alone() {
        use std::io::Write;
        let codec = BlockCodec {
            compression: 8,
            predictor: 3,
            sample_type: SampleType::Float32,
            little_endian: true,
        };
        let block = |side: usize, seed: f32| {
            let mut raw = Vec::new();
            for r in 0..side {
                let vals: Vec<f32> = (0..side)
                    .map(|c| seed + (r * 31 + c * 7) as f32 * 0.37 - (c as f32).sqrt())
                    .collect();
                raw.extend(float_predicted_row(&vals));
            }
            let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            e.write_all(&raw).expect("compress");
            e.finish().expect("compress")
        };
        let bits = |r: DecodingResult| match r {
            DecodingResult::F32(v) => v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            _ => panic!("not f32"),
        };
        let sizes = [(64usize, 1.0f32), (16, -5.0), (32, 900.5), (64, 3.25)];
        let alone: Vec<Vec<u32>> = sizes
            .iter()
            .map(|&(side, seed)| {
                let z = block(side, seed);
                std::thread::spawn(move || {
                    bits(decode_block(&codec, &z, side, side, side - 3, side - 1).expect("decode"))
                })
                .join()
                .expect("thread")
            })
            .collect();
        for (&(side, seed), want) in sizes.iter().zip(&alone) {
            let z = block(side, seed);
            let got =
                bits(decode_block(&codec, &z, side, side, side - 3, side - 1).expect("decode"));
            assert_eq!(&got, want, "block of {side}");
        }
    }

    #[test]
    fn deflate_in_one_call_or_streamed_gives_the_same_bytes() {
        use std::io::Write;
        let data: Vec<u8> = (0..200_000u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8 & 0x3F)
            .collect();
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(&data).expect("compress");
        let z = e.finish().expect("compress");
        let streamed = |src: &[u8], n: usize| {
            let mut out = Vec::with_capacity(n);
            let mut d = flate2::Decompress::new(true);
            let _ = d.decompress_vec(src, &mut out, flate2::FlushDecompress::Finish);
            out
        };
        // exactly the block
        assert!(inflate_whole(&z, data.len()).as_deref() == Some(&data[..]));
        assert_eq!(decompress(8, &z, data.len()).expect("deflate"), data);
        // a stream longer than the block: cut
        assert!(inflate_whole(&z, 1000).is_none());
        assert_eq!(
            decompress(8, &z, 1000).expect("deflate"),
            streamed(&z, 1000)
        );
        assert_eq!(
            &decompress(8, &z, 1000).expect("deflate")[..],
            &data[..1000]
        );
        // a stream shorter than the block: an error, as before
        assert!(inflate_whole(&z, data.len() + 1).is_none());
        assert!(decompress(8, &z, data.len() + 1).is_err());
        // a damaged checksum: left to the streaming inflate, which refuses
        // it (as before)
        let mut bad = z.clone();
        let last = bad.len() - 1;
        bad[last] ^= 0xFF;
        assert!(inflate_whole(&bad, data.len()).is_none());
        assert!(decompress(8, &bad, data.len()).is_err());
    }
}
