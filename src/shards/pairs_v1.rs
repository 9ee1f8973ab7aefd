//! Version 1 of the `pairs` table (`schemas/pairs-v1.md`): unsigned integer columns and no per-point
//! provenance. Datasets built before version 2 keep it; every reader upgrades their batches to version 2
//! ([`to_current`]: the integers reinterpreted bit for bit, empty provenance lists), and a build that
//! resumes such a dataset writes its new shards back in version 1 ([`downgrade`]), so a dataset never
//! mixes versions.

use super::schema::{list_item, pairs_schema, pairs_schema_v1, pairs_version_of, SCHEMA_VERSION_1};
use crate::error::{Error, Result};
use arrow::array::{Array, ArrayRef, Float32Array, Int32Array, Int64Array, Int8Array, ListArray, RecordBatch, UInt32Array, UInt64Array};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::SchemaRef;
use std::sync::Arc;

/// The 64-bit and 32-bit integer columns whose signedness changed in version 2.
const WIDE: [&str; 2] = ["unit_index", "seed"];
const NARROW: [&str; 4] = ["sample_index", "width", "height", "pose_draws"];
/// The columns version 2 added.
const PROVENANCE: [&str; 2] = ["target_known_share", "target_view"];

/// Whether `batch` is version 1 (by its metadata, or by its columns when it has none).
pub fn is_v1(batch: &RecordBatch) -> bool {
    pairs_version_of(&batch.schema()) == Ok(SCHEMA_VERSION_1)
}

/// `batch` as a version-2 batch: itself when it is one, upgraded when it is version 1. Errors name the
/// column when it matches neither.
pub fn to_current(batch: &RecordBatch) -> Result<RecordBatch> {
    match pairs_version_of(&batch.schema()) {
        Ok(SCHEMA_VERSION_1) => upgrade(batch),
        Ok(_) => Ok(batch.clone()),
        Err(m) => Err(Error::Parquet(format!("not a pairs batch: {m}"))),
    }
}

/// A version-1 batch as version 2.
fn upgrade(batch: &RecordBatch) -> Result<RecordBatch> {
    let n = batch.num_rows();
    let target = pairs_schema();
    let columns = target
        .fields()
        .iter()
        .map(|f| -> Result<ArrayRef> {
            let name = f.name().as_str();
            if PROVENANCE.contains(&name) {
                let values: ArrayRef = if name == "target_view" { Arc::new(Int8Array::from(Vec::<i8>::new())) } else { Arc::new(Float32Array::from(Vec::<f32>::new())) };
                return Ok(Arc::new(ListArray::new(list_item(f.data_type()), OffsetBuffer::new_zeroed(n), values, None)));
            }
            let c = column(batch, name)?;
            Ok(if WIDE.contains(&name) {
                Arc::new(Int64Array::from_iter_values(downcast::<UInt64Array>(name, c)?.values().iter().map(|&v| v as i64)))
            } else if NARROW.contains(&name) {
                Arc::new(Int32Array::from_iter_values(downcast::<UInt32Array>(name, c)?.values().iter().map(|&v| v as i32)))
            } else {
                c.clone()
            })
        })
        .collect::<Result<Vec<_>>>()?;
    rebuild(target, columns)
}

/// A version-2 batch as version 1 (the provenance columns dropped), for a version-1 dataset's new shards.
pub fn downgrade(batch: &RecordBatch) -> Result<RecordBatch> {
    let target = pairs_schema_v1();
    let columns = target
        .fields()
        .iter()
        .map(|f| -> Result<ArrayRef> {
            let name = f.name().as_str();
            let c = column(batch, name)?;
            Ok(if WIDE.contains(&name) {
                Arc::new(UInt64Array::from_iter_values(downcast::<Int64Array>(name, c)?.values().iter().map(|&v| v as u64)))
            } else if NARROW.contains(&name) {
                Arc::new(UInt32Array::from_iter_values(downcast::<Int32Array>(name, c)?.values().iter().map(|&v| v as u32)))
            } else {
                c.clone()
            })
        })
        .collect::<Result<Vec<_>>>()?;
    rebuild(target, columns)
}

fn column<'a>(batch: &'a RecordBatch, name: &str) -> Result<&'a ArrayRef> {
    batch.column_by_name(name).ok_or_else(|| Error::Parquet(format!("column `{name}` is missing")))
}

fn downcast<'a, T: Array + 'static>(name: &str, array: &'a ArrayRef) -> Result<&'a T> {
    array.as_any().downcast_ref::<T>().ok_or_else(|| Error::Parquet(format!("column `{name}` has an unexpected type {}", array.data_type())))
}

fn rebuild(schema: SchemaRef, columns: Vec<ArrayRef>) -> Result<RecordBatch> {
    RecordBatch::try_new(schema, columns).map_err(|e| Error::Parquet(format!("converting a pairs batch between versions: {e}")))
}
