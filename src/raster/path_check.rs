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

/// A path resolved for the checks: its canonical form ([`canonical`]) and
/// its file identity ([`identity`]), found once per path.
struct Resolved {
    canon: PathBuf,
    id: Option<(u64, u64)>,
}

impl Resolved {
    fn same(&self, other: &Resolved) -> bool {
        self.canon == other.canon || matches!((self.id, other.id), (Some(x), Some(y)) if x == y)
    }
}

/// Resolves paths, canonicalising each parent directory once: a file that
/// exists and is not a symbolic link is its canonical directory joined
/// with its name (what `canonicalize` gives, which resolves every
/// component of the path again, a `readlink` each), and its `lstat` is its
/// identity. Anything else (a link, a missing file, a path ending in `..`)
/// is resolved as [`canonical`] and [`identity`] do. On a directory of
/// 1,024 tiles this is 1,024 `lstat`s and one `realpath` instead of six
/// `realpath`s and four `stat`s per tile.
#[derive(Default)]
struct Resolver {
    dirs: std::collections::HashMap<PathBuf, Option<PathBuf>>,
}

impl Resolver {
    fn resolve(&mut self, p: &Path) -> Resolved {
        if let Some(r) = self.resolve_in_dir(p) {
            return r;
        }
        Resolved {
            canon: canonical(p),
            id: identity(p),
        }
    }

    fn resolve_in_dir(&mut self, p: &Path) -> Option<Resolved> {
        let name = match p.components().next_back() {
            Some(std::path::Component::Normal(n)) => n,
            _ => return None,
        };
        // (no trailing `/` or `/.`: the name must be the path's last bytes)
        if !p
            .as_os_str()
            .as_encoded_bytes()
            .ends_with(name.as_encoded_bytes())
        {
            return None;
        }
        let meta = std::fs::symlink_metadata(p).ok()?;
        if meta.file_type().is_symlink() {
            return None;
        }
        let parent = super::atomic_file::parent_dir(p);
        let dir = self
            .dirs
            .entry(parent.to_path_buf())
            .or_insert_with(|| parent.canonicalize().ok())
            .as_ref()?;
        Some(Resolved {
            canon: dir.join(name),
            id: Some((meta.dev(), meta.ino())),
        })
    }
}

/// Refuse outputs that would overwrite an input or each other, an output
/// directory that contains an input, and outputs inside an input tile
/// directory.
pub fn check_outputs(inputs: &[Input], outputs: &[Output]) -> Result<(), RasterError> {
    let refuse = |o: &Output, m: String| RasterError::Write {
        path: o.path.clone(),
        message: format!("{m}; nothing written"),
    };
    let mut resolver = Resolver::default();
    let ins: Vec<Resolved> = inputs.iter().map(|i| resolver.resolve(&i.path)).collect();
    let outs: Vec<Resolved> = outputs.iter().map(|o| resolver.resolve(&o.path)).collect();
    for (i, (o, or)) in outputs.iter().zip(&outs).enumerate() {
        let oc = &or.canon;
        for (inp, ir) in inputs.iter().zip(&ins) {
            if or.same(ir) {
                return Err(refuse(o, format!("{} names {}", o.flag, inp.what)));
            }
        }
        for (inp, ir) in inputs.iter().zip(&ins) {
            let ic = &ir.canon;
            if o.is_dir && ic.starts_with(oc) {
                return Err(refuse(
                    o,
                    format!("{} is a directory that holds {}", o.flag, inp.what),
                ));
            }
            if inp.is_dir && o.flag == "--out" && oc.starts_with(ic) {
                return Err(refuse(o, format!("{} lies inside {}", o.flag, inp.what)));
            }
        }
        for (p, pr) in outputs[..i].iter().zip(&outs) {
            if or.same(pr) {
                return Err(refuse(
                    o,
                    format!("given to both {} and {}", p.flag, o.flag),
                ));
            }
            let pc = &pr.canon;
            let inside = |dir: &Output, d: &Path, f: &Path| {
                dir.is_dir && dir.flag == "--out" && f != d && f.starts_with(d)
            };
            if inside(p, pc, oc) || inside(o, oc, pc) {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_resolver_gives_what_canonical_and_identity_give() {
        let tmp = tempfile::tempdir().expect("temporary directory");
        let d = tmp.path();
        std::fs::create_dir(d.join("sub")).expect("mkdir");
        std::fs::write(d.join("sub/tile.tif"), b"x").expect("write");
        std::os::unix::fs::symlink(d.join("sub/tile.tif"), d.join("link.tif")).expect("symlink");
        std::os::unix::fs::symlink(d.join("sub"), d.join("dirlink")).expect("symlink");
        std::fs::hard_link(d.join("sub/tile.tif"), d.join("hard.tif")).expect("hard link");
        let paths = [
            d.join("sub/tile.tif"),
            d.join("link.tif"),
            d.join("dirlink/tile.tif"),
            d.join("hard.tif"),
            d.join("sub/../sub/tile.tif"),
            d.join("sub/./tile.tif"),
            d.join("sub/tile.tif/"),
            d.join("sub/missing.tif"),
            d.join("missing/missing.tif"),
            d.join("sub"),
            d.join("sub/."),
            d.join("sub/.."),
            PathBuf::from("Cargo.toml"),
            PathBuf::from("src/../Cargo.toml"),
        ];
        let mut r = Resolver::default();
        for p in &paths {
            let got = r.resolve(p);
            assert_eq!(got.canon, canonical(p), "{}", p.display());
            assert_eq!(got.id, identity(p), "{}", p.display());
        }
        for a in &paths {
            for b in &paths {
                assert_eq!(r.resolve(a).same(&r.resolve(b)), same(a, b));
            }
        }
    }
}
