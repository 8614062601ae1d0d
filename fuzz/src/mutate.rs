//! A random-mutation fuzz driver that runs on stable Rust, over the same
//! target as `fuzz_targets/geotiff_decode.rs`
//! ([`demsketch::raster::geotiff::fuzz::decode_all_blocks`]), for machines
//! without cargo-fuzz. It is blind (no coverage feedback): each input is a
//! seed from the corpus with 1 to 8 mutations, TIFF-aware ones (IFD entry
//! type, count and value set to boundary values) among byte flips,
//! truncations, splices and repeats. A panic is caught, counted and its
//! input saved; an abort or out-of-memory ends the run (and shows).
//!
//!   cargo run --release --no-default-features --bin mutate -- \
//!       [--seconds 600] [--corpus corpus/geotiff_decode] [--crashes crashes] [--seed N]

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use demsketch::raster::geotiff::fuzz::decode_all_blocks;

/// xorshift64*: small, fast, reproducible from `--seed`.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

const INTERESTING: [u32; 14] = [
    0,
    1,
    2,
    7,
    8,
    0x7F,
    0xFF,
    0x7FFF,
    0x8000,
    0xFFFF,
    0x10000,
    0x7FFF_FFFF,
    0x8000_0000,
    0xFFFF_FFFF,
];

/// Offsets of the 12-byte entries of the first IFD of a classic TIFF.
fn ifd_entries(b: &[u8]) -> Vec<usize> {
    if b.len() < 8 || &b[2..4] != b"*\0" && &b[2..4] != b"\0*" {
        return Vec::new();
    }
    let le = b[0] == b'I';
    let u32_at = |o: usize| {
        let a = [b[o], b[o + 1], b[o + 2], b[o + 3]];
        if le {
            u32::from_le_bytes(a)
        } else {
            u32::from_be_bytes(a)
        }
    };
    let ifd = u32_at(4) as usize;
    if ifd + 2 > b.len() {
        return Vec::new();
    }
    let n = if le {
        u16::from_le_bytes([b[ifd], b[ifd + 1]])
    } else {
        u16::from_be_bytes([b[ifd], b[ifd + 1]])
    } as usize;
    (0..n)
        .map(|i| ifd + 2 + 12 * i)
        .take_while(|e| e + 12 <= b.len())
        .collect()
}

fn put(b: &mut [u8], at: usize, v: u32, width: usize, le: bool) {
    let bytes = if le { v.to_le_bytes() } else { v.to_be_bytes() };
    let src = if le {
        &bytes[..width]
    } else {
        &bytes[4 - width..]
    };
    if at + width <= b.len() {
        b[at..at + width].copy_from_slice(src);
    }
}

