//! clap value parsers for the arguments that name a dataset location or an output: text that looks like
//! a URL but is not a supported one (`s3:/bucket`, `s4://x`) is refused before any work, by the rule of
//! [`crate::shards::store::location::classify`].

use crate::error::Error;
use crate::shards::store::location::{classify, Location};
use std::path::PathBuf;

/// A dataset: a local folder or a supported object-store URL.
pub fn dataset(text: &str) -> Result<PathBuf, String> {
    classify(text.as_ref()).map(|_| PathBuf::from(text)).map_err(message)
}

/// An output written to local files only: a path, never a URL.
pub fn local_output(text: &str) -> Result<PathBuf, String> {
    match classify(text.as_ref()).map_err(message)? {
        // A plain path classifies as itself; a `file://` URL as the path it names.
        Location::Local(path) if path.as_os_str() == text => Ok(path),
        _ => Err(format!("`{text}` is a URL; this output is written to local files only: give a folder or file path")),
    }
}

/// The error's message without the `invalid configuration` frame (clap adds its own).
fn message(e: Error) -> String {
    match e {
        Error::Config { message, .. } => message,
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn datasets_take_urls_and_local_outputs_take_paths_only() {
        assert_eq!(dataset("s3://b/p"), Ok(PathBuf::from("s3://b/p")));
        assert_eq!(dataset("out/x"), Ok(PathBuf::from("out/x")));
        assert!(dataset("s3:/b/p").unwrap_err().contains("s3://b/p"));
        assert_eq!(local_output("out/x"), Ok(PathBuf::from("out/x")));
        assert_eq!(local_output("./s3:x"), Ok(PathBuf::from("./s3:x")));
        assert_eq!(local_output("/data/x://y"), Ok(PathBuf::from("/data/x://y")));
        for url in ["s3://b/p", "file:///tmp/x", "s3:/b", "gs:b"] {
            assert!(local_output(url).unwrap_err().contains(url), "{url}");
        }
    }
}
