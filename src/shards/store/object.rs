//! A dataset under a prefix of an object store (`s3://bucket/prefix`, `gs://…`, `az://…`) through the
//! `object_store` crate: opening it from a URL with the usual credentials, and its reads and listings.
//! The commit protocol (no rename on these stores) is [`super::object_commit`].
//!
//! Credentials and endpoint come the way each cloud's tools take them: `AWS_*` variables (also
//! `AWS_ENDPOINT_URL` for S3-compatible stores, and the shared `~/.aws` profile files when no key is in
//! the environment, [`super::aws_profile`]), `GOOGLE_APPLICATION_CREDENTIALS` / `GOOGLE_*`, `AZURE_*`.
//! An `http://` endpoint is allowed without setting `AWS_ALLOW_HTTP`.

use super::{aws_profile, DatasetStore, Leftover, Listed, QueryTarget, TMP_DIR};
use crate::atomic::{Published, TempName};
use crate::error::{Error, Result};
use crate::shards::manifest::ManifestEntry;
use arrow::array::RecordBatch;
use bytes::Bytes;
use futures::{StreamExt, TryStreamExt};
use object_store::multipart::MultipartStore;
use object_store::path::Path as StorePath;
use object_store::{ObjectStore, ObjectStoreExt, ObjectStoreScheme, PutMode, PutOptions, RetryConfig};
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

/// An upload record older than this is abandoned (its writer died on another machine): a shard's
/// upload takes seconds, and the record lives only from the upload's start to the manifest entry.
pub const STALE_RECORD_AGE: Duration = Duration::from_secs(3600);

/// Requests in flight when reading many small objects (manifest entries).
const CONCURRENT_READS: usize = 32;

/// How long a request is retried on transient errors (connection refused, 5xx), seconds; the variable
/// `POINTREGGPT_STORE_RETRY_SECONDS` overrides it.
const RETRY_SECONDS: u64 = 30;

/// The dataset at `url`: the store client, the key prefix and the runtime its requests run on.
pub struct ObjectDatasetStore {
    /// The URL as given, without a trailing `/`, as a path for messages.
    pub(super) root: PathBuf,
    /// `scheme://bucket`: what a query engine registers the store under.
    base: url::Url,
    /// Key prefix of the dataset in the bucket.
    pub(super) prefix: StorePath,
    pub(super) store: Arc<dyn ObjectStore>,
    pub(super) multipart: Arc<dyn MultipartStore>,
    runtime: Arc<tokio::runtime::Runtime>,
}

impl fmt::Debug for ObjectDatasetStore {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ObjectDatasetStore({})", self.root.display())
    }
}

impl ObjectDatasetStore {
    /// Opens the store client for `url` (`text` as the user wrote it). Nothing is requested yet;
    /// [`DatasetStore::prepare`] checks that the bucket can be reached.
    pub fn open(text: &str, url: &url::Url) -> Result<ObjectDatasetStore> {
        let text = text.trim_end_matches('/');
        let bad = |m: String| Error::Store { url: text.to_string(), message: m };
        let (scheme, prefix) = ObjectStoreScheme::parse(url).map_err(|_| unknown_scheme(text, url.scheme()))?;
        let retry = retry_config();
        let (store, multipart): (Arc<dyn ObjectStore>, Arc<dyn MultipartStore>) = match scheme {
            ObjectStoreScheme::AmazonS3 => {
                let mut b = object_store::aws::AmazonS3Builder::from_env().with_url(text).with_retry(retry);
                b = aws_profile::apply(b)?;
                if metadata_disabled() && !has_aws_credentials(&b) {
                    return Err(bad(
                        "no AWS credentials: none in the AWS_* variables or the AWS_PROFILE files, and \
                         AWS_EC2_METADATA_DISABLED turns off the instance metadata service (export \
                         AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY, or set AWS_PROFILE)"
                            .into(),
                    ));
                }
                let endpoint = b.get_config_value(&object_store::aws::AmazonS3ConfigKey::Endpoint);
                if endpoint.is_some_and(|e| e.starts_with("http://")) {
                    b = b.with_allow_http(true);
                }
                let s = Arc::new(b.build().map_err(|e| bad(format!("cannot configure the S3 client: {e}")))?);
                (s.clone(), s)
            }
            ObjectStoreScheme::GoogleCloudStorage => {
                let b = object_store::gcp::GoogleCloudStorageBuilder::from_env().with_url(text).with_retry(retry);
                let s = Arc::new(b.build().map_err(|e| bad(format!("cannot configure the GCS client: {e}")))?);
                (s.clone(), s)
            }
            ObjectStoreScheme::MicrosoftAzure => {
                let b = object_store::azure::MicrosoftAzureBuilder::from_env().with_url(text).with_retry(retry);
                let s = Arc::new(b.build().map_err(|e| bad(format!("cannot configure the Azure client: {e}")))?);
                (s.clone(), s)
            }
            _ => return Err(unknown_scheme(text, url.scheme())),
        };
        let host = url.host_str().ok_or_else(|| bad("no bucket in the URL (s3://<bucket>/<prefix>)".into()))?;
        let port = url.port().map(|p| format!(":{p}")).unwrap_or_default();
        let base = url::Url::parse(&format!("{}://{host}{port}", url.scheme())).map_err(|e| bad(e.to_string()))?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("pointreggpt-store")
            .enable_all()
            .build()
            .map_err(|e| Error::Internal(format!("tokio runtime: {e}")))?;
        Ok(ObjectDatasetStore { root: PathBuf::from(text), base, prefix, store, multipart, runtime: Arc::new(runtime) })
    }

