//! Provenance as a history: every edit appends one entry (tool version,
//! time, input, sketch digest, parameters, changed cells) to the file's
//! metadata, which `gdalinfo` shows. Entries are numbered items
//! `DEMSKETCH_PROVENANCE_1` .. `_N` in the default domain, earlier entries
//! kept as they were; `DEMSKETCH_PROVENANCE` repeats the latest entry for
//! readers of the single item older versions wrote (such an item, found
//! without numbered ones, becomes entry 1).

use sha2::{Digest, Sha256};

/// The item holding the latest entry.
pub const PROVENANCE_KEY: &str = "DEMSKETCH_PROVENANCE";

/// What an edit records about itself besides its id (all optional: a
/// library caller may know none of it).
#[derive(Debug, Clone, Default)]
pub struct ProvenanceRecord {
    /// The input DEM as the user named it.
    pub input: Option<String>,
    /// SHA-256 of the sketch file's bytes, hex.
    pub sketch_sha256: Option<String>,
    /// The edit's parameters, as flags (`--max-distance 50000 ...`).
    pub parameters: Option<String>,
}

/// SHA-256 of `bytes`, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// One history entry, `key=value; ...` (values stripped of `;` and line
/// breaks, so that an entry stays one line).
pub fn entry(edit_id: &str, time: &str, changed_cells: usize, record: &ProvenanceRecord) -> String {
    let clean = |s: &str| s.replace([';', '\n', '\r'], " ");
    let mut parts = vec![
        format!("tool=demsketch {}", env!("CARGO_PKG_VERSION")),
        format!("edit={}", clean(edit_id)),
        format!("time={time}"),
    ];
    if let Some(i) = &record.input {
        parts.push(format!("input={}", clean(i)));
    }
    if let Some(d) = &record.sketch_sha256 {
        parts.push(format!("sketch_sha256={d}"));
    }
    if let Some(p) = &record.parameters {
        parts.push(format!("parameters={}", clean(p)));
    }
    parts.push(format!("changed_cells={changed_cells}"));
    parts.join("; ")
}

/// The items to set so that `existing` (a dataset's default-domain
/// metadata, `KEY=VALUE` strings) gains `new_entry` at the end of its
/// history.
pub fn history_items(existing: &[String], new_entry: &str) -> Vec<(String, String)> {
    let prefix = format!("{PROVENANCE_KEY}_");
    let mut numbered = 0usize;
    let mut latest = None;
    for item in existing {
        let Some((k, v)) = item.split_once('=') else {
            continue;
        };
        if k == PROVENANCE_KEY {
            latest = Some(v.to_string());
        } else if let Some(n) = k
            .strip_prefix(&prefix)
            .and_then(|n| n.parse::<usize>().ok())
        {
            numbered = numbered.max(n);
        }
    }
    let mut items = Vec::new();
    if numbered == 0 {
        if let Some(old) = latest {
            numbered = 1;
            items.push((format!("{prefix}1"), old));
        }
    }
    items.push((format!("{prefix}{}", numbered + 1), new_entry.to_string()));
    items.push((PROVENANCE_KEY.to_string(), new_entry.to_string()));
    items
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn history_appends_and_keeps_the_old_single_item() {
        let first = history_items(&[], "a");
        assert_eq!(
            first,
            vec![
                ("DEMSKETCH_PROVENANCE_1".to_string(), "a".to_string()),
                ("DEMSKETCH_PROVENANCE".to_string(), "a".to_string())
            ]
        );
        let old = vec!["DEMSKETCH_PROVENANCE=old".to_string(), "X=1".to_string()];
        let items = history_items(&old, "b");
        assert_eq!(items[0], ("DEMSKETCH_PROVENANCE_1".into(), "old".into()));
        assert_eq!(items[1], ("DEMSKETCH_PROVENANCE_2".into(), "b".into()));
        let later = vec![
            "DEMSKETCH_PROVENANCE_1=a".to_string(),
            "DEMSKETCH_PROVENANCE_2=b".to_string(),
            "DEMSKETCH_PROVENANCE=b".to_string(),
        ];
        assert_eq!(history_items(&later, "c")[0].0, "DEMSKETCH_PROVENANCE_3");
    }

    #[test]
    fn sha256_of_abc() {
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
