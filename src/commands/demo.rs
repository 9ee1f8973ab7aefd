//! `pointreggpt demo` (being written).
use crate::error::Result;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
}

pub fn run(_args: &DemoArgs, _out: &mut dyn Write) -> Result<()> {
    Ok(())
}
