//! Scenes: for posed sequences, the frames around a source frame fused into one TSDF volume and ray-cast
//! at the sampled target pose, so that a target pixel is re-projected from the source, seen by the
//! scene's frames, or generated, in that order of preference (`correct.*.method = "scene"`,
//! `inpaint.method = "scene"`).
//!
//! [`config`] is the `[scene]` section (window and volume), [`window`] picks a scene's frames (and keeps
//! held-out views out of them), [`fuse`] fuses them, [`rules`] says what a scene decides about a view.
//! The build's stage is [`crate::stages::scene`]; `eval inpaint` uses the same functions.

pub mod config;
pub mod fuse;
pub mod rules;
pub mod window;

pub use config::SceneConfig;
pub use fuse::{fuse_scene, Scene};
pub use rules::{paste_scene, scene_keep_mask, Pasted};
pub use window::{block_of, window_frames, HeldOut, SceneFrames};
