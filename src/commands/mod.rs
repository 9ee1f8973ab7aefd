//! One module per subcommand; each parses nothing itself and calls library functions.

pub mod build;
pub mod demo;
pub mod inspect;
pub mod synth;
pub mod verify;
