//! The `demsketch` command line: a thin layer over the library. Each
//! subcommand lives in `cli/` and only parses flags, calls the library and
//! prints. Exit codes: 0 success, 1 user error (one line naming the file and
//! the problem), 2 internal error, 3 an edit whose fit is below `--min-fit`
//! (nothing written).

// No unwrap on what comes from a file, a user or the OS (see `lib.rs`).
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

mod cli;

// mimalloc keeps freed pages for reuse: the renderer's and solver's large
// per-view buffers would otherwise come back from the kernel zeroed, with a
// page fault per 4 KB, on every view of an edit (about a third of a 512 x 512
// render's time with glibc's allocator, `docs/benchmarks.md`).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use clap::Parser;

fn main() {
    no_transparent_huge_pages();
    // A panic is an internal error: report it in one line and exit 2.
    std::panic::set_hook(Box::new(|info| {
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        // `println!` to a closed pipe (`demsketch info --json | head`): the
        // reader has what it wanted; end quietly.
        if msg.contains("Broken pipe") || msg.contains("os error 32") {
            std::process::exit(0);
        }
        let loc = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!("demsketch: internal error: {msg}{loc}");
        std::process::exit(2);
    }));
    // GDAL's failures are captured (a write that GDAL reports as failed
    // fails), not printed (shown with --verbose); SIGINT/SIGTERM remove
    // temporary files.
    cli::install_gdal_error_handler();
    cli::install_proj_message_handler();
    demsketch::raster::atomic_file::install_signal_cleanup();
    // Bad flags are user errors (exit 1, as DESIGN.md says), not clap's
    // default 2, which demsketch keeps for internal errors.
    let args = match cli::Cli::try_parse_from(cli::gdal_style_args(std::env::args_os())) {
        Ok(a) => a,
        Err(e) => {
            let code = if e.use_stderr() { 1 } else { 0 };
            let _ = e.print();
            std::process::exit(code);
        }
    };
    match cli::run(args) {
        Ok(()) => {}
        Err(e) if cli::is_broken_pipe(&e) => std::process::exit(0),
        Err(e) => {
            let code = cli::exit_code(&e);
            let mut msg = e.to_string();
            for cause in e.chain().skip(1) {
                let c = cause.to_string();
                if !msg.contains(&c) {
                    msg.push_str(": ");
                    msg.push_str(&c);
                }
            }
            eprintln!("demsketch: {}", msg.replace('\n', " "));
            std::process::exit(code);
        }
    }
}

/// Turns transparent huge pages off for this process (Linux; elsewhere
/// nothing). mimalloc asks for them on its arenas, and the kernel then
/// clears a whole 2 MB page at the first touch of any byte of it, and may
/// compact memory first to find one: on the 512 x 512 dry run of
/// `docs/benchmarks.md` that was 0.01 to 0.2 s of system time a run
/// (varying with the machine's memory), for 40 MB more resident memory
/// than the edit touches. With 4 KB pages only what is written is cleared.
fn no_transparent_huge_pages() {
    #[cfg(target_os = "linux")]
    // SAFETY: prctl(PR_SET_THP_DISABLE, 1, 0, 0, 0) takes no pointers and
    // only sets a flag of this process; a failure (an old kernel) leaves
    // things as they were.
    unsafe {
        let _ = libc::prctl(libc::PR_SET_THP_DISABLE, 1, 0, 0, 0);
    }
}
