//! The Delta Lake schema (`metaData.schemaString`) of an Arrow schema: Delta's JSON schema format, with
//! the primitive names Spark uses (`long`, `integer`, `byte`, `float`, `double`, `string`, `binary`).
//!
//! Lists and fixed-size lists become `array` (Delta has no fixed-size arrays), structs `struct`;
//! `containsNull` and `nullable` follow the Arrow fields (the pairs table has no nullable field or item).
//! Unsigned integers have no Delta type: such a column is refused by name (`pairs/1` datasets).

use crate::error::{Error, Result};
use arrow::datatypes::{DataType, Field, Fields, Schema};
use serde_json::{json, Value};

/// The Delta schema of `schema` as JSON text (what `metaData.schemaString` holds).
pub fn schema_string(schema: &Schema) -> Result<String> {
    Ok(struct_type(schema.fields(), "")?.to_string())
}

/// `{"type": "struct", "fields": [...]}` of `fields`; `path` prefixes column names in messages.
fn struct_type(fields: &Fields, path: &str) -> Result<Value> {
    let fields = fields.iter().map(|f| struct_field(f, path)).collect::<Result<Vec<_>>>()?;
    Ok(json!({"type": "struct", "fields": fields}))
}

fn struct_field(field: &Field, path: &str) -> Result<Value> {
    let name = if path.is_empty() { field.name().clone() } else { format!("{path}.{}", field.name()) };
    Ok(json!({
        "name": field.name(),
        "type": delta_type(field.data_type(), &name)?,
        "nullable": field.is_nullable(),
        "metadata": {},
    }))
}

/// The Delta type of the Arrow type of column `name`.
fn delta_type(data_type: &DataType, name: &str) -> Result<Value> {
    let primitive = |t: &str| Ok(Value::String(t.to_string()));
    match data_type {
        DataType::Int64 => primitive("long"),
        DataType::Int32 => primitive("integer"),
        DataType::Int16 => primitive("short"),
        DataType::Int8 => primitive("byte"),
        DataType::Float32 => primitive("float"),
        DataType::Float64 => primitive("double"),
        DataType::Boolean => primitive("boolean"),
        DataType::Utf8 | DataType::LargeUtf8 => primitive("string"),
        DataType::Binary | DataType::LargeBinary => primitive("binary"),
        DataType::List(item) | DataType::LargeList(item) | DataType::FixedSizeList(item, _) => Ok(json!({
            "type": "array",
            "elementType": delta_type(item.data_type(), &format!("{name}[]"))?,
            "containsNull": item.is_nullable(),
        })),
        DataType::Struct(fields) => struct_type(fields, name),
        other => Err(Error::InvalidArgument(format!(
            "column `{name}`: Arrow type {other} has no Delta Lake type{}",
            if other.is_unsigned_integer() { " (Delta has no unsigned integers; schema pairs/2 has only signed ones)" } else { "" }
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shards::schema::{pairs_schema, pairs_schema_v1};
    use std::sync::Arc;

    /// The column `name` of a Delta schema.
    fn column<'a>(schema: &'a Value, name: &str) -> &'a Value {
        schema["fields"].as_array().unwrap().iter().find(|f| f["name"] == name).unwrap_or_else(|| panic!("no column {name}"))
    }

    #[test]
    fn the_pairs_schema_maps_to_spark_types() {
        let s: Value = serde_json::from_str(&schema_string(&pairs_schema()).unwrap()).unwrap();
        assert_eq!(s["type"], "struct");
        assert_eq!(s["fields"].as_array().unwrap().len(), pairs_schema().fields().len());
        for (name, t) in [("unit_index", "long"), ("seed", "long"), ("sample_index", "integer"), ("width", "integer"), ("pose_draws", "integer"),
            ("pair_key", "string"), ("overlap_source", "double"), ("source_depth_png", "binary")]
        {
            assert_eq!(column(&s, name)["type"], t, "{name}");
            assert_eq!(column(&s, name)["nullable"], false, "{name}");
        }
        let array = |e: Value| json!({"type": "array", "elementType": e, "containsNull": false});
        assert_eq!(column(&s, "target_view")["type"], array(json!("byte")));
        assert_eq!(column(&s, "target_known_share")["type"], array(json!("float")));
        assert_eq!(column(&s, "t_target_from_source")["type"], array(json!("double")));
        assert_eq!(column(&s, "source_points")["type"], array(array(json!("float"))));
        let timing = json!({"type": "struct", "fields": [
            {"name": "stage", "type": "string", "nullable": false, "metadata": {}},
            {"name": "ms", "type": "double", "nullable": false, "metadata": {}}]});
        assert_eq!(column(&s, "timings")["type"], array(timing));
    }

    #[test]
    fn unsigned_and_unknown_types_are_refused_by_column() {
        let err = schema_string(&pairs_schema_v1()).unwrap_err().to_string();
        assert!(err.contains("`unit_index`") && err.contains("unsigned"), "{err}");
        let nested = Schema::new(vec![Field::new("t", DataType::List(Arc::new(Field::new("item", DataType::Date32, true))), true)]);
        let err = schema_string(&nested).unwrap_err().to_string();
        assert!(err.contains("`t[]`") && err.contains("Date32"), "{err}");
        let nullable = Schema::new(vec![Field::new("x", DataType::List(Arc::new(Field::new("item", DataType::Int32, true))), true)]);
        let s: Value = serde_json::from_str(&schema_string(&nullable).unwrap()).unwrap();
        assert_eq!(column(&s, "x")["type"]["containsNull"], true);
        assert_eq!(column(&s, "x")["nullable"], true);
    }
}
