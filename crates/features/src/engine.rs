//! Running ONNX graphs. [`Engine`] is the seam between networks and runtimes; [`OrtEngine`]
//! runs them on ONNX Runtime, loaded at run time from the shared library that
//! `jointloc models fetch` installs (nothing is downloaded or linked at build time).

use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use serde::{Deserialize, Serialize};

use crate::error::{FeaturesError, Result};

/// Element data of a tensor.
#[derive(Debug, Clone, PartialEq)]
pub enum TensorData {
    F32(Vec<f32>),
    I64(Vec<i64>),
    Bool(Vec<bool>),
}

/// A dense row-major tensor passed to or returned by a network.
#[derive(Debug, Clone, PartialEq)]
pub struct NetTensor {
    pub shape: Vec<usize>,
    pub data: TensorData,
}

impl NetTensor {
    /// A float tensor; `data.len()` must equal the product of `shape`.
    pub fn f32(shape: &[usize], data: Vec<f32>) -> Self {
        debug_assert_eq!(shape.iter().product::<usize>(), data.len());
        Self {
            shape: shape.to_vec(),
            data: TensorData::F32(data),
        }
    }

    /// An int64 tensor.
    pub fn i64(shape: &[usize], data: Vec<i64>) -> Self {
        Self {
            shape: shape.to_vec(),
            data: TensorData::I64(data),
        }
    }

    /// The float values, or an error naming the tensor if it is not float.
    pub fn as_f32(&self, what: &str) -> Result<&[f32]> {
        match &self.data {
            TensorData::F32(v) => Ok(v),
            _ => Err(FeaturesError::Engine(format!(
                "output {what} is not float32"
            ))),
        }
    }

    /// The int64 values, or an error naming the tensor if it is not int64.
    pub fn as_i64(&self, what: &str) -> Result<&[i64]> {
        match &self.data {
            TensorData::I64(v) => Ok(v),
            _ => Err(FeaturesError::Engine(format!("output {what} is not int64"))),
        }
    }
}

/// Named outputs of one run, in the graph's output order.
#[derive(Debug, Clone, Default)]
pub struct Outputs(pub Vec<(String, NetTensor)>);

impl Outputs {
    /// The output called `name`.
    pub fn get(&self, name: &str) -> Result<&NetTensor> {
        self.0
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, t)| t)
            .ok_or_else(|| FeaturesError::Engine(format!("graph has no output `{name}`")))
    }
}

/// Something that runs one compiled graph.
pub trait Engine: Send + Sync + std::fmt::Debug {
    /// Runs the graph on named inputs.
    fn run(&self, inputs: Vec<(&str, NetTensor)>) -> Result<Outputs>;
}

/// Execution settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EngineConfig {
    /// Threads inside one operator. 1 by default so tracking keeps the other core.
    pub intra_threads: usize,
    /// Let ONNX Runtime fuse and constant-fold the graph (level "all"); off only for debugging.
    pub optimize: bool,
}

impl Default for EngineConfig {
    fn default() -> Self {
        Self {
            intra_threads: 1,
            optimize: true,
        }
    }
}

/// The process-wide ONNX Runtime environment: loaded once, from the first library asked for.
static RUNTIME: OnceLock<std::result::Result<(PathBuf, ort::environment::Environment), String>> =
    OnceLock::new();

fn runtime(library: &Path) -> Result<&'static ort::environment::Environment> {
    let state = RUNTIME.get_or_init(|| {
        let load = || -> std::result::Result<_, String> {
            let builder = ort::init_from(library).map_err(|e| e.to_string())?;
            let env = builder
                .with_name("jointloc")
                .build()
                .map_err(|e| e.to_string())?;
            Ok((library.to_owned(), env))
        };
        load()
    });
    match state {
        Ok((loaded, env)) => {
            if loaded != library {
                tracing::warn!(
                    loaded = %loaded.display(),
                    requested = %library.display(),
                    "ONNX Runtime is already loaded from another file; using it"
                );
            }
            Ok(env)
        }
        Err(e) => Err(FeaturesError::Engine(format!(
            "cannot load ONNX Runtime from {}: {e} (run `jointloc models fetch`)",
            library.display()
        ))),
    }
}

