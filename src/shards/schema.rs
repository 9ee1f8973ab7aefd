//! The Arrow schema of the `pairs` table, version 1 (`schemas/pairs-v1.md` is its human-readable twin).
//!
//! One column per [`PairRow`](super::row::PairRow) field, in the same order. No column is nullable: a
//! value that is "not stored" is an empty list or an empty binary. The schema's metadata carries
//! `schema_version = "pairs/1"`, which every Parquet shard embeds.

use arrow::datatypes::{DataType, Field, FieldRef, Fields, Schema, SchemaRef};
use std::collections::HashMap;
use std::sync::{Arc, OnceLock};

/// The version of the pairs schema, stored in the Arrow schema metadata under [`SCHEMA_VERSION_KEY`].
pub const SCHEMA_VERSION: &str = "pairs/1";

/// The schema-metadata key holding a table's schema version (`"pairs/1"`, `"labels/1"`, ...).
pub const SCHEMA_VERSION_KEY: &str = "schema_version";

/// Name of the child field of every list and fixed-size list (Arrow's convention).
const ITEM: &str = "item";

/// `fixed_size_list<float64, n>`: intrinsics (n = 4) and row-major poses (n = 16).
pub fn f64_vector_type(n: i32) -> DataType {
    DataType::FixedSizeList(Arc::new(Field::new(ITEM, DataType::Float64, false)), n)
}

/// `fixed_size_list<float32, 3>`: one point (x, y, z) in metres.
pub fn point_type() -> DataType {
    DataType::FixedSizeList(Arc::new(Field::new(ITEM, DataType::Float32, false)), 3)
}

/// `list<fixed_size_list<float32, 3>>`: a point cloud.
pub fn cloud_type() -> DataType {
    DataType::List(Arc::new(Field::new(ITEM, point_type(), false)))
}

/// The fields of one timing entry: `stage` (utf8) and `ms` (float64).
pub fn timing_fields() -> Fields {
    Fields::from(vec![Field::new("stage", DataType::Utf8, false), Field::new("ms", DataType::Float64, false)])
}

/// `list<struct<stage: utf8, ms: float64>>`: per-stage wall times.
pub fn timings_type() -> DataType {
    DataType::List(Arc::new(Field::new(ITEM, DataType::Struct(timing_fields()), false)))
}

/// The child field of a list type (the `item` field), for building list arrays that match the schema.
pub fn list_item(data_type: &DataType) -> FieldRef {
    match data_type {
        DataType::List(f) | DataType::FixedSizeList(f, _) => f.clone(),
        other => panic!("list_item on a non-list type {other}"),
    }
}

/// The pairs v1 schema (built once, shared).
pub fn pairs_schema() -> SchemaRef {
    static SCHEMA: OnceLock<SchemaRef> = OnceLock::new();
    SCHEMA.get_or_init(build_pairs_schema).clone()
}

fn build_pairs_schema() -> SchemaRef {
    use DataType::{Binary, Float64, UInt32, UInt64, Utf8};
    let col = |name: &str, t: DataType| Field::new(name, t, false);
    let fields = vec![
        col("unit_index", UInt64),
        col("pair_key", Utf8),
        col("scene", Utf8),
        col("frame_key", Utf8),
        col("sample_index", UInt32),
        col("source_path", Utf8),
        col("source_hash", Utf8),
        col("status", Utf8),
        col("message", Utf8),
        col("seed", UInt64),
        col("width", UInt32),
        col("height", UInt32),
        col("source_intrinsics", f64_vector_type(4)),
        col("target_intrinsics", f64_vector_type(4)),
        col("t_target_from_source", f64_vector_type(16)),
        col("pose_draws", UInt32),
        col("source_points", cloud_type()),
        col("target_points", cloud_type()),
        col("overlap_source", Float64),
        col("overlap_target", Float64),
        col("source_depth_png", Binary),
        col("condition_depth_png", Binary),
        col("target_depth_png", Binary),
        col("known_mask_png", Binary),
        col("config_hash", Utf8),
        col("code_version", Utf8),
        col("stages", Utf8),
        col("timings", timings_type()),
    ];
    let metadata = HashMap::from([(SCHEMA_VERSION_KEY.to_string(), SCHEMA_VERSION.to_string())]);
    Arc::new(Schema::new_with_metadata(fields, metadata))
}

