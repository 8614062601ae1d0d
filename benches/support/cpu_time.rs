//! Process CPU time for the timing examples (`examples/*_profile.rs`).

/// Process CPU time (user + system, all threads) in seconds, from
/// `/proc/self/stat` (clock ticks of 10 ms; average over many runs); 0
/// where that file is unavailable.
pub fn cpu_s() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = &s[s.rfind(')')? + 2..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some((f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / 100.0)
        })
        .unwrap_or(0.0)
}