/// One graph on ONNX Runtime's CPU execution provider.
#[derive(Debug)]
pub struct OrtEngine {
    session: Mutex<ort::session::Session>,
    label: String,
}

fn ort_err(label: &str) -> impl Fn(ort::Error) -> FeaturesError + '_ {
    move |e| FeaturesError::Engine(format!("{label}: {e}"))
}

impl OrtEngine {
    /// Loads the runtime from `library` (first call only) and compiles `model` (ONNX bytes).
    /// `label` names the graph in errors and logs.
    pub fn new(library: &Path, model: &[u8], label: &str, config: &EngineConfig) -> Result<Self> {
        if config.intra_threads == 0 {
            return Err(FeaturesError::InvalidConfig {
                field: "intra_threads",
                value: "0".into(),
                reason: "at least one thread",
            });
        }
        let env = runtime(library)?;
        let err = |e: ort::Error| FeaturesError::Engine(format!("{label}: {e}"));
        let level = if config.optimize {
            ort::session::builder::GraphOptimizationLevel::Level3
        } else {
            ort::session::builder::GraphOptimizationLevel::Disable
        };
        let mut builder = ort::session::Session::builder(env)
            .map_err(err)?
            .with_optimization_level(level)
            .map_err(|e| err(e.into()))?
            .with_intra_threads(config.intra_threads)
            .map_err(|e| err(e.into()))?
            .with_inter_threads(1)
            .map_err(|e| err(e.into()))?;
        // No spin-waiting: each network has its own pool, and on a small machine shared with
        // the SLAM thread spinning workers take the cores the others need (measured: two
        // threads per network were 2× slower than one with spinning on).
        builder = builder
            .with_intra_op_spinning(false)
            .map_err(|e| err(e.into()))?;
        let session = builder.commit_from_memory(model).map_err(err)?;
        Ok(Self {
            session: Mutex::new(session),
            label: label.into(),
        })
    }
}

impl Engine for OrtEngine {
    fn run(&self, inputs: Vec<(&str, NetTensor)>) -> Result<Outputs> {
        let err = ort_err(&self.label);
        let mut values: Vec<(
            std::borrow::Cow<'_, str>,
            ort::session::SessionInputValue<'_>,
        )> = Vec::with_capacity(inputs.len());
        for (name, t) in inputs {
            let shape: Vec<i64> = t.shape.iter().map(|&d| d as i64).collect();
            let v: ort::value::DynValue = match t.data {
                TensorData::F32(d) => ort::value::Tensor::from_array((shape, d))
                    .map_err(&err)?
                    .into_dyn(),
                TensorData::I64(d) => ort::value::Tensor::from_array((shape, d))
                    .map_err(&err)?
                    .into_dyn(),
                TensorData::Bool(d) => ort::value::Tensor::from_array((shape, d))
                    .map_err(&err)?
                    .into_dyn(),
            };
            values.push((name.into(), v.into()));
        }
        let mut session = self
            .session
            .lock()
            .map_err(|_| FeaturesError::Engine(format!("{}: session poisoned", self.label)))?;
        let outputs = session.run(values).map_err(&err)?;
        let mut out = Vec::with_capacity(outputs.len());
        for (name, value) in outputs.iter() {
            let t = if let Ok((shape, data)) = value.try_extract_tensor::<f32>() {
                NetTensor::f32(&dims(shape), data.to_vec())
            } else if let Ok((shape, data)) = value.try_extract_tensor::<i64>() {
                NetTensor::i64(&dims(shape), data.to_vec())
            } else if let Ok((shape, data)) = value.try_extract_tensor::<bool>() {
                NetTensor {
                    shape: dims(shape),
                    data: TensorData::Bool(data.to_vec()),
                }
            } else {
                return Err(FeaturesError::Engine(format!(
                    "{}: output {name} has an unsupported type",
                    self.label
                )));
            };
            out.push((name.to_string(), t));
        }
        Ok(Outputs(out))
    }
}

fn dims(shape: &ort::value::Shape) -> Vec<usize> {
    shape.iter().map(|&d| d.max(0) as usize).collect()
}
