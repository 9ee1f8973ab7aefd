//! Writing query results with arrow's own writers: a table (arrow's pretty printer), CSV, JSON lines or
//! Parquet.
//!
//! Non-finite floats: JSON writes NaN, +inf and -inf as `null` (strict JSON has no such numbers); CSV
//! writes `NaN`, `inf`, `-inf` and an empty field for null; the table shows `NaN`, `inf`, `-inf` and
//! `NULL`. Binary values are lowercase hex in every text format. A list or struct is JSON in `--format
//! json`, and the same JSON text in one quoted CSV field.

use crate::error::{Error, Result};
use datafusion::arrow::array::{Array, ArrayRef, RecordBatch, StringBuilder};
use datafusion::arrow::csv::WriterBuilder as CsvWriterBuilder;
use datafusion::arrow::datatypes::{DataType, Field, FieldRef, Schema};
use datafusion::arrow::error::ArrowError;
use datafusion::arrow::json::writer::{make_encoder, EncoderOptions, LineDelimited};
use datafusion::arrow::json::WriterBuilder as JsonWriterBuilder;
use datafusion::arrow::util::display::{
    ArrayFormatter, ArrayFormatterFactory, DisplayIndex, FormatError, FormatOptions, FormatResult,
};
use datafusion::arrow::util::pretty::pretty_format_batches_with_options;
use std::fmt;
use std::io::Write;
use std::sync::Arc;

/// Output formats of `pointreggpt query`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OutputFormat {
    /// A boxed text table and the row count; cells cut to 60 characters ("…"); shows NaN, inf, -inf, NULL.
    Table,
    /// A header line, one line per row; NaN, inf, -inf written as such (DuckDB reads them back), null as an
    /// empty field; a list as its JSON text.
    Csv,
    /// JSON lines: one object per row with every column; NaN, inf and -inf written as null (strict JSON).
    Json,
    /// A Parquet file (zstd) with the exact values, NaN and inf included; needs --output.
    Parquet,
}

/// The widest cell of the table format, in characters; a longer value (a whole point cloud) is cut
/// and ends in "…". CSV, JSON and Parquet are never cut.
pub const MAX_TABLE_CELL_CHARS: usize = 60;

/// Writes `batches` to `out` in `format` (Parquet is binary: write it to a file).
pub fn write_batches(batches: &[RecordBatch], format: OutputFormat, out: &mut dyn Write) -> Result<()> {
    let arrow_err = |e: ArrowError| Error::Parquet(format!("writing {format:?} output: {e}"));
    match format {
        OutputFormat::Parquet => {
            let Some(first) = batches.first() else { return Ok(()) };
            let bytes = crate::shards::write_parquet_bytes(&first.schema(), batches, crate::shards::ROW_GROUP_ROWS)?;
            out.write_all(&bytes).map_err(|e| Error::io("<output>", e))
        }
        OutputFormat::Table => write_table(batches, out),
        OutputFormat::Csv => {
            let mut writer = CsvWriterBuilder::new().with_header(true).build(out);
            for batch in batches {
                writer.write(&nested_as_json_text(batch)?).map_err(arrow_err)?;
            }
            Ok(())
        }
        OutputFormat::Json => {
            let mut writer = JsonWriterBuilder::new().with_explicit_nulls(true).build::<_, LineDelimited>(out);
            for batch in batches {
                writer.write(batch).map_err(arrow_err)?;
            }
            writer.finish().map_err(arrow_err)
        }
    }
}

/// The table format: arrow's pretty printer with every cell cut to [`MAX_TABLE_CELL_CHARS`], then the
/// row count.
fn write_table(batches: &[RecordBatch], out: &mut dyn Write) -> Result<()> {
    let io = |e: std::io::Error| Error::io("<output>", e);
    let rows: usize = batches.iter().map(RecordBatch::num_rows).sum();
    if !batches.is_empty() {
        let cut = CutCells(MAX_TABLE_CELL_CHARS);
        let options =
            FormatOptions::default().with_display_error(true).with_null("NULL").with_formatter_factory(Some(&cut));
        let table = pretty_format_batches_with_options(batches, &options)
            .map_err(|e| Error::Parquet(format!("writing table output: {e}")))?;
        writeln!(out, "{table}").map_err(io)?;
    }
    writeln!(out, "({rows} row{})", if rows == 1 { "" } else { "s" }).map_err(io)
}

