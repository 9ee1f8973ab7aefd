//! Writing one shard object: parquet's async Arrow writer into [`ShardUpload`], which hashes and counts
//! the bytes as they pass, sends a shard below [`PART_SIZE`] as one put and a larger one as a multipart
//! upload whose id it first records in the shard's upload record, so that `verify --repair` can abort
//! the upload if the writer dies (object stores cannot list a client's incomplete uploads through
//! `object_store`; that is also why this is not `object_store::buffered::BufWriter`, which hides the id).

use crate::error::{Error, Result};
use crate::shards::parquet_io::writer_properties;
use arrow::array::RecordBatch;
use bytes::Bytes;
use futures::future::BoxFuture;
use futures::FutureExt;
use object_store::multipart::{MultipartStore, PartId};
use object_store::path::Path as StorePath;
use object_store::{MultipartId, ObjectStore, PutPayload};
use parquet::arrow::async_writer::{AsyncArrowWriter, AsyncFileWriter};
use parquet::errors::ParquetError;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Bytes per part of a multipart upload; a shard smaller than this is one put. (S3 takes parts of
/// 5 MiB to 5 GiB; 10 MiB is also `BufWriter`'s default.)
pub const PART_SIZE: usize = 10 << 20;

/// The upload record of a shard being written (`.tmp/<host>~<pid>~<object>~<nonce>.tmp` on the store).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UploadRecord {
    /// The shard object's file name in `shards/`.
    pub object: String,
    /// The multipart upload's id once one is started.
    pub upload_id: Option<String>,
}

/// What a finished upload wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Uploaded {
    pub bytes: u64,
    pub blake3: blake3::Hash,
}

/// An [`AsyncFileWriter`] to one object: hashes, buffers, and uploads in one put or in parts.
pub struct ShardUpload {
    store: Arc<dyn ObjectStore>,
    multipart: Arc<dyn MultipartStore>,
    key: StorePath,
    /// Where the upload id is recorded, and the record.
    record_key: StorePath,
    record: UploadRecord,
    part_size: usize,
    hasher: blake3::Hasher,
    size: u64,
    buffer: Vec<u8>,
    upload: Option<(MultipartId, Vec<PartId>)>,
}

impl ShardUpload {
    pub fn new(
        store: Arc<dyn ObjectStore>,
        multipart: Arc<dyn MultipartStore>,
        key: StorePath,
        record_key: StorePath,
        record: UploadRecord,
        part_size: usize,
    ) -> ShardUpload {
        ShardUpload {
            store,
            multipart,
            key,
            record_key,
            record,
            part_size,
            hasher: blake3::Hasher::new(),
            size: 0,
            buffer: Vec::new(),
            upload: None,
        }
    }

    /// Sends the first `part_size` buffered bytes as the next part, starting the multipart upload (and
    /// recording its id) on the first.
    async fn send_part(&mut self) -> object_store::Result<()> {
        if self.upload.is_none() {
            let id = self.multipart.create_multipart(&self.key).await?;
            self.record.upload_id = Some(id.clone());
            let json = serde_json::to_vec(&self.record).expect("an upload record serializes");
            self.store.put_opts(&self.record_key, PutPayload::from(json), Default::default()).await?;
            self.upload = Some((id, Vec::new()));
        }
        let rest = self.buffer.split_off(self.part_size.min(self.buffer.len()));
        let part = Bytes::from(std::mem::replace(&mut self.buffer, rest));
        let (id, parts) = self.upload.as_mut().expect("started above");
        let part_id = self.multipart.put_part(&self.key, id, parts.len(), part.into()).await?;
        parts.push(part_id);
        Ok(())
    }

    async fn finish(&mut self) -> object_store::Result<()> {
        match &self.upload {
            None => {
                let body = Bytes::from(std::mem::take(&mut self.buffer));
                self.store.put_opts(&self.key, body.into(), Default::default()).await.map(|_| ())
            }
            Some(_) => {
                if !self.buffer.is_empty() {
                    self.send_part().await?;
                }
                let (id, parts) = self.upload.as_ref().expect("multipart");
                self.multipart.complete_multipart(&self.key, id, parts.clone()).await.map(|_| ())
            }
        }
    }

    /// Aborts the multipart upload, if one was started (best effort: the upload record stays for
    /// `verify --repair` when this fails too).
    pub async fn abort(&mut self) {
        if let Some((id, _)) = self.upload.take() {
            let _ = self.multipart.abort_multipart(&self.key, &id).await;
        }
    }

    /// The size and hash of the bytes written.
    pub fn uploaded(&self) -> Uploaded {
        Uploaded { bytes: self.size, blake3: self.hasher.finalize() }
    }
}

fn external(e: object_store::Error) -> ParquetError {
    ParquetError::External(Box::new(e))
}

impl AsyncFileWriter for ShardUpload {
    fn write(&mut self, bs: Bytes) -> BoxFuture<'_, parquet::errors::Result<()>> {
        async move {
            self.hasher.update(&bs);
            self.size += bs.len() as u64;
            self.buffer.extend_from_slice(&bs);
            while self.buffer.len() >= self.part_size {
                self.send_part().await.map_err(external)?;
            }
            Ok(())
        }
        .boxed()
    }

    fn complete(&mut self) -> BoxFuture<'_, parquet::errors::Result<()>> {
        async move { self.finish().await.map_err(external) }.boxed()
    }
}

/// Encodes `batch` as a zstd Parquet file (the same writer settings as a local shard) into `upload`;
/// on failure aborts the multipart upload. Errors name `url`. Returns what was written.
pub async fn write_batch(upload: ShardUpload, batch: &RecordBatch, url: &str, row_group_rows: usize) -> Result<Uploaded> {
    let schema = batch.schema();
    let mut writer = AsyncArrowWriter::try_new(upload, schema.clone(), Some(writer_properties(&schema, row_group_rows)))
        .map_err(|e| Error::Parquet(format!("writing Parquet: {e}")))?;
    let written = match writer.write(batch).await {
        Ok(()) => writer.finish().await.map(|_| ()),
        Err(e) => Err(e),
    };
    let mut upload = writer.into_inner();
    match written {
        Ok(()) => Ok(upload.uploaded()),
        Err(e) => {
            upload.abort().await;
            Err(match e {
                ParquetError::External(inner) => Error::Store { url: url.to_string(), message: inner.to_string() },
                other => Error::Parquet(format!("writing Parquet: {other}")),
            })
        }
    }
}
