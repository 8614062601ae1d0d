//! Times ridge detection (PPA) on the synthetic fractal DEM of the features
//! benchmark and prints a fingerprint of the network, so that a change of the
//! implementation can be checked to give the same lines.
//!
//! Run: `cargo run --release --example ridges_timing -- [width] [repeats] [height]`.
//! With `RIDGES_DUMP=file` it also writes every value of the network (lines
//! with their vertices, pixels, lengths and nodes; the nodes; the candidate
//! count) to `file`, for a byte-wise comparison of two versions with `cmp`.

use demsketch::features::{detect_ridges, RidgeParams};
use demsketch::raster::{GeoTransform, HeightMap};

#[path = "../benches/support/fractal.rs"]
mod fractal;
use fractal::fractal_rect as fractal;
use std::time::Instant;

// The allocator of the `demsketch` binary (see `src/main.rs`), so that the
// figures are those of the command line.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// The fractal DEM, kept in the temporary directory between runs (so that
/// profiles of this example show ridge detection, not the noise).
fn cached_fractal(w: usize, h: usize) -> HeightMap {
    let path = std::env::temp_dir().join(format!("demsketch_fractal_{w}x{h}.f32"));
    let mut map = fractal(w.min(2), h.min(2));
    if let Ok(bytes) = std::fs::read(&path) {
        if bytes.len() == w * h * 4 {
            map.data = bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            map.width = w;
            map.height = h;
            map.geotransform =
                GeoTransform::north_up(500_000.0, 4_000_000.0 + 30.0 * h as f64, 30.0, 30.0);
            return map;
        }
    }
    let map = fractal(w, h);
    let bytes: Vec<u8> = map.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    let _ = std::fs::write(&path, bytes);
    map
}

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(4096);
    let repeats: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(10);
    let h: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(n);
    let map = cached_fractal(n, h);
    let params = RidgeParams::default();
    let mut best = f64::INFINITY;
    let mut best_drop = f64::INFINITY;
    let mut net = None;
    for _ in 0..repeats {
        let t = Instant::now();
        let r = detect_ridges(&map, &params).expect("ridges");
        best = best.min(t.elapsed().as_secs_f64());
        let t = Instant::now();
        if let Some(old) = net.replace(r) {
            drop(old);
            best_drop = best_drop.min(t.elapsed().as_secs_f64());
        }
    }
    let Some(net) = net else { return };
    // Fingerprint: a hash of every vertex, line and node, in order.
    let mut fp = 0xcbf2_9ce4_8422_2325u64;
    let mut mix = |v: u64| {
        fp ^= v;
        fp = fp.wrapping_mul(0x100_0000_01b3);
    };
    for l in &net.lines {
        mix(l.nodes[0] as u64);
        mix(l.nodes[1] as u64);
        for p in net.line_points(l) {
            mix(p[0].to_bits());
            mix(p[1].to_bits());
            mix(p[2].to_bits());
        }
        mix(l.length_m.to_bits());
    }
    for nd in &net.nodes {
        mix(nd.cell[0] as u64 | (nd.cell[1] as u64) << 32);
        mix(nd.degree as u64);
    }
    if let Some(path) = std::env::var_os("RIDGES_DUMP") {
        // Every value of the network, in order, for a byte-wise comparison.
        let mut out: Vec<u8> = Vec::new();
        out.extend((net.candidate_cells as u64).to_le_bytes());
        for l in &net.lines {
            out.extend(l.id.to_le_bytes());
            out.extend(l.nodes[0].to_le_bytes());
            out.extend(l.nodes[1].to_le_bytes());
            out.extend(l.length_m.to_bits().to_le_bytes());
            out.extend((l.vertices.len() as u64).to_le_bytes());
            for p in net.line_points(l) {
                p.iter().for_each(|v| out.extend(v.to_bits().to_le_bytes()));
            }
            for p in net.line_pixels(l) {
                p.iter().for_each(|v| out.extend(v.to_bits().to_le_bytes()));
            }
        }
        for nd in &net.nodes {
            out.extend(nd.id.to_le_bytes());
            out.extend(nd.cell[0].to_le_bytes());
            out.extend(nd.cell[1].to_le_bytes());
            nd.point
                .iter()
                .for_each(|v| out.extend(v.to_bits().to_le_bytes()));
            out.push(nd.degree);
        }
        std::fs::write(path, out).expect("write the dump");
    }
    println!(
        "{n}x{h}: best of {repeats}: {:.2} ms (dropping the previous result {}); {} candidates, {} lines, {} nodes, {:.1} km, fingerprint {fp:016x}",
        best * 1e3,
        if best_drop.is_finite() {
            format!("{:.2} ms", best_drop * 1e3)
        } else {
            "not timed".to_string()
        },
        net.candidate_cells,
        net.lines.len(),
        net.nodes.len(),
        net.total_length_m() / 1e3
    );
}
