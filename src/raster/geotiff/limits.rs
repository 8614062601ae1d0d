//! Memory bounds of decoding. The budget for one decoded window or block
//! comes from the machine: half of what this process may use (physical
//! memory, the cgroup's `memory.max`, the `RLIMIT_AS` address-space limit,
//! whichever is smallest), unless `DEMSKETCH_MEMORY_BUDGET_MB` says
//! otherwise. The `tiff` crate's limits are sized from the file (a tag
//! cannot hold more values than the file has bytes), and every block's
//! claimed size is checked against what its compressed bytes can possibly
//! decode to, so that a crafted file fails at once instead of reserving
//! gigabytes.

use tiff::decoder::Limits;

/// The memory budget for one decoded window or block, in bytes
/// (`DEMSKETCH_MEMORY_BUDGET_MB`, else half the memory this process may use).
pub fn memory_budget() -> u64 {
    if let Some(mb) = std::env::var("DEMSKETCH_MEMORY_BUDGET_MB")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
    {
        return mb.saturating_mul(1024 * 1024);
    }
    usable_memory() / 2
}

/// The memory this process may use: the smallest of physical memory, the
/// cgroup limit and the address-space limit left after what is mapped now.
/// 8 GiB when none can be read.
fn usable_memory() -> u64 {
    let fixed = machine_limits();
    let mut m: Option<u64> = None;
    let mut take = |v: Option<u64>| {
        if let Some(v) = v {
            m = Some(m.map_or(v, |x: u64| x.min(v)));
        }
    };
    take(fixed.mem_total);
    take(fixed.cgroup_max);
    take(
        fixed
            .address_space
            .map(|lim| lim.saturating_sub(vm_size().unwrap_or(0))),
    );
    m.unwrap_or(8 << 30)
}

/// What bounds this process's memory and does not change while it runs,
/// read once (the budget is asked for every window and block read: three
/// files of /proc and /sys each time were a few percent of a view's CPU).
struct MachineLimits {
    mem_total: Option<u64>,
    cgroup_max: Option<u64>,
    address_space: Option<u64>,
}

fn machine_limits() -> &'static MachineLimits {
    static LIMITS: std::sync::OnceLock<MachineLimits> = std::sync::OnceLock::new();
    LIMITS.get_or_init(|| MachineLimits {
        mem_total: meminfo_kb("MemTotal:").map(|k| k * 1024),
        cgroup_max: std::fs::read_to_string("/sys/fs/cgroup/memory.max")
            .ok()
            .and_then(|s| s.trim().parse::<u64>().ok()),
        address_space: address_space_limit(),
    })
}

fn meminfo_kb(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// The soft `RLIMIT_AS` of this process (`prlimit --as`), if any.
fn address_space_limit() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/limits").ok()?;
    let line = s.lines().find(|l| l.starts_with("Max address space"))?;
    line["Max address space".len()..]
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The virtual size of this process now, in bytes.
fn vm_size() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmSize:"))?;
    line.split_whitespace()
        .nth(1)?
        .parse::<u64>()
        .ok()
        .map(|k| k * 1024)
}

/// The `tiff` decoder's limits for a file of `file_len` bytes: no tag value
/// list longer than the file could hold, and never more than the budget.
pub fn decoder_limits(file_len: u64) -> Limits {
    decoder_limits_within(file_len, memory_budget())
}

/// [`decoder_limits`] under a budget already computed.
pub(super) fn decoder_limits_within(file_len: u64, budget: u64) -> Limits {
    let per_value = std::mem::size_of::<tiff::decoder::ifd::Value>() as u64;
    let bound = file_len
        .saturating_mul(per_value)
        .clamp(1 << 20, budget.max(1 << 20));
    let bound = usize::try_from(bound).unwrap_or(usize::MAX);
    let mut l = Limits::default();
    l.decoding_buffer_size = bound;
    l.ifd_value_size = bound;
    l.intermediate_buffer_size = bound;
    l
}

/// The most bytes `compressed` bytes can decompress to with TIFF
/// compression `compression`, or `None` where the format has no useful
/// bound (ZSTD: its output is grown as it arrives instead).
pub fn max_decompressed(compression: u16, compressed: u64) -> Option<u64> {
    // Deflate: 258 bytes per 1-bit code at best (zlib's 1032:1); LZW: a
    // 9-bit code stands for at most 4096 bytes; PackBits: 2 bytes for 128.
    let ratio = match compression {
        1 => 1,
        8 | 32946 => 1032,
        5 => 3641,
        32773 => 64,
        _ => return None,
    };
    Some(compressed.saturating_mul(ratio).saturating_add(1024))
}
