//! The refusal of a run whose config differs from the dataset's: which keys differ, old → new.

use super::dataset::{DatasetHeader, DATASET_FILE};
use crate::error::Error;
use std::collections::BTreeMap;
use std::path::Path;

/// How many differing keys a config-mismatch message lists.
const MAX_LISTED_DIFFERENCES: usize = 10;

/// The refusal for a config whose hash differs from the dataset's, listing the differing keys.
pub(super) fn config_mismatch(
    root: &Path,
    header: &DatasetHeader,
    recorded: &toml::Table,
    config: &toml::Table,
    config_hash: &str,
) -> Error {
    let short = |h: &str| h.chars().take(12).collect::<String>();
    let diffs = config_differences(recorded, config);
    let mut msg = format!(
        "the dataset {} was built with another pipeline config (its config_hash {}…, this run's {}…).",
        root.display(),
        short(&header.config_hash),
        short(config_hash)
    );
    if diffs.is_empty() {
        msg.push_str(" The keys and values are equal; only the hashes differ (computed by another code version?).");
    } else {
        msg.push_str(" Differing keys (dataset → this run):");
        for d in diffs.iter().take(MAX_LISTED_DIFFERENCES) {
            msg.push_str("\n  ");
            msg.push_str(d);
        }
        if diffs.len() > MAX_LISTED_DIFFERENCES {
            msg.push_str(&format!("\n  … and {} more", diffs.len() - MAX_LISTED_DIFFERENCES));
        }
    }
    msg.push_str(&format!(
        "\nA dataset holds the output of one config: write this run to a new output folder, or rerun with the \
         config recorded in {} to resume the dataset.",
        root.join(DATASET_FILE).display()
    ));
    Error::config("config", msg)
}

/// `key: old → new` for every dotted key whose value differs (`(absent)` for a missing key), sorted.
pub fn config_differences(old: &toml::Table, new: &toml::Table) -> Vec<String> {
    let (mut a, mut b) = (BTreeMap::new(), BTreeMap::new());
    flatten("", old, &mut a);
    flatten("", new, &mut b);
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    let show = |v: Option<&String>| match v {
        None => "(absent)".to_string(),
        Some(s) if s.chars().count() > 60 => format!("{}…", s.chars().take(60).collect::<String>()),
        Some(s) => s.clone(),
    };
    keys.into_iter()
        .filter(|k| a.get(*k) != b.get(*k))
        .map(|k| format!("{k}: {} → {}", show(a.get(k)), show(b.get(k))))
        .collect()
}

fn flatten(prefix: &str, table: &toml::Table, out: &mut BTreeMap<String, String>) {
    for (k, v) in table {
        let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
        match v {
            toml::Value::Table(t) => flatten(&key, t, out),
            other => {
                out.insert(key, other.to_string());
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shards::manifest::utc_now;
    use crate::shards::schema::SCHEMA_VERSION;
    use crate::shards::CODE_VERSION;

    #[test]
    fn long_differences_are_cut_at_ten() {
        let old: toml::Table = (0..15).map(|i| format!("k{i:02} = {i}\n")).collect::<String>().parse().unwrap();
        let new = toml::Table::new();
        assert_eq!(config_differences(&old, &new).len(), 15);
        let header = DatasetHeader {
            config_hash: "a".into(),
            schema_version: SCHEMA_VERSION.into(),
            code_version: CODE_VERSION.into(),
            created: utc_now(),
        };
        let msg = config_mismatch(Path::new("/d"), &header, &old, &new, "b").to_string();
        assert!(msg.contains("k09: 9 → (absent)") && !msg.contains("k10:") && msg.contains("and 5 more"), "{msg}");
    }
}
