//! The default engine: tract, pure Rust. Each plan is the graph optimised for one set of
//! concrete input shapes; runs use a private rayon pool for tract's matrix products.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use tract_onnx::prelude::multithread::{multithread_tract_scope, Executor};
use tract_onnx::prelude::*;
use tract_onnx::tract_core::plan::SimpleState;

use super::{
    check_names, fp16, int8, octaves, pool, sine, transpose, Engine, EngineError, ModelSource,
    Plan, Tensor,
};
use crate::engine::manifest::Precision;

const NAME: &str = "tract";

pub struct TractEngine {
    threads: usize,
    executor: Executor,
}

/// tract 0.23.9's AMX int8 kernels crash now and then on Intel CPUs that have AMX
/// (SIGSEGV at a `tileloadd` on a worker thread: about one run in six of the int8 depth
/// network on this project's machines), so they are left out of tract's kernel pool
/// before any plan picks its kernels. This is a default below the environment: a user's
/// own `TRACT_CPU_ISA` still wins. AMX is x86_64's alone, and tract refuses (panics on)
/// an x86 token on another architecture, so on ARM boards there is nothing to set.
fn avoid_amx_kernels() {
    if !cfg!(target_arch = "x86_64") {
        return;
    }
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if let Err(e) =
            tract_onnx::tract_core::knobs::set_config_global("TRACT_CPU_ISA", "-amx-int8,-amx-bf16")
        {
            log::warn!("could not take tract's AMX kernels out: {e}");
        }
    });
}

impl TractEngine {
    pub fn new(threads: usize) -> Self {
        avoid_amx_kernels();
        let threads = threads.max(1);
        let executor = if threads > 1 {
            Executor::multithread_with_name(threads, "reshader-tract")
        } else {
            Executor::SingleThread
        };
        Self { threads, executor }
    }
}

impl Engine for TractEngine {
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
        let plan = guarded(model.path, || {
            TractPlan::new(
                model.path,
                optimized(model, shapes, outputs)?,
                &self.executor,
            )
        })?;
        Ok(Arc::new(plan))
    }
}

impl TractEngine {
    /// Milliseconds spent per operator type in one run of the optimised graph (after a
    /// warm-up run), largest first: where tract spends its time on our graphs.
    pub fn profile(
        &self,
        model: ModelSource<'_>,
        inputs: &[(&str, &Tensor)],
        outputs: &[&str],
    ) -> Result<Vec<(String, f64)>, EngineError> {
        let shapes: Vec<(&str, Vec<usize>)> =
            inputs.iter().map(|(n, t)| (*n, t.shape.clone())).collect();
        let plan = TractPlan::new(
            model.path,
            optimized(model, &shapes, outputs)?,
            &self.executor,
        )?;
        let run = |e: TractError| run_error(model.path, e);
        let mut times: std::collections::HashMap<String, f64> = Default::default();
        for pass in 0..2 {
            let values = plan.values(inputs)?;
            let mut state = SimpleState::new(&plan.runnable).map_err(run)?;
            multithread_tract_scope(self.executor.clone(), || {
                state.run_plan_with_eval(values, |ctx, op_state, node, input| {
                    let started = std::time::Instant::now();
                    let out = tract_onnx::tract_core::plan::eval(ctx, op_state, node, input);
                    if pass == 1 {
                        *times.entry(node.op.name().to_string()).or_default() +=
                            started.elapsed().as_secs_f64() * 1e3;
                    }
                    out
                })
            })
            .map_err(run)?;
        }
        let mut sorted: Vec<(String, f64)> = times.into_iter().collect();
        sorted.sort_by(|a, b| b.1.total_cmp(&a.1));
        Ok(sorted)
    }
}

