//! The correction U-Net's training side: label shards as tensors ([`data`]), mask metrics ([`metrics`]),
//! the training loop ([`train`]) and the comparison with the handcrafted filters ([`evaluate`]).

pub mod data;
pub mod evaluate;
pub mod metrics;
pub mod train;
