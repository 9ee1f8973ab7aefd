//! The registration instrument: does a dataset make registration better? Classical registration as pure
//! functions (rayon inside), the official 3DMatch metrics, and the benchmark files and protocol.
//!
//! Files: [`kdtree`] (neighbour search in 3D and feature space), [`normals`] (PCA, oriented to the
//! camera), [`fpfh`] (33-bin FPFH, multi-scale), [`matching`] (nearest / mutual nearest descriptors),
//! [`ransac`] (seeded, thread-count independent) and [`icp`] (point-to-point refinement), [`metrics`]
//! (IR, FMR, the official RR error, RRE / RTE, information matrices), [`descriptor`] (what
//! `--descriptor` selects: FPFH or a trained network, made of [`lrf`] (local reference frames), [`patch`]
//! (truncated-distance patches) and [`learned`] (the patch network or the FPFH MLP and their checkpoint)),
//! [`benchmark`] (gt.log / gt.info and layouts), [`evaluate`] (the protocol)
//! and [`report`] (tables and the paired comparison).

pub mod benchmark;
pub mod descriptor;
pub mod evaluate;
pub mod fpfh;
pub mod icp;
pub mod kdtree;
pub mod learned;
pub mod lrf;
pub mod matching;
pub mod metrics;
pub mod normals;
pub mod patch;
pub mod ransac;
pub mod report;

pub use descriptor::Descriptor;
pub use evaluate::{evaluate, EvalConfig, PairScore};
pub use kdtree::KdTree;
