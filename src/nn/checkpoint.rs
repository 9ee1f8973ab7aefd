//! Correction-network checkpoints: safetensors weights under the official state-dict keys, with the
//! configuration and training state as JSON in the header's `__metadata__` (key `pointreggpt`).
//!
//! A file without that metadata is read as the authors' layout (a converted `model-best.pt`, see
//! `docs/correction.md`): the widths are inferred from the tensor shapes.

use super::correction::{CorrectionNet, CorrectionNetConfig};
use super::unet::{Preset, UnetConfig};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::path::Path;
use tch::{nn, Device, Kind, Tensor};

/// Format tag stored in the metadata.
pub const FORMAT: &str = "pointreggpt.correction/1";
/// The `__metadata__` key holding [`CheckpointMeta`] as JSON.
pub const META_KEY: &str = "pointreggpt";

/// What a checkpoint says about itself besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMeta {
    pub format: String,
    pub net: CorrectionNetConfig,
    /// Completed training epochs.
    pub epoch: u32,
    /// Name and value of the validation metric the best checkpoint is chosen by (None: not validated).
    pub best_metric_name: String,
    pub best_metric: Option<f64>,
    /// Learning rate of the next epoch (resume continues the exponential decay from it).
    pub next_lr: f64,
    /// Free-form provenance: training options, data sets, last validation metrics.
    #[serde(default)]
    pub info: serde_json::Value,
}

impl CheckpointMeta {
    /// Metadata of an untrained or externally trained network.
    pub fn untrained(net: &CorrectionNetConfig) -> Self {
        CheckpointMeta {
            format: FORMAT.into(),
            net: net.clone(),
            epoch: 0,
            best_metric_name: String::new(),
            best_metric: None,
            next_lr: 0.0,
            info: serde_json::Value::Null,
        }
    }
}

fn torch(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Torch(format!("{}: {e}", path.display()))
}

/// Writes named f32 tensors as safetensors with `metadata` (atomically: temporary file, then rename).
pub fn write_safetensors(path: &Path, tensors: &[(String, Tensor)], metadata: &BTreeMap<String, String>) -> Result<()> {
    let mut header = serde_json::Map::new();
    if !metadata.is_empty() {
        header.insert("__metadata__".into(), serde_json::to_value(metadata).expect("strings"));
    }
    let mut sorted: Vec<&(String, Tensor)> = tensors.iter().collect();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    let mut data = Vec::new();
    for (name, t) in sorted {
        let t = t.detach().to_device(Device::Cpu).to_kind(Kind::Float).contiguous();
        let values: Vec<f32> = Vec::try_from(t.flatten(0, -1)).map_err(|e| torch(path, e))?;
        let start = data.len();
        data.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        header.insert(
            name.clone(),
            serde_json::json!({"dtype": "F32", "shape": t.size(), "data_offsets": [start, data.len()]}),
        );
    }
    let mut text = serde_json::to_string(&serde_json::Value::Object(header)).expect("json");
    while text.len() % 8 != 0 {
        text.push(' ');
    }
    let tmp = path.with_extension("safetensors.tmp");
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let mut f = std::fs::File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
    f.write_all(&(text.len() as u64).to_le_bytes())
        .and_then(|_| f.write_all(text.as_bytes()))
        .and_then(|_| f.write_all(&data))
        .and_then(|_| f.sync_all())
        .map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// The header of a safetensors file: its `__metadata__` and each tensor's shape.
pub fn read_header(path: &Path) -> Result<(BTreeMap<String, String>, BTreeMap<String, Vec<i64>>)> {
    let bad = |m: String| Error::input(path, m);
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut n = [0u8; 8];
    f.read_exact(&mut n).map_err(|_| bad("not a safetensors file (shorter than 8 bytes)".into()))?;
    let n = u64::from_le_bytes(n);
    if n > 100_000_000 {
        return Err(bad(format!("not a safetensors file (header length {n})")));
    }
    let mut text = vec![0u8; n as usize];
    f.read_exact(&mut text).map_err(|_| bad("truncated safetensors header".into()))?;
    let header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&text).map_err(|e| bad(format!("safetensors header is not JSON: {e}")))?;
    let mut meta = BTreeMap::new();
    let mut shapes = BTreeMap::new();
    for (k, v) in header {
        if k == "__metadata__" {
            meta = serde_json::from_value(v).map_err(|e| bad(format!("bad __metadata__: {e}")))?;
        } else {
            let shape = v
                .get("shape")
                .and_then(|s| serde_json::from_value::<Vec<i64>>(s.clone()).ok())
                .ok_or_else(|| bad(format!("tensor `{k}` has no shape")))?;
            shapes.insert(k, shape);
        }
    }
    Ok((meta, shapes))
}

/// Saves the network's variables with `meta` in the header.
pub fn save_correction(path: &Path, vs: &nn::VarStore, meta: &CheckpointMeta) -> Result<()> {
    let tensors: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    let metadata = BTreeMap::from([(META_KEY.to_string(), serde_json::to_string(meta).expect("json"))]);
    write_safetensors(path, &tensors, &metadata)
}

/// Saves the variables exactly as the authors' converted `model-best.pt` would look: official keys,
/// no metadata.
pub fn save_official_layout(path: &Path, vs: &nn::VarStore) -> Result<()> {
    let tensors: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
    write_safetensors(path, &tensors, &BTreeMap::new())
}

