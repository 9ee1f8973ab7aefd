//! The Arrow schema of the `pairs` table, version 3 (`schemas/pairs-v3.md` is its human-readable twin),
//! and versions 1 and 2, which datasets built before it still hold (`schemas/pairs-v1.md`, `pairs-v2.md`;
//! read and resumed through [`super::pairs_versions`]).
//!
//! One column per [`PairRow`](super::row::PairRow) field, in the same order. No column is nullable: a
//! value that is "not stored" is an empty list or an empty binary. Since version 2 only signed integers
//! (data-lake engines such as Delta, Spark and Trino have no unsigned ones; the 64-bit seed is stored bit
//! for bit as `int64`) and the per-point provenance of the target cloud; version 3 adds the scene (the
//! points the posed frames around the source saw, and how many frames the unit's scene fused). The
//! schema's metadata carries `schema_version`, which every Parquet shard embeds.

use arrow::datatypes::{DataType, Field, FieldRef, Fields, Schema, SchemaRef};
use std::collections::HashMap;
use std::sync::{Arc, OnceLock};

/// The version of the pairs schema this code writes, stored in the Arrow schema metadata under
/// [`SCHEMA_VERSION_KEY`] and in `dataset.toml`.
pub const SCHEMA_VERSION: &str = "pairs/3";

/// The earlier versions, still read (and written when a dataset of theirs is resumed).
pub const SCHEMA_VERSION_1: &str = "pairs/1";
pub const SCHEMA_VERSION_2: &str = "pairs/2";

/// Every version this code reads, newest first.
pub const PAIRS_VERSIONS: [&str; 3] = [SCHEMA_VERSION, SCHEMA_VERSION_2, SCHEMA_VERSION_1];

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

/// `list<T>` of non-null values.
pub fn list_of(t: DataType) -> DataType {
    DataType::List(Arc::new(Field::new(ITEM, t, false)))
}

/// The pairs v3 schema (built once, shared): what this code writes.
pub fn pairs_schema() -> SchemaRef {
    static SCHEMA: OnceLock<SchemaRef> = OnceLock::new();
    SCHEMA.get_or_init(|| build_pairs_schema(3)).clone()
}

/// The pairs v2 schema: provenance without the scene.
pub fn pairs_schema_v2() -> SchemaRef {
    static SCHEMA: OnceLock<SchemaRef> = OnceLock::new();
    SCHEMA.get_or_init(|| build_pairs_schema(2)).clone()
}

/// The pairs v1 schema: unsigned integers, no provenance columns.
pub fn pairs_schema_v1() -> SchemaRef {
    static SCHEMA: OnceLock<SchemaRef> = OnceLock::new();
    SCHEMA.get_or_init(|| build_pairs_schema(1)).clone()
}

/// The pairs schema of a recorded version (`pairs/1`, `pairs/2`, `pairs/3`), or `None` for a version
/// this code does not know.
pub fn pairs_schema_of(version: &str) -> Option<SchemaRef> {
    match version {
        SCHEMA_VERSION => Some(pairs_schema()),
        SCHEMA_VERSION_2 => Some(pairs_schema_v2()),
        SCHEMA_VERSION_1 => Some(pairs_schema_v1()),
        _ => None,
    }
}

