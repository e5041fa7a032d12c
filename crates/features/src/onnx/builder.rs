//! A small graph builder: network files describe their layers with it, reading weights from a
//! [`StateDict`], and get a standard ONNX model out.
//!
//! Values are named automatically (`conv_12`); weights keep their checkpoint names so a model
//! can be inspected next to the PyTorch code it came from.

use prost::Message;

use super::proto::{
    AttributeProto, Dimension, DimensionValue, GraphProto, ModelProto, NodeProto,
    OperatorSetIdProto, StringStringEntryProto, TensorProto, TensorShapeProto, TypeProto,
    TypeProtoTensor, ValueInfoProto, attribute_type, data_type,
};
use crate::error::Result;
use crate::pth::StateDict;

/// The ONNX opset our graphs target (`LayerNormalization` 17, `GridSample` 16, `DeformConv` 19).
pub const OPSET: i64 = 19;
/// IR version matching [`OPSET`].
pub const IR_VERSION: i64 = 9;

/// A named value in the graph.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Var(String);

impl Var {
    /// The value's name in the graph.
    pub fn name(&self) -> &str {
        &self.0
    }

    /// The empty name ONNX uses for an omitted optional input.
    pub fn none() -> Self {
        Var(String::new())
    }
}

/// One dimension of a graph input or output: fixed or symbolic (`"N"`, `"height"`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Dim {
    Fixed(usize),
    Named(String),
}

impl From<usize> for Dim {
    fn from(v: usize) -> Self {
        Dim::Fixed(v)
    }
}

impl From<&str> for Dim {
    fn from(v: &str) -> Self {
        Dim::Named(v.to_owned())
    }
}

/// An operator attribute.
#[derive(Debug, Clone, PartialEq)]
pub enum Attr {
    Int(&'static str, i64),
    Ints(&'static str, Vec<i64>),
    Float(&'static str, f32),
    Floats(&'static str, Vec<f32>),
    Str(&'static str, String),
}

impl Attr {
    fn to_proto(&self) -> AttributeProto {
        let mut a = AttributeProto::default();
        match self {
            Attr::Int(n, v) => {
                a.name = (*n).into();
                a.r#type = attribute_type::INT;
                a.i = *v;
            }
            Attr::Ints(n, v) => {
                a.name = (*n).into();
                a.r#type = attribute_type::INTS;
                a.ints = v.clone();
            }
            Attr::Float(n, v) => {
                a.name = (*n).into();
                a.r#type = attribute_type::FLOAT;
                a.f = *v;
            }
            Attr::Floats(n, v) => {
                a.name = (*n).into();
                a.r#type = attribute_type::FLOATS;
                a.floats = v.clone();
            }
            Attr::Str(n, v) => {
                a.name = (*n).into();
                a.r#type = attribute_type::STRING;
                a.s = v.as_bytes().to_vec();
            }
        }
        a
    }
}

/// Convolution geometry (PyTorch `Conv2d` arguments).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvOpts {
    pub stride: usize,
    /// Symmetric zero padding on every side.
    pub padding: usize,
    pub dilation: usize,
    pub groups: usize,
}

impl Default for ConvOpts {
    fn default() -> Self {
        Self {
            stride: 1,
            padding: 0,
            dilation: 1,
            groups: 1,
        }
    }
}

impl ConvOpts {
    /// Stride 1 with `padding` on every side.
    pub fn padded(padding: usize) -> Self {
        Self {
            padding,
            ..Self::default()
        }
    }
}

/// Builds one ONNX graph.
#[derive(Debug)]
pub struct GraphBuilder {
    name: String,
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
    inputs: Vec<ValueInfoProto>,
    outputs: Vec<ValueInfoProto>,
    metadata: Vec<(String, String)>,
    counter: usize,
}

fn value_info(name: &str, elem_type: i32, dims: &[Dim]) -> ValueInfoProto {
    let dim = dims
        .iter()
        .map(|d| Dimension {
            value: Some(match d {
                Dim::Fixed(v) => DimensionValue::DimValue(*v as i64),
                Dim::Named(s) => DimensionValue::DimParam(s.clone()),
            }),
        })
        .collect();
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TypeProtoTensor {
                elem_type,
                shape: Some(TensorShapeProto { dim }),
            }),
        }),
    }
}

impl GraphBuilder {
    /// An empty graph called `name`.
    pub fn new(name: &str) -> Self {
        Self {
            name: name.into(),
            nodes: Vec::new(),
            initializers: Vec::new(),
            inputs: Vec::new(),
            outputs: Vec::new(),
            metadata: Vec::new(),
            counter: 0,
        }
    }

    fn fresh(&mut self, prefix: &str) -> String {
        self.counter += 1;
        format!("{}_{}", prefix.to_ascii_lowercase(), self.counter)
    }

    /// Declares a float32 graph input.
    pub fn input_f32(&mut self, name: &str, dims: &[Dim]) -> Var {
        self.inputs.push(value_info(name, data_type::FLOAT, dims));
        Var(name.into())
    }

    /// Declares an int64 graph input.
    pub fn input_i64(&mut self, name: &str, dims: &[Dim]) -> Var {
        self.inputs.push(value_info(name, data_type::INT64, dims));
        Var(name.into())
    }

