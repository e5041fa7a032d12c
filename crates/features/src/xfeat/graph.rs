//! XFeat's backbone and heads as one ONNX graph with dynamic height and width.
//!
//! Every `BasicLayer` (conv without bias → `BatchNorm2d(affine=False)` → ReLU) is written as
//! one biased convolution: the batch norm is folded into the weights at build time (in f64),
//! which removes a node per layer and lets the runtime fuse conv + ReLU. The keypoint head's
//! first 1×1 convolution on the 8×8-unfolded image is the same as an 8×8 stride-8 convolution
//! on the image itself (its 64 input channels are the window's pixels in row-major order), so it
//! is written as that and the unfold disappears; likewise `skip1` (4×4 average pooling, 1×1
//! convolution) is one 4×4 stride-4 convolution. Measured with ONNX Runtime's per-node profile
//! (1 thread): these and the 8-channel padding of `block1.0` cut the graph's time by about 9 %.

use crate::error::{FeaturesError, Result};
use crate::onnx::{Attr, Dim, GraphBuilder, Var};
use crate::pth::StateDict;

/// `BatchNorm2d` epsilon (PyTorch default, also `InstanceNorm2d`'s).
const BN_EPS: f64 = 1e-5;

/// A `BasicLayer`: module prefix, in/out channels, kernel, stride (padding is `kernel / 2`).
type Basic = (&'static str, usize, usize, usize, usize);

const BLOCK1: [Basic; 4] = [
    ("block1.0", 1, 4, 3, 1),
    ("block1.1", 4, 8, 3, 2),
    ("block1.2", 8, 8, 3, 1),
    ("block1.3", 8, 24, 3, 2),
];
const BLOCK2: [Basic; 2] = [("block2.0", 24, 24, 3, 1), ("block2.1", 24, 24, 3, 1)];
const BLOCK3: [Basic; 3] = [
    ("block3.0", 24, 64, 3, 2),
    ("block3.1", 64, 64, 3, 1),
    ("block3.2", 64, 64, 1, 1),
];
const BLOCK4: [Basic; 3] = [
    ("block4.0", 64, 64, 3, 2),
    ("block4.1", 64, 64, 3, 1),
    ("block4.2", 64, 64, 3, 1),
];
const BLOCK5: [Basic; 4] = [
    ("block5.0", 64, 128, 3, 2),
    ("block5.1", 128, 128, 3, 1),
    ("block5.2", 128, 128, 3, 1),
    ("block5.3", 128, 64, 1, 1),
];
const FUSION: [Basic; 2] = [
    ("block_fusion.0", 64, 64, 3, 1),
    ("block_fusion.1", 64, 64, 3, 1),
];
const HEATMAP: [Basic; 2] = [
    ("heatmap_head.0", 64, 64, 1, 1),
    ("heatmap_head.1", 64, 64, 1, 1),
];
/// The keypoint head after its first layer (which is built as an 8×8 stride-8 convolution).
const KEYPOINT: [Basic; 2] = [
    ("keypoint_head.1", 64, 64, 1, 1),
    ("keypoint_head.2", 64, 64, 1, 1),
];

/// Compiles the XFeat network from its state dict (`xfeat.pt`) to ONNX bytes.
///
/// Input `image` 1×1×H×W (grey in [0, 1], H and W multiples of 32); outputs `feats`
/// 1×64×H/8×W/8 (not normalised), `keypoint_logits` 1×65×H/8×W/8 and `heatmap` 1×1×H/8×W/8
/// (reliability, after the sigmoid), exactly the reference `XFeatModel.forward`.
/// Every weight's shape is checked ([`FeaturesError::WeightShape`]).
pub fn build_graph(sd: &StateDict) -> Result<Vec<u8>> {
    let mut g = GraphBuilder::new("xfeat");
    let (h, w) = (Dim::from("height"), Dim::from("width"));
    let (h8, w8) = (Dim::from("height_8"), Dim::from("width_8"));
    let image = g.input_f32("image", &[1.into(), 1.into(), h, w]);

    // InstanceNorm2d(1): per-image zero mean, unit variance (no affine parameters).
    let one = g.tensor_f32(&[1], &[1.0]);
    let zero = g.tensor_f32(&[1], &[0.0]);
    let x = g.op(
        "InstanceNormalization",
        &[&image, &one, &zero],
        &[Attr::Float("epsilon", BN_EPS as f32)],
    );

    // block1.0 has 4 output channels: padded with 4 zero channels (ReLU keeps them 0) and
    // block1.1 with 4 zero-weight inputs, so both run in the runtime's 8-channel blocked
    // layout instead of reordering a full-resolution tensor in between.
    let x1 = basic_layer(&mut g, sd, &x, BLOCK1[0], 0, 4)?;
    let x1 = basic_layer(&mut g, sd, &x1, BLOCK1[1], 4, 0)?;
    let x1 = basic_chain(&mut g, sd, &x1, &BLOCK1[2..])?;
    let skip = skip_conv(&mut g, sd, &x)?;
    let x2 = g.binary("Add", &x1, &skip);
    let x2 = basic_chain(&mut g, sd, &x2, &BLOCK2)?;
    let x3 = basic_chain(&mut g, sd, &x2, &BLOCK3)?;
    let x4 = basic_chain(&mut g, sd, &x3, &BLOCK4)?;
    let x5 = basic_chain(&mut g, sd, &x4, &BLOCK5)?;

    // F.interpolate(..., size=x3's, mode='bilinear', align_corners=False): sizes are exact
    // multiples, so scales 2 and 4 with half-pixel centres are the same sampling.
    let x4 = upsample(&mut g, &x4, 2.0);
    let x5 = upsample(&mut g, &x5, 4.0);
    let fused = g.binary("Add", &x3, &x4);
    let fused = g.binary("Add", &fused, &x5);
    let f = basic_chain(&mut g, sd, &fused, &FUSION)?;
    let feats = conv_with_bias(&mut g, sd, &f, "block_fusion.2", 64, 64, 1)?;

    let hm = basic_chain(&mut g, sd, &feats, &HEATMAP)?;
    let hm = conv_with_bias(&mut g, sd, &hm, "heatmap_head.2", 64, 1, 1)?;
    let heatmap = g.unary("Sigmoid", &hm);

    let k = unfolded_basic(&mut g, sd, &x)?;
    let k = basic_chain(&mut g, sd, &k, &KEYPOINT)?;
    let logits = conv_with_bias(&mut g, sd, &k, "keypoint_head.3", 64, 65, 1)?;

    g.output_f32(
        &feats,
        "feats",
        &[1.into(), 64.into(), h8.clone(), w8.clone()],
    );
    g.output_f32(
        &logits,
        "keypoint_logits",
        &[1.into(), 65.into(), h8.clone(), w8.clone()],
    );
    g.output_f32(&heatmap, "heatmap", &[1.into(), 1.into(), h8, w8]);
    g.metadata("network", "XFeat (Potje et al., CVPR 2024)");
    Ok(g.to_bytes())
}

/// FLOPs (2 × multiply-adds of the convolutions) of one forward pass on a `width × height`
/// network input (multiples of 32).
pub fn network_flops(width: usize, height: usize) -> u64 {
    let conv = |cin: usize, cout: usize, k: usize, w: usize, h: usize| {
        2 * (cin * cout * k * k * w * h) as u64
    };
    let mut total = 0;
    let mut chain = |layers: &[Basic], mut w: usize, mut h: usize| {
        for &(_, cin, cout, k, stride) in layers {
            w /= stride;
            h /= stride;
            total += conv(cin, cout, k, w, h);
        }
        (w, h)
    };
    let (w4, h4) = chain(&BLOCK1, width, height);
    let (w4, h4) = chain(&BLOCK2, w4, h4);
    let (w8, h8) = chain(&BLOCK3, w4, h4);
    let (w16, h16) = chain(&BLOCK4, w8, h8);
    chain(&BLOCK5, w16, h16);
    chain(&FUSION, w8, h8);
    chain(&HEATMAP, w8, h8);
    chain(&KEYPOINT, w8, h8);
    total
        + conv(1, 24, 1, w4, h4) // skip1 (pooling not counted)
        + conv(64, 64, 1, w8, h8) // block_fusion.2
        + conv(64, 1, 1, w8, h8) // heatmap_head.2
        + conv(1, 64, 8, w8, h8) // keypoint_head.0 as an 8×8 stride-8 convolution
        + conv(64, 65, 1, w8, h8) // keypoint_head.3
}

fn basic_chain(g: &mut GraphBuilder, sd: &StateDict, x: &Var, layers: &[Basic]) -> Result<Var> {
    let mut x = x.clone();
    for &layer in layers {
        x = basic_layer(g, sd, &x, layer, 0, 0)?;
    }
    Ok(x)
}

/// One `BasicLayer` as a biased convolution + ReLU, with `pad_in` zero input channels and
/// `pad_out` zero output channels appended.
fn basic_layer(
    g: &mut GraphBuilder,
    sd: &StateDict,
    x: &Var,
    (prefix, cin, cout, k, stride): Basic,
    pad_in: usize,
    pad_out: usize,
) -> Result<Var> {
    let w = sd.get_shaped(&format!("{prefix}.layer.0.weight"), &[cout, cin, k, k])?;
    let (wf, mut bf) = fold_batch_norm(sd, &format!("{prefix}.layer.1"), &w.data, cout)?;
    let (ci, co) = (cin + pad_in, cout + pad_out);
    let mut wp = vec![0.0f32; co * ci * k * k];
    for o in 0..cout {
        for i in 0..cin {
            let src = (o * cin + i) * k * k;
            let dst = (o * ci + i) * k * k;
            wp[dst..dst + k * k].copy_from_slice(&wf[src..src + k * k]);
        }
    }
    bf.resize(co, 0.0);
    let wv = g.tensor_named(&format!("{prefix}.folded.weight"), &[co, ci, k, k], &wp);
    let bv = g.tensor_named(&format!("{prefix}.folded.bias"), &[co], &bf);
    let y = conv(g, x, &wv, &bv, k, stride, k / 2);
    Ok(g.relu(&y))
}

/// `skip1` (4×4 average pooling, then a 1×1 convolution 1 → 24) as one 4×4 stride-4
/// convolution with the 1×1 weights spread over the window.
fn skip_conv(g: &mut GraphBuilder, sd: &StateDict, x: &Var) -> Result<Var> {
    let w = sd.get_shaped("skip1.1.weight", &[24, 1, 1, 1])?;
    sd.get_shaped("skip1.1.bias", &[24])?;
    let wk: Vec<f32> = w.data.iter().flat_map(|&v| [v / 16.0; 16]).collect();
    let wv = g.tensor_named("skip1.1.weight.4x4", &[24, 1, 4, 4], &wk);
    let bv = g.weight(sd, "skip1.1.bias")?;
    Ok(conv(g, x, &wv, &bv, 4, 4, 0))
}

/// `keypoint_head.0` applied to `_unfold2d(x, 8)`, as an 8×8 stride-8 convolution on `x`.
fn unfolded_basic(g: &mut GraphBuilder, sd: &StateDict, x: &Var) -> Result<Var> {
    let prefix = "keypoint_head.0";
    let w = sd.get_shaped(&format!("{prefix}.layer.0.weight"), &[64, 64, 1, 1])?;
    let (wf, bf) = fold_batch_norm(sd, &format!("{prefix}.layer.1"), &w.data, 64)?;
    // Unfolded channel `ky * 8 + kx` is pixel (ky, kx) of the window: the [64, 64] matrix read
    // as [64, 1, 8, 8] is the equivalent kernel.
    let wv = g.tensor_named(&format!("{prefix}.folded.weight"), &[64, 1, 8, 8], &wf);
    let bv = g.tensor_named(&format!("{prefix}.folded.bias"), &[64], &bf);
    let y = conv(g, x, &wv, &bv, 8, 8, 0);
    Ok(g.relu(&y))
}

/// Folds `BatchNorm2d(affine=False)` (eval) into the preceding bias-free convolution:
/// `(conv(x) − mean) / sqrt(var + eps)` = `conv'(x) + b'`.
fn fold_batch_norm(
    sd: &StateDict,
    prefix: &str,
    weight: &[f32],
    cout: usize,
) -> Result<(Vec<f32>, Vec<f32>)> {
    let mean = &sd
        .get_shaped(&format!("{prefix}.running_mean"), &[cout])?
        .data;
    let var = &sd
        .get_shaped(&format!("{prefix}.running_var"), &[cout])?
        .data;
    let per_out = weight.len() / cout;
    let mut w = Vec::with_capacity(weight.len());
    let mut b = Vec::with_capacity(cout);
    for o in 0..cout {
        let v = f64::from(var[o]);
        if !(v >= 0.0 && v.is_finite()) {
            return Err(FeaturesError::InvalidInput(format!(
                "{prefix}.running_var[{o}] = {v} is not a variance"
            )));
        }
        let inv = 1.0 / (v + BN_EPS).sqrt();
        w.extend(
            weight[o * per_out..(o + 1) * per_out]
                .iter()
                .map(|&x| (f64::from(x) * inv) as f32),
        );
        b.push((-f64::from(mean[o]) * inv) as f32);
    }
    Ok((w, b))
}

fn conv_with_bias(
    g: &mut GraphBuilder,
    sd: &StateDict,
    x: &Var,
    prefix: &str,
    cin: usize,
    cout: usize,
    k: usize,
) -> Result<Var> {
    let wk = format!("{prefix}.weight");
    let bk = format!("{prefix}.bias");
    sd.get_shaped(&wk, &[cout, cin, k, k])?;
    sd.get_shaped(&bk, &[cout])?;
    let w = g.weight(sd, &wk)?;
    let b = g.weight(sd, &bk)?;
    Ok(conv(g, x, &w, &b, k, 1, k / 2))
}

fn conv(
    g: &mut GraphBuilder,
    x: &Var,
    w: &Var,
    b: &Var,
    k: usize,
    stride: usize,
    pad: usize,
) -> Var {
    let (k, s, p) = (k as i64, stride as i64, pad as i64);
    g.op(
        "Conv",
        &[x, w, b],
        &[
            Attr::Ints("kernel_shape", vec![k, k]),
            Attr::Ints("strides", vec![s, s]),
            Attr::Ints("pads", vec![p; 4]),
        ],
    )
}

fn upsample(g: &mut GraphBuilder, x: &Var, factor: f32) -> Var {
    let scales = g.tensor_f32(&[4], &[1.0, 1.0, factor, factor]);
    g.op(
        "Resize",
        &[x, &Var::none(), &scales],
        &[
            Attr::Str("mode", "linear".into()),
            Attr::Str("coordinate_transformation_mode", "half_pixel".into()),
        ],
    )
}
