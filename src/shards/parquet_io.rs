//! Record batches → zstd-compressed Parquet bytes, and Parquet files → record batches.
//!
//! Rows of the shard tables are big (two clouds of ~20k points and up to four PNGs: 0.5–2 MB each), so a row
//! group holds at most `row_group_rows` rows (the `output.row_group_rows` key of a build, default
//! [`ROW_GROUP_ROWS`]) or about [`ROW_GROUP_BYTES`]: a shard of a few hundred rows gives several row groups
//! that readers (DuckDB, pyarrow) decode in parallel, and a reader wanting one pair decodes one group. Dictionary encoding is
//! kept for the repetitive text columns and turned off for the bulky float and binary columns, where it
//! only costs time.

use crate::error::{Error, Result};
use arrow::array::RecordBatch;
use arrow::datatypes::{DataType, SchemaRef};
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::arrow::ArrowWriter;
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::schema::types::ColumnPath;
use std::path::Path;

/// zstd level of every column.
pub const ZSTD_LEVEL: i32 = 3;

/// Most rows in one row group unless a build's `output.row_group_rows` says otherwise (chosen by
/// measurement: benchmarks/README.md, "Row-group size").
pub const ROW_GROUP_ROWS: usize = 16;

/// Row groups are closed once their encoded size passes this (bytes).
pub const ROW_GROUP_BYTES: usize = 128 << 20;

/// Rows read per batch.
const READ_BATCH_ROWS: usize = 64;

/// The writer settings for a table of `schema`: zstd, row groups of at most `row_group_rows` rows, no
/// dictionary or statistics on float lists and binary columns.
pub fn writer_properties(schema: &SchemaRef, row_group_rows: usize) -> WriterProperties {
    let level = ZstdLevel::try_new(ZSTD_LEVEL).expect("valid zstd level");
    let mut props = WriterProperties::builder()
        .set_compression(Compression::ZSTD(level))
        .set_max_row_group_row_count(Some(row_group_rows.max(1)))
        .set_max_row_group_bytes(Some(ROW_GROUP_BYTES))
        .set_created_by(format!("{} (parquet-rs)", super::CODE_VERSION));
    for field in schema.fields() {
        if bulky(field.data_type()) {
            for path in leaf_paths(field.name(), field.data_type()) {
                props = props
                    .set_column_dictionary_enabled(path.clone(), false)
                    .set_column_statistics_enabled(path, EnabledStatistics::None);
            }
        }
    }
    props.build()
}

/// Encodes `batches` (all of the same schema) as one Parquet file in memory, in row groups of at most
/// `row_group_rows` rows.
pub fn write_parquet_bytes(schema: &SchemaRef, batches: &[RecordBatch], row_group_rows: usize) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let err = |e: parquet::errors::ParquetError| Error::Parquet(format!("writing Parquet: {e}"));
    let mut writer = ArrowWriter::try_new(&mut out, schema.clone(), Some(writer_properties(schema, row_group_rows))).map_err(err)?;
    for batch in batches {
        if batch.schema().fields() != schema.fields() {
            return Err(Error::Parquet("writing Parquet: a batch does not have the file's schema".into()));
        }
        writer.write(batch).map_err(err)?;
    }
    writer.close().map_err(err)?;
    Ok(out)
}

/// The schema and every batch of the Parquet file at `path`. A truncated or corrupt file is an
/// [`Error::InputData`] naming it.
pub fn read_parquet_file(path: &Path) -> Result<(SchemaRef, Vec<RecordBatch>)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    decode(file, path)
}

/// The schema and every batch of a Parquet file held in memory (read from `location`, which errors name).
pub fn read_parquet_bytes(bytes: bytes::Bytes, location: &Path) -> Result<(SchemaRef, Vec<RecordBatch>)> {
    decode(bytes, location)
}

fn decode<R: parquet::file::reader::ChunkReader + 'static>(reader: R, path: &Path) -> Result<(SchemaRef, Vec<RecordBatch>)> {
    let bad = |e: &dyn std::fmt::Display| Error::input(path, format!("not a readable Parquet file: {e}"));
    let builder = ParquetRecordBatchReaderBuilder::try_new(reader).map_err(|e| bad(&e))?;
    let schema = builder.schema().clone();
    let reader = builder.with_batch_size(READ_BATCH_ROWS).build().map_err(|e| bad(&e))?;
    let batches = reader.collect::<std::result::Result<Vec<_>, _>>().map_err(|e| bad(&e))?;
    Ok((schema, batches))
}

/// Float lists and binaries: the columns where dictionaries and min/max statistics are useless.
fn bulky(data_type: &DataType) -> bool {
    match data_type {
        DataType::Binary | DataType::LargeBinary => true,
        DataType::List(f) | DataType::LargeList(f) | DataType::FixedSizeList(f, _) => {
            matches!(f.data_type(), DataType::Float32 | DataType::Float64) || bulky(f.data_type())
        }
        _ => false,
    }
}

