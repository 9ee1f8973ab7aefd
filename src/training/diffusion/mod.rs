//! The denoiser's training side: depth frames in network space ([`data`]), the holes a re-projection
//! leaves for hole-aware fine-tuning ([`holes`]), the training loop
//! ([`train`]; its optimiser and EMA are [`crate::training::optim`]) and sample previews ([`preview`]).

pub mod data;
pub mod holes;
pub mod preview;
pub mod train;
