"""Where a dataset lives: a local folder, or a prefix of an object store, as a pyarrow filesystem.

``filesystem_for(url, storage_options)`` returns ``(filesystem, base)`` where ``base`` is the dataset's
path inside ``filesystem`` (no trailing slash). URLs are the ones the ``pointreggpt`` binary takes:

* a folder (``out/demo``, ``/data/prgpt``, ``file:///data/prgpt``): ``pyarrow.fs.LocalFileSystem``;
* ``s3://bucket/prefix`` (also ``s3a://``): ``pyarrow.fs.S3FileSystem``;
* ``az://container/prefix`` (also ``azure://``, ``abfs://``, ``abfss://container@account.dfs.core.windows.net/prefix``):
  ``pyarrow.fs.AzureFileSystem`` (pyarrow >= 16; an older pyarrow raises ``StoreError`` saying so);
* ``gs://bucket/prefix``: ``pyarrow.fs.GcsFileSystem`` (not exercised by the tests).

``storage_options`` (a dict) names credentials and endpoints explicitly; what it does not name comes from
the environment, as for the binary:

S3
    ``endpoint_url`` (``"http://127.0.0.1:9000"``, for S3-compatible stores; else ``AWS_ENDPOINT_URL_S3`` or
    ``AWS_ENDPOINT_URL``), ``access_key``, ``secret_key``, ``session_token``, ``region`` (also the
    object_store / Polars spellings ``aws_access_key_id``, ``aws_secret_access_key``, ``aws_session_token``,
    ``aws_region``, ``aws_endpoint``/``endpoint``); any other key is passed to ``S3FileSystem`` as is
    (``anonymous``, ``request_timeout``, ...). Without keys, the AWS SDK's chain is used (``AWS_*``
    variables, ``AWS_PROFILE`` and ``~/.aws``, web identity, instance metadata).
Azure
    ``account_name`` (else ``AZURE_STORAGE_ACCOUNT_NAME``), ``account_key`` (else
    ``AZURE_STORAGE_ACCOUNT_KEY`` / ``AZURE_STORAGE_ACCESS_KEY``), ``sas_token`` (else
    ``AZURE_STORAGE_SAS_TOKEN``), ``client_id``/``client_secret``/``tenant_id`` (a service principal; else
    ``AZURE_CLIENT_ID``/``AZURE_CLIENT_SECRET``/``AZURE_TENANT_ID``), ``endpoint`` (``"http://127.0.0.1:10000"``
    for the Azurite emulator; sets the blob and DFS authorities and schemes); other keys go to
    ``AzureFileSystem`` as is. Without a key, token or service principal, Azure's default credential chain.
GCS
    passed to ``GcsFileSystem`` as is (``access_token``, ``credential_token_expiration``, ``endpoint_override``,
    ``scheme``, ``anonymous``, ...).

A ready ``pyarrow.fs.FileSystem`` can be given instead (``filesystem=``); the URL is then the path in it.
"""

import os
from urllib.parse import urlsplit

import pyarrow.fs as pafs


class StoreError(RuntimeError):
    """The dataset's store cannot be opened (unknown scheme, missing support in pyarrow, bad options)."""


S3_SCHEMES = ("s3", "s3a")
AZURE_SCHEMES = ("az", "azure", "abfs", "abfss")
GCS_SCHEMES = ("gs", "gcs")

_S3_ALIASES = {
    "aws_access_key_id": "access_key",
    "aws_secret_access_key": "secret_key",
    "aws_session_token": "session_token",
    "aws_region": "region",
    "aws_endpoint": "endpoint_url",
    "aws_endpoint_url": "endpoint_url",
    "endpoint": "endpoint_url",
}


def is_url(path):
    """Whether ``path`` is an object-store URL (``scheme://...`` other than ``file://``)."""
    text = os.fspath(path)
    return "://" in text and not text.startswith("file://")


def filesystem_for(url, storage_options=None, filesystem=None):
    """``(pyarrow filesystem, base path)`` of the dataset at ``url``; see the module documentation."""
    text = os.fspath(url)
    options = dict(storage_options or {})
    if filesystem is not None:
        if options:
            raise StoreError("give either filesystem= or storage_options=, not both")
        if "://" in text:
            parts = urlsplit(text)
            text = parts.netloc + parts.path
        return filesystem, text.rstrip("/")
    if not is_url(text):
        if options:
            raise StoreError(f"{text}: storage_options are for object-store URLs, this is a local path")
        path = text[len("file://"):] if text.startswith("file://") else text
        return pafs.LocalFileSystem(), os.path.abspath(path).rstrip("/") or "/"
    parts = urlsplit(text)
    scheme = parts.scheme.lower()
    if scheme in S3_SCHEMES:
        return _s3(parts, options), _bucket_path(text, parts.netloc, parts.path)
    if scheme in AZURE_SCHEMES:
        return _azure(text, parts, options)
    if scheme in GCS_SCHEMES:
        try:
            fs = pafs.GcsFileSystem(**options)
        except TypeError as e:
            raise StoreError(f"{text}: bad storage_options for GcsFileSystem: {e}") from None
        return fs, _bucket_path(text, parts.netloc, parts.path)
    raise StoreError(
        f"{text}: unknown URL scheme `{parts.scheme}`; a dataset is a local folder or an object-store URL: "
        "s3://bucket/prefix (also s3a://), gs://bucket/prefix, az://container/prefix (also abfs[s]://, azure://)"
    )


