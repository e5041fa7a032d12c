//! ONNX graphs written from Rust: the schema subset ([`proto`]), a builder ([`GraphBuilder`]) and
//! PyTorch-like layers on top of it.

mod builder;
mod layers;
pub mod proto;

pub use builder::{Attr, ConvOpts, Dim, GraphBuilder, IR_VERSION, OPSET, Var};
