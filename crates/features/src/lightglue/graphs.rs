//! LightGlue's networks as ONNX graphs, one per stage so Rust can stop or prune between
//! layers: the input graph (projection and rotary encoding of one image's points), one graph
//! per transformer layer (self + cross attention, and the confidence/matchability heads the
//! adaptive control reads), one assignment graph per layer (the log double-softmax assignment,
//! reduced to row/column maxima). Every keypoint count is a dynamic dimension.
//!
//! Layouts are ours where that is exact: the `Wqkv` rows are reordered (q, k, v blocks; inside
//! a head the even rotary components before the odd ones, which leaves dot products unchanged
//! and makes the rotation two half-vectors), and the attention scales are folded into the q
//! and qk projections.

use std::collections::BTreeMap;

use crate::error::{FeaturesError, Result};
use crate::onnx::{Attr, Dim, GraphBuilder, Var};
use crate::pth::StateDict;

/// Bump when a graph below changes (part of the cached graphs' key).
pub const GRAPH_VERSION: u32 = 3;

/// Sizes of a LightGlue model, read from its weights.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Arch {
    /// Descriptor length the model accepts.
    pub input_dim: usize,
    /// Width of the transformer.
    pub dim: usize,
    /// Attention heads.
    pub heads: usize,
    /// Transformer layers.
    pub n_layers: usize,
}

impl Arch {
    /// Width of one head.
    pub fn head_dim(&self) -> usize {
        self.dim / self.heads
    }

    /// Multiply-add FLOPs (×2) of the input graphs for `m` and `n` points.
    pub fn input_flops(&self, m: usize, n: usize) -> f64 {
        let (m, n) = (m as f64, n as f64);
        2.0 * (m + n) * (self.input_dim * self.dim + self.head_dim()) as f64
    }

    /// FLOPs of one transformer layer (self attention on both sides, cross attention, heads).
    pub fn layer_flops(&self, m: usize, n: usize) -> f64 {
        let (m, n, d) = (m as f64, n as f64, self.dim as f64);
        // Self: qkv 6d², out 2d², ffn 8d² + 4d² per point; qkᵀ and attn·v 4·N²·d.
        let self_attn = 20.0 * (m + n) * d * d + 4.0 * (m * m + n * n) * d;
        // Cross: qk, v, out 6d², ffn 12d² per point; sim 2mnd, two attn·v 4mnd.
        let cross = 18.0 * (m + n) * d * d + 6.0 * m * n * d;
        let heads = 2.0 * (m + n) * d * 2.0;
        self_attn + cross + heads
    }

    /// FLOPs of the assignment graph.
    pub fn assignment_flops(&self, m: usize, n: usize) -> f64 {
        let (m, n, d) = (m as f64, n as f64, self.dim as f64);
        2.0 * (m + n) * d * d + 2.0 * m * n * d + 2.0 * (m + n) * d
    }

    /// FLOPs of a full-depth run without pruning (input, every layer, last assignment).
    pub fn full_flops(&self, m: usize, n: usize) -> f64 {
        self.input_flops(m, n)
            + self.n_layers as f64 * self.layer_flops(m, n)
            + self.assignment_flops(m, n)
    }
}

/// Renames checkpoint keys to the current module names: XFeat's `matcher.` prefix and the
/// old `self_attn.{i}` / `cross_attn.{i}` spelling of the DISK weights.
pub fn canonical_weights(sd: &StateDict) -> StateDict {
    let mut tensors = BTreeMap::new();
    for name in sd.names() {
        let Ok(t) = sd.get(name) else { continue };
        let key = name.strip_prefix("matcher.").unwrap_or(name);
        let key = rename_old_block(key).unwrap_or_else(|| key.to_owned());
        tensors.insert(key, t.clone());
    }
    StateDict::from_tensors(sd.path().to_owned(), tensors)
}

fn rename_old_block(key: &str) -> Option<String> {
    for block in ["self_attn", "cross_attn"] {
        if let Some(rest) = key.strip_prefix(block).and_then(|r| r.strip_prefix('.')) {
            let (layer, tail) = rest.split_once('.')?;
            layer.parse::<usize>().ok()?;
            return Some(format!("transformers.{layer}.{block}.{tail}"));
        }
    }
    None
}

