//! Outputs never land on inputs. Before anything is written, every output
//! path a command was given (`--out`, `--report`, `--renders`, `--depth`,
//! ...) is compared with every input (each tile of the DEM, the sketch) and
//! with the other outputs, after canonicalisation (symlinks and `..`
//! resolved; an output that does not exist yet by its directory) and by
//! file identity (device and inode, so a hard link is caught too). An
//! output directory may not contain an input, and `--out` may not lie
//! inside an input tile directory (its tiles would join the input). The refusal is one line naming the
//! output.

use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use super::RasterError;

/// An input: what it is (for the message) and its path.
pub struct Input {
    pub what: String,
    pub path: PathBuf,
    /// A directory of tiles (nothing may be written inside it).
    pub is_dir: bool,
}

/// An output: the flag that named it and its path.
pub struct Output {
    pub flag: String,
    pub path: PathBuf,
    /// A directory the command fills (it may not contain an input).
    pub is_dir: bool,
}

/// The canonical form of `p`: `canonicalize` when it exists, otherwise its
/// canonical directory joined with its name.
fn canonical(p: &Path) -> PathBuf {
    if let Ok(c) = p.canonicalize() {
        return c;
    }
    let parent = super::atomic_file::parent_dir(p);
    match (parent.canonicalize(), p.file_name()) {
        (Ok(d), Some(n)) => d.join(n),
        _ => std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf()),
    }
}

/// Device and inode of an existing file.
fn identity(p: &Path) -> Option<(u64, u64)> {
    std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()))
}

fn same(a: &Path, b: &Path) -> bool {
    canonical(a) == canonical(b)
        || matches!((identity(a), identity(b)), (Some(x), Some(y)) if x == y)
}

/// Refuse outputs that would overwrite an input or each other, an output
/// directory that contains an input, and outputs inside an input tile
/// directory.
pub fn check_outputs(inputs: &[Input], outputs: &[Output]) -> Result<(), RasterError> {
    let refuse = |o: &Output, m: String| RasterError::Write {
        path: o.path.clone(),
        message: format!("{m}; nothing written"),
    };
    for (i, o) in outputs.iter().enumerate() {
        let oc = canonical(&o.path);
        for inp in inputs {
            if same(&o.path, &inp.path) {
                return Err(refuse(o, format!("{} names {}", o.flag, inp.what)));
            }
        }
        for inp in inputs {
            let ic = canonical(&inp.path);
            if o.is_dir && ic.starts_with(&oc) {
                return Err(refuse(
                    o,
                    format!("{} is a directory that holds {}", o.flag, inp.what),
                ));
            }
            if inp.is_dir && o.flag == "--out" && oc.starts_with(&ic) {
                return Err(refuse(o, format!("{} lies inside {}", o.flag, inp.what)));
            }
        }
        for p in &outputs[..i] {
            if same(&o.path, &p.path) {
                return Err(refuse(
                    o,
                    format!("given to both {} and {}", p.flag, o.flag),
                ));
            }
            let pc = canonical(&p.path);
            let inside = |dir: &Output, d: &Path, f: &Path| {
                dir.is_dir && dir.flag == "--out" && f != d && f.starts_with(d)
            };
            if inside(p, &pc, &oc) || inside(o, &oc, &pc) {
                return Err(refuse(o, format!("{} and {} overlap", p.flag, o.flag)));
            }
        }
    }
    Ok(())
}

/// The files GDAL reads for a dataset (a VRT's sources included), as GDAL
/// lists them.
fn gdal_files(ds: &gdal::Dataset) -> Vec<PathBuf> {
    let mut out = Vec::new();
    // SAFETY: the dataset handle is valid while `ds` lives; the list is a
    // NULL-terminated array of C strings that we free with CSLDestroy.
    unsafe {
        let list = gdal_sys::GDALGetFileList(ds.c_dataset());
        if list.is_null() {
            return out;
        }
        let mut i = 0;
        loop {
            let p = *list.add(i);
            if p.is_null() {
                break;
            }
            let s = std::ffi::CStr::from_ptr(p).to_string_lossy().into_owned();
            out.push(PathBuf::from(s));
            i += 1;
        }
        gdal_sys::CSLDestroy(list);
    }
    out
}

/// The inputs of a DEM: each of its tile files (by the path it was opened
/// with; for a raster GDAL reads, every file GDAL lists, such as a VRT's
/// sources), and for a tile directory the directory itself.
pub fn dem_inputs(dem: &super::Dem) -> Vec<Input> {
    let mut v: Vec<Input> = dem
        .tiles
        .iter()
        .map(|t| Input {
            what: if dem.tiles.len() == 1 {
                format!("the input DEM {}", t.path.display())
            } else {
                format!("the input tile {}", t.path.display())
            },
            path: t.path.clone(),
            is_dir: false,
        })
        .collect();
    for t in &dem.tiles {
        if let super::TileSource::Gdal(ds) = &t.source {
            if let Ok(ds) = ds.lock() {
                for f in gdal_files(&ds) {
                    if !same(&f, &t.path) {
                        v.push(Input {
                            what: format!("{}, a file of the input DEM", f.display()),
                            path: f,
                            is_dir: false,
                        });
                    }
                }
            }
        }
    }
    if dem.kind == super::LayerKind::TileDirectory {
        v.push(Input {
            what: format!("the input tile directory {}", dem.path.display()),
            path: dem.path.clone(),
            is_dir: true,
        });
    }
    v
}