/// Reads the metadata of a checkpoint, or infers the configuration of an official-layout file.
pub fn read_meta(path: &Path) -> Result<CheckpointMeta> {
    let (meta, shapes) = read_header(path)?;
    match meta.get(META_KEY) {
        Some(json) => {
            let m: CheckpointMeta =
                serde_json::from_str(json).map_err(|e| Error::input(path, format!("bad checkpoint metadata: {e}")))?;
            if m.format != FORMAT {
                return Err(Error::input(path, format!("checkpoint format `{}`, expected `{FORMAT}`", m.format)));
            }
            Ok(m)
        }
        None => Ok(CheckpointMeta::untrained(&infer_official_config(path, &shapes)?)),
    }
}

/// The configuration of an official `MaskUnet` state dict, from its tensor shapes (GroupNorm groups
/// cannot be seen in the shapes: the official 8).
pub fn infer_official_config(path: &Path, shapes: &BTreeMap<String, Vec<i64>>) -> Result<CorrectionNetConfig> {
    let bad = |m: &str| Error::input(path, format!("not a correction checkpoint of the official layout: {m}"));
    let init =
        shapes.get("init_conv.weight").filter(|s| s.len() == 4).ok_or_else(|| bad("no 4-D `init_conv.weight`"))?;
    let (dim, in_channels) = (init[0], init[1]);
    let mut dim_mults = Vec::new();
    while let Some(s) = shapes.get(&format!("downs.{}.3.weight", dim_mults.len())) {
        if s[0] % dim != 0 {
            return Err(bad("level widths are not multiples of dim"));
        }
        dim_mults.push(s[0] / dim);
    }
    if dim_mults.is_empty() {
        return Err(bad("no `downs.0.3.weight`"));
    }
    if shapes.keys().any(|k| k.contains(".mlp.")) {
        return Err(bad("its ResnetBlocks are conditioned (a diffusion U-Net?)"));
    }
    let out = shapes.get("final_conv.0.weight").ok_or_else(|| bad("no `final_conv.0.weight`"))?;
    // Heads cannot be seen in the shapes either: the official 4, with the width per head from `to_qkv`.
    let hidden = shapes.get("downs.0.2.fn.fn.to_qkv.weight").map_or(3 * 4 * 32, |s| s[0]) / 3;
    let unet = UnetConfig {
        dim,
        dim_mults,
        in_channels,
        out_channels: out[0],
        resnet_groups: 8,
        cond_dim: None,
        attention: shapes.contains_key("downs.0.2.fn.norm.g"),
        attn_heads: 4,
        attn_dim_head: hidden / 4,
        final_conv_in_sequential: true,
    };
    let augment = in_channels == 3;
    let preset = [Preset::Paper, Preset::Tiny].into_iter().find(|p| p.correction_unet(augment) == unet);
    Ok(CorrectionNetConfig { preset, augment, unet })
}

/// Copies the tensors of `path` into `vs`; every variable must be present with its shape and the file
/// may hold no other tensor.
pub fn load_weights(path: &Path, vs: &mut nn::VarStore) -> Result<()> {
    let file: HashMap<String, Tensor> =
        Tensor::read_safetensors(path).map_err(|e| torch(path, e))?.into_iter().collect();
    let mut vars = vs.variables();
    let mut extra: Vec<&String> = file.keys().filter(|k| !vars.contains_key(*k)).collect();
    extra.sort();
    if !extra.is_empty() {
        return Err(Error::input(
            path,
            format!("{} tensors the network does not have, first `{}`", extra.len(), extra[0]),
        ));
    }
    tch::no_grad(|| {
        for (name, var) in vars.iter_mut() {
            let src = file.get(name).ok_or_else(|| Error::input(path, format!("tensor `{name}` is missing")))?;
            if src.size() != var.size() {
                return Err(Error::input(
                    path,
                    format!("tensor `{name}` has shape {:?}, the network {:?}", src.size(), var.size()),
                ));
            }
            var.copy_(&src.to_kind(var.kind()));
        }
        Ok(())
    })
}

/// Loads a checkpoint (ours, or the official layout) onto `device`.
pub fn load_correction(path: &Path, device: Device) -> Result<(nn::VarStore, CorrectionNet, CheckpointMeta)> {
    let meta = read_meta(path)?;
    let mut vs = nn::VarStore::new(Device::Cpu);
    let net = CorrectionNet::new(&vs.root(), &meta.net)?;
    load_weights(path, &mut vs)?;
    if device != Device::Cpu {
        vs.set_device(device);
    }
    Ok((vs, net, meta))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trip_and_corrupt_files_name_the_problem() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.safetensors");
        let t = Tensor::from_slice(&[1.5f32, -2.0, 3.25, 0.0, 7.0, 8.0]).view([2, 3]);
        write_safetensors(&p, &[("a.b".into(), t.shallow_clone())], &BTreeMap::from([("k".into(), "v".into())]))
            .unwrap();
        let (meta, shapes) = read_header(&p).unwrap();
        assert_eq!(meta.get("k").map(String::as_str), Some("v"));
        assert_eq!(shapes.get("a.b"), Some(&vec![2, 3]));
        // tch's own reader accepts the file.
        let back = Tensor::read_safetensors(&p).unwrap();
        assert_eq!(back[0].0, "a.b");
        assert!(back[0].1.equal(&t));
        std::fs::write(&p, b"abc").unwrap();
        assert!(read_meta(&p).unwrap_err().to_string().contains("not a safetensors file"));
    }
}
