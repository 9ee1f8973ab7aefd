//! The file and folder paths a config names: where they resolve, and how a resolved config is identified.
//!
//! - A relative path written in a config file resolves against the **config file's folder**; one given
//!   on the command line (`--set key=value`) against the **working directory**, as a shell user expects.
//!   Absolute paths and built-in models (`builtin:models/…`) stay as they are. [`PathBase`] does this.
//! - The **identity** of a resolved config (what a dataset records in `dataset.toml` and hashes, checked on
//!   resume) must not depend on where the command was started or where the checkout lies, yet two
//!   different checkpoints must never look alike: [`identity_toml`] writes every path inside the
//!   config's folder relative to it again (as the file wrote it) and appends the blake3 of every
//!   checkpoint's content.

use crate::error::{Error, Result};
use crate::nn::ModelPath;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A config with paths in it.
pub trait ConfigPaths: Clone + Serialize {
    /// Calls `visit(key, path)` on every file or folder path of the config, with its dotted key
    /// (`source.path`, `correct.condition.checkpoint`); `visit` may change the path.
    fn for_each_path(&mut self, visit: &mut dyn FnMut(&str, &mut PathBuf));
    /// The model checkpoints among those paths, by key.
    fn checkpoints(&self) -> Vec<(&'static str, ModelPath)>;
    /// The folder its relative paths were resolved against (`None`: made in code, paths as given).
    fn folder(&self) -> Option<&Path>;
    fn set_folder(&mut self, folder: PathBuf);
}

/// Visits a checkpoint path with `visit` (a [`ModelPath`] is an interned string, not a `PathBuf`).
pub fn visit_model(visit: &mut dyn FnMut(&str, &mut PathBuf), key: &str, model: &mut ModelPath) {
    let mut path = model.as_path().to_path_buf();
    visit(key, &mut path);
    if path != model.as_path() {
        *model = ModelPath::new(&path.to_string_lossy());
    }
}

/// Where the relative paths of one config resolve.
#[derive(Clone, Debug)]
pub struct PathBase {
    /// The config file's folder, absolute.
    folder: PathBuf,
    /// The working directory.
    cwd: PathBuf,
    /// Dotted keys given on the command line (`--set`): a path at or below one of them came from there.
    command_line: Vec<String>,
}

impl PathBase {
    /// For the config file `file` (a path relative to the working directory, or absolute) loaded with the
    /// `--set` assignments `set`.
    pub fn of_file(file: &Path, set: &[String]) -> Result<PathBase> {
        let cwd = std::env::current_dir().map_err(|e| Error::io(".", e))?;
        let file = std::path::absolute(file).map_err(|e| Error::io(file, e))?;
        let folder = file.parent().map(Path::to_path_buf).unwrap_or_else(|| cwd.clone());
        let command_line = set.iter().filter_map(|s| s.split_once('=')).map(|(k, _)| k.trim().to_string()).collect();
        Ok(PathBase { folder, cwd, command_line })
    }

    /// The config file's folder.
    pub fn folder(&self) -> &Path {
        &self.folder
    }

    /// `path`, the value of `key`, resolved: against the working directory when `key` was set on the
    /// command line, else against the config's folder. Absolute, empty and built-in paths are kept.
    pub fn resolve(&self, key: &str, path: &Path) -> PathBuf {
        if path.is_absolute() || path.as_os_str().is_empty() || crate::nn::shipped::is_builtin(path) {
            return path.to_path_buf();
        }
        let from_command_line = self.command_line.iter().any(|k| key == k || key.strip_prefix(k.as_str()).is_some_and(|r| r.starts_with('.')));
        if from_command_line { self.cwd.join(path) } else { self.folder.join(path) }
    }

    /// Resolves every path of `config` and records its folder.
    pub fn apply<C: ConfigPaths>(&self, config: &mut C) {
        config.for_each_path(&mut |key, path| *path = self.resolve(key, path));
        config.set_folder(self.folder.clone());
    }
}

/// `config` with every path inside its folder written relative to that folder again (what the config
/// file said, whatever the working directory or the checkout's place).
pub fn relative_to_folder<C: ConfigPaths>(config: &C) -> C {
    let mut c = config.clone();
    if let Some(folder) = config.folder() {
        c.for_each_path(&mut |_, path| {
            if let Ok(rest) = path.strip_prefix(folder) {
                if !rest.as_os_str().is_empty() {
                    *path = rest.to_path_buf();
                }
            }
        });
    }
    c
}

/// The identity of a resolved config as TOML: [`relative_to_folder`], then a `[checkpoint_blake3]`
/// table with the content hash of each checkpoint by key (none without checkpoints, so a config without
/// models keeps the text, and the hash, it had before checkpoints were hashed).
pub fn identity_toml<C: ConfigPaths>(config: &C) -> Result<String> {
    let text = toml::to_string(&relative_to_folder(config)).map_err(|e| Error::Internal(format!("config to TOML: {e}")))?;
    let mut hashes: BTreeMap<&str, String> = BTreeMap::new();
    let mut by_file: BTreeMap<&str, String> = BTreeMap::new();
    for (key, model) in config.checkpoints() {
        let hash = match by_file.get(model.as_str()) {
            Some(h) => h.clone(),
            None => model.blake3().map_err(|e| Error::config(key, format!("checkpoint `{model}`: {e}")))?,
        };
        by_file.insert(model.as_str(), hash.clone());
        hashes.insert(key, hash);
    }
    if hashes.is_empty() {
        return Ok(text);
    }
    let table = BTreeMap::from([("checkpoint_blake3", hashes)]);
    let tail = toml::to_string(&table).map_err(|e| Error::Internal(format!("checkpoint hashes to TOML: {e}")))?;
    Ok(format!("{text}\n{tail}"))
}

/// What identifies a resolved config: the text a dataset records in `dataset.toml`, its blake3 (the
/// dataset's config hash, checked on resume) and the blake3 of the content-determining part (without the
/// shard size: each row's `config_hash`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigIdentity {
    pub toml: String,
    pub dataset_hash: String,
    pub content_hash: String,
}

