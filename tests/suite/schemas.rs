//! The versioned shard schemas in `schemas/*.md`, checked against the Arrow schemas the code writes:
//! names, order, types and nullability of every column.

use arrow::datatypes::SchemaRef;
use pointreggpt::shards::labels::LABELS_SCHEMA_VERSION;
use pointreggpt::shards::schema::type_notation;
use pointreggpt::shards::schema::{pairs_schema_v1, pairs_schema_v2};
use pointreggpt::shards::{labels_schema, pairs_schema, SCHEMA_VERSION, SCHEMA_VERSION_1, SCHEMA_VERSION_2};

/// Rows `(column, type, nullable)` of the first markdown table of a `schemas/*.md` file.
fn markdown_columns(text: &str) -> Vec<(String, String, String)> {
    let mut rows = Vec::new();
    let mut in_table = false;
    for line in text.lines() {
        let line = line.trim();
        if !line.starts_with('|') {
            if in_table {
                break;
            }
            continue;
        }
        let cells: Vec<String> =
            line.trim_matches('|').split('|').map(|c| c.trim().trim_matches('`').to_string()).collect();
        if !in_table {
            assert_eq!(cells[..3], ["column", "type", "nullable"], "table header of a schemas/*.md file");
            in_table = true;
            continue;
        }
        if cells[0].starts_with("---") {
            continue;
        }
        rows.push((cells[0].clone(), cells[1].clone(), cells[2].clone()));
    }
    rows
}

/// Checks the table of `schemas/<file>` against `schema`: names, order, types and nullability.
fn check_markdown(file: &str, version: &str, schema: &SchemaRef) {
    let path = format!("{}/schemas/{file}", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(&path).expect("schema markdown");
    assert!(text.contains(&format!("`{version}`")), "{file} names the schema version {version}");
    let doc = markdown_columns(&text);
    let code: Vec<(String, String, String)> = schema
        .fields()
        .iter()
        .map(|f| {
            let nullable = if f.is_nullable() { "yes" } else { "no" };
            (f.name().clone(), type_notation(f.data_type()), nullable.to_string())
        })
        .collect();
    for (i, (d, c)) in doc.iter().zip(&code).enumerate() {
        assert_eq!(d, c, "row {i} of the table in schemas/{file} differs from the code schema");
    }
    assert_eq!(doc.len(), code.len(), "column count of schemas/{file} vs the code schema");
}

#[test]
fn markdown_schemas_match_the_code() {
    let _timing = crate::support::timed();
    check_markdown("pairs-v3.md", SCHEMA_VERSION, &pairs_schema());
    check_markdown("pairs-v2.md", SCHEMA_VERSION_2, &pairs_schema_v2());
    check_markdown("pairs-v1.md", SCHEMA_VERSION_1, &pairs_schema_v1());
    check_markdown("labels-v1.md", LABELS_SCHEMA_VERSION, &labels_schema());
}