/// Reads the sizes from canonical weights and checks every tensor the graphs use.
pub fn read_arch(sd: &StateDict) -> Result<Arch> {
    let ip = sd.get("input_proj.weight")?;
    let [dim, input_dim] = ip.shape[..] else {
        return Err(shape_err("input_proj.weight", &[0, 0], &ip.shape));
    };
    let wr = sd.get("posenc.Wr.weight")?;
    let [half, 2] = wr.shape[..] else {
        return Err(shape_err("posenc.Wr.weight", &[0, 2], &wr.shape));
    };
    let head_dim = 2 * half;
    if head_dim == 0 || !dim.is_multiple_of(head_dim) {
        return Err(shape_err("posenc.Wr.weight", &[dim / 8, 2], &wr.shape));
    }
    let n_layers = (0..)
        .take_while(|i| sd.contains(&format!("transformers.{i}.self_attn.Wqkv.weight")))
        .count();
    if n_layers == 0 {
        return Err(FeaturesError::MissingWeight {
            path: sd.path().to_owned(),
            name: "transformers.0.self_attn.Wqkv.weight".into(),
        });
    }
    let arch = Arch {
        input_dim,
        dim,
        heads: dim / head_dim,
        n_layers,
    };
    check_shapes(sd, &arch)?;
    Ok(arch)
}

fn shape_err(name: &str, expected: &[usize], found: &[usize]) -> FeaturesError {
    FeaturesError::WeightShape {
        name: name.into(),
        expected: expected.to_vec(),
        found: found.to_vec(),
    }
}

fn check_shapes(sd: &StateDict, a: &Arch) -> Result<()> {
    let d = a.dim;
    sd.get_shaped("input_proj.bias", &[d])?;
    for i in 0..a.n_layers {
        let s = format!("transformers.{i}.self_attn");
        sd.get_shaped(&format!("{s}.Wqkv.weight"), &[3 * d, d])?;
        sd.get_shaped(&format!("{s}.Wqkv.bias"), &[3 * d])?;
        sd.get_shaped(&format!("{s}.out_proj.weight"), &[d, d])?;
        sd.get_shaped(&format!("{s}.out_proj.bias"), &[d])?;
        let c = format!("transformers.{i}.cross_attn");
        for p in ["to_qk", "to_v", "to_out"] {
            sd.get_shaped(&format!("{c}.{p}.weight"), &[d, d])?;
            sd.get_shaped(&format!("{c}.{p}.bias"), &[d])?;
        }
        for block in [&s, &c] {
            sd.get_shaped(&format!("{block}.ffn.0.weight"), &[2 * d, 2 * d])?;
            sd.get_shaped(&format!("{block}.ffn.0.bias"), &[2 * d])?;
            sd.get_shaped(&format!("{block}.ffn.1.weight"), &[2 * d])?;
            sd.get_shaped(&format!("{block}.ffn.1.bias"), &[2 * d])?;
            sd.get_shaped(&format!("{block}.ffn.3.weight"), &[d, 2 * d])?;
            sd.get_shaped(&format!("{block}.ffn.3.bias"), &[d])?;
        }
        let la = format!("log_assignment.{i}");
        sd.get_shaped(&format!("{la}.matchability.weight"), &[1, d])?;
        sd.get_shaped(&format!("{la}.matchability.bias"), &[1])?;
        sd.get_shaped(&format!("{la}.final_proj.weight"), &[d, d])?;
        sd.get_shaped(&format!("{la}.final_proj.bias"), &[d])?;
        if i + 1 < a.n_layers {
            let t = format!("token_confidence.{i}.token.0");
            sd.get_shaped(&format!("{t}.weight"), &[1, d])?;
            sd.get_shaped(&format!("{t}.bias"), &[1])?;
        }
    }
    Ok(())
}

/// A linear layer's initializers (`Wᵀ` stored `[in, out]`), created once and applied to
/// either image.
struct Lin {
    w: Var,
    b: Var,
}

impl Lin {
    /// From PyTorch-layout rows `w` `[out, in]` and bias `b` `[out]` (already transformed).
    fn from_rows(g: &mut GraphBuilder, name: &str, w: &[f32], b: &[f32], inp: usize) -> Self {
        let out = b.len();
        let mut wt = vec![0.0f32; out * inp];
        for o in 0..out {
            for i in 0..inp {
                wt[i * out + o] = w[o * inp + i];
            }
        }
        Self {
            w: g.tensor_named(&format!("{name}.weight.T"), &[inp, out], &wt),
            b: g.tensor_named(&format!("{name}.bias"), &[out], b),
        }
    }