    /// Runs `f` to completion on the store's runtime (from synchronous code only).
    pub(super) fn run<F: std::future::Future>(&self, f: F) -> Result<F::Output> {
        if tokio::runtime::Handle::try_current().is_ok() {
            return Err(Error::Internal("an object-store dataset was used from inside an async runtime".into()));
        }
        Ok(self.runtime.block_on(f))
    }

    /// The object key of `rel`, verbatim (upload records have `~` in their names, which
    /// `object_store`'s path builder would percent-encode).
    pub(super) fn key(&self, rel: &str) -> StorePath {
        let full = if self.prefix.as_ref().is_empty() { rel.to_string() } else { format!("{}/{rel}", self.prefix) };
        StorePath::parse(&full).unwrap_or_else(|_| rel.split('/').fold(self.prefix.clone(), |p, part| p.join(part)))
    }

    /// An error of the store on `rel`, with a hint for the common causes.
    pub(super) fn err(&self, rel: &str, e: object_store::Error) -> Error {
        let url = self.locate(rel).display().to_string();
        Error::Store { url, message: format!("{e}{}", hint(&e)) }
    }

    /// The objects under `rel/` with their size and age, sorted by name.
    pub(super) fn list_meta(&self, rel: &str) -> Result<Vec<(String, u64, Duration)>> {
        let dir = self.key(rel);
        let metas: Vec<object_store::ObjectMeta> =
            self.run(self.store.list(Some(&dir)).try_collect())?.map_err(|e| self.err(rel, e))?;
        let now = now_secs();
        let mut out: Vec<(String, u64, Duration)> = metas
            .into_iter()
            .filter_map(|m| {
                let name = m.location.prefix_match(&dir)?.map(|p| p.as_ref().to_string()).collect::<Vec<_>>();
                let [name] = &name[..] else { return None };
                let age = Duration::from_secs(now.saturating_sub(m.last_modified.timestamp().max(0) as u64));
                Some((name.clone(), m.size, age))
            })
            .collect();
        out.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(out)
    }

    /// Deletes `rel` (nothing if it does not exist).
    pub(super) fn delete(&self, rel: &str) -> Result<()> {
        match self.run(self.store.delete(&self.key(rel)))? {
            Ok(()) | Err(object_store::Error::NotFound { .. }) => Ok(()),
            Err(e) => Err(self.err(rel, e)),
        }
    }
}

