//! The ALIKED backbone and score head as one ONNX graph with dynamic height and width
//! (multiples of [`DIVISOR`]).
//!
//! Input `image` `[1, 1, H, W]`: the grey image in [0, 1] after resizing and replicate padding.
//! The reference feeds the grey image repeated to RGB; since the three channels are equal,
//! `block1.conv1` is applied with its weights summed over the input channels (same result,
//! a third of the work). The deformable convolutions of blocks 3 and 4 use ONNX `DeformConv`
//! (opset 19, torchvision's `deform_conv2d` semantics: `(dy, dx)` per tap, bilinear sampling
//! with zeros outside, checked in [`super::deform`]).
//!
//! Outputs: `scores` `[1, 1, H, W]` (sigmoid score map), `x1` `[1, c1, H, W]` (block 1 output)
//! and `x2g`, `x3g`, `x4g` `[1, H/s, W/s, dim/4]` (s = 2, 8, 32: the gated 1×1 projections of
//! blocks 2–4 before upsampling, channels last so that the descriptor head reads one pixel's
//! channels in one go). The reference concatenates the four projections upsampled to
//! full resolution into a 128-channel map; that map is never formed here: the score head's
//! first 1×1 convolution (linear, no bias) is applied to each part before its upsampling, which
//! commutes with it, and the descriptor head evaluates the normalised map only at the pixels it
//! samples (see [`super::sddh`]). This saves a 512 MB tensor at 1024×1024.

use crate::error::{FeaturesError, Result};
use crate::onnx::{Attr, ConvOpts, Dim, GraphBuilder, Var};
use crate::pth::StateDict;

/// The graph's input sides must be multiples of this (five halvings: 2, 4, 4).
pub const DIVISOR: usize = 32;

/// Changes whenever the graph construction changes (part of the graph cache key).
pub const GRAPH_VERSION: &str = "aliked-graph-3 grey-folded split-score-head nhwc-projections";

/// Batch-norm epsilon of PyTorch's `nn.BatchNorm2d` default.
const BN_EPS: f32 = 1e-5;

/// Channel widths of one ALIKED variant (the reference's `cfgs`: c1, c2, c3, c4, dim, K, M).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dims {
    pub c1: usize,
    pub c2: usize,
    pub c3: usize,
    pub c4: usize,
    /// Descriptor and aggregated feature dimension.
    pub dim: usize,
    /// Side of the descriptor head's offset-estimation kernel.
    pub kernel: usize,
    /// Number of deformable sample positions per keypoint.
    pub positions: usize,
}

impl Dims {
    /// Channels of each of the four aggregated projections (`dim / 4`).
    pub fn quarter(&self) -> usize {
        self.dim / 4
    }
}

/// Every tensor the network reads, with the shape this variant needs.
fn expected_shapes(d: &Dims) -> Vec<(String, Vec<usize>)> {
    let mut v: Vec<(String, Vec<usize>)> = Vec::new();
    let bn = |v: &mut Vec<(String, Vec<usize>)>, p: &str, c: usize| {
        for s in ["weight", "bias", "running_mean", "running_var"] {
            v.push((format!("{p}.{s}"), vec![c]));
        }
    };
    v.push(("block1.conv1.weight".into(), vec![d.c1, 3, 3, 3]));
    bn(&mut v, "block1.bn1", d.c1);
    v.push(("block1.conv2.weight".into(), vec![d.c1, d.c1, 3, 3]));
    bn(&mut v, "block1.bn2", d.c1);
    for (b, cin, cout, dcn) in [
        ("block2", d.c1, d.c2, false),
        ("block3", d.c2, d.c3, true),
        ("block4", d.c3, d.c4, true),
    ] {
        for (conv, ci) in [("conv1", cin), ("conv2", cout)] {
            if dcn {
                v.push((format!("{b}.{conv}.offset_conv.weight"), vec![18, ci, 3, 3]));
                v.push((format!("{b}.{conv}.offset_conv.bias"), vec![18]));
                v.push((
                    format!("{b}.{conv}.regular_conv.weight"),
                    vec![cout, ci, 3, 3],
                ));
            } else {
                v.push((format!("{b}.{conv}.weight"), vec![cout, ci, 3, 3]));
            }
        }
        bn(&mut v, &format!("{b}.bn1"), cout);
        bn(&mut v, &format!("{b}.bn2"), cout);
        v.push((format!("{b}.downsample.weight"), vec![cout, cin, 1, 1]));
        v.push((format!("{b}.downsample.bias"), vec![cout]));
    }
    let q = d.quarter();
    for (i, c) in [d.c1, d.c2, d.c3, d.dim].into_iter().enumerate() {
        v.push((format!("conv{}.weight", i + 1), vec![q, c, 1, 1]));
    }
    v.push(("score_head.0.weight".into(), vec![8, d.dim, 1, 1]));
    v.push(("score_head.2.weight".into(), vec![4, 8, 3, 3]));
    v.push(("score_head.4.weight".into(), vec![4, 4, 3, 3]));
    v.push(("score_head.6.weight".into(), vec![1, 4, 3, 3]));
    let (m2, k) = (2 * d.positions, d.kernel);
    v.push((
        "desc_head.agg_weights".into(),
        vec![d.positions, d.dim, d.dim],
    ));
    v.push((
        "desc_head.offset_conv.0.weight".into(),
        vec![m2, d.dim, k, k],
    ));
    v.push(("desc_head.offset_conv.0.bias".into(), vec![m2]));
    v.push(("desc_head.offset_conv.2.weight".into(), vec![m2, m2, 1, 1]));
    v.push(("desc_head.offset_conv.2.bias".into(), vec![m2]));
    v.push(("desc_head.sf_conv.weight".into(), vec![d.dim, d.dim, 1, 1]));
    v
}

