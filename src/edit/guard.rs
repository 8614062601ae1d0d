//! What `demsketch edit` does around an edit before it runs, for every
//! caller of [`super::run`] that is a command (the CLI, the Python
//! package): take the DEM's edit lock (one edit at a time), finish or undo
//! an edit a killed run left half-applied ([`crate::raster::journal`]),
//! remove temporary files of dead runs, and refuse outputs that name an
//! input or each other ([`crate::raster::path_check`]).

use std::path::Path;
use std::time::Duration;

use super::EditOptions;
use crate::raster::atomic_file::clean_stale;
use crate::raster::edit_lock::{lock_dir, EditLock};
use crate::raster::path_check::{check_outputs, dem_inputs, Input, Output};
use crate::raster::{journal, Dem, Destination, LayerKind, RasterError};

/// Prepare an edit of `dem` with `sketch` and `opts`: the lock (held until
/// it is dropped; none for a DEM that is not a file or directory on disk,
/// such as a GDAL virtual path, which cannot be rewritten in place), after
/// waiting at most `timeout` for another edit; each recovery or clean-up
/// is said in one line to `note`.
pub fn prepare(
    dem: &Path,
    sketch: &Path,
    opts: &EditOptions,
    timeout: Duration,
    note: &mut dyn FnMut(&str),
) -> Result<Option<EditLock>, RasterError> {
    prepare_open(dem, sketch, opts, timeout, note).map(|(lock, _)| lock)
}

/// [`prepare`], handing back the DEM it opened (after any recovery) with
/// the lock: for [`super::run_opened`], so that an edit opens the DEM once
/// (on a directory of 1,024 tiles an open reads every tile's header).
pub fn prepare_open(
    dem: &Path,
    sketch: &Path,
    opts: &EditOptions,
    timeout: Duration,
    note: &mut dyn FnMut(&str),
) -> Result<(Option<EditLock>, Dem), RasterError> {
    // A DEM that is not a file or directory on disk (missing, or a GDAL
    // virtual path such as /vsizip/) has no directory to lock: its own
    // error, or no lock (it cannot be rewritten in place).
    let lock = if lock_dir(dem).is_dir() && dem.exists() {
        let lock = EditLock::acquire(dem, timeout, |m| note(m))?;
        for n in journal::recover(dem, &lock.dir)? {
            note(&n);
        }
        for n in clean_stale(&lock.dir) {
            note(&n);
        }
        Some(lock)
    } else {
        None
    };
    let layer = Dem::open(dem)?;
    let mut inputs = dem_inputs(&layer);
    inputs.push(Input {
        what: format!("the sketch {}", sketch.display()),
        path: sketch.to_path_buf(),
        is_dir: false,
    });
    let mut outputs = Vec::new();
    if let Destination::Path(out) = &opts.destination {
        outputs.push(Output {
            flag: "--out".into(),
            path: out.clone(),
            is_dir: layer.kind == LayerKind::TileDirectory,
        });
    }
    for (flag, p, is_dir) in [
        ("--report", &opts.report, false),
        ("--renders", &opts.renders, true),
        ("--dz", &opts.dz, false),
    ] {
        if let Some(p) = p {
            outputs.push(Output {
                flag: flag.into(),
                path: p.clone(),
                is_dir,
            });
        }
    }
    check_outputs(&inputs, &outputs)?;
    Ok((lock, layer))
}
