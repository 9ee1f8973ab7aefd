//! One module per subcommand; each parses nothing itself and calls library functions.

pub mod build;
pub mod demo;
pub mod fuse;
pub mod export;
pub mod inspect;
pub mod labels;
pub mod locations;
pub mod preview;
pub mod publish;
pub mod stats;
pub mod query;
pub mod report;
pub mod synth;
pub mod verify;
pub mod train;
pub mod train_descriptor;
pub mod eval;
pub mod eval_inpaint;
pub mod eval_registration;
pub mod eval_boost;
pub mod fragments;
pub mod sequence_args;