    /// `{prefix}.weight` and `{prefix}.bias` of the checkpoint.
    fn from_sd(g: &mut GraphBuilder, sd: &StateDict, prefix: &str) -> Result<Self> {
        let w = sd.get(&format!("{prefix}.weight"))?;
        let b = sd.get(&format!("{prefix}.bias"))?;
        let inp = w.shape.get(1).copied().unwrap_or(0);
        if w.shape.len() != 2 || w.shape[0] != b.numel() {
            return Err(shape_err(
                &format!("{prefix}.weight"),
                &[b.numel(), inp],
                &w.shape,
            ));
        }
        Ok(Self::from_rows(g, prefix, &w.data, &b.data, inp))
    }

    fn apply(&self, g: &mut GraphBuilder, x: &Var) -> Var {
        let y = g.op("MatMul", &[x, &self.w], &[]);
        g.op("Add", &[&y, &self.b], &[])
    }
}

/// Exact GELU, `0.5·x·(1 + erf(x/√2))`, in the node pattern ONNX Runtime fuses into one op.
fn gelu(g: &mut GraphBuilder, x: &Var) -> Var {
    let sqrt2 = g.scalar_f32(std::f32::consts::SQRT_2);
    let one = g.scalar_f32(1.0);
    let half = g.scalar_f32(0.5);
    let t = g.op("Div", &[x, &sqrt2], &[]);
    let t = g.op("Erf", &[&t], &[]);
    let t = g.op("Add", &[&t, &one], &[]);
    let t = g.op("Mul", &[x, &t], &[]);
    g.op("Mul", &[&t, &half], &[])
}

/// `x + ffn(cat[x, message])` with `Linear → LayerNorm → GELU → Linear`.
struct Ffn {
    l0: Lin,
    ln_w: Var,
    ln_b: Var,
    l3: Lin,
}

impl Ffn {
    fn new(g: &mut GraphBuilder, sd: &StateDict, block: &str) -> Result<Self> {
        Ok(Self {
            l0: Lin::from_sd(g, sd, &format!("{block}.ffn.0"))?,
            ln_w: g.weight(sd, &format!("{block}.ffn.1.weight"))?,
            ln_b: g.weight(sd, &format!("{block}.ffn.1.bias"))?,
            l3: Lin::from_sd(g, sd, &format!("{block}.ffn.3"))?,
        })
    }

    fn residual(&self, g: &mut GraphBuilder, x: &Var, message: &Var) -> Var {
        let h = g.concat(&[x, message], 1);
        let h = self.l0.apply(g, &h);
        let h = g.op(
            "LayerNormalization",
            &[&h, &self.ln_w, &self.ln_b],
            &[Attr::Int("axis", -1), Attr::Float("epsilon", 1e-5)],
        );
        let h = gelu(g, &h);
        let h = self.l3.apply(g, &h);
        g.op("Add", &[x, &h], &[])
    }
}

/// `[N, heads·hd] → [heads, N, hd]`.
fn split_heads(g: &mut GraphBuilder, x: &Var, a: &Arch) -> Var {
    let r = g.reshape(x, &[-1, a.heads as i64, a.head_dim() as i64]);
    g.transpose(&r, &[1, 0, 2])
}

/// `[heads, N, hd] → [N, heads·hd]`.
fn merge_heads(g: &mut GraphBuilder, x: &Var, a: &Arch) -> Var {
    let t = g.transpose(x, &[1, 0, 2]);
    g.reshape(&t, &[-1, a.dim as i64])
}

