//! The `labels` table (schema labels v1): correction-network training examples made by TSDF fusion.
//!
//! One row per (window, sample): the sparse re-projection `I_s` (the network input, with penetration),
//! the dense re-projection `I_d` (the reference) and the keep label `M_gt = [|I_s − I_d| < τ_gt]`
//! (reference §4.2: pixels empty in both are kept; a sparse depth with no dense depth is dropped).

use super::row::Status;
use super::schema::{f64_vector_type, list_item, SCHEMA_VERSION_KEY};
use crate::error::{Error, Result};
use arrow::array::{Array, ArrayRef, BinaryArray, FixedSizeListArray, Float32Array, Float64Array, RecordBatch, StringArray, UInt32Array, UInt64Array};
use arrow::datatypes::{DataType, Field, Schema, SchemaRef};
use std::collections::HashMap;
use std::sync::Arc;

/// The table name of label shards.
pub const LABELS_TABLE: &str = "labels";
/// Schema version stored in the Arrow metadata of label shards.
pub const LABELS_SCHEMA_VERSION: &str = "labels/1";

/// One training example for the correction network.
#[derive(Clone, Debug, PartialEq)]
pub struct LabelRow {
    /// Index of the window (the work unit) in the build.
    pub unit_index: u64,
    pub sample_index: u32,
    /// `<scene>/window-XXXXXX#<sample>`.
    pub label_key: String,
    pub scene: String,
    /// Keys of the first and last fused frames, and how many frames were fused.
    pub first_frame: String,
    pub last_frame: String,
    pub frames: u32,
    /// The frame the pose is sampled relative to (and the fused clouds are expressed in).
    pub reference_frame: String,
    pub status: Status,
    pub message: String,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// `[fx, fy, cx, cy]` of the target camera at the working resolution.
    pub intrinsics: [f64; 4],
    /// Row-major 4×4 `T_target_from_reference`.
    pub t_target_from_reference: [f64; 16],
    /// TSDF voxel, sparse-copy voxel and τ_gt, metres.
    pub tsdf_voxel: f32,
    pub sparse_voxel: f32,
    pub tau_gt: f32,
    /// Points of the dense surface cloud and of its sparse copy.
    pub dense_points: u64,
    pub sparse_points: u64,
    /// Pixels with sparse depth, and those of them labelled "drop" (penetrated or unsupported).
    pub sparse_pixels: u64,
    pub dropped_pixels: u64,
    /// 16-bit millimetre PNGs of `I_s` and `I_d`, and the 8-bit PNG of `M_gt` (255 = keep).
    pub sparse_depth_png: Vec<u8>,
    pub dense_depth_png: Vec<u8>,
    pub label_png: Vec<u8>,
    pub config_hash: String,
    pub code_version: String,
    /// JSON: stages with parameters, and per-stage milliseconds.
    pub stages: String,
    pub timings: String,
}

/// The labels v1 Arrow schema (no nullable column).
pub fn labels_schema() -> SchemaRef {
    let f = |n: &str, t: DataType| Field::new(n, t, false);
    let fields = vec![
        f("unit_index", DataType::UInt64),
        f("sample_index", DataType::UInt32),
        f("label_key", DataType::Utf8),
        f("scene", DataType::Utf8),
        f("first_frame", DataType::Utf8),
        f("last_frame", DataType::Utf8),
        f("frames", DataType::UInt32),
        f("reference_frame", DataType::Utf8),
        f("status", DataType::Utf8),
        f("message", DataType::Utf8),
        f("seed", DataType::UInt64),
        f("width", DataType::UInt32),
        f("height", DataType::UInt32),
        f("intrinsics", f64_vector_type(4)),
        f("t_target_from_reference", f64_vector_type(16)),
        f("tsdf_voxel", DataType::Float32),
        f("sparse_voxel", DataType::Float32),
        f("tau_gt", DataType::Float32),
        f("dense_points", DataType::UInt64),
        f("sparse_points", DataType::UInt64),
        f("sparse_pixels", DataType::UInt64),
        f("dropped_pixels", DataType::UInt64),
        f("sparse_depth_png", DataType::Binary),
        f("dense_depth_png", DataType::Binary),
        f("label_png", DataType::Binary),
        f("config_hash", DataType::Utf8),
        f("code_version", DataType::Utf8),
        f("stages", DataType::Utf8),
        f("timings", DataType::Utf8),
    ];
    let meta = HashMap::from([(SCHEMA_VERSION_KEY.to_string(), LABELS_SCHEMA_VERSION.to_string())]);
    Arc::new(Schema::new_with_metadata(fields, meta))
}

