//! `pointreggpt eval boost`: does a training set make a learned descriptor register better? Each
//! training condition (raw FPFH, real pairs, generated pairs of several pipelines, real + generated)
//! trains the patch descriptor with several seeds and is scored on the same benchmark with the same
//! RANSAC seeds; one table with the spread over seeds and paired IR differences with 95 % intervals.
//!
//! Files: [`conditions`] (the condition grammar, the C0–C6 aliases, the generators), [`config`] (what a run
//! needs), [`histogram`] (real
//! pairs subsampled to a generated overlap histogram), [`data`] (the real single-frame, real fragment and
//! generated training pairs), [`draw`] (the pools and the draws units train on, paired unit by unit), [`scores_file`]
//! (one unit's scores, written atomically), [`settings`] (the recorded training settings a rerun must
//! match), [`table`] (the summary) and [`run`] (the resumable protocol).

pub mod conditions;
pub mod config;
pub mod data;
pub mod draw;
pub mod histogram;
pub mod run;
pub mod scores_file;
pub mod settings;
pub mod table;

pub use conditions::Condition;
pub use run::{run_boost, BoostConfig};