/// Rotary encoding of `x` `[N, dim]` whose heads are laid out `[evens | odds]`, with
/// `cos`/`sin` `[N, hd/2]`: `(a, b) → (a·cos − b·sin, b·cos + a·sin)`. Returns `[heads, N, hd]`.
fn rotate(g: &mut GraphBuilder, x: &Var, cos: &Var, sin: &Var, a: &Arch) -> Var {
    let half = (a.head_dim() / 2) as i64;
    let x4 = g.reshape(x, &[-1, a.heads as i64, 2, half]);
    let split = g.const_i64(&[1, 1]);
    let parts = g.op_n("Split", &[&x4, &split], &[Attr::Int("axis", 2)], 2);
    let axes = g.const_i64(&[1, 2]);
    let c = g.op("Unsqueeze", &[cos, &axes], &[]);
    let s = g.op("Unsqueeze", &[sin, &axes], &[]);
    let (pa, pb) = (&parts[0], &parts[1]);
    let ac = g.op("Mul", &[pa, &c], &[]);
    let bs = g.op("Mul", &[pb, &s], &[]);
    let bc = g.op("Mul", &[pb, &c], &[]);
    let as_ = g.op("Mul", &[pa, &s], &[]);
    let ra = g.op("Sub", &[&ac, &bs], &[]);
    let rb = g.op("Add", &[&bc, &as_], &[]);
    let r = g.concat(&[&ra, &rb], 2);
    let r = g.reshape(&r, &[-1, a.dim as i64]);
    split_heads(g, &r, a)
}

/// Row of the reordered `Wqkv` output for PyTorch row `(h, d, c)` (`c` = q, k, v).
fn qkv_row(h: usize, d: usize, c: usize, a: &Arch) -> usize {
    let hd = a.head_dim();
    let within = if c == 2 {
        d
    } else if d.is_multiple_of(2) {
        d / 2
    } else {
        hd / 2 + d / 2
    };
    c * a.dim + h * hd + within
}

/// The self-attention block of one layer (shared by both images).
struct SelfBlock {
    qkv: Lin,
    out: Lin,
    ffn: Ffn,
}

impl SelfBlock {
    fn new(g: &mut GraphBuilder, sd: &StateDict, i: usize, a: &Arch) -> Result<Self> {
        let p = format!("transformers.{i}.self_attn");
        let d = a.dim;
        let w = &sd.get(&format!("{p}.Wqkv.weight"))?.data;
        let b = &sd.get(&format!("{p}.Wqkv.bias"))?.data;
        // PyTorch row (h·hd + dd)·3 + c  →  our row qkv_row(h, dd, c); q scaled by 1/√hd.
        let scale = (a.head_dim() as f64).powf(-0.5) as f32;
        let (mut w2, mut b2) = (vec![0.0f32; 3 * d * d], vec![0.0f32; 3 * d]);
        for h in 0..a.heads {
            for dd in 0..a.head_dim() {
                for c in 0..3 {
                    let src = (h * a.head_dim() + dd) * 3 + c;
                    let dst = qkv_row(h, dd, c, a);
                    let s = if c == 0 { scale } else { 1.0 };
                    for k in 0..d {
                        w2[dst * d + k] = w[src * d + k] * s;
                    }
                    b2[dst] = b[src] * s;
                }
            }
        }
        Ok(Self {
            qkv: Lin::from_rows(g, &format!("{p}.Wqkv.reordered"), &w2, &b2, d),
            out: Lin::from_sd(g, sd, &format!("{p}.out_proj"))?,
            ffn: Ffn::new(g, sd, &p)?,
        })
    }

    fn apply(&self, g: &mut GraphBuilder, x: &Var, cos: &Var, sin: &Var, a: &Arch) -> Var {
        let d = a.dim as i64;
        let qkv = self.qkv.apply(g, x);
        let split = g.const_i64(&[d; 3]);
        let parts = g.op_n("Split", &[&qkv, &split], &[Attr::Int("axis", 1)], 3);
        let q = rotate(g, &parts[0], cos, sin, a);
        let k = rotate(g, &parts[1], cos, sin, a);
        let v = split_heads(g, &parts[2], a);
        let kt = g.transpose(&k, &[0, 2, 1]);
        let sim = g.op("MatMul", &[&q, &kt], &[]);
        let attn = g.softmax(&sim, -1);
        let ctx = g.op("MatMul", &[&attn, &v], &[]);
        let ctx = merge_heads(g, &ctx, a);
        let message = self.out.apply(g, &ctx);
        self.ffn.residual(g, x, &message)
    }
}

/// The cross-attention block of one layer (shared qk, bidirectional).
struct CrossBlock {
    qk: Lin,
    v: Lin,
    out: Lin,
    ffn: Ffn,
}

