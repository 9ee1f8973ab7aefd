//! `ModelPath`: a `Copy` file path for configs that must stay `Copy` (the pipeline's correction configs):
//! a checkpoint file, or a built-in model named `builtin:models/<file>` ([`super::shipped`]).

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::collections::HashSet;
use std::path::Path;
use std::sync::Mutex;

/// A path interned for the life of the process (each distinct path is stored once), so a config enum
/// holding it stays `Copy`. Serialises as a plain string.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct ModelPath(&'static str);

static INTERNED: Mutex<Option<HashSet<&'static str>>> = Mutex::new(None);

impl ModelPath {
    pub fn new(path: &str) -> ModelPath {
        let mut guard = INTERNED.lock().unwrap_or_else(|e| e.into_inner());
        let set = guard.get_or_insert_with(HashSet::new);
        if let Some(s) = set.get(path) {
            return ModelPath(s);
        }
        let s: &'static str = Box::leak(path.to_owned().into_boxed_str());
        set.insert(s);
        ModelPath(s)
    }

    pub fn as_path(&self) -> &'static Path {
        Path::new(self.0)
    }

    pub fn as_str(&self) -> &'static str {
        self.0
    }

    /// Whether this names a built-in model rather than a file.
    pub fn is_builtin(&self) -> bool {
        super::shipped::is_builtin(self.as_path())
    }

    /// blake3 of the model's bytes, hex: what identifies a checkpoint wherever its file lies.
    pub fn blake3(&self) -> crate::Result<String> {
        Ok(blake3::hash(&super::shipped::read_model(self.as_path())?).to_hex().to_string())
    }
}

impl std::fmt::Debug for ModelPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.0)
    }
}

impl std::fmt::Display for ModelPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.0)
    }
}

impl Serialize for ModelPath {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.0)
    }
}

impl<'de> Deserialize<'de> for ModelPath {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Ok(ModelPath::new(&String::deserialize(d)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equal_paths_share_one_string_and_round_trip_through_toml() {
        let (a, b) = (ModelPath::new("models/x.safetensors"), ModelPath::new(&String::from("models/x.safetensors")));
        assert!(std::ptr::eq(a.as_str(), b.as_str()));
        #[derive(Serialize, Deserialize)]
        struct T {
            p: ModelPath,
        }
        let text = toml::to_string(&T { p: a }).unwrap();
        assert_eq!(text.trim(), "p = \"models/x.safetensors\"");
        assert_eq!(toml::from_str::<T>(&text).unwrap().p, a);
    }
}
