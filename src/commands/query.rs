//! `pointreggpt query`: SQL over a dataset's committed shards (tables `pairs`, `labels`, `manifest`).

use crate::error::{Error, Result};
use crate::query::{run_query, write_batches, OutputFormat};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(after_help = "Binary values are lowercase hex in the table, csv and json formats.\n\n\
Examples:\n  \
pointreggpt query out/demo \"select status, count(*) n from pairs group by status\"\n  \
pointreggpt query out/demo \"select floor(overlap_source*10)/10 bin, count(*) from pairs where status='ok' group by bin order by bin\"\n  \
pointreggpt query out/demo \"select scene, count(*) pairs, avg(array_length(source_points)) pts from pairs group by scene\" --format csv\n  \
pointreggpt query out/demo \"select shard, rows, bytes from manifest order by shard\"")]
pub struct QueryArgs {
    /// The dataset: a folder, or an object-store URL (s3://bucket/prefix, gs://bucket/prefix, az://container/prefix).
    #[arg(value_parser = crate::commands::locations::dataset)]
    pub dataset: PathBuf,
    /// The SQL statement. Tables: pairs, labels, manifest (committed shards only).
    pub sql: String,
    /// Output format. NaN and ±inf: null in json; NaN, inf, -inf in csv and table (details in --help).
    #[arg(long, value_enum, default_value = "table")]
    pub format: OutputFormat,
    /// Write to this file instead of standard output (required for parquet).
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub output: Option<PathBuf>,
}

pub fn run(args: &QueryArgs, out: &mut dyn Write) -> Result<()> {
    let batches = run_query(&args.dataset, &args.sql)?;
    match &args.output {
        Some(path) => {
            let mut buf = Vec::new();
            write_batches(&batches, args.format, &mut buf)?;
            std::fs::write(path, buf).map_err(|e| Error::io(path, e))
        }
        None if args.format == OutputFormat::Parquet => Err(Error::config("--output", "parquet output needs a file (--output results.parquet)")),
        None => write_batches(&batches, args.format, out),
    }
}