impl CrossBlock {
    fn new(g: &mut GraphBuilder, sd: &StateDict, i: usize, a: &Arch) -> Result<Self> {
        let p = format!("transformers.{i}.cross_attn");
        // Both sides are scaled by hd^(-1/4), so sim = qk0·qk1ᵀ / √hd as in the reference.
        let s = ((a.head_dim() as f64).powf(-0.5)).powf(0.5) as f32;
        let w = &sd.get(&format!("{p}.to_qk.weight"))?.data;
        let b = &sd.get(&format!("{p}.to_qk.bias"))?.data;
        let ws: Vec<f32> = w.iter().map(|v| v * s).collect();
        let bs: Vec<f32> = b.iter().map(|v| v * s).collect();
        Ok(Self {
            qk: Lin::from_rows(g, &format!("{p}.to_qk.scaled"), &ws, &bs, a.dim),
            v: Lin::from_sd(g, sd, &format!("{p}.to_v"))?,
            out: Lin::from_sd(g, sd, &format!("{p}.to_out"))?,
            ffn: Ffn::new(g, sd, &p)?,
        })
    }

    fn apply(&self, g: &mut GraphBuilder, x0: &Var, x1: &Var, a: &Arch) -> (Var, Var) {
        let qk0 = self.qk.apply(g, x0);
        let qk1 = self.qk.apply(g, x1);
        let v0 = self.v.apply(g, x0);
        let v1 = self.v.apply(g, x1);
        let (qk0, qk1) = (split_heads(g, &qk0, a), split_heads(g, &qk1, a));
        let (v0, v1) = (split_heads(g, &v0, a), split_heads(g, &v1, a));
        let qk1t = g.transpose(&qk1, &[0, 2, 1]);
        let sim = g.op("MatMul", &[&qk0, &qk1t], &[]);
        let attn01 = g.softmax(&sim, -1);
        let m0 = g.op("MatMul", &[&attn01, &v1], &[]);
        let sim_t = g.transpose(&sim, &[0, 2, 1]);
        let attn10 = g.softmax(&sim_t, -1);
        let m1 = g.op("MatMul", &[&attn10, &v0], &[]);
        let m0 = merge_heads(g, &m0, a);
        let m1 = merge_heads(g, &m1, a);
        let m0 = self.out.apply(g, &m0);
        let m1 = self.out.apply(g, &m1);
        let y0 = self.ffn.residual(g, x0, &m0);
        let y1 = self.ffn.residual(g, x1, &m1);
        (y0, y1)
    }
}

/// `[token; matchability]` of layer `i` as one `[dim, 2]` linear: after a sigmoid, column 0
/// is the token confidence and column 1 the matchability.
fn heads_lin(g: &mut GraphBuilder, sd: &StateDict, i: usize, d: usize) -> Result<Lin> {
    let tw = &sd
        .get(&format!("token_confidence.{i}.token.0.weight"))?
        .data;
    let tb = &sd.get(&format!("token_confidence.{i}.token.0.bias"))?.data;
    let mw = &sd
        .get(&format!("log_assignment.{i}.matchability.weight"))?
        .data;
    let mb = &sd
        .get(&format!("log_assignment.{i}.matchability.bias"))?
        .data;
    let w: Vec<f32> = tw.iter().chain(mw.iter()).copied().collect();
    Ok(Lin::from_rows(
        g,
        &format!("heads.{i}"),
        &w,
        &[tb[0], mb[0]],
        d,
    ))
}

/// Graph inputs/outputs of the stage graphs.
pub mod io {
    /// Input graph: descriptors `[N, input_dim]`.
    pub const DESC: &str = "descriptors";
    /// Input graph: normalised keypoints `[N, 2]`.
    pub const KPTS: &str = "keypoints";
    /// Input graph output / layer input: projected descriptors `[N, dim]`.
    pub const STATE: &str = "state";
    /// Rotary cosines `[N, hd/2]`.
    pub const COS: &str = "cos";
    /// Rotary sines `[N, hd/2]`.
    pub const SIN: &str = "sin";
    /// Layer and assignment graphs: per-image names get a `0`/`1` suffix.
    pub fn side(name: &str, s: usize) -> String {
        format!("{name}{s}")
    }
    /// Layer output: updated state (graph outputs cannot reuse input names).
    pub const NEXT: &str = "next_state";
    /// Layer output: `[N, 2]` token confidence and matchability.
    pub const HEADS: &str = "heads";
    /// Assignment: best log score per row `[M]`.
    pub const MAX0: &str = "max0";
    /// Assignment: best column per row `[M]`.
    pub const ARG0: &str = "arg0";
    /// Assignment: best row per column `[N]`.
    pub const ARG1: &str = "arg1";
}

