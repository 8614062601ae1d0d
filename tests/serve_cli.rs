//! `demsketch serve` from the command line: the help names the options,
//! and bad input (a missing DEM, an --out naming the DEM, a bad --out
//! format, a bad --max-distance, an --underlay that is missing, not a
//! raster or without a georeference) is one line naming the file and the
//! problem, exit code 1, before anything listens or is written. The app
//! itself is tested through Chromium by `tests/browser/run.py` (run by
//! `tools/test.sh`).

mod common;

use common::{demsketch, fixture, gdal_translate, gdalinfo};

fn stderr_line(out: &std::process::Output) -> String {
    let s = String::from_utf8_lossy(&out.stderr).trim_end().to_string();
    assert_eq!(s.lines().count(), 1, "expected one line, got: {s}");
    s
}

#[test]
fn help_lists_the_options() {
    let out = demsketch(&["serve", "--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    for opt in [
        "--out",
        "--port",
        "--bind",
        "--open",
        "--max-distance",
        "--min-fit",
        "--underlay",
    ] {
        assert!(help.contains(opt), "{opt} missing from: {help}");
    }
}

#[test]
fn missing_dem_is_one_line_exit_1() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = dir.path().join("nope.tif");
    let out_path = dir.path().join("out.tif");
    let out = demsketch(&[
        "serve",
        dem.to_str().expect("utf-8"),
        "--out",
        out_path.to_str().expect("utf-8"),
        "--port",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(line.contains("nope.tif"), "{line}");
    assert!(!out_path.exists());
}

#[test]
fn out_naming_the_dem_is_refused() {
    let dem = fixture("zion_srtm_utm12n.tif");
    let d = dem.to_str().expect("utf-8");
    let out = demsketch(&["serve", d, "--out", d, "--port", "0"]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(line.contains("--out"), "{line}");
}

#[test]
fn bad_out_format_and_distance_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("zion_srtm_utm12n.tif");
    let bad = dir.path().join("out.unknownext");
    let out = demsketch(&[
        "serve",
        dem.to_str().expect("utf-8"),
        "--out",
        bad.to_str().expect("utf-8"),
        "--port",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    let line = stderr_line(&out);
    assert!(line.contains("out.unknownext"), "{line}");
    let out = demsketch(&[
        "serve",
        dem.to_str().expect("utf-8"),
        "--max-distance",
        "-5",
        "--port",
        "0",
    ]);
    assert_eq!(out.status.code(), Some(1));
    stderr_line(&out);
}

#[test]
fn bad_underlay_is_one_line_naming_it_exit_1() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dem = fixture("zion_srtm_utm12n.tif");
    let out_path = dir.path().join("out.tif");
    let text = dir.path().join("notes.txt");
    std::fs::write(&text, "not a raster\n").expect("write");
    let missing = dir.path().join("missing.tif");
    for (bad, why) in [(&missing, "no such file"), (&text, "not a raster")] {
        let out = demsketch(&[
            "serve",
            dem.to_str().expect("utf-8"),
            "--out",
            out_path.to_str().expect("utf-8"),
            "--port",
            "0",
            "--underlay",
            bad.to_str().expect("utf-8"),
        ]);
        assert_eq!(out.status.code(), Some(1));
        let line = stderr_line(&out);
        assert!(
            line.contains(bad.to_str().expect("utf-8")) && line.contains(why),
            "{line}"
        );
        assert!(!String::from_utf8_lossy(&out.stdout).contains("http://"));
        assert!(!out_path.exists());
    }
}

/// A running `demsketch serve` (killed when dropped) and its address.
struct Server {
    child: std::process::Child,
    addr: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start `demsketch serve ARGS --port 0` and wait for its URL; also the
/// seconds from the start to the URL.
fn serve(args: &[&str]) -> (Server, f64) {
    use std::io::BufRead;
    let t0 = std::time::Instant::now();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_demsketch"))
        .arg("serve")
        .args(args)
        .args(["--port", "0"])
        .env("GDAL_PAM_ENABLED", "NO")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("start demsketch serve");
    let stdout = child.stdout.take().expect("stdout");
    let mut lines = std::io::BufReader::new(stdout).lines();
    let addr = loop {
        let line = lines
            .next()
            .expect("serve exited before printing its URL")
            .expect("read stdout");
        if let Some(rest) = line.split("http://").nth(1) {
            break rest.trim_end_matches('/').to_string();
        }
    };
    let secs = t0.elapsed().as_secs_f64();
    (Server { child, addr }, secs)
}

/// `GET path` from the server: status and body (HTTP/1.1, one request).
fn get(server: &Server, path: &str) -> (u32, Vec<u8>) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(&server.addr).expect("connect");
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
        server.addr
    )
    .expect("send");
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("read");
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("headers end");
    let head = String::from_utf8_lossy(&raw[..split]).to_string();
    let status = head
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .expect("status");
    let body = raw[split + 4..].to_vec();
    if let Some(len) = head.lines().find_map(|l| {
        l.to_ascii_lowercase()
            .strip_prefix("content-length:")
            .map(|v| v.trim().to_string())
    }) {
        assert_eq!(len.parse::<usize>().ok(), Some(body.len()), "{head}");
    }
    (status, body)
}

/// `POST path` with a JSON body: status and body (HTTP/1.1, one request).
fn post(server: &Server, path: &str, body: &str) -> (u32, String) {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(&server.addr).expect("connect");
    write!(
        s,
        "POST {path} HTTP/1.1\r\nHost: {}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        server.addr,
        body.len()
    )
    .expect("send");
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("read");
    let text = String::from_utf8_lossy(&raw).to_string();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .expect("status");
    let body = text.split("\r\n\r\n").nth(1).unwrap_or("").to_string();
    (status, body)
}

/// RGBA pixels of a PNG.
fn decode_rgba(png_bytes: &[u8]) -> (usize, usize, Vec<u8>) {
    let mut reader = png::Decoder::new(std::io::Cursor::new(png_bytes))
        .read_info()
        .expect("a PNG");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut buf).expect("decode");
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    (info.width as usize, info.height as usize, buf)
}

/// An 8192 x 8192 orthophoto (the fixture underlay upsampled, with
/// overviews by `gdaladdo`) opens fast: the server prints its URL within a
/// few seconds and serves the underlay at the map's size, with the
/// colours the fixture itself gives (read from the served PNG).
#[test]
fn large_underlay_opens_fast_through_its_overviews() {
    let dir = tempfile::tempdir().expect("tempdir");
    let small = fixture("underlay/zion_rgb_epsg4326.tif");
    let big = dir.path().join("ortho8192.tif");
    gdal_translate(
        &small,
        &big,
        &[
            "-outsize",
            "8192",
            "8192",
            "-r",
            "bilinear",
            "-co",
            "TILED=YES",
            "-co",
            "COMPRESS=DEFLATE",
            "-co",
            "ZLEVEL=1",
        ],
    );
    let b = big.to_str().expect("utf-8");
    common::run(
        "gdaladdo",
        &["-q", "-r", "average", b, "2", "4", "8", "16", "32"],
    );
    let info = gdalinfo(&big);
    assert_eq!(info["size"], serde_json::json!([8192, 8192]));
    let overviews = info["bands"][0]["overviews"].as_array().map_or(0, Vec::len);
    assert_eq!(overviews, 5, "gdaladdo made the overviews");
    let dem = fixture("zion_srtm_utm12n.tif");
    let d = dem.to_str().expect("utf-8");
    let (plain, plain_s) = serve(&[d]);
    let (server, secs) = serve(&[d, "--underlay", b]);
    let (ref_server, _) = serve(&[d, "--underlay", small.to_str().expect("utf-8")]);
    eprintln!(
        "start to URL: {plain_s:.2} s without an underlay, {secs:.2} s with the 8192 x 8192 one"
    );
    // Generous for a loaded machine; warping all 8192^2 pixels took longer.
    assert!(secs < plain_s + 3.0, "{secs:.2} s to open the underlay");
    drop(plain);
    let (status, png_big) = get(&server, "/api/underlay.png");
    assert_eq!(status, 200);
    let (status, png_small) = get(&ref_server, "/api/underlay.png");
    assert_eq!(status, 200);
    let (w, h, big_px) = decode_rgba(&png_big);
    let (w2, h2, small_px) = decode_rgba(&png_small);
    assert_eq!((w, h), (w2, h2), "both at the map's size");
    let (mut both, mut diff) = (0usize, 0u64);
    for (p, q) in big_px.chunks_exact(4).zip(small_px.chunks_exact(4)) {
        if p[3] == 255 && q[3] == 255 {
            both += 1;
            diff += (0..3).map(|k| p[k].abs_diff(q[k]) as u64).sum::<u64>();
        }
    }
    let opaque = |px: &[u8]| px.chunks_exact(4).filter(|p| p[3] == 255).count();
    let (ob, os) = (opaque(&big_px), opaque(&small_px));
    assert!(os > w * h / 2, "the fixture covers most of the map");
    assert!(
        (ob as f64 - os as f64).abs() < 0.02 * os as f64,
        "opaque pixels: {ob} with the large file, {os} with the fixture"
    );
    let mean = diff as f64 / (3 * both.max(1)) as f64;
    eprintln!("{w} x {h}: mean channel difference {mean:.2} over {both} pixels");
    assert!(mean < 6.0, "mean channel difference {mean:.2}");
}

/// A view or locate request whose absolute eye (`alt_m`) is at or below
/// the ground at the viewpoint is answered 422 with the edit's one-line
/// message, and an absurd camera number 400 naming the field; the server
/// goes on answering.
#[test]
fn an_eye_below_the_ground_is_a_4xx_and_the_server_goes_on() {
    let dem = fixture("zion_srtm_utm12n.tif");
    let (server, _) = serve(&[dem.to_str().expect("utf-8")]);
    let req = |viewpoint: &str, heading: &str, pixel: &str| {
        format!(
            r#"{{"viewpoint": {viewpoint}, "camera": {{"heading_deg": {heading}, "hfov_deg": 40, "width": 320, "height": 180}}{pixel}}}"#
        )
    };
    let below = r#"{"lon": -112.9, "lat": 37.4, "alt_m": 10}"#;
    for (path, pixel) in [
        ("/api/render", ""),
        ("/api/locate", r#", "pixel": [160, 90]"#),
    ] {
        let (status, body) = post(&server, path, &req(below, "200", pixel));
        assert_eq!(status, 422, "{path}: {body}");
        assert!(
            body.contains("viewpoint alt_m 10 is not above the ground (")
                && body.contains("m) at the viewpoint")
                && !body.contains('\n'),
            "{path}: {body}"
        );
    }
    let above = r#"{"lon": -112.9, "lat": 37.4, "eye_height_m": 1.7}"#;
    let (status, body) = post(&server, "/api/render", &req(above, "1e300", ""));
    assert_eq!(status, 400, "{body}");
    assert!(
        body.contains("camera.heading_deg 1e300 is not in [-360, 360]"),
        "{body}"
    );
    let (status, _) = post(&server, "/api/render", &req(above, "200", ""));
    assert_eq!(status, 200, "the server goes on");
}

/// A locate request whose pixel lies outside the image is answered 400
/// with the line `demsketch locate` prints (`Camera::check_pixel`, one
/// rule for both), and the server goes on answering.
#[test]
fn a_locate_pixel_outside_the_image_is_a_400_and_the_server_goes_on() {
    let dem = fixture("zion_srtm_utm12n.tif");
    let (server, _) = serve(&[dem.to_str().expect("utf-8")]);
    let req = |pixel: &str| {
        format!(
            r#"{{"viewpoint": {{"lon": -112.9, "lat": 37.4, "eye_height_m": 1.7}}, "camera": {{"heading_deg": 200, "hfov_deg": 40, "width": 320, "height": 180}}, "pixel": {pixel}}}"#
        )
    };
    for (pixel, line) in [
        (
            "[1e300, 5]",
            "locate: pixel 1e300,5 lies outside the 320x180 image",
        ),
        (
            "[-1, 90]",
            "locate: pixel -1,90 lies outside the 320x180 image",
        ),
        (
            "[160, 181]",
            "locate: pixel 160,181 lies outside the 320x180 image",
        ),
    ] {
        let (status, body) = post(&server, "/api/locate", &req(pixel));
        assert_eq!(status, 400, "{pixel}: {body}");
        assert!(
            body.contains(line) && !body.contains('\n'),
            "{pixel}: {body}"
        );
    }
    let (status, body) = post(&server, "/api/locate", &req("[160, 90]"));
    assert_eq!(status, 200, "the server goes on: {body}");
}