/// One batch of the labels v1 schema holding `rows` in order.
pub fn labels_to_batch(rows: &[LabelRow]) -> Result<RecordBatch> {
    let schema = labels_schema();
    let utf8 = |f: fn(&LabelRow) -> &str| -> ArrayRef { Arc::new(StringArray::from_iter_values(rows.iter().map(f))) };
    let bin = |f: fn(&LabelRow) -> &[u8]| -> ArrayRef { Arc::new(BinaryArray::from_iter_values(rows.iter().map(f))) };
    let u32s = |f: fn(&LabelRow) -> u32| -> ArrayRef { Arc::new(UInt32Array::from_iter_values(rows.iter().map(f))) };
    let u64s = |f: fn(&LabelRow) -> u64| -> ArrayRef { Arc::new(UInt64Array::from_iter_values(rows.iter().map(f))) };
    let f32s = |f: fn(&LabelRow) -> f32| -> ArrayRef { Arc::new(Float32Array::from_iter_values(rows.iter().map(f))) };
    let vectors = |n: i32, f: fn(&LabelRow) -> &[f64]| -> Result<ArrayRef> {
        let values = Float64Array::from_iter_values(rows.iter().flat_map(|r| f(r).iter().copied()));
        let t = f64_vector_type(n);
        Ok(Arc::new(FixedSizeListArray::try_new(list_item(&t), n, Arc::new(values), None).map_err(|e| Error::Parquet(e.to_string()))?))
    };
    let columns = vec![
        u64s(|r| r.unit_index),
        u32s(|r| r.sample_index),
        utf8(|r| &r.label_key),
        utf8(|r| &r.scene),
        utf8(|r| &r.first_frame),
        utf8(|r| &r.last_frame),
        u32s(|r| r.frames),
        utf8(|r| &r.reference_frame),
        utf8(|r| r.status.as_str()),
        utf8(|r| &r.message),
        u64s(|r| r.seed),
        u32s(|r| r.width),
        u32s(|r| r.height),
        vectors(4, |r| &r.intrinsics)?,
        vectors(16, |r| &r.t_target_from_reference)?,
        f32s(|r| r.tsdf_voxel),
        f32s(|r| r.sparse_voxel),
        f32s(|r| r.tau_gt),
        u64s(|r| r.dense_points),
        u64s(|r| r.sparse_points),
        u64s(|r| r.sparse_pixels),
        u64s(|r| r.dropped_pixels),
        bin(|r| &r.sparse_depth_png),
        bin(|r| &r.dense_depth_png),
        bin(|r| &r.label_png),
        utf8(|r| &r.config_hash),
        utf8(|r| &r.code_version),
        utf8(|r| &r.stages),
        utf8(|r| &r.timings),
    ];
    RecordBatch::try_new(schema, columns).map_err(|e| Error::Parquet(format!("building a labels batch: {e}")))
}

