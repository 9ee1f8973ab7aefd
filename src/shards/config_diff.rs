//! Which keys of two configs differ, old → new: what the refusal of a run whose config differs from the
//! dataset's lists.

use std::collections::BTreeMap;

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

    #[test]
    fn nested_keys_are_dotted_and_long_values_cut() {
        let old: toml::Table = "a = 1\n[b]\nc = \"x\"\nd = [1, 2]\n".parse().unwrap();
        let new: toml::Table = format!("a = 1\n[b]\nc = \"y\"\ne = \"{}\"\n", "z".repeat(80)).parse().unwrap();
        let d = config_differences(&old, &new);
        assert_eq!(d.len(), 3, "{d:?}");
        assert_eq!(d[0], "b.c: \"x\" → \"y\"");
        assert_eq!(d[1], "b.d: [1, 2] → (absent)");
        assert!(d[2].starts_with("b.e: (absent) → \"zzz") && d[2].ends_with('…'), "{}", d[2]);
        assert!(config_differences(&old, &old).is_empty());
    }
}