/// What an error of the store most likely means, from its kind or (for listings, which `object_store`
/// reports as generic errors) the HTTP status and S3 error code in its text.
fn hint(e: &object_store::Error) -> &'static str {
    let text = e.to_string();
    let has = |words: &[&str]| words.iter().any(|w| text.contains(w));
    if matches!(e, object_store::Error::PermissionDenied { .. } | object_store::Error::Unauthenticated { .. })
        || has(&["403 Forbidden", "401 Unauthorized", "InvalidAccessKeyId", "SignatureDoesNotMatch", "AccessDenied"])
    {
        " (the credentials were refused: check AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY or AWS_PROFILE, \
         GOOGLE_APPLICATION_CREDENTIALS, AZURE_STORAGE_ACCOUNT_KEY)"
    } else if has(&["NoSuchBucket", "ContainerNotFound", "404 Not Found"]) || matches!(e, object_store::Error::NotFound { .. }) {
        " (does the bucket exist?)"
    } else if has(&["error sending request", "Connection refused", "dns error"]) {
        " (cannot reach the store: check the endpoint, e.g. AWS_ENDPOINT_URL or AZURITE_BLOB_STORAGE_URL, and the network)"
    } else {
        ""
    }
}

fn unknown_scheme(text: &str, scheme: &str) -> Error {
    Error::config(
        "dataset",
        format!(
            "{text}: unknown URL scheme `{scheme}`; a dataset is a local folder or an object-store URL: \
             s3://bucket/prefix (also s3a://), gs://bucket/prefix, az://container/prefix (also abfs[s]://, azure://)"
        ),
    )
}

/// Retries for [`RETRY_SECONDS`] (or `POINTREGGPT_STORE_RETRY_SECONDS`): the time bound alone ends them.
/// (`object_store`'s default also stops after 10 retries, and its jittered backoff, each wait drawn
/// between 0.1 s and `base` × the previous one, does not grow with base 2: ten retries took 1–3 s, so
/// a store away for a few seconds failed the build. Base 3, the decorrelated jitter AWS recommends,
/// grows slowly; waits are capped at 5 s so that work resumes soon after the store is back.)
fn retry_config() -> RetryConfig {
    let seconds = std::env::var("POINTREGGPT_STORE_RETRY_SECONDS").ok().and_then(|v| v.trim().parse().ok()).unwrap_or(RETRY_SECONDS);
    RetryConfig {
        retry_timeout: Duration::from_secs(seconds),
        max_retries: usize::MAX,
        backoff: object_store::BackoffConfig { init_backoff: Duration::from_millis(100), max_backoff: Duration::from_secs(5), base: 3.0 },
    }
}

/// `AWS_EC2_METADATA_DISABLED=true`, as the AWS SDKs read it: never ask the instance metadata service.
fn metadata_disabled() -> bool {
    std::env::var("AWS_EC2_METADATA_DISABLED").is_ok_and(|v| v.trim().eq_ignore_ascii_case("true"))
}

/// Whether `b` has credentials of its own (keys, web identity, container credentials) or signs nothing,
/// so that `object_store` will not fall back to the instance metadata service (which it does whatever
/// `AWS_EC2_METADATA_DISABLED` says).
fn has_aws_credentials(b: &object_store::aws::AmazonS3Builder) -> bool {
    use object_store::aws::AmazonS3ConfigKey as K;
    let has = |k: K| b.get_config_value(&k).is_some_and(|v| !v.trim().is_empty());
    has(K::AccessKeyId)
        || has(K::SecretAccessKey)
        || (has(K::WebIdentityTokenFile) && has(K::RoleArn))
        || has(K::ContainerCredentialsRelativeUri)
        || (has(K::ContainerCredentialsFullUri) && has(K::ContainerAuthorizationTokenFile))
        || b.get_config_value(&K::SkipSignature).is_some_and(|v| v.trim().eq_ignore_ascii_case("true"))
}

/// Seconds since the Unix epoch.
fn now_secs() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0)
}

impl DatasetStore for ObjectDatasetStore {
    fn root(&self) -> &Path {
        &self.root
    }

    fn locate(&self, rel: &str) -> PathBuf {
        PathBuf::from(format!("{}/{rel}", self.root.display()))
    }

    fn prepare(&self) -> Result<()> {
        self.check_reachable()
    }