/// Checks that the checkpoint has every weight of this variant with its shape: a checkpoint of
/// another variant fails here with [`FeaturesError::WeightShape`] naming the first mismatch.
pub fn validate(sd: &StateDict, d: &Dims) -> Result<()> {
    if !d.dim.is_multiple_of(4) || d.c4 != d.dim {
        return Err(FeaturesError::InvalidConfig {
            field: "dims",
            value: format!("{d:?}"),
            reason: "dim divisible by 4 and equal to c4",
        });
    }
    for (key, shape) in expected_shapes(d) {
        sd.get_shaped(&key, &shape)?;
    }
    Ok(())
}

fn selu(g: &mut GraphBuilder, x: &Var) -> Var {
    g.unary("Selu", x)
}

/// Convolution with an explicit weight value (no bias), stride 1.
fn conv_with(g: &mut GraphBuilder, x: &Var, w: &Var, k: usize, pad: usize) -> Var {
    let p = pad as i64;
    g.op(
        "Conv",
        &[x, w],
        &[
            Attr::Ints("kernel_shape", vec![k as i64; 2]),
            Attr::Ints("pads", vec![p; 4]),
        ],
    )
}

/// `max(h, w) / 4` of `x` as a scalar float, the reference's offset clamp.
fn max_offset(g: &mut GraphBuilder, x: &Var) -> Var {
    let shape = g.op("Shape", &[x], &[]);
    let hw = g.slice(&shape, 0, 2, 4);
    let m = g.op("ReduceMax", &[&hw], &[Attr::Int("keepdims", 0)]);
    let m = g.op("Cast", &[&m], &[Attr::Int("to", 1)]);
    let four = g.scalar_f32(4.0);
    g.binary("Div", &m, &four)
}

/// A 3×3 convolution of a block: plain, or deformable (offsets from their own convolution,
/// clamped to ±max(h, w)/4, no mask, no bias).
fn block_conv(g: &mut GraphBuilder, sd: &StateDict, p: &str, x: &Var, dcn: bool) -> Result<Var> {
    if !dcn {
        return g.conv2d(x, sd, p, ConvOpts::padded(1));
    }
    let offset = g.conv2d(x, sd, &format!("{p}.offset_conv"), ConvOpts::padded(1))?;
    let hi = max_offset(g, x);
    let lo = g.unary("Neg", &hi);
    let offset = g.op("Clip", &[&offset, &lo, &hi], &[]);
    let w = g.weight(sd, &format!("{p}.regular_conv.weight"))?;
    Ok(super::deform::deform_conv_native(g, x, &offset, &w))
}

/// torchvision-style basic residual block with a 1×1 (biased) projection shortcut.
fn res_block(g: &mut GraphBuilder, sd: &StateDict, p: &str, x: &Var, dcn: bool) -> Result<Var> {
    let out = block_conv(g, sd, &format!("{p}.conv1"), x, dcn)?;
    let out = g.batch_norm(&out, sd, &format!("{p}.bn1"), BN_EPS)?;
    let out = selu(g, &out);
    let out = block_conv(g, sd, &format!("{p}.conv2"), &out, dcn)?;
    let out = g.batch_norm(&out, sd, &format!("{p}.bn2"), BN_EPS)?;
    let id = g.conv2d(x, sd, &format!("{p}.downsample"), ConvOpts::default())?;
    let sum = g.binary("Add", &out, &id);
    Ok(selu(g, &sum))
}

/// Bilinear upsampling by an integer factor with `align_corners=True` (`nn.Upsample`).
fn upsample(g: &mut GraphBuilder, x: &Var, factor: usize) -> Var {
    let f = factor as f32;
    let scales = g.tensor_f32(&[4], &[1.0, 1.0, f, f]);
    g.op(
        "Resize",
        &[x, &Var::none(), &scales],
        &[
            Attr::Str("mode", "linear".into()),
            Attr::Str("coordinate_transformation_mode", "align_corners".into()),
        ],
    )
}