/// Input projection and rotary frequencies of one image's points.
pub fn input_graph(sd: &StateDict, a: &Arch, metadata: &[(&str, &str)]) -> Result<Vec<u8>> {
    let mut g = GraphBuilder::new("lightglue_input");
    for (k, v) in metadata {
        g.metadata(k, v);
    }
    let n = Dim::from("N");
    let desc = g.input_f32(io::DESC, &[n.clone(), a.input_dim.into()]);
    let kpts = g.input_f32(io::KPTS, &[n.clone(), 2.into()]);
    let state = Lin::from_sd(&mut g, sd, "input_proj")?.apply(&mut g, &desc);
    let wr = &sd.get("posenc.Wr.weight")?.data;
    let half = a.head_dim() / 2;
    let mut wt = vec![0.0f32; 2 * half];
    for o in 0..half {
        for i in 0..2 {
            wt[i * half + o] = wr[o * 2 + i];
        }
    }
    let w = g.tensor_named("posenc.Wr.weight.T", &[2, half], &wt);
    let proj = g.op("MatMul", &[&kpts, &w], &[]);
    let cos = g.unary("Cos", &proj);
    let sin = g.unary("Sin", &proj);
    g.output_f32(&state, io::STATE, &[n.clone(), a.dim.into()]);
    g.output_f32(&cos, io::COS, &[n.clone(), half.into()]);
    g.output_f32(&sin, io::SIN, &[n, half.into()]);
    Ok(g.to_bytes())
}

/// Transformer layer `i` on both images; all but the last layer also output the heads.
pub fn layer_graph(sd: &StateDict, a: &Arch, i: usize) -> Result<Vec<u8>> {
    let mut g = GraphBuilder::new(&format!("lightglue_layer{i}"));
    let half = a.head_dim() / 2;
    let mut x = Vec::new();
    let mut enc = Vec::new();
    for s in 0..2 {
        let n = Dim::from(if s == 0 { "M" } else { "N" });
        x.push(g.input_f32(&io::side(io::STATE, s), &[n.clone(), a.dim.into()]));
        let c = g.input_f32(&io::side(io::COS, s), &[n.clone(), half.into()]);
        let sn = g.input_f32(&io::side(io::SIN, s), &[n, half.into()]);
        enc.push((c, sn));
    }
    let sb = SelfBlock::new(&mut g, sd, i, a)?;
    let cb = CrossBlock::new(&mut g, sd, i, a)?;
    let heads = if i + 1 < a.n_layers {
        Some(heads_lin(&mut g, sd, i, a.dim)?)
    } else {
        None
    };
    let y0 = sb.apply(&mut g, &x[0], &enc[0].0, &enc[0].1, a);
    let y1 = sb.apply(&mut g, &x[1], &enc[1].0, &enc[1].1, a);
    let (z0, z1) = cb.apply(&mut g, &y0, &y1, a);
    for (s, z) in [(0, &z0), (1, &z1)] {
        let n = Dim::from(if s == 0 { "M" } else { "N" });
        g.output_f32(z, &io::side(io::NEXT, s), &[n.clone(), a.dim.into()]);
        if let Some(h) = &heads {
            let y = h.apply(&mut g, z);
            let y = g.unary("Sigmoid", &y);
            g.output_f32(&y, &io::side(io::HEADS, s), &[n, 2.into()]);
        }
    }
    Ok(g.to_bytes())
}