    /// One listing of the dataset's prefix: fails with the store's reason when the bucket is missing,
    /// the credentials are refused or the endpoint cannot be reached.
    fn check_reachable(&self) -> Result<()> {
        let prefix = self.prefix.clone();
        match self.run(self.store.list_with_delimiter(Some(&prefix)))? {
            Ok(_) => Ok(()),
            Err(e) => {
                let mut err = self.err("", e);
                if let Error::Store { url, .. } = &mut err {
                    *url = self.root.display().to_string();
                }
                Err(err)
            }
        }
    }

    fn read_text(&self, rel: &str) -> Result<Option<String>> {
        let key = self.key(rel);
        let got = self.run(async { self.store.get(&key).await?.bytes().await })?;
        match got {
            Ok(bytes) => String::from_utf8(bytes.to_vec())
                .map(Some)
                .map_err(|_| Error::input(self.locate(rel), "not UTF-8 text")),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(self.err(rel, e)),
        }
    }

    fn read_texts(&self, rels: &[String]) -> Vec<Result<Option<String>>> {
        let fetch = futures::stream::iter(rels.iter().map(|rel| {
            let (key, store) = (self.key(rel), self.store.clone());
            async move { store.get(&key).await?.bytes().await }
        }))
        .buffered(CONCURRENT_READS)
        .collect::<Vec<_>>();
        match self.run(fetch) {
            Err(e) => rels.iter().map(|_| Err(Error::Internal(e.to_string()))).collect(),
            Ok(results) => results
                .into_iter()
                .zip(rels)
                .map(|(r, rel)| match r {
                    Ok(b) => String::from_utf8(b.to_vec()).map(Some).map_err(|_| Error::input(self.locate(rel), "not UTF-8 text")),
                    Err(object_store::Error::NotFound { .. }) => Ok(None),
                    Err(e) => Err(self.err(rel, e)),
                })
                .collect(),
        }
    }

    /// A create-only put (`If-None-Match: *`): the first creator wins, the others see `AlreadyThere`.
    fn create_text(&self, rel: &str, text: &str) -> Result<Published> {
        let opts = PutOptions { mode: PutMode::Create, ..Default::default() };
        let payload = Bytes::from(text.to_string()).into();
        match self.run(self.store.put_opts(&self.key(rel), payload, opts))? {
            Ok(_) => Ok(Published::Written),
            Err(object_store::Error::AlreadyExists { .. } | object_store::Error::Precondition { .. }) => Ok(Published::AlreadyThere),
            Err(e) => Err(self.err(rel, e)),
        }
    }

    fn list(&self, dir: &str) -> Result<Vec<Listed>> {
        Ok(self.list_meta(dir)?.into_iter().map(|(name, size, _)| Listed { name, size }).collect())
    }

    fn read_bytes(&self, rel: &str) -> Result<Bytes> {
        let key = self.key(rel);
        self.run(async { self.store.get(&key).await?.bytes().await })?.map_err(|e| self.err(rel, e))
    }

    fn commit(&self, draft: ManifestEntry, batch: &RecordBatch, row_group_rows: usize) -> Result<ManifestEntry> {
        self.commit_object(draft, batch, row_group_rows)
    }

    fn retract(&self, rel: &str, file: &str) -> Result<()> {
        self.delete(rel)?;
        if file.is_empty() {
            return Ok(());
        }
        self.delete(&format!("{}/{file}", super::SHARDS_DIR))
    }

    fn leftovers(&self) -> Result<Vec<Leftover>> {
        Ok(self
            .list_meta(TMP_DIR)?
            .into_iter()
            .map(|(name, _, age)| {
                let dead = TempName::parse(&name).is_some_and(|n| n.is_stale());
                Leftover { location: self.locate(&format!("{TMP_DIR}/{name}")), stale: dead || age > STALE_RECORD_AGE }
            })
            .collect())
    }

    fn clean_stale(&self) -> Result<Vec<PathBuf>> {
        self.clean_stale_records()
    }

    fn remove_orphans(&self, orphans: &[String]) -> Result<Vec<PathBuf>> {
        self.remove_orphan_objects(orphans)
    }

    fn query_target(&self, rel: &str) -> Result<QueryTarget> {
        let url = format!("{}/{}", self.base.as_str().trim_end_matches('/'), self.key(rel));
        Ok(QueryTarget { url, store: Some((self.base.clone(), self.store.clone())) })
    }
}