/// `batch` with every nested column (list, struct, map) replaced by a string column holding each
/// value's JSON text, written by arrow's JSON encoder (so NaN and ±inf inside a list are null there).
/// Arrow's CSV writer refuses nested columns.
fn nested_as_json_text(batch: &RecordBatch) -> Result<RecordBatch> {
    let schema = batch.schema();
    if !schema.fields().iter().any(|f| f.data_type().is_nested()) {
        return Ok(batch.clone());
    }
    let err = |e: ArrowError| Error::Parquet(format!("writing Csv output: {e}"));
    let options = EncoderOptions::default().with_explicit_nulls(true);
    let mut fields: Vec<FieldRef> = Vec::with_capacity(schema.fields().len());
    let mut columns: Vec<ArrayRef> = Vec::with_capacity(schema.fields().len());
    for (field, column) in schema.fields().iter().zip(batch.columns()) {
        if !field.data_type().is_nested() {
            fields.push(field.clone());
            columns.push(column.clone());
            continue;
        }
        let mut encoder = make_encoder(field, column.as_ref(), &options).map_err(err)?;
        let mut text = StringBuilder::new();
        let mut buf = Vec::new();
        for row in 0..column.len() {
            if column.is_null(row) {
                text.append_null();
                continue;
            }
            buf.clear();
            encoder.encode(row, &mut buf);
            text.append_value(String::from_utf8_lossy(&buf));
        }
        fields.push(Arc::new(Field::new(field.name(), DataType::Utf8, true)));
        columns.push(Arc::new(text.finish()));
    }
    RecordBatch::try_new(Arc::new(Schema::new(fields)), columns).map_err(err)
}

/// Makes table formatters that cut each top-level cell to `.0` characters.
#[derive(Debug)]
struct CutCells(usize);

impl ArrayFormatterFactory for CutCells {
    fn create_array_formatter<'a>(
        &self,
        array: &'a dyn Array,
        options: &FormatOptions<'a>,
        _field: Option<&'a Field>,
    ) -> std::result::Result<Option<ArrayFormatter<'a>>, ArrowError> {
        // The inner formatter has no factory, so the elements of a list are not cut one by one.
        let plain = options.clone().with_formatter_factory(None);
        let inner = ArrayFormatter::try_new(array, &plain)?;
        Ok(Some(ArrayFormatter::new(Box::new(CutCell { inner, max_chars: self.0 }), options.safe())))
    }
}

/// One column's default formatter, cut to `max_chars` characters (the last one "…" when cut).
struct CutCell<'a> {
    inner: ArrayFormatter<'a>,
    max_chars: usize,
}

impl DisplayIndex for CutCell<'_> {
    fn write(&self, idx: usize, f: &mut dyn fmt::Write) -> FormatResult {
        let mut text = Capped { text: String::new(), room: self.max_chars, cut: false };
        // Formatting stops with an error as soon as the cap is passed: a point cloud is not rendered whole.
        match self.inner.value(idx).write(&mut text) {
            Ok(()) => {}
            Err(_) if text.cut => {
                text.text.pop();
                text.text.push('…');
            }
            Err(e) => return Err(FormatError::Arrow(e)),
        }
        f.write_str(&text.text)?;
        Ok(())
    }
}

/// A string that takes at most `room` more characters, then fails and records that it was cut.
struct Capped {
    text: String,
    room: usize,
    cut: bool,
}

impl fmt::Write for Capped {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for c in s.chars() {
            if self.room == 0 {
                self.cut = true;
                return Err(fmt::Error);
            }
            self.text.push(c);
            self.room -= 1;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use datafusion::arrow::array::{BinaryArray, Float64Array};

    fn text(batch: &RecordBatch, format: OutputFormat) -> String {
        let mut out = Vec::new();
        write_batches(std::slice::from_ref(batch), format, &mut out).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn non_finite_floats_and_binary_in_each_format() {
        let x: ArrayRef = Arc::new(Float64Array::from(vec![
            Some(f64::NAN),
            Some(f64::INFINITY),
            Some(f64::NEG_INFINITY),
            None,
            Some(1.5),
        ]));
        let b: ArrayRef =
            Arc::new(BinaryArray::from(vec![Some(&b"\x00\xff"[..]), None, Some(b"a"), Some(b"pq"), Some(b"z")]));
        let batch = RecordBatch::try_from_iter([("x", x), ("b", b)]).unwrap();
        assert_eq!(text(&batch, OutputFormat::Csv), "x,b\nNaN,00ff\ninf,\n-inf,61\n,7071\n1.5,7a\n");
        let json = text(&batch, OutputFormat::Json);
        let rows: Vec<&str> = json.lines().collect();
        assert_eq!(
            rows,
            [
                r#"{"x":null,"b":"00ff"}"#,
                r#"{"x":null,"b":null}"#,
                r#"{"x":null,"b":"61"}"#,
                r#"{"x":null,"b":"7071"}"#,
                r#"{"x":1.5,"b":"7a"}"#
            ]
        );
        let table = text(&batch, OutputFormat::Table);
        assert!(
            table.contains("| NaN  | 00ff |") && table.contains("| -inf | 61   |") && table.contains("| NULL |"),
            "{table}"
        );
        assert!(table.ends_with("(5 rows)\n"), "{table}");
    }

    #[test]
    fn table_cells_are_cut_and_other_formats_are_not() {
        let long = "y".repeat(500);
        let s: ArrayRef = Arc::new(datafusion::arrow::array::StringArray::from(vec![long.as_str(), "short"]));
        let batch = RecordBatch::try_from_iter([("s", s)]).unwrap();
        let table = text(&batch, OutputFormat::Table);
        let cut = format!("{}…", "y".repeat(MAX_TABLE_CELL_CHARS - 1));
        assert!(table.contains(&format!("| {cut} |")) && !table.contains(&"y".repeat(MAX_TABLE_CELL_CHARS)), "{table}");
        assert!(text(&batch, OutputFormat::Csv).contains(&long));
    }
}
