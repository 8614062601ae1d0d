//! The manifest of a batch: which sketches, in which order. Three forms:
//!
//! - a JSON file `{"edits": [{"id": "e1", "sketch": "sketches/e1.json"},
//!   {"id": "e2", "corrections": "fix/lakes.geojson"}, ...]}` (DESIGN.md;
//!   each edit a sketch or a map-view corrections file as `demsketch
//!   correct --features` reads it; `id` optional, default the file's stem;
//!   paths relative to the manifest);
//! - a text file, one sketch path per line (blank lines and lines starting
//!   with `#` skipped; relative to the manifest);
//! - a directory: its `*.json` files, sorted by name.
//!
//! Every sketch is read and parsed here, and its SHA-256 kept, so that a
//! missing or broken sketch stops the batch before anything is written, and
//! a sketch changed after planning is noticed. A corrections file is read
//! and hashed here too; its features are checked against the DEM when the
//! plan is made ([`super::plan`]).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::BatchError;
use crate::raster::provenance::sha256_hex;
use crate::sketch::SketchFile;

/// What an edit of a manifest applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EditKind {
    /// A sketch, as `demsketch edit OUT --sketch S --in-place` applies it.
    #[default]
    Sketch,
    /// Map-view corrections (GeoJSON), as `demsketch correct OUT
    /// --features F --in-place` applies them.
    Corrections,
}

/// One edit of a manifest.
#[derive(Debug, Clone)]
pub struct ManifestEdit {
    /// Unique within the manifest.
    pub id: String,
    pub kind: EditKind,
    /// The sketch or corrections file (as the manifest names it, joined to
    /// the manifest's directory, made absolute).
    pub sketch: PathBuf,
    /// SHA-256 of the file's bytes.
    pub sketch_sha256: String,
    /// The sketch, parsed (`None` for corrections).
    pub parsed: Option<SketchFile>,
}

/// A manifest, read and checked.
#[derive(Debug, Clone)]
pub struct Manifest {
    pub path: PathBuf,
    pub edits: Vec<ManifestEdit>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonManifest {
    edits: Vec<JsonEdit>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct JsonEdit {
    id: Option<String>,
    sketch: Option<String>,
    corrections: Option<String>,
}

fn bad(path: &Path, message: impl Into<String>) -> BatchError {
    BatchError::Manifest {
        path: path.display().to_string(),
        message: message.into(),
    }
}

impl Manifest {
    /// Read the manifest at `path` (a file or a directory of sketches) and
    /// every sketch it names.
    pub fn read(path: &Path) -> Result<Manifest, BatchError> {
        let entries = if path.is_dir() {
            directory_entries(path)?
        } else {
            let text = std::fs::read_to_string(path).map_err(|e| bad(path, e.to_string()))?;
            let base = path.parent().unwrap_or(Path::new("."));
            if text.trim_start().starts_with('{') {
                json_entries(path, &text, base)?
            } else {
                text_entries(&text, base)
            }
        };
        if entries.is_empty() {
            return Err(bad(path, "lists no sketch"));
        }
        let mut edits: Vec<ManifestEdit> = Vec::new();
        for (k, (id, kind, sketch)) in entries.into_iter().enumerate() {
            let sketch = std::path::absolute(&sketch).unwrap_or(sketch);
            let id = id.unwrap_or_else(|| {
                sketch
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| format!("edit{}", k + 1))
            });
            if !valid_id(&id) {
                return Err(bad(
                    path,
                    format!("edit id \"{id}\" must be letters, digits, '-', '_' or '.'"),
                ));
            }
            if edits.iter().any(|e| e.id == id) {
                return Err(bad(path, format!("edit id \"{id}\" appears twice")));
            }
            let what = match kind {
                EditKind::Sketch => "sketch",
                EditKind::Corrections => "corrections",
            };
            let bytes = std::fs::read(&sketch).map_err(|e| {
                bad(
                    path,
                    format!("edit \"{id}\": {what} {}: {e}", sketch.display()),
                )
            })?;
            let parsed = match kind {
                EditKind::Sketch => Some(
                    SketchFile::from_path(&sketch)
                        .map_err(|e| bad(path, format!("edit \"{id}\": {e}")))?,
                ),
                EditKind::Corrections => None,
            };
            edits.push(ManifestEdit {
                id,
                kind,
                sketch,
                sketch_sha256: sha256_hex(&bytes),
                parsed,
            });
        }
        Ok(Manifest {
            path: path.to_path_buf(),
            edits,
        })
    }
}

/// An id usable as a file name: letters, digits, `-`, `_`, `.` (not only dots).
fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 200
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
        && id.chars().any(|c| c != '.')
}

/// A manifest's entry: id (if given), kind, path.
type Entry = (Option<String>, EditKind, PathBuf);

fn json_entries(path: &Path, text: &str, base: &Path) -> Result<Vec<Entry>, BatchError> {
    let m: JsonManifest =
        serde_json::from_str(text).map_err(|e| bad(path, format!("not a batch manifest: {e}")))?;
    m.edits
        .into_iter()
        .enumerate()
        .map(|(k, e)| match (e.sketch, e.corrections) {
            (Some(s), None) => Ok((e.id, EditKind::Sketch, base.join(s))),
            (None, Some(c)) => Ok((e.id, EditKind::Corrections, base.join(c))),
            _ => Err(bad(
                path,
                format!(
                    "edit {}: give exactly one of \"sketch\" or \"corrections\"",
                    k + 1
                ),
            )),
        })
        .collect()
}

fn text_entries(text: &str, base: &Path) -> Vec<Entry> {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| (None, EditKind::Sketch, base.join(l)))
        .collect()
}

fn directory_entries(dir: &Path) -> Result<Vec<Entry>, BatchError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| bad(dir, e.to_string()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    Ok(files
        .into_iter()
        .map(|p| (None, EditKind::Sketch, p))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_file_names() {
        assert!(valid_id("e1"));
        assert!(valid_id("north-rim_2.v1"));
        assert!(!valid_id(".."));
        assert!(!valid_id("a/b"));
        assert!(!valid_id(""));
    }

    #[test]
    fn text_lists_skip_comments_and_blank_lines() {
        let e = text_entries("# header\n\na.json\n  b.json  \n", Path::new("/m"));
        let paths: Vec<PathBuf> = e.into_iter().map(|(_, _, p)| p).collect();
        assert_eq!(
            paths,
            vec![PathBuf::from("/m/a.json"), PathBuf::from("/m/b.json")]
        );
    }
}