fn mutate(rng: &mut Rng, input: &mut Vec<u8>, seeds: &[Vec<u8>]) {
    let le = input.first() == Some(&b'I');
    for _ in 0..1 + rng.below(8) {
        let len = input.len();
        match rng.below(10) {
            0 if len > 0 => {
                let i = rng.below(len);
                input[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                input[i] = rng.next() as u8;
            }
            2 | 3 | 4 => {
                // An IFD entry's type, count or value.
                let e = ifd_entries(input);
                if e.is_empty() {
                    continue;
                }
                let at = e[rng.below(e.len())];
                let v = if rng.below(3) == 0 {
                    rng.next() as u32
                } else {
                    INTERESTING[rng.below(INTERESTING.len())]
                };
                match rng.below(4) {
                    0 => put(input, at + 2, v % 20, 2, le),
                    1 => put(input, at + 4, v, 4, le),
                    2 => put(input, at + 8, v, 2, le),
                    _ => put(input, at + 8, v, 4, le),
                }
            }
            5 if len > 4 => {
                let at = rng.below(len - 3);
                let v = INTERESTING[rng.below(INTERESTING.len())];
                put(input, at, v, 4, le);
            }
            6 if len > 8 => {
                let keep = 8 + rng.below(len - 8);
                input.truncate(keep);
            }
            7 if len > 16 => {
                // Repeat a chunk (bigger blocks, cycles in offsets).
                let a = rng.below(len - 8);
                let n = 1 + rng.below((len - a).min(256));
                let chunk = input[a..a + n].to_vec();
                let at = rng.below(len);
                input.splice(at..at, chunk);
            }
            8 if !seeds.is_empty() => {
                // Splice the tail of another seed.
                let other = &seeds[rng.below(seeds.len())];
                if other.len() > 8 && len > 8 {
                    let from = 8 + rng.below(other.len() - 8);
                    let at = 8 + rng.below(len - 8);
                    input.truncate(at);
                    input.extend_from_slice(&other[from..]);
                }
            }
            _ => {
                if len > 0 {
                    let i = rng.below(len);
                    input[i] = input[i].wrapping_add(1 + rng.below(3) as u8);
                }
            }
        }
    }
}

fn arg(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

fn peak_rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).map(String::from))
        })
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seconds: u64 = arg(&args, "--seconds")
        .and_then(|s| s.parse().ok())
        .unwrap_or(60);
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let corpus = arg(&args, "--corpus")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("corpus/geotiff_decode"));
    let crashes = arg(&args, "--crashes")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("crashes"));
    let seed: u64 = arg(&args, "--seed")
        .and_then(|s| s.parse().ok())
        .unwrap_or(0x9E37_79B9_7F4A_7C15);
    std::env::set_var("DEMSKETCH_MEMORY_BUDGET_MB", "256");

    let mut seeds: Vec<Vec<u8>> = std::fs::read_dir(&corpus)
        .unwrap_or_else(|e| panic!("corpus {}: {e}", corpus.display()))
        .filter_map(|e| e.ok())
        .filter_map(|e| std::fs::read(e.path()).ok())
        .collect();
    seeds.sort();
    assert!(!seeds.is_empty(), "empty corpus {}", corpus.display());

    let last_panic = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    {
        let last_panic = last_panic.clone();
        std::panic::set_hook(Box::new(move |info| {
            if let Ok(mut m) = last_panic.lock() {
                *m = info.to_string().replace('\n', " ");
            }
        }));
    }

    let mut rng = Rng(seed | 1);
    let start = Instant::now();
    let deadline = Duration::from_secs(seconds);
    let (mut execs, mut ok, mut err, mut panics) = (0u64, 0u64, 0u64, 0u64);
    let mut kinds: BTreeMap<String, u64> = BTreeMap::new();
    let mut slowest = (Duration::ZERO, 0u64);
    let mut next_report = Duration::from_secs(10);
    // Seeds first, unchanged: they must decode.
    for (i, s) in seeds.iter().enumerate() {
        if let Err(e) = decode_all_blocks(s) {
            println!("seed {i} does not decode: {e}");
        }
    }
    while start.elapsed() < deadline {
        let mut input = seeds[rng.below(seeds.len())].clone();
        mutate(&mut rng, &mut input, &seeds);
        let t0 = Instant::now();
        let r = std::panic::catch_unwind(|| decode_all_blocks(&input));
        let dt = t0.elapsed();
        if dt > slowest.0 {
            slowest = (dt, execs);
        }
        execs += 1;
        match r {
            Ok(Ok(_)) => ok += 1,
            Ok(Err(e)) => {
                err += 1;
                let msg = e.to_string();
                // The message without the file name, digits folded.
                let kind: String = msg
                    .split_once(": ")
                    .map_or(msg.as_str(), |(_, rest)| rest)
                    .chars()
                    .map(|c| if c.is_ascii_digit() { '#' } else { c })
                    .take(70)
                    .collect();
                *kinds.entry(kind).or_default() += 1;
            }
            Err(_) => {
                panics += 1;
                let _ = std::fs::create_dir_all(&crashes);
                let p = crashes.join(format!("crash-{execs}.tif"));
                let _ = std::fs::write(&p, &input);
                println!(
                    "PANIC at exec {execs}: {} (input saved to {})",
                    last_panic.lock().map(|m| m.clone()).unwrap_or_default(),
                    p.display()
                );
            }
        }
        if start.elapsed() >= next_report {
            println!(
                "{:>5} s: {execs} execs ({:.0}/s), {ok} decoded, {err} errors, {panics} panics, peak RSS {} MB",
                start.elapsed().as_secs(),
                execs as f64 / start.elapsed().as_secs_f64(),
                peak_rss_kb() / 1024
            );
            next_report += Duration::from_secs(10);
        }
    }
    println!(
        "done: {execs} execs in {:.0} s ({:.0}/s) from {} seeds; {ok} decoded, {err} errors, {panics} panics; slowest exec {:.3} s (#{}); peak RSS {} MB",
        start.elapsed().as_secs_f64(),
        execs as f64 / start.elapsed().as_secs_f64(),
        seeds.len(),
        slowest.0.as_secs_f64(),
        slowest.1,
        peak_rss_kb() / 1024
    );
    println!("most frequent errors:");
    let mut k: Vec<_> = kinds.into_iter().collect();
    k.sort_by(|a, b| b.1.cmp(&a.1));
    for (kind, n) in k.iter().take(12) {
        println!("  {n:>9}  {kind}");
    }
    if panics > 0 {
        std::process::exit(1);
    }
}
