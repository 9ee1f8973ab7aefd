//! Correction-network checkpoints: safetensors weights under the official state-dict keys, with the
//! configuration and training state as JSON in the header's `__metadata__` (key `pointreggpt`).
//!
//! A file without that metadata is read as the authors' layout (their `model-best.pt` converted by
//! `scripts/convert-official.py correction`): the widths are inferred from the tensor shapes. Files are
//! read and written through the `safetensors` crate; saves are atomic.

use super::correction::{CorrectionNet, CorrectionNetConfig};
use super::unet::{Preset, UnetConfig};
use crate::error::{Error, Result};
// The atomic-write helper the shards' commit protocol uses.
use crate::atomic;
use safetensors::tensor::{Dtype, Metadata, SafeTensorError, SafeTensors, TensorInfo, View};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::io::Read;
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

/// Largest header the crate accepts (its `MAX_HEADER_SIZE`).
const MAX_HEADER_BYTES: u64 = 100_000_000;

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::input(path, format!("not a valid safetensors file: {what}"))
}

/// The crate's error in words (its `Display` is the variant's name).
fn describe(e: &SafeTensorError) -> String {
    match e {
        SafeTensorError::HeaderTooSmall => "shorter than 8 bytes".into(),
        SafeTensorError::HeaderTooLarge => format!("header longer than {MAX_HEADER_BYTES} bytes"),
        SafeTensorError::InvalidHeaderLength => "the header length runs past the end of the file (truncated?)".into(),
        SafeTensorError::MetadataIncompleteBuffer => "the tensor data does not match the header (truncated?)".into(),
        SafeTensorError::InvalidHeader | SafeTensorError::InvalidHeaderStart => "the header is not a JSON object".into(),
        other => format!("{other:?}"),
    }
}

/// One tensor as the crate serialises it: f32 little-endian bytes, copied out when the crate asks for them,
/// so only the file's buffer and one tensor's bytes are in memory at a time.
struct F32View {
    /// A contiguous f32 tensor on the CPU.
    tensor: Tensor,
    shape: Vec<usize>,
}

impl F32View {
    fn new(t: &Tensor) -> Self {
        let tensor = t.detach().to_device(Device::Cpu).to_kind(Kind::Float).contiguous();
        let shape = tensor.size().iter().map(|&d| d as usize).collect();
        F32View { tensor, shape }
    }
}

impl View for F32View {
    fn dtype(&self) -> Dtype {
        Dtype::F32
    }
    fn shape(&self) -> &[usize] {
        &self.shape
    }
    fn data(&self) -> Cow<'_, [u8]> {
        let n = self.shape.iter().product::<usize>();
        let mut values = vec![0f32; n];
        self.tensor.f_copy_data(&mut values, n).expect("a contiguous CPU f32 tensor copies into a buffer of its size");
        Cow::Owned(values.iter().flat_map(|v| v.to_le_bytes()).collect())
    }
    fn data_len(&self) -> usize {
        4 * self.shape.iter().product::<usize>()
    }
}

/// Writes named tensors (as f32) as safetensors with `metadata`, through [`atomic::write_atomic`]: a temporary
/// file in the checkpoint's folder, fsynced, renamed over `path`, the folder fsynced. A crash leaves the
/// previous file whole; its stale temporary file is removed by the next save of the same file.
pub fn write_safetensors(path: &Path, tensors: &[(String, Tensor)], metadata: &BTreeMap<String, String>) -> Result<()> {
    let mut names: Vec<&str> = tensors.iter().map(|(n, _)| n.as_str()).collect();
    names.sort_unstable();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        return Err(Error::InvalidArgument(format!("{}: tensor `{}` given twice", path.display(), w[0])));
    }
    let views = tensors.iter().map(|(name, t)| (name.as_str(), F32View::new(t)));
    let info = (!metadata.is_empty()).then(|| metadata.clone().into_iter().collect::<HashMap<_, _>>());
    let bytes = safetensors::serialize(views, &info).map_err(|e| Error::Internal(format!("{}: {e}", path.display())))?;
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    atomic::write_atomic(dir, path, &bytes, atomic::Publish::Replace)?;
    let target = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    for (temp, name) in atomic::list_temps(dir).unwrap_or_default() {
        if name.is_some_and(|n| n.target == target && n.is_stale()) {
            let _ = std::fs::remove_file(temp);
        }
    }
    Ok(())
}

/// Reads and checks the header of a safetensors file without reading its tensor data: the 8-byte length
/// and the JSON header, parsed by the crate; the tensors must tile the rest of the file exactly (as the
/// crate checks when it has the whole file), so a truncated file is caught here too.
fn read_metadata(path: &Path) -> Result<Metadata> {
    let (mut f, file_len) = super::shipped::open_model(path)?;
    let mut n = [0u8; 8];
    f.read_exact(&mut n).map_err(|_| invalid(path, describe(&SafeTensorError::HeaderTooSmall)))?;
    let n = u64::from_le_bytes(n);
    if n > MAX_HEADER_BYTES || 8 + n > file_len {
        return Err(invalid(path, format!("header length {n} in a file of {file_len} bytes (truncated?)")));
    }
    let mut text = vec![0u8; n as usize];
    f.read_exact(&mut text).map_err(|e| Error::io(path, e))?;
    if text.first() != Some(&b'{') {
        return Err(invalid(path, describe(&SafeTensorError::InvalidHeaderStart)));
    }
    let meta: Metadata = serde_json::from_slice(&text).map_err(|e| invalid(path, format!("header: {e}")))?;
    let mut infos: Vec<(String, &TensorInfo)> = meta.tensors().into_iter().collect();
    infos.sort_by_key(|(_, i)| i.data_offsets);
    let mut end = 0usize;
    for (name, info) in infos {
        let bytes = info.shape.iter().try_fold(info.dtype.size(), |a, &d| a.checked_mul(d));
        let (s, e) = info.data_offsets;
        if s != end || e < s || bytes != Some(e - s) {
            return Err(invalid(path, format!("tensor `{name}`: offsets {s}..{e} do not fit its shape and the other tensors")));
        }
        end = e;
    }
    if 8 + n + end as u64 != file_len {
        return Err(invalid(path, format!("{} bytes after the header, the header declares {end} (truncated?)", file_len - 8 - n)));
    }
    Ok(meta)
}

/// The header of a safetensors file: its `__metadata__` and each tensor's shape (the data is not read).
pub fn read_header(path: &Path) -> Result<(BTreeMap<String, String>, BTreeMap<String, Vec<i64>>)> {
    let meta = read_metadata(path)?;
    let shapes = meta.tensors().into_iter().map(|(k, i)| (k, i.shape.iter().map(|&d| d as i64).collect())).collect();
    Ok((meta.metadata().clone().unwrap_or_default().into_iter().collect(), shapes))
}

/// Every tensor of a safetensors file, in the file's dtype, read through the crate.
pub fn read_tensors(path: &Path) -> Result<Vec<(String, Tensor)>> {
    let bytes = super::shipped::read_model(path)?;
    let file = SafeTensors::deserialize(&bytes).map_err(|e| invalid(path, describe(&e)))?;
    file.tensors()
        .into_iter()
        .map(|(name, view)| {
            let t = Tensor::try_from(view).map_err(|e| Error::input(path, format!("tensor `{name}`: {e}")))?;
            Ok((name, t))
        })
        .collect()
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
    let file: HashMap<String, Tensor> = read_tensors(path)?.into_iter().collect();
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
