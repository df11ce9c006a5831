//! onnxruntime as an optional engine (cargo feature `ort`): bound at run time to the
//! `libonnxruntime.so` named by `ORT_DYLIB_PATH` (the onnxruntime PyPI wheel ships one in
//! `onnxruntime/capi/`), so the build downloads nothing and the binary does not need it.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use ort::session::builder::GraphOptimizationLevel;
use ort::session::Session;
use ort::value::Tensor as OrtTensor;

use super::{check_names, Engine, EngineError, ModelSource, Plan, Tensor};

const NAME: &str = "ort";

static ENVIRONMENT: OnceLock<Result<ort::environment::Environment, String>> = OnceLock::new();

fn environment() -> Result<&'static ort::environment::Environment, EngineError> {
    let env = ENVIRONMENT.get_or_init(|| {
        let path = std::env::var_os("ORT_DYLIB_PATH").filter(|p| !p.is_empty()).ok_or_else(|| {
            "set ORT_DYLIB_PATH to a libonnxruntime.so (the onnxruntime wheel has one in onnxruntime/capi/)"
                .to_owned()
        })?;
        let path = PathBuf::from(path);
        if !path.is_file() {
            return Err(format!("ORT_DYLIB_PATH {} is not a file", path.display()));
        }
        ort::init_from(&path)
            .map_err(|e| format!("cannot load {}: {e}", path.display()))?
            .with_name("reshader")
            .build()
            .map_err(|e| e.to_string())
    });
    env.as_ref().map_err(|message| EngineError::Load {
        engine: NAME,
        path: PathBuf::from("libonnxruntime"),
        message: message.clone(),
    })
}

pub struct OrtEngine {
    threads: usize,
}

impl OrtEngine {
    pub fn new(threads: usize) -> Result<Self, EngineError> {
        environment()?;
        Ok(Self {
            threads: threads.max(1),
        })
    }
}

impl Engine for OrtEngine {
    fn name(&self) -> &'static str {
        NAME
    }

    fn threads(&self) -> usize {
        self.threads
    }

    fn plan(
        &self,
        model: ModelSource<'_>,
        shapes: &[(&str, Vec<usize>)],
        outputs: &[&str],
    ) -> Result<Arc<dyn Plan>, EngineError> {
        let load = |e: ort::Error| EngineError::Load {
            engine: NAME,
            path: model.path.to_owned(),
            message: e.to_string(),
        };
        let session = Session::builder(environment()?)
            .map_err(load)?
            .with_optimization_level(GraphOptimizationLevel::Level3)
            .map_err(|e| load(e.into()))?
            .with_intra_threads(self.threads)
            .map_err(|e| load(e.into()))?
            .commit_from_memory(model.bytes)
            .map_err(load)?;
        let inputs: Vec<String> = session
            .inputs()
            .iter()
            .map(|i| i.name().to_owned())
            .collect();
        let graph_outputs: Vec<String> = session
            .outputs()
            .iter()
            .map(|o| o.name().to_owned())
            .collect();
        let wanted: Vec<&str> = shapes.iter().map(|(n, _)| *n).collect();
        check_names(model.path, "inputs", &inputs, &wanted)?;
        check_names(model.path, "outputs", &graph_outputs, outputs)?;
        Ok(Arc::new(OrtPlan {
            path: model.path.to_owned(),
            outputs: outputs.iter().map(|s| s.to_string()).collect(),
            session: Mutex::new(session),
        }))
    }
}

struct OrtPlan {
    path: PathBuf,
    outputs: Vec<String>,
    session: Mutex<Session>,
}

impl Plan for OrtPlan {
    fn run(&self, inputs: &[(&str, &Tensor)]) -> Result<Vec<Tensor>, EngineError> {
        let run = |e: ort::Error| run_error(&self.path, e);
        let mut feed = Vec::with_capacity(inputs.len());
        for (name, t) in inputs {
            let value = OrtTensor::from_array((t.shape.clone(), t.data.clone())).map_err(run)?;
            feed.push((name.to_string(), value));
        }
        let mut session = self.session.lock().unwrap_or_else(|p| p.into_inner());
        let outputs = session.run(feed).map_err(run)?;
        self.outputs
            .iter()
            .map(|name| {
                let value = &outputs[name.as_str()];
                let (shape, data) = value.try_extract_tensor::<f32>().map_err(run)?;
                let shape = shape.iter().map(|&d| d as usize).collect();
                Ok(Tensor::new(shape, data.to_vec()))
            })
            .collect()
    }
}

fn run_error(path: &Path, e: ort::Error) -> EngineError {
    EngineError::Run {
        engine: NAME,
        path: path.to_owned(),
        message: e.to_string(),
    }
}
