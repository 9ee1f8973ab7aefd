//! Training the patch descriptor (`pointreggpt train descriptor`): corresponding points of generated (or
//! real) pairs read from dataset shards ([`data`]), and the contrastive training loop ([`train`]).

pub mod data;
pub mod train;
