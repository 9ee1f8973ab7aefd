//! The denoiser's training side: depth frames in network space ([`data`]), the holes a re-projection
//! leaves for hole-aware fine-tuning ([`holes`]), the optimiser and EMA ([`optim`]), the training loop
//! ([`train`]) and sample previews ([`preview`]).

pub mod data;
pub mod holes;
pub mod optim;
pub mod preview;
pub mod train;
