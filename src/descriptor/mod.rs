//! A learned local descriptor for registration (3DMatch-style, issue 16's patch network): each keypoint's
//! neighbourhood is expressed in a local reference frame ([`lrf`]), voxelised as a truncated distance
//! field on a small cube ([`patch`]) and encoded by a 3D ConvNet ([`crate::nn::patch_net`]) into a unit
//! vector; [`learned`] loads a trained network and describes keypoints of a cloud.

pub mod learned;
pub mod lrf;
pub mod patch;

pub use learned::LearnedDescriptor;
pub use patch::PatchConfig;