/// Reads every row of a labels v1 batch; errors name the column that does not match.
pub fn batch_to_labels(batch: &RecordBatch) -> Result<Vec<LabelRow>> {
    fn col<'a, T: Array + 'static>(b: &'a RecordBatch, name: &str) -> Result<&'a T> {
        b.column_by_name(name)
            .ok_or_else(|| Error::Parquet(format!("labels column `{name}` is missing")))?
            .as_any()
            .downcast_ref::<T>()
            .ok_or_else(|| Error::Parquet(format!("labels column `{name}` has the wrong type")))
    }
    let s = |n: &str| col::<StringArray>(batch, n);
    let b = |n: &str| col::<BinaryArray>(batch, n);
    let u32c = |n: &str| col::<UInt32Array>(batch, n);
    let u64c = |n: &str| col::<UInt64Array>(batch, n);
    let f32c = |n: &str| col::<Float32Array>(batch, n);
    let fixed = |n: &str| -> Result<Vec<f64>> {
        let a = col::<FixedSizeListArray>(batch, n)?;
        let v = a.values().as_any().downcast_ref::<Float64Array>().ok_or_else(|| Error::Parquet(format!("labels column `{n}` has the wrong type")))?;
        Ok(v.values().to_vec())
    };
    let (intr, pose) = (fixed("intrinsics")?, fixed("t_target_from_reference")?);
    let mut rows = Vec::with_capacity(batch.num_rows());
    for i in 0..batch.num_rows() {
        let status_text = s("status")?.value(i);
        rows.push(LabelRow {
            unit_index: u64c("unit_index")?.value(i),
            sample_index: u32c("sample_index")?.value(i),
            label_key: s("label_key")?.value(i).into(),
            scene: s("scene")?.value(i).into(),
            first_frame: s("first_frame")?.value(i).into(),
            last_frame: s("last_frame")?.value(i).into(),
            frames: u32c("frames")?.value(i),
            reference_frame: s("reference_frame")?.value(i).into(),
            status: Status::parse(status_text).ok_or_else(|| Error::Parquet(format!("unknown status `{status_text}`")))?,
            message: s("message")?.value(i).into(),
            seed: u64c("seed")?.value(i),
            width: u32c("width")?.value(i),
            height: u32c("height")?.value(i),
            intrinsics: intr[i * 4..i * 4 + 4].try_into().expect("4 values"),
            t_target_from_reference: pose[i * 16..i * 16 + 16].try_into().expect("16 values"),
            tsdf_voxel: f32c("tsdf_voxel")?.value(i),
            sparse_voxel: f32c("sparse_voxel")?.value(i),
            tau_gt: f32c("tau_gt")?.value(i),
            dense_points: u64c("dense_points")?.value(i),
            sparse_points: u64c("sparse_points")?.value(i),
            sparse_pixels: u64c("sparse_pixels")?.value(i),
            dropped_pixels: u64c("dropped_pixels")?.value(i),
            sparse_depth_png: b("sparse_depth_png")?.value(i).to_vec(),
            dense_depth_png: b("dense_depth_png")?.value(i).to_vec(),
            label_png: b("label_png")?.value(i).to_vec(),
            config_hash: s("config_hash")?.value(i).into(),
            code_version: s("code_version")?.value(i).into(),
            stages: s("stages")?.value(i).into(),
            timings: s("timings")?.value(i).into(),
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(i: u64) -> LabelRow {
        LabelRow {
            unit_index: i,
            sample_index: 1,
            label_key: format!("s/window-{i:06}#1"),
            scene: "s".into(),
            first_frame: "s/frame-000000".into(),
            last_frame: "s/frame-000049".into(),
            frames: 50,
            reference_frame: "s/frame-000000".into(),
            status: if i % 2 == 0 { Status::Ok } else { Status::InputError },
            message: String::new(),
            seed: 99 + i,
            width: 256,
            height: 256,
            intrinsics: [311.6, 312.0, 128.5, 128.0],
            t_target_from_reference: std::array::from_fn(|k| k as f64 * 0.5),
            tsdf_voxel: 0.006,
            sparse_voxel: 0.025,
            tau_gt: 0.05,
            dense_points: 1_000_000,
            sparse_points: 40_000,
            sparse_pixels: 30_000,
            dropped_pixels: 2_000 + i,
            sparse_depth_png: vec![1, 2, 3],
            dense_depth_png: vec![],
            label_png: vec![9; 10],
            config_hash: "abc".into(),
            code_version: "v".into(),
            stages: "[]".into(),
            timings: "{}".into(),
        }
    }

    #[test]
    fn round_trip_through_parquet_is_exact() {
        let rows: Vec<LabelRow> = (0..5).map(row).collect();
        let batch = labels_to_batch(&rows).unwrap();
        let bytes = super::super::write_parquet_bytes(&labels_schema(), &[batch], crate::shards::ROW_GROUP_ROWS).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("l.parquet");
        std::fs::write(&p, bytes).unwrap();
        let (schema, batches) = super::super::read_parquet_file(&p).unwrap();
        assert_eq!(schema.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str), Some(LABELS_SCHEMA_VERSION));
        let back: Vec<LabelRow> = batches.iter().flat_map(|b| batch_to_labels(b).unwrap()).collect();
        assert_eq!(back, rows);
    }
}
