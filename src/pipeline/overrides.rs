//! `--set key=value` overrides applied to a TOML document before it is parsed into a config.

use crate::error::{Error, Result};
use toml::{Table, Value};

/// Applies `dotted.key=value` to `doc`. The value is parsed as a TOML value (`3`, `0.5`, `true`,
/// `"text"`, `[1, 2]`, `{ a = 1 }`); anything that does not parse is taken as a string. Intermediate
/// tables are created as needed.
pub fn apply_override(doc: &mut Table, assignment: &str) -> Result<()> {
    let (key, raw) = assignment
        .split_once('=')
        .ok_or_else(|| Error::config("--set", format!("`{assignment}` is not of the form key=value")))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(|p| p.is_empty()) {
        return Err(Error::config("--set", format!("`{key}` is not a dotted key")));
    }
    let value = parse_value(raw.trim());
    let parts: Vec<&str> = key.split('.').collect();
    let mut table = doc;
    for part in &parts[..parts.len() - 1] {
        let entry = table.entry(part.to_string()).or_insert_with(|| Value::Table(Table::new()));
        table = entry
            .as_table_mut()
            .ok_or_else(|| Error::config(key, format!("`{part}` is a value, not a table")))?;
    }
    table.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

fn parse_value(raw: &str) -> Value {
    let wrapped = format!("v = {raw}");
    match wrapped.parse::<Table>() {
        Ok(mut t) => t.remove("v").unwrap_or_else(|| Value::String(raw.to_string())),
        Err(_) => Value::String(raw.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_nested_values_with_toml_types() {
        let mut doc: Table = "seed = 1\n[voxelize]\nvoxel = 0.025\n".parse().unwrap();
        apply_override(&mut doc, "voxelize.voxel=0.05").unwrap();
        apply_override(&mut doc, "seed = 9").unwrap();
        apply_override(&mut doc, "source.path=/data/3dmatch").unwrap();
        apply_override(&mut doc, "working.crop_box.min=[-1.0, -1.0, 0.5]").unwrap();
        assert_eq!(doc["voxelize"]["voxel"].as_float(), Some(0.05));
        assert_eq!(doc["seed"].as_integer(), Some(9));
        assert_eq!(doc["source"]["path"].as_str(), Some("/data/3dmatch"));
        assert_eq!(doc["working"]["crop_box"]["min"].as_array().unwrap().len(), 3);
    }

    #[test]
    fn malformed_assignments_are_refused() {
        let mut doc = Table::new();
        assert!(apply_override(&mut doc, "novalue").is_err());
        assert!(apply_override(&mut doc, "a..b=1").is_err());
        apply_override(&mut doc, "a=1").unwrap();
        assert!(apply_override(&mut doc, "a.b=1").unwrap_err().to_string().contains("not a table"));
    }
}
