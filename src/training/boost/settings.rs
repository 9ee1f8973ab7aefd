//! The guard against mixing unlike units: the first run of `eval boost` records the settings its units
//! train with in `<out>/boost-settings.json`, and a rerun with other ones is refused, naming each setting
//! that differs.

use crate::atomic::{write_atomic, Publish};
use crate::error::{Error, Result};
use std::path::Path;

/// The settings a run's units and generated pairs were made with, in `<out>`: a rerun with other
/// settings would mix units trained differently in one table, so it is refused.
pub const SETTINGS: &str = "boost-settings.json";

/// Records a run's training settings (`now`, one key per setting) in `<out>/boost-settings.json`, or
/// checks them against the ones recorded, naming every setting that differs.
pub fn check(out: &Path, now: &serde_json::Value) -> Result<()> {
    let path = out.join(SETTINGS);
    match std::fs::read_to_string(&path) {
        Ok(text) => {
            let before: serde_json::Value = serde_json::from_str(&text).map_err(|e| Error::input(&path, format!("not readable JSON: {e}")))?;
            let mut lines = Vec::new();
            json_differences("", &before, now, &mut lines);
            if lines.is_empty() {
                return Ok(());
            }
            Err(Error::input(
                &path,
                format!(
                    "this run's units were trained with other settings; a table mixing them would compare unlike units. \
                     Rerun with the recorded settings, or give another --out:\n{}",
                    lines.join("\n")
                ),
            ))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
            let text = serde_json::to_string_pretty(now).expect("JSON values serialise");
            write_atomic(out, &path, format!("{text}\n").as_bytes(), Publish::Replace).map(|_| ())
        }
        Err(e) => Err(Error::io(&path, e)),
    }
}

/// Every leaf setting in which `now` differs from `before`, as `  a.b: recorded X, now Y`.
fn json_differences(at: &str, before: &serde_json::Value, now: &serde_json::Value, out: &mut Vec<String>) {
    use serde_json::Value;
    match (before, now) {
        (Value::Object(b), Value::Object(n)) => {
            let mut keys: Vec<&String> = b.keys().chain(n.keys()).collect();
            keys.sort();
            keys.dedup();
            let null = Value::Null;
            for k in keys {
                let path = if at.is_empty() { k.clone() } else { format!("{at}.{k}") };
                json_differences(&path, b.get(k).unwrap_or(&null), n.get(k).unwrap_or(&null), out);
            }
        }
        (b, n) if b != n => out.push(format!("  {at}: recorded {b}, now {n}")),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn differences_name_every_changed_leaf_and_only_those() {
        let before = json!({"pairs": 2000, "train": {"steps": 3, "lr": 0.001}, "gone": 1});
        let now = json!({"pairs": 2000, "train": {"steps": 4, "lr": 0.001}, "new": "x"});
        let mut lines = Vec::new();
        json_differences("", &before, &now, &mut lines);
        assert_eq!(lines, ["  gone: recorded 1, now null", "  new: recorded null, now \"x\"", "  train.steps: recorded 3, now 4"]);
        lines.clear();
        json_differences("", &before, &before, &mut lines);
        assert!(lines.is_empty());
    }

    #[test]
    fn a_first_run_records_and_a_different_rerun_is_refused_naming_the_setting() {
        let out = tempfile::tempdir().unwrap();
        let out = out.path().join("run");
        check(&out, &json!({"steps": 3})).unwrap();
        check(&out, &json!({"steps": 3})).unwrap();
        let err = check(&out, &json!({"steps": 4})).unwrap_err().to_string();
        assert!(err.contains("steps: recorded 3, now 4") && err.contains(SETTINGS), "{err}");
    }
}
