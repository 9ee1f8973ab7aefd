//! Writing query results: an aligned table, CSV, JSON lines or Parquet.

use crate::error::{Error, Result};
use datafusion::arrow::array::{Array, RecordBatch};
use datafusion::arrow::datatypes::DataType;
use datafusion::arrow::util::display::{ArrayFormatter, FormatOptions};
use std::io::Write;

/// Output formats of `pointreggpt query`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OutputFormat {
    /// An aligned text table.
    Table,
    /// Comma-separated values with a header line.
    Csv,
    /// One JSON object per row.
    Json,
    /// A Parquet file (zstd); needs --output.
    Parquet,
}

/// Writes `batches` to `out` in `format` (Parquet is binary: write it to a file).
pub fn write_batches(batches: &[RecordBatch], format: OutputFormat, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<output>", e);
    let Some(first) = batches.first() else {
        if format == OutputFormat::Table {
            writeln!(out, "(no rows)").map_err(w)?;
        }
        return Ok(());
    };
    let schema = first.schema();
    let names: Vec<String> = schema.fields().iter().map(|f| f.name().clone()).collect();
    match format {
        OutputFormat::Parquet => {
            let bytes = crate::shards::write_parquet_bytes(&schema, batches)?;
            out.write_all(&bytes).map_err(w)
        }
        OutputFormat::Table => {
            let rows = cells(batches)?;
            let mut widths: Vec<usize> = names.iter().map(|n| n.chars().count()).collect();
            for r in &rows {
                for (i, c) in r.iter().enumerate() {
                    widths[i] = widths[i].max(c.chars().count().min(60));
                }
            }
            let line = |cells: &[String]| -> String {
                cells.iter().zip(&widths).map(|(c, w)| format!("{:<w$}", truncate(c, 60), w = *w)).collect::<Vec<_>>().join(" | ")
            };
            writeln!(out, "{}", line(&names)).map_err(w)?;
            writeln!(out, "{}", widths.iter().map(|w| "-".repeat(*w)).collect::<Vec<_>>().join("-+-")).map_err(w)?;
            for r in &rows {
                writeln!(out, "{}", line(r)).map_err(w)?;
            }
            writeln!(out, "({} rows)", rows.len()).map_err(w)
        }
        OutputFormat::Csv => {
            writeln!(out, "{}", names.iter().map(|n| csv_quote(n)).collect::<Vec<_>>().join(",")).map_err(w)?;
            for r in cells(batches)? {
                writeln!(out, "{}", r.iter().map(|c| csv_quote(c)).collect::<Vec<_>>().join(",")).map_err(w)?;
            }
            Ok(())
        }
        OutputFormat::Json => {
            for batch in batches {
                let fmts = formatters(batch)?;
                for i in 0..batch.num_rows() {
                    let fields: Vec<String> = (0..batch.num_columns())
                        .map(|c| {
                            let col = batch.column(c);
                            let value = if col.is_null(i) {
                                "null".to_string()
                            } else if is_number(col.data_type()) {
                                fmts[c].value(i).to_string()
                            } else {
                                serde_json::Value::String(fmts[c].value(i).to_string()).to_string()
                            };
                            format!("{}:{}", serde_json::Value::String(names[c].clone()), value)
                        })
                        .collect();
                    writeln!(out, "{{{}}}", fields.join(",")).map_err(w)?;
                }
            }
            Ok(())
        }
    }
}

fn formatters(batch: &RecordBatch) -> Result<Vec<ArrayFormatter<'_>>> {
    let options = FormatOptions::default().with_null("");
    batch
        .columns()
        .iter()
        .map(|c| ArrayFormatter::try_new(c.as_ref(), &options).map_err(|e| Error::Parquet(e.to_string())))
        .collect()
}

fn cells(batches: &[RecordBatch]) -> Result<Vec<Vec<String>>> {
    let mut rows = Vec::new();
    for batch in batches {
        let fmts = formatters(batch)?;
        for i in 0..batch.num_rows() {
            rows.push(fmts.iter().map(|f| f.value(i).to_string()).collect());
        }
    }
    Ok(rows)
}

fn is_number(t: &DataType) -> bool {
    t.is_integer() || t.is_floating() || t.is_numeric()
}

fn csv_quote(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(n - 1).collect::<String>())
    }
}