/// Runs a loading step, turning a panic inside tract into a load error: tract panics on
/// some malformed graphs (fuzzing found a graph output that no node produces), and a
/// corrupt model file must give an error naming it, not abort the run.
fn guarded<T>(
    path: &Path,
    step: impl FnOnce() -> Result<T, EngineError>,
) -> Result<T, EngineError> {
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(step)).unwrap_or_else(|panic| {
        let reason = crate::io::limits::panic_text(&*panic);
        // tract panics when an allocation fails (the kernel holds the heap to
        // --max-memory): that is the ceiling, not a broken model.
        let message = if crate::io::limits::is_out_of_memory(reason) {
            crate::io::limits::OutOfMemory::now(" while loading it").to_string()
        } else {
            format!("the graph is malformed (tract failed: {reason})")
        };
        Err(EngineError::Load {
            engine: NAME,
            path: path.to_owned(),
            message,
        })
    })
}

/// tract sizes a buffer by the largest entry of a Transpose's `perm` before checking that
/// it is a permutation (fuzzing: one entry of 2^26 made it allocate 512 MiB), so such
/// graphs are refused first.
fn check_transposes(model: &tract_onnx::pb::ModelProto) -> Result<(), String> {
    let nodes = model.graph.iter().flat_map(|g| &g.node);
    for node in nodes.filter(|n| n.op_type == "Transpose") {
        let Some(perm) = node.attribute.iter().find(|a| a.name == "perm") else {
            continue;
        };
        let mut seen = vec![false; perm.ints.len()];
        for &axis in &perm.ints {
            match usize::try_from(axis).ok().and_then(|a| seen.get_mut(a)) {
                Some(slot) if !*slot => *slot = true,
                _ => {
                    return Err(format!(
                        "the graph is malformed: Transpose node {:?} has perm {:?}, not a \
                         permutation of its axes",
                        node.name, perm.ints
                    ))
                }
            }
        }
    }
    Ok(())
}

fn load_error(path: &Path, e: TractError) -> EngineError {
    EngineError::Load {
        engine: NAME,
        path: path.to_owned(),
        message: format!("{e:#}"),
    }
}

/// The graph optimised for `shapes`, its input names in graph order, and where each
/// requested output sits among the graph's outputs; `transposed` when it runs on tall
/// inputs with their image axes swapped (see [`transpose`]).
fn optimized(
    model: ModelSource<'_>,
    shapes: &[(&str, Vec<usize>)],
    outputs: &[&str],
) -> Result<Optimized, EngineError> {
    let load = |e: TractError| load_error(model.path, e);
    let onnx = tract_onnx::onnx();
    let mut proto = onnx
        .proto_model_for_read(&mut &*model.bytes)
        .map_err(load)?;
    check_transposes(&proto).map_err(|message| EngineError::Load {
        engine: NAME,
        path: model.path.to_owned(),
        message,
    })?;
    if model.precision == Precision::Fp16 {
        let n = fp16::widen_to_f32(&mut proto);
        log::debug!("{}: widened {n} fp16 tensors to f32", model.path.display());
    }
    if model.precision == Precision::Int8 {
        let rewrite_error = |message| EngineError::Load {
            engine: NAME,
            path: model.path.to_owned(),
            message,
        };
        let n = int8::fold_weight_dequantization(&mut proto).map_err(rewrite_error)?;
        log::debug!(
            "{}: folded {n} int8 weight tensors to f32",
            model.path.display()
        );
        let n = int8::unfuse_qlinear_convs(&mut proto).map_err(rewrite_error)?;
        log::debug!(
            "{}: {n} QLinearConv nodes run as float convolutions between their quantisation points",
            model.path.display()
        );
        let n = int8::fake_quantize_activations(&mut proto).map_err(rewrite_error)?;
        log::debug!(
            "{}: {n} QuantizeLinear/DequantizeLinear pairs run as float rounding",
            model.path.display()
        );
    }
    // After the int8 rewrites: a pool's channels are read from float weights.
    let n = octaves::double_angle_octaves(&mut proto);
    log::debug!(
        "{}: {n} frequency-encoding octaves computed from the octave below",
        model.path.display()
    );
    let n = sine::polynomial_sines(&mut proto);
    log::debug!(
        "{}: {n} Sin/Cos nodes evaluated as polynomials",
        model.path.display()
    );
    let n = pool::average_pools_as_depthwise(&mut proto);
    log::debug!(
        "{}: {n} average pools run as depthwise convolutions",
        model.path.display()
    );
    let transposed = transpose::tall(shapes)
        && match transpose::axes_swapped(&proto) {
            Ok(swapped) => {
                proto = swapped;
                true
            }
            Err(why) => {
                log::debug!(
                    "{}: tall inputs run as they are: {why}",
                    model.path.display()
                );
                false
            }
        };
    let mut graph = onnx.model_for_proto_model(&proto).map_err(load)?;
    let names = input_names(&graph).map_err(load)?;
    let wanted: Vec<&str> = shapes.iter().map(|(n, _)| *n).collect();
    check_names(model.path, "inputs", &names, &wanted)?;
    for (ix, name) in names.iter().enumerate() {
        let shape = &shapes
            .iter()
            .find(|(n, _)| n == name)
            .expect("names checked")
            .1;
        let shape = if transposed {
            transpose::swapped_shape(shape)
        } else {
            shape.clone()
        };
        graph
            .set_input_fact(ix, f32::fact(shape).into())
            .map_err(load)?;
    }
    let graph_outputs = output_names(&graph).map_err(load)?;
    check_names(model.path, "outputs", &graph_outputs, outputs)?;
    let order = outputs
        .iter()
        .map(|o| {
            graph_outputs
                .iter()
                .position(|g| g == o)
                .expect("names checked")
        })
        .collect();
    let typed = graph.into_optimized().map_err(load)?;
    Ok(Optimized {
        typed,
        inputs: names,
        order,
        transposed,
    })
}

