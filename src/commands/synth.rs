//! `pointreggpt synth` (being written).
use crate::error::Result;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(_args: &SynthArgs, _out: &mut dyn Write) -> Result<()> {
    Ok(())
}