    /// Declares `v` as a float32 graph output called `name`.
    pub fn output_f32(&mut self, v: &Var, name: &str, dims: &[Dim]) {
        self.output_typed(v, name, data_type::FLOAT, dims);
    }

    /// Declares `v` as an int64 graph output called `name`.
    pub fn output_i64(&mut self, v: &Var, name: &str, dims: &[Dim]) {
        self.output_typed(v, name, data_type::INT64, dims);
    }

    fn output_typed(&mut self, v: &Var, name: &str, elem: i32, dims: &[Dim]) {
        self.nodes.push(NodeProto {
            input: vec![v.0.clone()],
            output: vec![name.into()],
            name: format!("output_{name}"),
            op_type: "Identity".into(),
            ..Default::default()
        });
        self.outputs.push(value_info(name, elem, dims));
    }

    /// Records a `key = value` pair in the model's metadata (weights hash, settings).
    pub fn metadata(&mut self, key: &str, value: &str) {
        self.metadata.push((key.into(), value.into()));
    }

    /// A float32 initializer with an explicit name (must be unique).
    pub fn tensor_named(&mut self, name: &str, shape: &[usize], data: &[f32]) -> Var {
        debug_assert_eq!(shape.iter().product::<usize>(), data.len());
        self.initializers.push(TensorProto {
            dims: shape.iter().map(|&d| d as i64).collect(),
            data_type: data_type::FLOAT,
            name: name.into(),
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        });
        Var(name.into())
    }

    /// A float32 constant.
    pub fn tensor_f32(&mut self, shape: &[usize], data: &[f32]) -> Var {
        let name = self.fresh("const");
        self.tensor_named(&name, shape, data)
    }

    /// A float32 scalar constant.
    pub fn scalar_f32(&mut self, v: f32) -> Var {
        self.tensor_f32(&[], &[v])
    }

    /// A 1-D int64 constant (shapes, axes, indices).
    pub fn const_i64(&mut self, data: &[i64]) -> Var {
        let name = self.fresh("const");
        self.initializers.push(TensorProto {
            dims: vec![data.len() as i64],
            data_type: data_type::INT64,
            name: name.clone(),
            raw_data: data.iter().flat_map(|v| v.to_le_bytes()).collect(),
        });
        Var(name)
    }

    /// An int64 scalar constant.
    pub fn scalar_i64(&mut self, v: i64) -> Var {
        let name = self.fresh("const");
        self.initializers.push(TensorProto {
            dims: vec![],
            data_type: data_type::INT64,
            name: name.clone(),
            raw_data: v.to_le_bytes().to_vec(),
        });
        Var(name)
    }

    /// A checkpoint tensor as an initializer named after its key (added once).
    pub fn weight(&mut self, sd: &StateDict, key: &str) -> Result<Var> {
        if self.initializers.iter().any(|t| t.name == key) {
            return Ok(Var(key.into()));
        }
        let t = sd.get(key)?;
        Ok(self.tensor_named(key, &t.shape.clone(), &t.data.clone()))
    }

    /// Like [`Self::weight`], checking the shape first.
    pub fn weight_shaped(&mut self, sd: &StateDict, key: &str, shape: &[usize]) -> Result<Var> {
        sd.get_shaped(key, shape)?;
        self.weight(sd, key)
    }

    /// A node with one output.
    pub fn op(&mut self, op_type: &str, inputs: &[&Var], attrs: &[Attr]) -> Var {
        self.op_n(op_type, inputs, attrs, 1)
            .pop()
            .expect("one output")
    }

    /// A node with `n` outputs.
    pub fn op_n(&mut self, op_type: &str, inputs: &[&Var], attrs: &[Attr], n: usize) -> Vec<Var> {
        let base = self.fresh(op_type);
        let outputs: Vec<String> = if n == 1 {
            vec![base.clone()]
        } else {
            (0..n).map(|i| format!("{base}_{i}")).collect()
        };
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|v| v.0.clone()).collect(),
            output: outputs.clone(),
            name: base,
            op_type: op_type.into(),
            attribute: attrs.iter().map(Attr::to_proto).collect(),
            ..Default::default()
        });
        outputs.into_iter().map(Var).collect()
    }

    /// The finished model.
    pub fn finish(self) -> ModelProto {
        ModelProto {
            ir_version: IR_VERSION,
            opset_import: vec![OperatorSetIdProto {
                domain: String::new(),
                version: OPSET,
            }],
            producer_name: "jointloc".into(),
            producer_version: env!("CARGO_PKG_VERSION").into(),
            graph: Some(GraphProto {
                node: self.nodes,
                name: self.name,
                initializer: self.initializers,
                input: self.inputs,
                output: self.outputs,
                ..Default::default()
            }),
            metadata_props: self
                .metadata
                .into_iter()
                .map(|(key, value)| StringStringEntryProto { key, value })
                .collect(),
            ..Default::default()
        }
    }

    /// The finished model, serialised as an `.onnx` file's bytes.
    pub fn to_bytes(self) -> Vec<u8> {
        self.finish().encode_to_vec()
    }
}