/// The type in the notation of `schemas/*.md`: `uint64`, `utf8`, `binary`, `float64`,
/// `fixed_size_list<float64,4>`, `list<fixed_size_list<float32,3>>`, `struct<stage: utf8, ms: float64>`.
/// Types the schemas do not use are written with Arrow's own `Debug` form.
pub fn type_notation(data_type: &DataType) -> String {
    match data_type {
        DataType::UInt32 => "uint32".into(),
        DataType::UInt64 => "uint64".into(),
        DataType::Int32 => "int32".into(),
        DataType::Int64 => "int64".into(),
        DataType::UInt8 => "uint8".into(),
        DataType::UInt16 => "uint16".into(),
        DataType::Float32 => "float32".into(),
        DataType::Float64 => "float64".into(),
        DataType::Boolean => "bool".into(),
        DataType::Utf8 => "utf8".into(),
        DataType::Binary => "binary".into(),
        DataType::List(f) => format!("list<{}>", type_notation(f.data_type())),
        DataType::FixedSizeList(f, n) => format!("fixed_size_list<{},{n}>", type_notation(f.data_type())),
        DataType::Struct(fields) => {
            let inner: Vec<String> =
                fields.iter().map(|f| format!("{}: {}", f.name(), type_notation(f.data_type()))).collect();
            format!("struct<{}>", inner.join(", "))
        }
        other => format!("{other:?}"),
    }
}

/// The first difference between `found` and the pairs schema (by column name), or `None` when the fields
/// match in names, order, types and nullability. Metadata is not compared.
pub fn pairs_schema_mismatch(found: &Schema) -> Option<String> {
    fields_mismatch(pairs_schema().fields(), found.fields())
}

/// The first difference between two field lists, naming the column.
pub fn fields_mismatch(expected: &Fields, found: &Fields) -> Option<String> {
    for (i, e) in expected.iter().enumerate() {
        let Some(f) = found.get(i) else {
            return Some(format!("column `{}` (#{i}) is missing ({} columns found)", e.name(), found.len()));
        };
        if f.name() != e.name() {
            return Some(format!("column #{i} should be `{}`, found `{}`", e.name(), f.name()));
        }
        if f.data_type() != e.data_type() {
            return Some(format!(
                "column `{}` should be {}, found {}",
                e.name(),
                type_notation(e.data_type()),
                type_notation(f.data_type())
            ));
        }
        if f.is_nullable() != e.is_nullable() {
            return Some(format!(
                "column `{}` should be {}nullable",
                e.name(),
                if e.is_nullable() { "" } else { "non-" }
            ));
        }
    }
    if found.len() > expected.len() {
        return Some(format!("unexpected extra column `{}`", found[expected.len()].name()));
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schema_has_version_and_no_nullable_column() {
        let schema = pairs_schema();
        assert_eq!(schema.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str), Some("pairs/1"));
        assert_eq!(schema.fields().len(), 28);
        assert!(schema.fields().iter().all(|f| !f.is_nullable()));
        assert_eq!(schema.field(0).name(), "unit_index");
        assert_eq!(schema.field(27).name(), "timings");
    }

    #[test]
    fn notation_of_nested_types() {
        assert_eq!(type_notation(&cloud_type()), "list<fixed_size_list<float32,3>>");
        assert_eq!(type_notation(&f64_vector_type(16)), "fixed_size_list<float64,16>");
        assert_eq!(type_notation(&timings_type()), "list<struct<stage: utf8, ms: float64>>");
    }

    #[test]
    fn mismatch_names_the_column() {
        let schema = pairs_schema();
        assert_eq!(pairs_schema_mismatch(&schema), None);
        let mut fields: Vec<Field> = schema.fields().iter().map(|f| f.as_ref().clone()).collect();
        fields[18] = Field::new("overlap_source", DataType::Float32, false);
        let msg = pairs_schema_mismatch(&Schema::new(fields.clone())).unwrap();
        assert!(msg.contains("overlap_source") && msg.contains("float64") && msg.contains("float32"), "{msg}");
        fields[18] = schema.field(18).clone();
        fields.pop();
        let msg = pairs_schema_mismatch(&Schema::new(fields)).unwrap();
        assert!(msg.contains("timings"), "{msg}");
    }
}