struct Optimized {
    typed: TypedModel,
    inputs: Vec<String>,
    order: Vec<usize>,
    transposed: bool,
}

fn input_names(graph: &InferenceModel) -> TractResult<Vec<String>> {
    Ok(graph
        .input_outlets()?
        .iter()
        .map(|o| graph.node(o.node).name.clone())
        .collect())
}

fn output_names(graph: &InferenceModel) -> TractResult<Vec<String>> {
    Ok(graph
        .output_outlets()?
        .iter()
        .map(|&o| {
            graph
                .outlet_label(o)
                .map_or_else(|| graph.node(o.node).name.clone(), str::to_owned)
        })
        .collect())
}

struct TractPlan {
    path: PathBuf,
    inputs: Vec<String>,
    order: Vec<usize>,
    /// Inputs and outputs have their image axes swapped on the way in and out.
    transposed: bool,
    runnable: Arc<TypedRunnableModel>,
    executor: Executor,
}

impl TractPlan {
    fn new(path: &Path, optimized: Optimized, executor: &Executor) -> Result<Self, EngineError> {
        let runnable = optimized
            .typed
            .into_runnable()
            .map_err(|e| load_error(path, e))?;
        Ok(TractPlan {
            path: path.to_owned(),
            inputs: optimized.inputs,
            order: optimized.order,
            transposed: optimized.transposed,
            runnable,
            executor: executor.clone(),
        })
    }

    fn values(&self, inputs: &[(&str, &Tensor)]) -> Result<TVec<TValue>, EngineError> {
        let run = |e: TractError| run_error(&self.path, e);
        let mut values = TVec::new();
        for name in &self.inputs {
            let (_, t) = inputs
                .iter()
                .find(|(n, _)| n == name)
                .ok_or_else(|| run(TractError::msg(format!("input {name:?} was not given"))))?;
            let tensor = if self.transposed {
                let (shape, data) = transpose::image_axes_swapped(&t.shape, &t.data);
                tract_onnx::prelude::Tensor::from_shape(&shape, &data)
            } else {
                tract_onnx::prelude::Tensor::from_shape(&t.shape, &t.data)
            };
            values.push(tensor.map_err(run)?.into_tvalue());
        }
        Ok(values)
    }
}

