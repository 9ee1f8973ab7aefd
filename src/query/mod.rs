//! SQL over a dataset with DataFusion: tables `pairs`, `labels` and `manifest`, registered over the
//! committed shards only (a dataset still being built can be queried safely), in a folder or on an
//! object store.

pub mod output;

use crate::error::{Error, Result};
use crate::shards::dataset::{Dataset, SHARDS_DIR};
use crate::shards::store::QueryTarget;
use crate::shards::labels::{labels_schema, LABELS_TABLE};
use crate::shards::{pairs_schema, pairs_schema_of, ManifestEntry, PAIRS_TABLE};
use datafusion::arrow::array::{ArrayRef, RecordBatch, StringArray, UInt64Array};
use datafusion::arrow::datatypes::{DataType, Field, Schema, SchemaRef};
use datafusion::datasource::file_format::parquet::ParquetFormat;
use datafusion::datasource::listing::{ListingOptions, ListingTable, ListingTableConfig, ListingTableUrl};
use datafusion::datasource::MemTable;
use datafusion::prelude::SessionContext;
use std::path::Path;
use std::sync::Arc;

pub use output::{write_batches, OutputFormat};

fn df_err(e: datafusion::error::DataFusionError) -> Error {
    Error::Parquet(format!("query: {e}"))
}

/// Runs `sql` over the dataset at `root` (a folder or an object-store URL) and returns the result batches.
pub fn run_query(root: &Path, sql: &str) -> Result<Vec<RecordBatch>> {
    run_query_on(&Dataset::open(root)?, sql)
}

/// Runs `sql` over the committed shards of `ds`. On an object store, DataFusion reads the shard objects
/// where they are (ranged reads through the dataset's own store client).
pub fn run_query_on(ds: &Dataset, sql: &str) -> Result<Vec<RecordBatch>> {
    // Everything that talks to the dataset's store runs before entering this function's runtime.
    let pairs = ds.committed(PAIRS_TABLE)?;
    let labels = ds.committed(LABELS_TABLE)?;
    let targets = |entries: &std::collections::BTreeMap<u64, ManifestEntry>| -> Result<Vec<QueryTarget>> {
        entries.values().map(|e| ds.store().query_target(&format!("{SHARDS_DIR}/{}", e.file))).collect()
    };
    let (pair_files, label_files) = (targets(&pairs)?, targets(&labels)?);
    let entries: Vec<ManifestEntry> = pairs.into_values().chain(labels.into_values()).collect();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(rayon::current_num_threads().max(1))
        .enable_all()
        .build()
        .map_err(|e| Error::Internal(format!("tokio runtime: {e}")))?;
    runtime.block_on(async {
        let ctx = SessionContext::new();
        if let Some((url, store)) = pair_files.iter().chain(&label_files).find_map(|t| t.store.clone()) {
            ctx.register_object_store(&url, store);
        }
        // A version-1 dataset is queried with its own (unsigned, provenance-free) schema.
        let schema = pairs_schema_of(&ds.header().schema_version).unwrap_or_else(pairs_schema);
        register_table(&ctx, PAIRS_TABLE, schema, &pair_files)?;
        register_table(&ctx, LABELS_TABLE, labels_schema(), &label_files)?;
        ctx.register_table("manifest", Arc::new(manifest_table(&entries)?)).map_err(df_err)?;
        let df = ctx.sql(sql).await.map_err(df_err)?;
        df.collect().await.map_err(df_err)
    })
}

/// Registers `table` over the committed shard files `files` (an empty table if none).
fn register_table(ctx: &SessionContext, table: &str, schema: SchemaRef, files: &[QueryTarget]) -> Result<()> {
    if files.is_empty() {
        let empty = MemTable::try_new(schema, vec![vec![]]).map_err(df_err)?;
        ctx.register_table(table, Arc::new(empty)).map_err(df_err)?;
        return Ok(());
    }
    let urls = files.iter().map(|f| ListingTableUrl::parse(&f.url).map_err(df_err)).collect::<Result<Vec<_>>>()?;
    let options = ListingOptions::new(Arc::new(ParquetFormat::default())).with_file_extension(".parquet");
    let config = ListingTableConfig::new_with_multi_paths(urls).with_listing_options(options).with_schema(schema);
    let provider = ListingTable::try_new(config).map_err(df_err)?;
    ctx.register_table(table, Arc::new(provider)).map_err(df_err)?;
    Ok(())
}

/// The manifest entries as a table: one row per committed shard.
fn manifest_table(entries: &[ManifestEntry]) -> Result<MemTable> {
    let schema = Arc::new(Schema::new(vec![
        Field::new("table", DataType::Utf8, false),
        Field::new("shard", DataType::UInt64, false),
        Field::new("first_unit", DataType::UInt64, false),
        Field::new("units", DataType::UInt64, false),
        Field::new("rows", DataType::UInt64, false),
        Field::new("file", DataType::Utf8, false),
        Field::new("bytes", DataType::UInt64, false),
        Field::new("blake3", DataType::Utf8, false),
        Field::new("config_hash", DataType::Utf8, false),
        Field::new("code_version", DataType::Utf8, false),
        Field::new("worker", DataType::Utf8, false),
        Field::new("created", DataType::Utf8, false),
    ]));
    let s = |f: fn(&ManifestEntry) -> &str| -> ArrayRef { Arc::new(StringArray::from_iter_values(entries.iter().map(f))) };
    let u = |f: fn(&ManifestEntry) -> u64| -> ArrayRef { Arc::new(UInt64Array::from_iter_values(entries.iter().map(f))) };
    let columns = vec![
        s(|e| &e.table),
        u(|e| e.shard),
        u(|e| e.first_unit),
        u(|e| e.units),
        u(|e| e.rows),
        s(|e| &e.file),
        u(|e| e.bytes),
        s(|e| &e.blake3),
        s(|e| &e.config_hash),
        s(|e| &e.code_version),
        s(|e| &e.worker),
        s(|e| &e.created),
    ];
    let batch = RecordBatch::try_new(schema.clone(), columns).map_err(|e| Error::Parquet(e.to_string()))?;
    MemTable::try_new(schema, vec![vec![batch]]).map_err(df_err)
}
