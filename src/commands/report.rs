//! The output of the `eval` commands that print a table and write the same rows as CSV.

use crate::error::{Error, Result};
use std::io::Write;

/// Prints the table and writes the CSV to `csv_path` (creating its folder).
pub(super) fn report(out: &mut dyn Write, table: &str, csv: &str, csv_path: &std::path::Path) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    write!(out, "{table}").map_err(w)?;
    if let Some(dir) = csv_path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    std::fs::write(csv_path, csv).map_err(|e| Error::io(csv_path, e))?;
    writeln!(out, "wrote {}", csv_path.display()).map_err(w)
}