def _bucket_path(text, bucket, path):
    if not bucket:
        raise StoreError(f"{text}: no bucket in the URL (scheme://<bucket>/<prefix>)")
    prefix = path.strip("/")
    return f"{bucket}/{prefix}" if prefix else bucket


def _endpoint(value):
    """``(scheme, host[:port])`` of an endpoint URL (``http://127.0.0.1:9000``) or a bare ``host:port`` (https)."""
    if "://" in value:
        p = urlsplit(value)
        return p.scheme, p.netloc
    return "https", value


def _s3(parts, options):
    opts = {}
    for k, v in options.items():
        opts[_S3_ALIASES.get(k, k)] = v
    endpoint = opts.pop("endpoint_url", None) or os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL")
    if endpoint and "endpoint_override" not in opts:
        scheme, host = _endpoint(endpoint)
        opts["endpoint_override"] = host
        opts.setdefault("scheme", scheme)
    if "region" not in opts:
        region = os.environ.get("AWS_REGION") or os.environ.get("AWS_DEFAULT_REGION")
        if region:
            opts["region"] = region
    if ("access_key" in opts) != ("secret_key" in opts):
        raise StoreError(f"{parts.geturl()}: storage_options need both access_key and secret_key (or neither)")
    try:
        return pafs.S3FileSystem(**opts)
    except TypeError as e:
        raise StoreError(f"{parts.geturl()}: bad storage_options for S3FileSystem: {e}") from None


def _azure(text, parts, options):
    if not hasattr(pafs, "AzureFileSystem"):
        import pyarrow

        raise StoreError(
            f"{text}: this pyarrow ({pyarrow.__version__}) has no AzureFileSystem; Azure needs pyarrow >= 16 "
            "(pip install -U pyarrow), or pass filesystem= (e.g. pyarrow.fs.PyFileSystem(pyarrow.fs.FSSpecHandler(adlfs.AzureBlobFileSystem(...))))"
        )
    # az://container/prefix, azure://container/prefix, abfs[s]://container@account.dfs.core.windows.net/prefix
    container, account = parts.netloc, None
    if "@" in container:
        container, host = container.split("@", 1)
        account = host.split(".", 1)[0]
    if not container:
        raise StoreError(f"{text}: no container in the URL (az://<container>/<prefix>)")
    opts = dict(options)
    env = os.environ.get
    opts.setdefault("account_name", account or env("AZURE_STORAGE_ACCOUNT_NAME") or env("AZURE_STORAGE_ACCOUNT"))
    if not opts["account_name"]:
        raise StoreError(f"{text}: no Azure storage account: pass storage_options={{'account_name': ...}} or set AZURE_STORAGE_ACCOUNT_NAME")
    explicit = any(opts.get(k) for k in ("account_key", "sas_token", "client_id", "client_secret", "tenant_id"))
    if not explicit:
        key = env("AZURE_STORAGE_ACCOUNT_KEY") or env("AZURE_STORAGE_ACCESS_KEY")
        sas = env("AZURE_STORAGE_SAS_TOKEN")
        if key:
            opts["account_key"] = key
        elif sas:
            opts["sas_token"] = sas
        elif env("AZURE_CLIENT_ID") and env("AZURE_CLIENT_SECRET") and env("AZURE_TENANT_ID"):
            opts.update(client_id=env("AZURE_CLIENT_ID"), client_secret=env("AZURE_CLIENT_SECRET"), tenant_id=env("AZURE_TENANT_ID"))
    endpoint = opts.pop("endpoint", None)
    if endpoint:
        scheme, host = _endpoint(endpoint)
        opts.setdefault("blob_storage_authority", host)
        opts.setdefault("dfs_storage_authority", host)
        opts.setdefault("blob_storage_scheme", scheme)
        opts.setdefault("dfs_storage_scheme", scheme)
    opts = {k: v for k, v in opts.items() if v is not None}
    try:
        fs = pafs.AzureFileSystem(**opts)
    except TypeError as e:
        raise StoreError(f"{text}: bad storage_options for AzureFileSystem: {e}") from None
    prefix = parts.path.strip("/")
    return fs, f"{container}/{prefix}" if prefix else container