/// Log assignment of layer `i`, reduced to what `filter_matches` reads.
pub fn assignment_graph(sd: &StateDict, a: &Arch, i: usize) -> Result<Vec<u8>> {
    let mut g = GraphBuilder::new(&format!("lightglue_assignment{i}"));
    let (m, n) = (Dim::from("M"), Dim::from("N"));
    let x0 = g.input_f32(&io::side(io::STATE, 0), &[m.clone(), a.dim.into()]);
    let x1 = g.input_f32(&io::side(io::STATE, 1), &[n.clone(), a.dim.into()]);
    let p = format!("log_assignment.{i}");
    let root = g.scalar_f32((a.dim as f64).powf(0.25) as f32);
    let fp = Lin::from_sd(&mut g, sd, &format!("{p}.final_proj"))?;
    let ma = Lin::from_sd(&mut g, sd, &format!("{p}.matchability"))?;
    let md0 = fp.apply(&mut g, &x0);
    let md0 = g.op("Div", &[&md0, &root], &[]);
    let md1 = fp.apply(&mut g, &x1);
    let md1 = g.op("Div", &[&md1, &root], &[]);
    let md1t = g.transpose(&md1, &[1, 0]);
    let sim = g.op("MatMul", &[&md0, &md1t], &[]);
    let z0 = ma.apply(&mut g, &x0);
    let z1 = ma.apply(&mut g, &x1);
    // logsigmoid(z) = -softplus(-z).
    let logsig = |g: &mut GraphBuilder, z: &Var| {
        let nz = g.unary("Neg", z);
        let sp = g.unary("Softplus", &nz);
        g.unary("Neg", &sp)
    };
    let c0 = logsig(&mut g, &z0); // [M, 1]
    let c1 = logsig(&mut g, &z1); // [N, 1]
    let c1t = g.transpose(&c1, &[1, 0]);
    let s0 = g.op("LogSoftmax", &[&sim], &[Attr::Int("axis", 1)]);
    let s1 = g.op("LogSoftmax", &[&sim], &[Attr::Int("axis", 0)]);
    let scores = g.op("Add", &[&s0, &s1], &[]);
    let certainties = g.op("Add", &[&c0, &c1t], &[]);
    let scores = g.op("Add", &[&scores, &certainties], &[]);
    let axis1 = g.const_i64(&[1]);
    let max0 = g.op("ReduceMax", &[&scores, &axis1], &[Attr::Int("keepdims", 0)]);
    let arg0 = g.op(
        "ArgMax",
        &[&scores],
        &[Attr::Int("axis", 1), Attr::Int("keepdims", 0)],
    );
    let arg1 = g.op(
        "ArgMax",
        &[&scores],
        &[Attr::Int("axis", 0), Attr::Int("keepdims", 0)],
    );
    g.output_f32(&max0, io::MAX0, std::slice::from_ref(&m));
    g.output_i64(&arg0, io::ARG0, &[m]);
    g.output_i64(&arg1, io::ARG1, &[n]);
    Ok(g.to_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pth::Tensor;

    #[test]
    fn old_block_names_are_renamed() {
        assert_eq!(
            rename_old_block("self_attn.3.Wqkv.weight").as_deref(),
            Some("transformers.3.self_attn.Wqkv.weight")
        );
        assert_eq!(
            rename_old_block("cross_attn.10.ffn.0.bias").as_deref(),
            Some("transformers.10.cross_attn.ffn.0.bias")
        );
        assert_eq!(rename_old_block("log_assignment.0.r"), None);
        assert_eq!(rename_old_block("self_attn_x.1.a"), None);
    }

    #[test]
    fn qkv_rows_are_a_permutation() {
        let a = Arch {
            input_dim: 4,
            dim: 8,
            heads: 2,
            n_layers: 1,
        };
        let mut seen = [false; 24];
        for h in 0..2 {
            for d in 0..4 {
                for c in 0..3 {
                    let r = qkv_row(h, d, c, &a);
                    assert!(!seen[r]);
                    seen[r] = true;
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        // Even components first inside a head; v untouched.
        assert_eq!(qkv_row(1, 2, 0, &a), 4 + 1);
        assert_eq!(qkv_row(1, 3, 1, &a), 8 + 4 + 2 + 1);
        assert_eq!(qkv_row(1, 3, 2, &a), 16 + 4 + 3);
    }

    #[test]
    fn flops_grow_quadratically_in_attention() {
        let a = Arch {
            input_dim: 128,
            dim: 256,
            heads: 4,
            n_layers: 9,
        };
        let f1 = a.layer_flops(512, 512);
        let f2 = a.layer_flops(1024, 1024);
        assert!(f2 > 2.0 * f1 && f2 < 4.0 * f1);
        // 38·(m+n)·d² + 4(m²+n²)d + 6mnd + heads, at 1024 points: ≈ 8.86 GFLOP.
        assert!((f2 / 1e9 - 8.86).abs() < 0.02, "{}", f2 / 1e9);
    }

    /// A tiny random LightGlue checkpoint in the old (DISK) key spelling.
    fn synthetic(d: usize, hd: usize, layers: usize) -> StateDict {
        let mut t = BTreeMap::new();
        let mut seed = 1u64;
        let mut put = |name: String, shape: &[usize]| {
            let n: usize = shape.iter().product();
            let data = (0..n)
                .map(|_| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1);
                    (seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5
                })
                .collect();
            t.insert(
                name,
                Tensor {
                    shape: shape.to_vec(),
                    data,
                },
            );
        };
        put("input_proj.weight".into(), &[d, 4]);
        put("input_proj.bias".into(), &[d]);
        put("posenc.Wr.weight".into(), &[hd / 2, 2]);
        for i in 0..layers {
            put(format!("self_attn.{i}.Wqkv.weight"), &[3 * d, d]);
            put(format!("self_attn.{i}.Wqkv.bias"), &[3 * d]);
            put(format!("self_attn.{i}.out_proj.weight"), &[d, d]);
            put(format!("self_attn.{i}.out_proj.bias"), &[d]);
            for p in ["to_qk", "to_v", "to_out"] {
                put(format!("cross_attn.{i}.{p}.weight"), &[d, d]);
                put(format!("cross_attn.{i}.{p}.bias"), &[d]);
            }
            for b in ["self_attn", "cross_attn"] {
                put(format!("{b}.{i}.ffn.0.weight"), &[2 * d, 2 * d]);
                put(format!("{b}.{i}.ffn.0.bias"), &[2 * d]);
                put(format!("{b}.{i}.ffn.1.weight"), &[2 * d]);
                put(format!("{b}.{i}.ffn.1.bias"), &[2 * d]);
                put(format!("{b}.{i}.ffn.3.weight"), &[d, 2 * d]);
                put(format!("{b}.{i}.ffn.3.bias"), &[d]);
            }
            put(format!("log_assignment.{i}.matchability.weight"), &[1, d]);
            put(format!("log_assignment.{i}.matchability.bias"), &[1]);
            put(format!("log_assignment.{i}.final_proj.weight"), &[d, d]);
            put(format!("log_assignment.{i}.final_proj.bias"), &[d]);
            if i + 1 < layers {
                put(format!("token_confidence.{i}.token.0.weight"), &[1, d]);
                put(format!("token_confidence.{i}.token.0.bias"), &[1]);
            }
        }
        StateDict::from_tensors("synthetic.pth".into(), t)
    }

    #[test]
    fn arch_is_read_from_weights_and_graphs_build() {
        let sd = canonical_weights(&synthetic(8, 4, 2));
        let a = read_arch(&sd).unwrap();
        assert_eq!(
            a,
            Arch {
                input_dim: 4,
                dim: 8,
                heads: 2,
                n_layers: 2
            }
        );
        assert!(!input_graph(&sd, &a, &[]).unwrap().is_empty());
        for i in 0..2 {
            assert!(!layer_graph(&sd, &a, i).unwrap().is_empty());
            assert!(!assignment_graph(&sd, &a, i).unwrap().is_empty());
        }
    }

    #[test]
    fn bad_or_missing_weights_are_errors() {
        let raw = synthetic(8, 4, 2);
        let mut t: BTreeMap<String, Tensor> = raw
            .names()
            .map(|n| (n.to_owned(), raw.get(n).unwrap().clone()))
            .collect();
        t.insert(
            "cross_attn.1.to_v.weight".into(),
            Tensor {
                shape: vec![8, 7],
                data: vec![0.0; 56],
            },
        );
        let sd = canonical_weights(&StateDict::from_tensors("bad.pth".into(), t.clone()));
        match read_arch(&sd) {
            Err(FeaturesError::WeightShape { name, found, .. }) => {
                assert_eq!(name, "transformers.1.cross_attn.to_v.weight");
                assert_eq!(found, vec![8, 7]);
            }
            other => panic!("expected a shape error, got {other:?}"),
        }
        t.remove("cross_attn.1.to_v.weight");
        let sd = canonical_weights(&StateDict::from_tensors("bad.pth".into(), t));
        assert!(matches!(
            read_arch(&sd),
            Err(FeaturesError::MissingWeight { .. })
        ));
    }
}
