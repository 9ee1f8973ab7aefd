//! Training the patch descriptor (`pointreggpt train descriptor`): corresponding points of generated (or
//! real) pairs read from dataset shards ([`data`]), the augmentation and known-point rules ([`augment`]),
//! and the contrastive training loop ([`train`]).

pub mod augment;
pub mod data;
pub mod train;
