//! DISK's U-Net as an ONNX graph, built from the `disk-depth-save.pth` state dict.
//!
//! Architecture (kornia's default DISK U-Net): five down blocks of widths 16, 32, 64, 64, 64
//! (the first a bare 5×5 conv, the others 2×2 average pool → instance norm → PReLU → 5×5 conv)
//! and four up blocks of widths 64, 64, 64, 129 (bilinear ×2 upsampling → concatenation with the
//! skip → instance norm → PReLU → 5×5 conv). Output channel 128 is the detection heatmap
//! (log-probability), channels 0..128 the raw descriptors.

use crate::error::{FeaturesError, Result};
use crate::onnx::{Attr, Dim, GraphBuilder, Var};
use crate::pth::StateDict;

/// Widths of the encoder blocks.
const DOWN: [usize; 5] = [16, 32, 64, 64, 64];
/// Widths of the decoder blocks (the last is 128 descriptor channels + 1 heatmap).
const UP: [usize; 4] = [64, 64, 64, 129];
/// Kernel size of every convolution.
const KERNEL: usize = 5;
/// Input channels of the pretrained network (RGB; we feed grey on all three).
const RGB: usize = 3;
/// Descriptor length.
pub const DESCRIPTOR_DIM: usize = 128;
/// Side multiple the U-Net needs (four 2× poolings).
pub const DIVISOR: usize = 16;
/// Name of the graph input: `1×1×H×W` grey in [0, 1], H and W multiples of [`DIVISOR`].
pub const INPUT: &str = "image";
/// Name of the graph output: `1×129×H×W` (descriptors, then heatmap).
pub const OUTPUT: &str = "unet_output";
/// Changes whenever this file builds a different graph, so cached graphs are rebuilt.
pub const GRAPH_VERSION: &str = "disk-grey-2";
/// Instance-norm epsilon (PyTorch default).
const IN_EPS: f32 = 1e-5;

/// The U-Net's weights under their kornia names, with or without the checkpoint's
/// `extractor.` prefix.
pub(crate) fn unet_weights(sd: &StateDict) -> Result<StateDict> {
    let first = "unet.path_down.0.1.3.weight";
    if sd.contains(&format!("extractor.{first}")) {
        Ok(sd.sub("extractor").sub("unet"))
    } else if sd.contains(first) {
        Ok(sd.sub("unet"))
    } else {
        Err(FeaturesError::MissingWeight {
            path: sd.path().to_owned(),
            name: format!("extractor.{first} (not a DISK checkpoint)"),
        })
    }
}

/// Channel widths `(in, out)` of down block `i` and up block `j`.
fn down_dims(i: usize) -> (usize, usize) {
    (if i == 0 { RGB } else { DOWN[i - 1] }, DOWN[i])
}

fn up_dims(j: usize) -> (usize, usize, usize) {
    let bottom = if j == 0 {
        DOWN[DOWN.len() - 1]
    } else {
        UP[j - 1]
    };
    // Skips come from the encoder outputs in reverse, ending with the first block's output.
    let horizontal = DOWN[DOWN.len() - 2 - j];
    (bottom, horizontal, UP[j])
}

/// Checks every tensor's shape before anything is built, so a wrong checkpoint gives
/// [`FeaturesError::WeightShape`] or [`FeaturesError::MissingWeight`], never a panic.
fn check_shapes(unet: &StateDict) -> Result<()> {
    for i in 0..DOWN.len() {
        let (cin, cout) = down_dims(i);
        let p = format!("path_down.{i}.1");
        unet.get_shaped(&format!("{p}.3.weight"), &[cout, cin, KERNEL, KERNEL])?;
        unet.get_shaped(&format!("{p}.3.bias"), &[cout])?;
        if i > 0 {
            unet.get_shaped(&format!("{p}.1.weight"), &[cin])?;
        }
    }
    for j in 0..UP.len() {
        let (bot, hor, out) = up_dims(j);
        let p = format!("path_up.{j}.conv");
        unet.get_shaped(&format!("{p}.1.weight"), &[bot + hor])?;
        unet.get_shaped(&format!("{p}.3.weight"), &[out, bot + hor, KERNEL, KERNEL])?;
        unet.get_shaped(&format!("{p}.3.bias"), &[out])?;
    }
    Ok(())
}

/// A same-padded 5×5 convolution from explicit weights.
fn conv(g: &mut GraphBuilder, x: &Var, w: &Var, b: &Var) -> Var {
    let p = (KERNEL / 2) as i64;
    g.op(
        "Conv",
        &[x, w, b],
        &[
            Attr::Ints("kernel_shape", vec![KERNEL as i64; 2]),
            Attr::Ints("pads", vec![p; 4]),
        ],
    )
}

