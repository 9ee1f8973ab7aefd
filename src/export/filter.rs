//! `--where` predicates: one SQL expression over the columns of the `pairs` table (the SQL of
//! `pointreggpt query ... where <predicate>`), parsed and planned once with DataFusion, then evaluated on
//! each shard's record batch to select rows before they are decoded into [`PairRow`](crate::shards::PairRow)s.
//!
//! `status = 'ok' and overlap_source >= 0.3`, `scene in ('a', 'b') and pair_key like '%#0'`,
//! `not (unit_index between 3 and 5)`, `array_length(target_points) < 2000`. A row where the predicate
//! is null (SQL `WHERE` semantics) is not selected. Errors name the problem under the field `--where`.

use crate::error::{Error, Result};
use crate::shards::{pairs_schema, PAIRS_TABLE};
use arrow::array::{Array, BooleanArray, RecordBatch};
use arrow::compute::{cast, filter_record_batch};
use arrow::datatypes::DataType;
use datafusion::common::tree_node::TreeNode;
use datafusion::common::{DFSchema, DataFusionError, SchemaError};
use datafusion::logical_expr::Expr;
use datafusion::physical_expr::PhysicalExpr;
use datafusion::prelude::SessionContext;
use std::sync::Arc;

/// Which rows to take: all of them, or those where a SQL predicate is true.
#[derive(Clone, Debug)]
pub enum Filter {
    All,
    Sql(Predicate),
}

/// A parsed and planned SQL predicate over the pairs schema.
#[derive(Clone, Debug)]
pub struct Predicate {
    /// The text as the user wrote it.
    text: String,
    /// The planned expression; it reads columns by their index in the pairs schema.
    physical: Arc<dyn PhysicalExpr>,
}

impl Filter {
    /// Parses a predicate; an empty or blank text gives [`Filter::All`]. Column names may be qualified
    /// with the table (`pairs.status`), as in `pointreggpt query`.
    pub fn parse(text: &str) -> Result<Filter> {
        if text.trim().is_empty() {
            return Ok(Filter::All);
        }
        let schema = pairs_schema();
        let df_schema = DFSchema::try_from_qualified_schema(PAIRS_TABLE, &schema)
            .map_err(|e| Error::Internal(format!("pairs schema for --where: {e}")))?;
        let ctx = SessionContext::new();
        let expr = ctx.parse_sql_expr(text, &df_schema).map_err(explain)?;
        let per_group = |e: &Expr| Ok(matches!(e, Expr::AggregateFunction(_) | Expr::WindowFunction(_)));
        if expr.exists(per_group).unwrap_or(false) {
            return Err(bad(format!("`{text}` uses an aggregate or window function; a predicate tests one row at a time")));
        }
        let physical = ctx.create_physical_expr(expr, &df_schema).map_err(explain)?;
        match physical.data_type(&schema).map_err(explain)? {
            DataType::Boolean | DataType::Null => {}
            other => {
                return Err(bad(format!(
                    "`{text}` gives {other} values, not true/false; compare it, e.g. `overlap_source >= 0.3`"
                )))
            }
        }
        let filter = Filter::Sql(Predicate { text: text.to_string(), physical });
        // Evaluated once on no rows, so an error in a constant (a text that is no number, ...) shows
        // before any file is read or written.
        filter.select(&RecordBatch::new_empty(schema))?;
        Ok(filter)
    }

    /// Parses `Some(text)`, or gives [`Filter::All`] for `None`.
    pub fn parse_opt(text: Option<&str>) -> Result<Filter> {
        text.map_or(Ok(Filter::All), Filter::parse)
    }

    /// The predicate text, `None` for [`Filter::All`].
    pub fn sql(&self) -> Option<&str> {
        match self {
            Filter::All => None,
            Filter::Sql(p) => Some(&p.text),
        }
    }

    /// The rows of `batch` (pairs schema, in its column order) where the predicate is true.
    pub fn select(&self, batch: &RecordBatch) -> Result<RecordBatch> {
        let Filter::Sql(p) = self else {
            return Ok(batch.clone());
        };
        let value = p.physical.evaluate(batch).and_then(|v| v.into_array(batch.num_rows())).map_err(explain)?;
        // A predicate that is the literal `null` has the type Null: no row is selected.
        let value = if value.data_type() == &DataType::Null { cast(&value, &DataType::Boolean).map_err(arrow_err)? } else { value };
        let mask = value
            .as_any()
            .downcast_ref::<BooleanArray>()
            .ok_or_else(|| bad(format!("`{}` gives {} values, not true/false", p.text, value.data_type())))?;
        // `filter_record_batch` drops the rows where the mask is null, as SQL `WHERE` does.
        filter_record_batch(batch, mask).map_err(arrow_err)
    }
}

fn bad(message: String) -> Error {
    Error::config("--where", message)
}

fn arrow_err(e: arrow::error::ArrowError) -> Error {
    bad(e.to_string())
}

