//! The small default checkpoints of `models/`, built into the binary: a config or a flag names one as
//! `builtin:models/<file>` (e.g. `builtin:models/correction-tiny.safetensors`), which works wherever the
//! binary runs. Every model file read goes through [`read_model`] / [`open_model`], which serve these
//! names from memory and any other path from disk.

use crate::error::{Error, Result};
use std::borrow::Cow;
use std::io::Read;
use std::path::Path;

/// The prefix of a built-in model's name.
pub const BUILTIN: &str = "builtin:";

/// The built-in files, by name (the path under the checkout, after [`BUILTIN`]).
const FILES: [(&str, &[u8]); 4] = [
    ("models/correction-tiny.safetensors", include_bytes!("../../models/correction-tiny.safetensors")),
    ("models/diffusion-tiny.safetensors", include_bytes!("../../models/diffusion-tiny.safetensors")),
    ("models/diffusion-tiny-refine.safetensors", include_bytes!("../../models/diffusion-tiny-refine.safetensors")),
    ("models/diffusion-tiny-holes.safetensors", include_bytes!("../../models/diffusion-tiny-holes.safetensors")),
];

/// Whether `path` names a built-in model (`builtin:…`; a local file of that name is written `./builtin:…`).
pub fn is_builtin(path: &Path) -> bool {
    path.to_str().is_some_and(|s| s.starts_with(BUILTIN))
}

/// The bytes of the built-in model `path` names; `None` when `path` is not a `builtin:` name.
fn builtin(path: &Path) -> Option<Result<&'static [u8]>> {
    let name = path.to_str()?.strip_prefix(BUILTIN)?;
    let found = FILES.iter().find(|(n, _)| *n == name).map(|(_, bytes)| *bytes);
    Some(found.ok_or_else(|| {
        let known: Vec<String> = FILES.iter().map(|(n, _)| format!("{BUILTIN}{n}")).collect();
        Error::input(path, format!("no such built-in model; the built-in models are {}", known.join(", ")))
    }))
}

/// The whole model file at `path` (a built-in name or a file on disk).
pub fn read_model(path: &Path) -> Result<Cow<'static, [u8]>> {
    match builtin(path) {
        Some(bytes) => bytes.map(Cow::Borrowed),
        None => std::fs::read(path).map(Cow::Owned).map_err(|e| Error::io(path, e)),
    }
}

/// The model file at `path` opened for reading, and its length in bytes.
pub fn open_model(path: &Path) -> Result<(Box<dyn Read>, u64)> {
    match builtin(path) {
        Some(bytes) => bytes.map(|b| (Box::new(b) as Box<dyn Read>, b.len() as u64)),
        None => {
            let f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
            let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
            Ok((Box::new(f), len))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_names_read_the_shipped_files_and_unknown_names_list_the_known_ones() {
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/correction-tiny.safetensors");
        let name = Path::new("builtin:models/correction-tiny.safetensors");
        assert!(is_builtin(name) && !is_builtin(Path::new("./builtin:models/x")) && !is_builtin(&shipped));
        assert_eq!(read_model(name).unwrap().as_ref(), std::fs::read(&shipped).unwrap().as_slice());
        let (mut r, len) = open_model(name).unwrap();
        let mut head = [0u8; 8];
        r.read_exact(&mut head).unwrap();
        assert_eq!(len, std::fs::metadata(&shipped).unwrap().len());
        let e = read_model(Path::new("builtin:models/nope.safetensors")).unwrap_err().to_string();
        assert!(e.contains("builtin:models/nope.safetensors") && e.contains("builtin:models/diffusion-tiny-holes.safetensors"), "{e}");
        assert!(matches!(read_model(Path::new("no/such/file.safetensors")), Err(Error::Io { .. })));
    }
}
