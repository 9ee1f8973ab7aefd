//! Registration benchmarks on disk: the official 3DMatch files ([`gtlog`]: `gt.log`, `gt.info`,
//! `gt_overlap.log`), the folder layouts that hold them ([`layout`]), and making them from a sequence ([`make`]).

pub mod gtlog;
pub mod layout;
pub mod make;

pub use gtlog::{read_gt_info, read_gt_log, read_gt_overlap, write_gt_info, write_gt_log, write_gt_overlap, GtPair};
pub use layout::{find_benchmarks, BenchPair, Benchmark};
