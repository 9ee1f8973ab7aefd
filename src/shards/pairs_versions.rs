//! Earlier versions of the `pairs` table: version 1 (`schemas/pairs-v1.md`: unsigned integer columns, no
//! per-point provenance) and version 2 (`schemas/pairs-v2.md`: two provenance kinds, no scene). Datasets
//! built before the current version keep theirs: every reader upgrades their batches to the current one
//! ([`to_current`]: integers reinterpreted bit for bit; version 1's provenance lists empty; version 2's
//! scene shares all 0 and `scene_frames` 0, which is exact, since no scene existed), and a build that
//! resumes such a dataset writes its new shards back in the dataset's version ([`downgrade`]), so a
//! dataset never mixes versions.

use super::schema::{list_item, pairs_schema, pairs_schema_of, pairs_version_of, SCHEMA_VERSION, SCHEMA_VERSION_1};
use crate::error::{Error, Result};
use arrow::array::{Array, ArrayRef, Float32Array, Int32Array, Int64Array, Int8Array, ListArray, RecordBatch, UInt32Array, UInt64Array};
use arrow::buffer::OffsetBuffer;
use arrow::datatypes::SchemaRef;
use std::sync::Arc;

/// The 64-bit and 32-bit integer columns that are unsigned in version 1.
const WIDE: [&str; 2] = ["unit_index", "seed"];
const NARROW: [&str; 4] = ["sample_index", "width", "height", "pose_draws"];
/// The provenance columns version 2 added (version 1 reads them as empty lists).
const PROVENANCE: [&str; 2] = ["target_known_share", "target_view"];

/// Whether `batch` is version 1 (by its metadata, or by its columns when it has none).
pub fn is_v1(batch: &RecordBatch) -> bool {
    pairs_version_of(&batch.schema()) == Ok(SCHEMA_VERSION_1)
}

/// `batch` as a batch of the current version: itself when it is one, upgraded when it is an earlier
/// one. Errors name the column when it matches no version.
pub fn to_current(batch: &RecordBatch) -> Result<RecordBatch> {
    match pairs_version_of(&batch.schema()) {
        Ok(SCHEMA_VERSION) => Ok(batch.clone()),
        Ok(version) => upgrade(batch, version),
        Err(m) => Err(Error::Parquet(format!("not a pairs batch: {m}"))),
    }
}

/// An earlier version's batch as the current version.
fn upgrade(batch: &RecordBatch, version: &str) -> Result<RecordBatch> {
    let n = batch.num_rows();
    let target = pairs_schema();
    let columns = target
        .fields()
        .iter()
        .map(|f| -> Result<ArrayRef> {
            let name = f.name().as_str();
            let Some(c) = batch.column_by_name(name) else {
                return Ok(match name {
                    _ if PROVENANCE.contains(&name) => {
                        let values: ArrayRef = if name == "target_view" { Arc::new(Int8Array::from(Vec::<i8>::new())) } else { Arc::new(Float32Array::from(Vec::<f32>::new())) };
                        Arc::new(ListArray::new(list_item(f.data_type()), OffsetBuffer::new_zeroed(n), values, None))
                    }
                    // No scene: every point's scene share is 0, one per point of the known shares (version 1
                    // has none: empty lists, as its other provenance).
                    "target_scene_share" => {
                        let offsets = match batch.column_by_name("target_known_share") {
                            Some(c) => downcast::<ListArray>("target_known_share", c)?.offsets().clone(),
                            None => OffsetBuffer::new_zeroed(n),
                        };
                        let zeros = Float32Array::from(vec![0.0f32; *offsets.last().unwrap_or(&0) as usize]);
                        Arc::new(ListArray::new(list_item(f.data_type()), offsets, Arc::new(zeros), None))
                    }
                    "scene_frames" => Arc::new(Int32Array::from(vec![0i32; n])),
                    _ => return Err(Error::Parquet(format!("{version}: column `{name}` is missing"))),
                });
            };
            Ok(if version == SCHEMA_VERSION_1 && WIDE.contains(&name) {
                Arc::new(Int64Array::from_iter_values(downcast::<UInt64Array>(name, c)?.values().iter().map(|&v| v as i64)))
            } else if version == SCHEMA_VERSION_1 && NARROW.contains(&name) {
                Arc::new(Int32Array::from_iter_values(downcast::<UInt32Array>(name, c)?.values().iter().map(|&v| v as i32)))
            } else {
                c.clone()
            })
        })
        .collect::<Result<Vec<_>>>()?;
    rebuild(target, columns)
}

/// A current batch as `version` (its columns only), for the new shards of a dataset of that version. The
/// columns the version lacks are dropped: a build resuming such a dataset has its config, which makes no
/// scene (a `scene` method did not exist then), so nothing is lost.
pub fn downgrade(batch: &RecordBatch, version: &str) -> Result<RecordBatch> {
    let target: SchemaRef = pairs_schema_of(version).ok_or_else(|| Error::Internal(format!("no pairs schema {version}")))?;
    let columns = target
        .fields()
        .iter()
        .map(|f| -> Result<ArrayRef> {
            let name = f.name().as_str();
            let c = column(batch, name)?;
            Ok(if version == SCHEMA_VERSION_1 && WIDE.contains(&name) {
                Arc::new(UInt64Array::from_iter_values(downcast::<Int64Array>(name, c)?.values().iter().map(|&v| v as u64)))
            } else if version == SCHEMA_VERSION_1 && NARROW.contains(&name) {
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
