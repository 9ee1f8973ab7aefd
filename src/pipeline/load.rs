//! Reading a config file of any kind (a build pipeline, a label pipeline, a training data config): the
//! TOML, the `--set` overrides, then its relative paths resolved ([`crate::config_paths`]: against the
//! file's folder, `--set` values against the working directory). The classical pipeline `eval boost`
//! starts from by default is also built into the binary, as [`BUILTIN_CLASSICAL`].

use super::overrides::apply_override;
use crate::config_paths::{ConfigPaths, PathBase};
use crate::error::{Error, Result};
use std::path::Path;

/// `pipelines/paper-3dmatch-classical.toml` as shipped, built in (its relative paths, having no folder,
/// are relative to the working directory).
pub const BUILTIN_CLASSICAL: &str = "builtin:pipelines/paper-3dmatch-classical.toml";

const BUILTIN_CONFIGS: [(&str, &str); 1] = [(BUILTIN_CLASSICAL, include_str!("../../pipelines/paper-3dmatch-classical.toml"))];

/// Reads the config file `path` (or a built-in config), applies the `--set` assignments `set` and
/// resolves its relative paths.
pub fn load_toml<T: serde::de::DeserializeOwned + ConfigPaths>(path: &Path, set: &[String]) -> Result<T> {
    let origin = path.display().to_string();
    let builtin = crate::nn::shipped::is_builtin(path);
    let text = match builtin {
        true => BUILTIN_CONFIGS.iter().find(|(name, _)| Path::new(name) == path).map(|(_, text)| text.to_string()).ok_or_else(|| {
            let known: Vec<&str> = BUILTIN_CONFIGS.iter().map(|(name, _)| *name).collect();
            Error::config(&origin, format!("no such built-in config; the built-in configs are {}", known.join(", ")))
        })?,
        false => std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?,
    };
    let mut doc: toml::Table = text.parse().map_err(|e: toml::de::Error| Error::config(&origin, e.to_string()))?;
    for s in set {
        apply_override(&mut doc, s)?;
    }
    let mut config: T = toml::Value::Table(doc).try_into().map_err(|e: toml::de::Error| super::config::config_error(&origin, &e))?;
    if !builtin {
        PathBase::of_file(path, set)?.apply(&mut config);
    }
    Ok(config)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::BuildConfig;

    #[test]
    fn the_built_in_classical_config_is_the_shipped_file_and_unknown_names_are_refused() {
        let builtin: BuildConfig = load_toml(Path::new(BUILTIN_CLASSICAL), &["seed=4".into()]).unwrap();
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/paper-3dmatch-classical.toml");
        let file: BuildConfig = load_toml(&shipped, &["seed=4".into()]).unwrap();
        assert_eq!((builtin.folder.as_deref(), file.folder.as_deref()), (None, shipped.parent()));
        assert_ne!(builtin, file, "the file's source path is resolved against its folder");
        assert_eq!(builtin.identity().unwrap(), file.identity().unwrap(), "the same config as written");
        let e = load_toml::<BuildConfig>(Path::new("builtin:pipelines/demo.toml"), &[]).unwrap_err().to_string();
        assert!(e.contains("builtin:pipelines/demo.toml") && e.contains(BUILTIN_CLASSICAL), "{e}");
    }
}