/// A DataFusion error as a `--where` error: unknown columns list the columns, syntax errors say so.
fn explain(e: DataFusionError) -> Error {
    match e.find_root() {
        DataFusionError::SchemaError(s, _) => match s.as_ref() {
            SchemaError::FieldNotFound { field, .. } => bad(unknown_column(field.name())),
            other => bad(other.to_string()),
        },
        DataFusionError::Plan(m) if m.starts_with("table '") => {
            bad(format!("{m}: a predicate reads the columns of its row only (subqueries need `pointreggpt query`)"))
        }
        DataFusionError::SQL(p, _) => bad(format!("not a SQL expression: {}", p.to_string().trim_start_matches("sql parser error: "))),
        other => bad(other.message().into_owned()),
    }
}

fn unknown_column(name: &str) -> String {
    let columns: Vec<String> = pairs_schema().fields().iter().map(|f| f.name().clone()).collect();
    let hint = match name {
        "n_source_points" | "n_target_points" => {
            format!("; the point count is `array_length({}_points)`", name.trim_start_matches("n_").trim_end_matches("_points"))
        }
        _ => String::new(),
    };
    format!("unknown column `{name}`{hint} (columns: {}; text values are quoted: 'ok')", columns.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::tests_support::empty_row;
    use crate::geometry::Point;
    use crate::shards::{batch_to_pairs, pairs_to_batch, PairRow, Status};

    fn row(key: &str, status: Status, scene: &str, ov: f64, n: usize) -> PairRow {
        let mut r = empty_row();
        (r.pair_key, r.status, r.scene, r.overlap_source) = (key.into(), status, scene.into(), ov);
        r.source_points = vec![Point::origin(); n];
        r
    }

    /// The keys of `rows` that `predicate` selects, through a batch as the exporter does.
    fn selected(predicate: &str, rows: &[PairRow]) -> Vec<String> {
        let batch = Filter::parse(predicate).unwrap().select(&pairs_to_batch(rows).unwrap()).unwrap();
        batch_to_pairs(&batch).unwrap().into_iter().map(|r| r.pair_key).collect()
    }

    fn rows() -> Vec<PairRow> {
        vec![
            row("a#0", Status::Ok, "a", 0.3, 0),
            row("a#1", Status::Ok, "a", 0.29, 3),
            row("b#0", Status::LowOverlap, "b", 0.0, 2),
            row("b#1", Status::Ok, "b", f64::NAN, 3),
            row("c#0", Status::Ok, "c", -0.5, 3),
        ]
    }

    #[test]
    fn sql_precedence_and_operators() {
        let rows = rows();
        // `and` binds tighter than `or`.
        assert_eq!(selected("status = 'ok' and overlap_source >= 0.3 or scene = 'b'", &rows), ["a#0", "b#0", "b#1"]);
        assert_eq!(selected("status = 'ok' and (overlap_source >= 0.3 or scene = 'b')", &rows), ["a#0", "b#1"]);
        // Keywords and names are case-insensitive; columns may be qualified with the table.
        assert_eq!(selected("STATUS = 'ok' AND pairs.Scene IN ('a', 'b') AND array_length(source_points) > 2", &rows), ["a#1", "b#1"]);
        assert_eq!(selected("not scene in ('a', 'c')", &rows), ["b#0", "b#1"]);
        assert_eq!(selected("pair_key like '%#0' and scene <> 'it''s'", &rows), ["a#0", "b#0", "c#0"]);
        assert_eq!(selected("overlap_source < -1e-3", &rows), ["c#0"]);
        assert_eq!(selected("unit_index = 0", &rows).len(), 5);
        // Null is "not selected"; NaN is a value (DataFusion orders it above every number).
        assert!(selected("null", &rows).is_empty());
        assert_eq!(selected("nullif(scene, 'a') = scene", &rows), ["b#0", "b#1", "c#0"]);
        assert_eq!(selected("isnan(overlap_source)", &rows), ["b#1"]);
        assert_eq!(selected("overlap_source > 1e300", &rows), ["b#1"]);
        assert!(matches!(Filter::parse("  ").unwrap(), Filter::All));
        assert_eq!(Filter::parse_opt(Some("scene = 'a'")).unwrap().sql(), Some("scene = 'a'"));
    }

    #[test]
    fn errors_name_the_column_or_the_problem() {
        let e = |s: &str| Filter::parse(s).unwrap_err().to_string();
        let m = e("overlap > 0.3");
        assert!(m.contains("--where") && m.contains("unknown column `overlap`") && m.contains("overlap_source, overlap_target"), "{m}");
        assert!(e("status = ok").contains("unknown column `ok`"));
        assert!(e("n_target_points > 3").contains("array_length(target_points)"));
        assert!(e("status = 'ok' and").contains("not a SQL expression"), "{}", e("status = 'ok' and"));
        assert!(e("(status = 'ok'").contains("not a SQL expression"));
        assert!(e("status = 'ok' scene").contains("not a SQL expression"));
        assert!(e("status = 'ok'; drop table pairs").contains("not a SQL expression"));
        let m = e("overlap_source + 1");
        assert!(m.contains("Float64 values, not true/false"), "{m}");
        assert!(e("scene").contains("not true/false"));
        assert!(e("count(*) > 1").contains("aggregate or window function"));
        assert!(e("unit_index in (select unit_index from pairs)").contains("subqueries need `pointreggpt query`"));
    }
}