/// Builds the graph (see the module doc) after checking every weight's shape.
pub fn build(sd: &StateDict, d: &Dims) -> Result<Vec<u8>> {
    validate(sd, d)?;
    let mut g = GraphBuilder::new("aliked");
    let (hd, wd) = (Dim::from("height"), Dim::from("width"));
    let image = g.input_f32("image", &[1.into(), 1.into(), hd.clone(), wd.clone()]);

    // Block 1 on the grey image: RGB kernel summed over its input channels.
    let w = &sd.get("block1.conv1.weight")?.data;
    let folded: Vec<f32> = (0..d.c1 * 9)
        .map(|i| {
            let (o, k) = (i / 9, i % 9);
            (0..3).map(|c| w[(o * 3 + c) * 9 + k]).sum()
        })
        .collect();
    let w1 = g.tensor_named("block1.conv1.weight.grey", &[d.c1, 1, 3, 3], &folded);
    let x = conv_with(&mut g, &image, &w1, 3, 1);
    let x = g.batch_norm(&x, sd, "block1.bn1", BN_EPS)?;
    let x = selu(&mut g, &x);
    let x = g.conv2d(&x, sd, "block1.conv2", ConvOpts::padded(1))?;
    let x = g.batch_norm(&x, sd, "block1.bn2", BN_EPS)?;
    let x1 = selu(&mut g, &x);

    let x2 = g.avg_pool(&x1, 2, 2);
    let x2 = res_block(&mut g, sd, "block2", &x2, false)?;
    let x3 = g.avg_pool(&x2, 4, 4);
    let x3 = res_block(&mut g, sd, "block3", &x3, true)?;
    let x4 = g.avg_pool(&x3, 4, 4);
    let x4 = res_block(&mut g, sd, "block4", &x4, true)?;

    let mut gated = Vec::new();
    for (i, x) in [&x1, &x2, &x3, &x4].into_iter().enumerate() {
        let y = g.conv2d(x, sd, &format!("conv{}", i + 1), ConvOpts::default())?;
        gated.push(selu(&mut g, &y));
    }

    // Score head, first 1×1 convolution split over the four parts of the concatenation.
    let q = d.quarter();
    let w0 = &sd.get("score_head.0.weight")?.data;
    let mut s: Option<Var> = None;
    for (part, factor) in [1usize, 2, 8, 32].into_iter().enumerate() {
        let wp: Vec<f32> = (0..8 * q)
            .map(|i| w0[(i / q) * d.dim + part * q + i % q])
            .collect();
        let wv = g.tensor_named(
            &format!("score_head.0.weight.part{part}"),
            &[8, q, 1, 1],
            &wp,
        );
        let y = conv_with(&mut g, &gated[part], &wv, 1, 0);
        let y = if factor > 1 {
            upsample(&mut g, &y, factor)
        } else {
            y
        };
        s = Some(match s {
            None => y,
            Some(acc) => g.binary("Add", &acc, &y),
        });
    }
    let mut s = s.expect("four parts");
    for layer in [2, 4, 6] {
        s = selu(&mut g, &s);
        s = g.conv2d(&s, sd, &format!("score_head.{layer}"), ConvOpts::padded(1))?;
    }
    let scores = g.unary("Sigmoid", &s);

    let full = |c: usize| [Dim::from(1), Dim::from(c), hd.clone(), wd.clone()];
    g.output_f32(&scores, "scores", &full(1));
    g.output_f32(&x1, "x1", &full(d.c1));
    for (i, s) in [(1, "2"), (2, "8"), (3, "32")] {
        let nhwc = g.transpose(&gated[i], &[0, 2, 3, 1]);
        let dims = [
            Dim::from(1),
            Dim::from(format!("height/{s}").as_str()),
            Dim::from(format!("width/{s}").as_str()),
            Dim::from(q),
        ];
        g.output_f32(&nhwc, &format!("x{}g", i + 1), &dims);
    }
    g.metadata("network", "ALIKED (Zhao et al., IEEE TIM 2023)");
    g.metadata("graph_version", GRAPH_VERSION);
    Ok(g.to_bytes())
}

/// Multiply-adds of the graph for a padded `hp × wp` input (convolutions; the deformable ones
/// counted as dense 3×3 convolutions plus their offset convolutions).
pub fn backbone_macs(d: &Dims, hp: usize, wp: usize) -> u64 {
    let full = (hp * wp) as u64;
    let (half, eighth, last) = (full / 4, full / 64, full / 1024);
    let (c1, c2, c3, c4) = (d.c1 as u64, d.c2 as u64, d.c3 as u64, d.c4 as u64);
    let q = d.quarter() as u64;
    let res = |cin: u64, cout: u64, dcn: bool| {
        let offsets = if dcn { 18 * 9 * (cin + cout) } else { 0 };
        9 * cin * cout + 9 * cout * cout + cin * cout + offsets
    };
    let block1 = full * (9 * c1 + 9 * c1 * c1);
    let blocks = half * res(c1, c2, false) + eighth * res(c2, c3, true) + last * res(c3, c4, true);
    let projections = full * c1 * q + half * c2 * q + eighth * c3 * q + last * c4 * q;
    let score_first = (full + half + eighth + last) * q * 8;
    let score_rest = full * 9 * (8 * 4 + 4 * 4 + 4);
    block1 + blocks + projections + score_first + score_rest
}
