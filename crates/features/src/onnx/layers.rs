//! PyTorch layers expressed with [`GraphBuilder`] nodes, so network files read like the
//! modules they port.

use super::builder::{Attr, ConvOpts, GraphBuilder, Var};
use crate::error::{FeaturesError, Result};
use crate::pth::StateDict;

impl GraphBuilder {
    /// `nn.Conv2d` with weights `{prefix}.weight` and, if present, `{prefix}.bias`.
    pub fn conv2d(&mut self, x: &Var, sd: &StateDict, prefix: &str, o: ConvOpts) -> Result<Var> {
        let w = self.weight(sd, &format!("{prefix}.weight"))?;
        let shape = sd.get(&format!("{prefix}.weight"))?.shape.clone();
        if shape.len() != 4 {
            return Err(FeaturesError::WeightShape {
                name: format!("{prefix}.weight"),
                expected: vec![0, 0, 0, 0],
                found: shape,
            });
        }
        let bias_key = format!("{prefix}.bias");
        let b = if sd.contains(&bias_key) {
            Some(self.weight(sd, &bias_key)?)
        } else {
            None
        };
        let p = o.padding as i64;
        let attrs = [
            Attr::Ints("kernel_shape", vec![shape[2] as i64, shape[3] as i64]),
            Attr::Ints("strides", vec![o.stride as i64; 2]),
            Attr::Ints("pads", vec![p; 4]),
            Attr::Ints("dilations", vec![o.dilation as i64; 2]),
            Attr::Int("group", o.groups as i64),
        ];
        Ok(match &b {
            Some(b) => self.op("Conv", &[x, &w, b], &attrs),
            None => self.op("Conv", &[x, &w], &attrs),
        })
    }

    /// `nn.BatchNorm2d` in eval mode; `affine=False` checkpoints (no weight/bias) get 1 and 0.
    pub fn batch_norm(&mut self, x: &Var, sd: &StateDict, prefix: &str, eps: f32) -> Result<Var> {
        let mean_key = format!("{prefix}.running_mean");
        let n = sd.get(&mean_key)?.numel();
        let mean = self.weight(sd, &mean_key)?;
        let var = self.weight(sd, &format!("{prefix}.running_var"))?;
        let (wk, bk) = (format!("{prefix}.weight"), format!("{prefix}.bias"));
        let scale = if sd.contains(&wk) {
            self.weight(sd, &wk)?
        } else {
            self.tensor_f32(&[n], &vec![1.0; n])
        };
        let bias = if sd.contains(&bk) {
            self.weight(sd, &bk)?
        } else {
            self.tensor_f32(&[n], &vec![0.0; n])
        };
        Ok(self.op(
            "BatchNormalization",
            &[x, &scale, &bias, &mean, &var],
            &[Attr::Float("epsilon", eps)],
        ))
    }

    /// `nn.Linear` on the last axis: `x @ Wᵀ + b`, with Wᵀ stored pre-transposed.
    pub fn linear(&mut self, x: &Var, sd: &StateDict, prefix: &str) -> Result<Var> {
        let wk = format!("{prefix}.weight");
        let t = sd.get(&wk)?;
        let [out, inp] = t.shape[..] else {
            return Err(FeaturesError::WeightShape {
                name: wk,
                expected: vec![0, 0],
                found: t.shape.clone(),
            });
        };
        let mut wt = vec![0.0f32; out * inp];
        for o in 0..out {
            for i in 0..inp {
                wt[i * out + o] = t.data[o * inp + i];
            }
        }
        let w = self.tensor_named(&format!("{wk}.T"), &[inp, out], &wt);
        let y = self.op("MatMul", &[x, &w], &[]);
        let bk = format!("{prefix}.bias");
        if sd.contains(&bk) {
            let b = self.weight(sd, &bk)?;
            Ok(self.op("Add", &[&y, &b], &[]))
        } else {
            Ok(y)
        }
    }

    /// `nn.LayerNorm` over the last axis (elementwise affine).
    pub fn layer_norm(&mut self, x: &Var, sd: &StateDict, prefix: &str, eps: f32) -> Result<Var> {
        let w = self.weight(sd, &format!("{prefix}.weight"))?;
        let b = self.weight(sd, &format!("{prefix}.bias"))?;
        Ok(self.op(
            "LayerNormalization",
            &[x, &w, &b],
            &[Attr::Int("axis", -1), Attr::Float("epsilon", eps)],
        ))
    }

    /// Elementwise unary op (`Relu`, `Sigmoid`, `Exp`, `Sqrt`, ...).
    pub fn unary(&mut self, op: &str, x: &Var) -> Var {
        self.op(op, &[x], &[])
    }

    /// `ReLU`.
    pub fn relu(&mut self, x: &Var) -> Var {
        self.unary("Relu", x)
    }

    /// Elementwise binary op with broadcasting (`Add`, `Sub`, `Mul`, `Div`, `Pow`).
    pub fn binary(&mut self, op: &str, a: &Var, b: &Var) -> Var {
        self.op(op, &[a, b], &[])
    }

    /// `x.reshape(shape)`; `0` copies a dimension, `-1` infers one.
    pub fn reshape(&mut self, x: &Var, shape: &[i64]) -> Var {
        let s = self.const_i64(shape);
        self.op("Reshape", &[x, &s], &[])
    }

    /// `x.permute(perm)`.
    pub fn transpose(&mut self, x: &Var, perm: &[i64]) -> Var {
        self.op("Transpose", &[x], &[Attr::Ints("perm", perm.to_vec())])
    }

    /// `torch.cat(xs, axis)`.
    pub fn concat(&mut self, xs: &[&Var], axis: i64) -> Var {
        self.op("Concat", xs, &[Attr::Int("axis", axis)])
    }

    /// `softmax(x, axis)`.
    pub fn softmax(&mut self, x: &Var, axis: i64) -> Var {
        self.op("Softmax", &[x], &[Attr::Int("axis", axis)])
    }

    /// `F.max_pool2d` with a square kernel.
    pub fn max_pool(&mut self, x: &Var, kernel: usize, stride: usize, padding: usize) -> Var {
        let (k, s, p) = (kernel as i64, stride as i64, padding as i64);
        self.op(
            "MaxPool",
            &[x],
            &[
                Attr::Ints("kernel_shape", vec![k, k]),
                Attr::Ints("strides", vec![s, s]),
                Attr::Ints("pads", vec![p; 4]),
            ],
        )
    }

    /// `F.avg_pool2d` with a square kernel (padding counted as PyTorch does by default).
    pub fn avg_pool(&mut self, x: &Var, kernel: usize, stride: usize) -> Var {
        let (k, s) = (kernel as i64, stride as i64);
        self.op(
            "AveragePool",
            &[x],
            &[
                Attr::Ints("kernel_shape", vec![k, k]),
                Attr::Ints("strides", vec![s, s]),
            ],
        )
    }

    /// `x[..., start:end]` along `axis`.
    pub fn slice(&mut self, x: &Var, axis: i64, start: i64, end: i64) -> Var {
        let s = self.const_i64(&[start]);
        let e = self.const_i64(&[end]);
        let a = self.const_i64(&[axis]);
        self.op("Slice", &[x, &s, &e, &a], &[])
    }
}