/// `InstanceNorm2d` (no affine, biased variance) with row-then-column means: ONNX Runtime's
/// `InstanceNormalization` sums a whole plane in one f32 accumulator, which at 1024×1024 shifts
/// DISK's heatmap by ~1e-4 relative; sums of at most one row or one column stay within ~1e-6.
fn instance_norm(g: &mut GraphBuilder, x: &Var) -> Var {
    let mean2d = |g: &mut GraphBuilder, v: &Var| {
        let (w, h) = (g.const_i64(&[3]), g.const_i64(&[2]));
        let rows = g.op("ReduceMean", &[v, &w], &[Attr::Int("keepdims", 1)]);
        g.op("ReduceMean", &[&rows, &h], &[Attr::Int("keepdims", 1)])
    };
    let mean = mean2d(g, x);
    let centred = g.binary("Sub", x, &mean);
    let sq = g.binary("Mul", &centred, &centred);
    let var = mean2d(g, &sq);
    let eps = g.scalar_f32(IN_EPS);
    let var = g.binary("Add", &var, &eps);
    let inv = g.unary("Sqrt", &var);
    let inv = g.unary("Reciprocal", &inv);
    g.binary("Mul", &centred, &inv)
}

/// kornia's `Conv` block with norm and gate: instance norm (no affine) → PReLU → conv.
fn gated_conv(
    g: &mut GraphBuilder,
    x: &Var,
    sd: &StateDict,
    prefix: &str,
    cin: usize,
) -> Result<Var> {
    let x = instance_norm(g, x);
    let slope = sd.get(&format!("{prefix}.1.weight"))?.data.clone();
    let slope = g.tensor_named(&format!("{prefix}.1.weight"), &[cin, 1, 1], &slope);
    let x = g.op("PRelu", &[&x, &slope], &[]);
    let w = g.weight(sd, &format!("{prefix}.3.weight"))?;
    let b = g.weight(sd, &format!("{prefix}.3.bias"))?;
    Ok(conv(g, &x, &w, &b))
}

/// The U-Net graph for a grey input. The first convolution's weights are summed over the
/// three colour channels: the reference feeds grey repeated to RGB, which that sum computes
/// with a third of the work.
pub fn build(sd: &StateDict) -> Result<Vec<u8>> {
    let unet = unet_weights(sd)?;
    check_shapes(&unet)?;
    let mut g = GraphBuilder::new("disk");
    g.metadata(
        "network",
        "DISK (Tyszkiewicz et al. 2020), kornia U-Net, grey input",
    );
    let dims = [
        Dim::from(1),
        Dim::from(1),
        Dim::from("height"),
        Dim::from("width"),
    ];
    let input = g.input_f32(INPUT, &dims);

    let w0 = unet.get("path_down.0.1.3.weight")?;
    let (c0, k2) = (DOWN[0], KERNEL * KERNEL);
    let mut folded = vec![0.0f32; c0 * k2];
    for o in 0..c0 {
        for c in 0..RGB {
            for k in 0..k2 {
                folded[o * k2 + k] += w0.data[(o * RGB + c) * k2 + k];
            }
        }
    }
    let w0 = g.tensor_named(
        "path_down.0.1.3.weight.grey",
        &[c0, 1, KERNEL, KERNEL],
        &folded,
    );
    let b0 = g.weight(&unet, "path_down.0.1.3.bias")?;
    let mut features = vec![conv(&mut g, &input, &w0, &b0)];
    for i in 1..DOWN.len() {
        let pooled = g.avg_pool(&features[i - 1], 2, 2);
        let y = gated_conv(
            &mut g,
            &pooled,
            &unet,
            &format!("path_down.{i}.1"),
            DOWN[i - 1],
        )?;
        features.push(y);
    }

    let scales = g.tensor_f32(&[4], &[1.0, 1.0, 2.0, 2.0]);
    let mut bottom = features[DOWN.len() - 1].clone();
    for j in 0..UP.len() {
        let (bot, hor, _) = up_dims(j);
        let up = g.op(
            "Resize",
            &[&bottom, &Var::none(), &scales],
            &[
                Attr::Str("mode", "linear".into()),
                Attr::Str("coordinate_transformation_mode", "half_pixel".into()),
            ],
        );
        let skip = &features[DOWN.len() - 2 - j];
        let cat = g.concat(&[&up, skip], 1);
        bottom = gated_conv(&mut g, &cat, &unet, &format!("path_up.{j}.conv"), bot + hor)?;
    }
    let out_dims = [
        Dim::from(1),
        Dim::from(DESCRIPTOR_DIM + 1),
        Dim::from("height"),
        Dim::from("width"),
    ];
    g.output_f32(&bottom, OUTPUT, &out_dims);
    Ok(g.to_bytes())
}

/// Floating-point operations of the U-Net's convolutions (2 × multiply-adds) on a
/// `width × height` network input (already resized and padded), as the graph computes them
/// (grey first layer).
pub fn flops(width: usize, height: usize) -> u64 {
    let px = (width * height) as u64;
    let k2 = (KERNEL * KERNEL) as u64;
    let mut macs = px * k2 * DOWN[0] as u64; // grey first layer
    for i in 1..DOWN.len() {
        let (cin, cout) = down_dims(i);
        macs += (px >> (2 * i)) * k2 * (cin * cout) as u64;
    }
    for j in 0..UP.len() {
        let (bot, hor, out) = up_dims(j);
        let level = DOWN.len() - 2 - j;
        macs += (px >> (2 * level)) * k2 * ((bot + hor) * out) as u64;
    }
    2 * macs
}