impl Plan for TractPlan {
    fn run(&self, inputs: &[(&str, &Tensor)]) -> Result<Vec<Tensor>, EngineError> {
        let run = |e: TractError| run_error(&self.path, e);
        let values = self.values(inputs)?;
        let outputs = multithread_tract_scope(self.executor.clone(), || self.runnable.run(values))
            .map_err(run)?;
        self.order
            .iter()
            .map(|&ix| {
                let view = outputs[ix].to_plain_array_view::<f32>().map_err(run)?;
                let data: std::borrow::Cow<[f32]> = match view.as_slice() {
                    Some(data) => data.into(),
                    None => view.iter().copied().collect::<Vec<_>>().into(),
                };
                let (shape, data) = if self.transposed {
                    transpose::image_axes_swapped(view.shape(), &data)
                } else {
                    (view.shape().to_vec(), data.into_owned())
                };
                Ok(Tensor::new(shape, data))
            })
            .collect()
    }
}

fn run_error(path: &Path, e: TractError) -> EngineError {
    EngineError::Run {
        engine: NAME,
        path: path.to_owned(),
        message: format!("{e:#}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The graph's outputs as tract computes them with none of the load-time rewrites.
    fn untouched(
        bytes: &[u8],
        shapes: &[(&str, Vec<usize>)],
        inputs: &[Vec<f32>],
    ) -> Vec<Vec<f32>> {
        let mut graph = tract_onnx::onnx().model_for_read(&mut &*bytes).unwrap();
        for (ix, (_, shape)) in shapes.iter().enumerate() {
            graph.set_input_fact(ix, f32::fact(shape).into()).unwrap();
        }
        let plan = graph.into_optimized().unwrap().into_runnable().unwrap();
        let values = shapes
            .iter()
            .zip(inputs)
            .map(|((_, s), x)| {
                tract_onnx::prelude::Tensor::from_shape(s, x)
                    .unwrap()
                    .into()
            })
            .collect();
        crate::engine::test_graphs::flat_outputs(&plan.run(values).unwrap())
    }

    #[test]
    fn tall_inputs_run_swapped_and_give_what_the_untouched_graph_gives() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let cases: [(&str, &[(&str, usize)]); 2] = [
            ("models/depth/tiefenrausch-fp32.onnx", &[("image", 3)]),
            (
                "models/fixtures/reshade-fixture-fp32-encoder.onnx",
                &[("image", 3), ("disparity", 1)],
            ),
        ];
        for (file, inputs) in cases {
            let path = root.join(file);
            let bytes = std::fs::read(&path).unwrap();
            let shapes: Vec<(&str, Vec<usize>)> = inputs
                .iter()
                .map(|&(n, c)| (n, vec![1, c, 64, 32]))
                .collect();
            let data: Vec<Vec<f32>> = shapes
                .iter()
                .map(|(_, s)| {
                    let n = s.iter().product::<usize>();
                    (0..n)
                        .map(|i| 0.5 + 0.4 * (i as f32 * 0.013).sin())
                        .collect()
                })
                .collect();
            let graph = tract_onnx::onnx().model_for_read(&mut &*bytes).unwrap();
            let outputs = output_names(&graph).unwrap();
            let outputs: Vec<&str> = outputs.iter().map(String::as_str).collect();
            let source = ModelSource {
                path: &path,
                bytes: &bytes,
                precision: Precision::Fp32,
            };
            assert!(
                optimized(source, &shapes, &outputs).unwrap().transposed,
                "{file}"
            );
            let plan = TractEngine::new(2).plan(source, &shapes, &outputs).unwrap();
            let feed: Vec<Tensor> = shapes
                .iter()
                .zip(&data)
                .map(|((_, s), x)| Tensor::new(s.clone(), x.clone()))
                .collect();
            let named: Vec<(&str, &Tensor)> = shapes.iter().map(|(n, _)| *n).zip(&feed).collect();
            let got = plan.run(&named).unwrap();
            let want = untouched(&bytes, &shapes, &data);
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(&want) {
                assert_eq!(g.data.len(), w.len());
                let scale = w.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-3);
                let worst = g
                    .data
                    .iter()
                    .zip(w)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0f32, f32::max);
                assert!(
                    worst <= 1e-4 * scale,
                    "{file}: off by {worst} (scale {scale})"
                );
            }
        }
    }
}
