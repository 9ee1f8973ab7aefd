//! The one rule that tells a dataset location's kind: a local folder, or an object-store URL. Text that
//! starts like a URL but is not a supported one (`s3:/bucket`, `s3:bucket`, `az:/x`, `file:/x`, `s4://x`)
//! is refused, never taken for a local folder of that name.

use crate::error::{Error, Result};
use object_store::ObjectStoreScheme;
use std::path::{Path, PathBuf};

/// What a location names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Location {
    /// A local folder (or file): a plain path, or a `file://` URL.
    Local(PathBuf),
    /// An object-store URL (`s3://`, `gs://`, `az://` and their aliases), as written.
    Remote(String),
}

/// The URL forms a dataset location may take, for messages.
pub const SUPPORTED: &str = "s3://bucket/prefix (also s3a://), gs://bucket/prefix, az://container/prefix (also adl://, \
azure://, abfs[s]://, and https:// URLs of S3 or Azure endpoints), file:///absolute/path";

/// Classifies `location`. The rule: text beginning with `<scheme>:` (a letter, then letters, digits, `+`,
/// `-` or `.`; two characters at least) is a URL and must be `<scheme>://…` with a supported scheme and a
/// bucket; anything else is a local path. A local name with a colon is written `./s3:x`.
pub fn classify(location: &Path) -> Result<Location> {
    let Some(text) = location.to_str() else { return Ok(Location::Local(location.to_path_buf())) };
    let Some((scheme, rest)) = text.split_once(':').filter(|(s, _)| is_scheme(s)) else {
        return Ok(Location::Local(location.to_path_buf()));
    };
    let bad = |why: String| Error::config("location", format!("`{text}` {why}"));
    let file = scheme.eq_ignore_ascii_case("file");
    let Some(after) = rest.strip_prefix("//") else {
        let fixed = format!("{scheme}://{}{}", if file { "/" } else { "" }, rest.trim_start_matches('/'));
        return Err(bad(format!(
            "looks like a URL but is not one (a URL is <scheme>://…, e.g. {fixed}). Supported: {SUPPORTED}. \
             For a local folder whose name has a colon, write ./{text}"
        )));
    };
    if !file && (after.is_empty() || after.starts_with('/')) {
        return Err(bad(format!("names no bucket (e.g. {scheme}://bucket/prefix)")));
    }
    let url = url::Url::parse(text).map_err(|e| bad(format!("is not a valid URL ({e})")))?;
    match ObjectStoreScheme::parse(&url) {
        _ if file => url.to_file_path().map(Location::Local).map_err(|_| bad("is not a local file URL (file:///absolute/path)".into())),
        Ok((ObjectStoreScheme::AmazonS3 | ObjectStoreScheme::GoogleCloudStorage | ObjectStoreScheme::MicrosoftAzure, _)) => {
            Ok(Location::Remote(text.to_string()))
        }
        _ => Err(bad(format!("has an unknown URL scheme `{scheme}`; a dataset is a local folder or one of: {SUPPORTED}"))),
    }
}

fn is_scheme(s: &str) -> bool {
    s.len() > 1 && s.starts_with(|c: char| c.is_ascii_alphabetic()) && s.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kind(s: &str) -> std::result::Result<Location, String> {
        classify(Path::new(s)).map_err(|e| e.to_string())
    }

    #[test]
    fn paths_and_supported_urls_are_told_apart() {
        for path in ["out/demo", "/data/x://y", "./s3:/bucket/x", "out/run:1", "C:data", "-", "", "../a:b"] {
            assert_eq!(kind(path), Ok(Location::Local(PathBuf::from(path))), "{path}");
        }
        for url in ["s3://bucket/prefix", "S3://bucket", "s3a://b/p", "gs://b/p", "az://c/p", "abfss://c@a.dfs.core.windows.net/p", "https://b.s3.amazonaws.com/p"] {
            assert_eq!(kind(url), Ok(Location::Remote(url.to_string())), "{url}");
        }
        assert_eq!(kind("file:///tmp/x"), Ok(Location::Local(PathBuf::from("/tmp/x"))));
    }

    #[test]
    fn text_that_looks_like_a_url_but_is_not_a_supported_one_is_refused() {
        for (text, says) in [
            ("s3:/bucket/x", "s3://bucket/x"),
            ("s3:bucket", "s3://bucket"),
            ("az:/container/p", "az://container/p"),
            ("gs:/b", "gs://b"),
            ("file:/tmp/x", "file:///tmp/x"),
            ("s4://x", "unknown URL scheme `s4`"),
            ("ftp://host/data", "unknown URL scheme `ftp`"),
            ("http://example.com/data", "unknown URL scheme `http`"),
            ("s3://", "names no bucket"),
            ("s3:///prefix", "names no bucket"),
            ("file://host/x", "not a local file URL"),
        ] {
            let e = kind(text).unwrap_err();
            assert!(e.contains(&format!("`{text}`")) && e.contains(says), "{text}: {e}");
        }
        let e = kind("s3:/bucket/x").unwrap_err();
        assert!(e.contains("./s3:/bucket/x") && e.contains("gs://bucket/prefix"), "names the local form and the supported ones: {e}");
    }
}