/// The Parquet leaf column paths of an Arrow field (lists nest as `<name>.list.<item>`).
fn leaf_paths(name: &str, data_type: &DataType) -> Vec<ColumnPath> {
    fn walk(prefix: Vec<String>, data_type: &DataType, out: &mut Vec<ColumnPath>) {
        match data_type {
            DataType::List(f) | DataType::LargeList(f) | DataType::FixedSizeList(f, _) => {
                let mut p = prefix;
                p.extend(["list".to_string(), f.name().clone()]);
                walk(p, f.data_type(), out)
            }
            DataType::Struct(fields) => {
                for f in fields {
                    let mut p = prefix.clone();
                    p.push(f.name().clone());
                    walk(p, f.data_type(), out)
                }
            }
            _ => out.push(ColumnPath::new(prefix)),
        }
    }
    let mut out = Vec::new();
    walk(vec![name.to_string()], data_type, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shards::pairs::tests::sample_row;
    use crate::shards::{batch_to_pairs, pairs_schema, pairs_to_batch, SCHEMA_VERSION, SCHEMA_VERSION_KEY};
    use parquet::file::reader::{FileReader, SerializedFileReader};

    fn write_sample(dir: &Path, n: u64) -> (std::path::PathBuf, Vec<crate::shards::PairRow>) {
        let rows: Vec<_> = (0..n).map(sample_row).collect();
        let bytes = write_parquet_bytes(&pairs_schema(), &[pairs_to_batch(&rows).unwrap()], ROW_GROUP_ROWS).unwrap();
        let path = dir.join("s.parquet");
        std::fs::write(&path, bytes).unwrap();
        (path, rows)
    }

    #[test]
    fn parquet_round_trip_is_exact_and_keeps_the_schema() {
        let dir = tempfile::tempdir().unwrap();
        let (path, rows) = write_sample(dir.path(), 12);
        let (schema, batches) = read_parquet_file(&path).unwrap();
        assert_eq!(schema.fields(), pairs_schema().fields());
        assert_eq!(schema.metadata().get(SCHEMA_VERSION_KEY).map(String::as_str), Some(SCHEMA_VERSION));
        let back: Vec<_> = batches.iter().flat_map(|b| batch_to_pairs(b).unwrap()).collect();
        assert_eq!(back, rows);
        let digests = |r: &[crate::shards::PairRow]| r.iter().map(|p| p.content_digest()).collect::<Vec<_>>();
        assert_eq!(digests(&back), digests(&rows));
    }

    #[test]
    fn every_column_chunk_is_zstd_and_row_groups_are_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = write_sample(dir.path(), 150);
        let reader = SerializedFileReader::new(std::fs::File::open(&path).unwrap()).unwrap();
        let meta = reader.metadata();
        assert_eq!(meta.file_metadata().num_rows(), 150);
        assert_eq!(meta.num_row_groups(), 150usize.div_ceil(ROW_GROUP_ROWS), "150 rows in groups of at most {ROW_GROUP_ROWS}");
        for rg in meta.row_groups() {
            assert!(rg.num_rows() as usize <= ROW_GROUP_ROWS);
            // 32 columns, clouds and provenance lists give one leaf each, timings two.
            assert_eq!(rg.num_columns(), 33);
            for col in rg.columns() {
                assert!(
                    matches!(col.compression(), Compression::ZSTD(_)),
                    "{} is {:?}",
                    col.column_path(),
                    col.compression()
                );
            }
        }
    }

    #[test]
    fn bulky_columns_have_no_dictionary() {
        let paths: Vec<String> =
            leaf_paths("source_points", &crate::shards::schema::cloud_type()).iter().map(|p| p.string()).collect();
        assert_eq!(paths, ["source_points.list.item.list.item"]);
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = write_sample(dir.path(), 8);
        let reader = SerializedFileReader::new(std::fs::File::open(&path).unwrap()).unwrap();
        for col in reader.metadata().row_group(0).columns() {
            let name = col.column_path().string();
            let dictionary = col.dictionary_page_offset().is_some();
            let expect = !(name.contains("points")
                || name.contains("known_share")
                || name.contains("scene_share")
                || name.contains("png")
                || name.contains("intrinsics")
                || name.starts_with("t_target"));
            assert_eq!(dictionary, expect, "dictionary on {name}");
        }
    }

    #[test]
    fn truncated_and_garbage_files_are_input_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = write_sample(dir.path(), 4);
        let bytes = std::fs::read(&path).unwrap();
        for (name, content) in [("cut.parquet", &bytes[..bytes.len() / 2]), ("junk.parquet", &b"hello world"[..])] {
            let p = dir.path().join(name);
            std::fs::write(&p, content).unwrap();
            let err = read_parquet_file(&p).unwrap_err();
            assert!(matches!(err, Error::InputData { .. }), "{err:?}");
            assert!(err.to_string().contains(name), "{err}");
        }
        let missing = read_parquet_file(&dir.path().join("none.parquet")).unwrap_err();
        assert!(matches!(missing, Error::Io { .. }));
    }

    #[test]
    fn writing_a_batch_of_another_schema_fails() {
        let batch = pairs_to_batch(&[sample_row(0)]).unwrap();
        let other = batch.project(&[0, 1]).unwrap();
        assert!(write_parquet_bytes(&pairs_schema(), &[other], ROW_GROUP_ROWS).is_err());
    }
}