fn build_pairs_schema(version: u32) -> SchemaRef {
    use DataType::{Binary, Float32, Float64, Int32, Int64, Int8, UInt32, UInt64, Utf8};
    let col = |name: &str, t: DataType| Field::new(name, t, false);
    let (u64t, u32t) = if version == 1 { (UInt64, UInt32) } else { (Int64, Int32) };
    let mut fields = vec![
        col("unit_index", u64t.clone()),
        col("pair_key", Utf8),
        col("scene", Utf8),
        col("frame_key", Utf8),
        col("sample_index", u32t.clone()),
        col("source_path", Utf8),
        col("source_hash", Utf8),
        col("status", Utf8),
        col("message", Utf8),
        col("seed", u64t),
        col("width", u32t.clone()),
        col("height", u32t.clone()),
        col("source_intrinsics", f64_vector_type(4)),
        col("target_intrinsics", f64_vector_type(4)),
        col("t_target_from_source", f64_vector_type(16)),
        col("pose_draws", u32t.clone()),
    ];
    if version >= 3 {
        fields.push(col("scene_frames", u32t));
    }
    fields.extend([col("source_points", cloud_type()), col("target_points", cloud_type())]);
    if version >= 2 {
        fields.push(col("target_known_share", list_of(Float32)));
    }
    if version >= 3 {
        fields.push(col("target_scene_share", list_of(Float32)));
    }
    if version >= 2 {
        fields.push(col("target_view", list_of(Int8)));
    }
    fields.extend([
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
    ]);
    let name = PAIRS_VERSIONS[3 - version as usize];
    let metadata = HashMap::from([(SCHEMA_VERSION_KEY.to_string(), name.to_string())]);
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
        DataType::Int8 => "int8".into(),
        DataType::Int16 => "int16".into(),
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

/// The pairs schema version `found` is: the version its metadata records (`schema_version`), checked
/// against that version's fields; without the metadata (a batch a reader rebuilt), whichever version's
/// fields it has. The error is the first difference, naming the column.
pub fn pairs_version_of(found: &Schema) -> std::result::Result<&'static str, String> {
    let check = |version: &'static str| -> std::result::Result<&'static str, String> {
        let expected = pairs_schema_of(version).expect("a known version");
        match fields_mismatch(expected.fields(), found.fields()) {
            None => Ok(version),
            Some(m) => Err(format!("{version}: {m}")),
        }
    };
    match found.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str) {
        Some(v) => match PAIRS_VERSIONS.iter().find(|k| **k == v) {
            Some(known) => check(known),
            None => Err(format!("unknown pairs schema version {v:?} (this code reads {})", PAIRS_VERSIONS.join(", "))),
        },
        // The newest version that fits; the error is the newest version's.
        None => PAIRS_VERSIONS.iter().map(|v| check(v)).find(|r| r.is_ok()).unwrap_or_else(|| check(SCHEMA_VERSION)),
    }
}

/// The first difference between `found` and the pairs schema of its version ([`pairs_version_of`]), or
/// `None` when the fields match in names, order, types and nullability.
pub fn pairs_schema_mismatch(found: &Schema) -> Option<String> {
    pairs_version_of(found).err()
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
        assert_eq!(schema.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str), Some("pairs/3"));
        assert_eq!(schema.fields().len(), 32);
        assert!(schema.fields().iter().all(|f| !f.is_nullable()));
        assert_eq!(schema.field(0).name(), "unit_index");
        assert_eq!(schema.field(31).name(), "timings");
        let v2 = pairs_schema_v2();
        assert_eq!(v2.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str), Some("pairs/2"));
        assert_eq!(v2.fields().len(), 30);
        let v1 = pairs_schema_v1();
        assert_eq!(v1.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str), Some("pairs/1"));
        assert_eq!(v1.fields().len(), 28);
    }

    #[test]
    fn version_2_has_no_unsigned_integer() {
        fn unsigned(t: &DataType) -> bool {
            match t {
                DataType::UInt8 | DataType::UInt16 | DataType::UInt32 | DataType::UInt64 => true,
                DataType::List(f) | DataType::FixedSizeList(f, _) => unsigned(f.data_type()),
                DataType::Struct(fs) => fs.iter().any(|f| unsigned(f.data_type())),
                _ => false,
            }
        }
        assert!(pairs_schema().fields().iter().all(|f| !unsigned(f.data_type())));
        assert!(pairs_schema_v1().fields().iter().any(|f| unsigned(f.data_type())));
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
        assert_eq!(pairs_schema_mismatch(&pairs_schema_v1()), None);
        assert_eq!(pairs_schema_mismatch(&pairs_schema_v2()), None);
        let i = schema.index_of("overlap_source").unwrap();
        let mut fields: Vec<Field> = schema.fields().iter().map(|f| f.as_ref().clone()).collect();
        fields[i] = Field::new("overlap_source", DataType::Float32, false);
        let msg = pairs_schema_mismatch(&Schema::new(fields.clone())).unwrap();
        assert!(msg.contains("overlap_source") && msg.contains("float64") && msg.contains("float32"), "{msg}");
        fields[i] = schema.field(i).clone();
        fields.pop();
        let msg = pairs_schema_mismatch(&Schema::new(fields)).unwrap();
        assert!(msg.contains("timings"), "{msg}");
        // A v1 file is compared with the v1 schema: the v2 columns in it are an error.
        let v1_tagged = Schema::new_with_metadata(schema.fields().clone(), pairs_schema_v1().metadata().clone());
        let msg = pairs_schema_mismatch(&v1_tagged).unwrap();
        assert!(msg.contains("pairs/1") && msg.contains("unit_index"), "{msg}");
    }
}