impl ConfigIdentity {
    /// From the identity texts of the config and of the config without its shard size.
    pub fn new(toml: String, content_toml: &str) -> ConfigIdentity {
        let hash = |t: &str| blake3::hash(t.as_bytes()).to_hex().to_string();
        ConfigIdentity { dataset_hash: hash(&toml), content_hash: hash(content_toml), toml }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn base(folder: &Path, cwd: &Path, set: &[&str]) -> PathBase {
        PathBase { folder: folder.to_path_buf(), cwd: cwd.to_path_buf(), command_line: set.iter().map(|s| s.to_string()).collect() }
    }

    #[test]
    fn file_values_resolve_against_the_folder_and_command_line_values_against_the_working_directory() {
        let b = base(Path::new("/cfg"), Path::new("/run"), &["source.path", "inpaint"]);
        assert_eq!(b.resolve("correct.condition.checkpoint", Path::new("m.safetensors")), Path::new("/cfg/m.safetensors"));
        assert_eq!(b.resolve("source.path", Path::new("seq")), Path::new("/run/seq"));
        assert_eq!(b.resolve("inpaint.checkpoint", Path::new("d.safetensors")), Path::new("/run/d.safetensors"), "set as a table");
        assert_eq!(b.resolve("source.pathx", Path::new("a")), Path::new("/cfg/a"), "only whole key parts match");
        for kept in ["/abs/x", "builtin:models/correction-tiny.safetensors", ""] {
            assert_eq!(b.resolve("correct.output.checkpoint", Path::new(kept)), Path::new(kept));
        }
    }

    /// A config with a folder path and a checkpoint, as the real ones have.
    #[derive(Clone, Serialize)]
    struct Config {
        frames: PathBuf,
        checkpoint: ModelPath,
        #[serde(skip)]
        folder: Option<PathBuf>,
    }

    impl ConfigPaths for Config {
        fn for_each_path(&mut self, visit: &mut dyn FnMut(&str, &mut PathBuf)) {
            visit("frames", &mut self.frames);
            visit_model(visit, "checkpoint", &mut self.checkpoint);
        }
        fn checkpoints(&self) -> Vec<(&'static str, ModelPath)> {
            vec![("checkpoint", self.checkpoint)]
        }
        fn folder(&self) -> Option<&Path> {
            self.folder.as_deref()
        }
        fn set_folder(&mut self, folder: PathBuf) {
            self.folder = Some(folder);
        }
    }

    /// The config `frames = "frames"`, `checkpoint = "net.safetensors"` as if it were a file in `folder`,
    /// read from the working directory `cwd`.
    fn resolved(folder: &Path, cwd: &Path) -> Config {
        let mut c = Config { frames: "frames".into(), checkpoint: ModelPath::new("net.safetensors"), folder: None };
        base(folder, cwd, &[]).apply(&mut c);
        c
    }

    #[test]
    fn the_identity_is_the_same_from_any_folder_and_differs_with_the_checkpoint_content() {
        let dir = tempfile::tempdir().unwrap();
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/correction-tiny.safetensors");
        let (a, b) = (dir.path().join("a"), dir.path().join("moved/b"));
        for f in [&a, &b] {
            std::fs::create_dir_all(f).unwrap();
            std::fs::copy(&shipped, f.join("net.safetensors")).unwrap();
        }
        let ca = resolved(&a, Path::new("/run/one"));
        assert_eq!((ca.frames.as_path(), ca.checkpoint.as_path()), (a.join("frames").as_path(), a.join("net.safetensors").as_path()));
        let text = identity_toml(&ca).unwrap();
        let hash = blake3::hash(&std::fs::read(&shipped).unwrap()).to_hex().to_string();
        let want = format!("frames = \"frames\"\ncheckpoint = \"net.safetensors\"\n\n[checkpoint_blake3]\ncheckpoint = \"{hash}\"\n");
        assert_eq!(text, want);
        // Another working directory, or the same files in another place: the same identity.
        assert_eq!(identity_toml(&resolved(&a, Path::new("/elsewhere"))).unwrap(), text);
        assert_eq!(identity_toml(&resolved(&b, Path::new("/run/one"))).unwrap(), text);
        // Without a folder (made in code) paths stay as they are; without checkpoints no hash table.
        assert!(identity_toml(&Config { folder: None, ..ca.clone() }).unwrap().contains(&a.join("frames").display().to_string()));
        // Another checkpoint at the same relative path: another identity.
        let mut bytes = std::fs::read(b.join("net.safetensors")).unwrap();
        *bytes.last_mut().unwrap() ^= 1;
        std::fs::write(b.join("net.safetensors"), bytes).unwrap();
        assert_ne!(identity_toml(&resolved(&b, Path::new("/run/one"))).unwrap(), text);
        // A missing checkpoint is a config error naming its key and file.
        std::fs::remove_file(a.join("net.safetensors")).unwrap();
        let e = identity_toml(&ca).unwrap_err().to_string();
        assert!(e.contains("`checkpoint`") && e.contains("net.safetensors"), "{e}");
    }
}
