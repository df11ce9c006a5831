//! Tall images run through a graph with its height and width swapped, rewritten in the
//! ONNX graph at load time.
//!
//! tract's depthwise convolution walks each output zone along its longest axis and has a
//! vectorised kernel only for walks along a row. On a portrait image the longest axis is
//! the height, so every depthwise convolution of the depth network ran scalar there: the
//! example photo (288×384) took about 1.4 times as long in depth as the same photo turned
//! sideways. A graph made only of operations that treat the two image axes alike gives
//! the transpose of its output for the transpose of its input once each kernel, stride,
//! padding and scale is swapped between the axes, so a tall input is transposed, run
//! through the swapped graph as a wide one, and its outputs transposed back. Graphs with
//! any other operation (shapes, reshapes, matrix products) are left as they are.

use std::collections::{BTreeSet, HashMap};

use tract_onnx::pb::{self, tensor_proto::DataType};

use super::proto::{initializer_index, readers};

/// Element-wise operations: the same whichever axis is which, provided that their
/// constant operands are the same along both image axes (see [`axis_free`]).
const ELEMENT_WISE: [&str; 22] = [
    "Add",
    "Sub",
    "Mul",
    "Div",
    "Clip",
    "Relu",
    "LeakyRelu",
    "Sigmoid",
    "Tanh",
    "Sin",
    "Cos",
    "Exp",
    "Floor",
    "Round",
    "Neg",
    "Abs",
    "Identity",
    "Cast",
    "QuantizeLinear",
    "DequantizeLinear",
    "Max",
    "Min",
];

/// Whether inputs of these shapes run transposed: every input an image batch (rank 4)
/// taller than it is wide.
pub fn tall(shapes: &[(&str, Vec<usize>)]) -> bool {
    !shapes.is_empty() && shapes.iter().all(|(_, s)| s.len() == 4 && s[2] > s[3])
}

/// An NCHW shape with its image axes swapped.
pub fn swapped_shape(shape: &[usize]) -> Vec<usize> {
    let mut shape = shape.to_vec();
    shape.swap(2, 3);
    shape
}

/// A row-major tensor of rank 4 with its image axes swapped: each plane transposed.
pub fn image_axes_swapped(shape: &[usize], data: &[f32]) -> (Vec<usize>, Vec<f32>) {
    let [_, _, h, w] = shape else {
        panic!("an image tensor has rank 4, not shape {shape:?}");
    };
    let (h, w) = (*h, *w);
    let mut out = vec![0.0; data.len()];
    for (src, dst) in data.chunks_exact(h * w).zip(out.chunks_exact_mut(h * w)) {
        for (y, row) in src.chunks_exact(w).enumerate() {
            for (x, &v) in row.iter().enumerate() {
                dst[x * h + y] = v;
            }
        }
    }
    (swapped_shape(shape), out)
}

/// The graph with its two image axes swapped, or why it cannot be: the name of the first
/// operation that does not treat the axes alike.
pub fn axes_swapped(model: &pb::ModelProto) -> Result<pb::ModelProto, String> {
    let graph = model.graph.as_ref().ok_or("the model has no graph")?;
    // Checked on the model as it is, copied only once it qualifies (a graph that does
    // not, such as the reshading decoder, is refused on every plan).
    let (swapped_weights, resize_constants) = swapped_tensors(graph)?;
    let mut model = model.clone();
    let graph = model.graph.as_mut().expect("checked above");
    for at in swapped_weights {
        swap_last_axes_of(&mut graph.initializer[at])?;
    }
    for at in resize_constants {
        swap_resize_constant(&mut graph.initializer[at])?;
    }
    for node in &mut graph.node {
        if matches!(node.op_type.as_str(), "Conv" | "AveragePool" | "MaxPool") {
            node.attribute.iter_mut().for_each(swap_attribute);
        }
    }
    for info in graph.input.iter_mut().chain(graph.output.iter_mut()) {
        swap_declared_shape(info);
    }
    Ok(model)
}

/// The initializers to swap, by position: the convolutions' kernels and the resizes'
/// scales, sizes and regions; an error naming what does not treat the axes alike.
fn swapped_tensors(graph: &pb::GraphProto) -> Result<(BTreeSet<usize>, BTreeSet<usize>), String> {
    let initializers = initializer_index(graph);
    let constants: HashMap<String, Vec<i64>> = graph
        .node
        .iter()
        .filter(|n| n.op_type == "Constant")
        .filter_map(|n| Some((n.output.first()?.clone(), constant_dims(n))))
        .collect();
    let dims = |name: &str| {
        initializers
            .get(name)
            .map(|&i| graph.initializer[i].dims.clone())
            .or_else(|| constants.get(name).cloned())
    };
    let mut swapped_weights = BTreeSet::new();
    let mut resize_constants = BTreeSet::new();
    for node in &graph.node {
        let why = |what: &str| format!("{} node {:?} {what}", node.op_type, node.name);
        match node.op_type.as_str() {
            "Constant" => {}
            "Conv" | "AveragePool" | "MaxPool" => {
                if node.output.len() != 1 {
                    return Err(why("has more than one output"));
                }
                if node.op_type == "Conv" {
                    let weights = node.input.get(1).ok_or_else(|| why("has no weights"))?;
                    let &at = initializers
                        .get(weights)
                        .ok_or_else(|| why("computes its weights"))?;
                    swapped_weights.insert(at);
                }
            }
            "Resize" => {
                if node.attribute.iter().any(|a| a.name == "axes") {
                    return Err(why("names its axes"));
                }
                for input in node.input.iter().skip(1).filter(|i| !i.is_empty()) {
                    let &at = initializers
                        .get(input)
                        .ok_or_else(|| why("computes its scales or sizes"))?;
                    resize_constants.insert(at);
                }
            }
            "Concat" => {
                let axis = node.attribute.iter().find(|a| a.name == "axis");
                if !matches!(axis.map(|a| a.i), Some(1 | -3)) {
                    return Err(why("joins along an image axis"));
                }
            }
            op if ELEMENT_WISE.contains(&op) => {
                for input in &node.input {
                    if dims(input).is_some_and(|d| !axis_free(&d)) {
                        return Err(why("has a constant that varies along an image axis"));
                    }
                }
            }
            _ => return Err(why("is not known to treat the image axes alike")),
        }
    }
    if let Some(out) = graph.output.iter().find(|o| dims(&o.name).is_some()) {
        return Err(format!("output {:?} is a constant", out.name));
    }
    let readers = readers(graph);
    for &at in swapped_weights.iter().chain(&resize_constants) {
        let name = &graph.initializer[at].name;
        let swapped_twice = swapped_weights.contains(&at) && resize_constants.contains(&at);
        let read_elsewhere = readers.get(name).into_iter().flatten().any(|&n| {
            let op = graph.node[n].op_type.as_str();
            !matches!(op, "Conv" | "Resize")
        });
        if swapped_twice || read_elsewhere {
            return Err(format!(
                "initializer {name:?} is read by more than its kernels or scales"
            ));
        }
    }
    Ok((swapped_weights, resize_constants))
}

/// Whether a constant of these dimensions broadcasts the same value along both image
/// axes: its last two dimensions (the height and width it lines up with) are 1 or absent.
fn axis_free(dims: &[i64]) -> bool {
    dims.iter().rev().take(2).all(|&d| d == 1)
}

/// The dimensions of a Constant node's value (a list attribute is one-dimensional).
fn constant_dims(node: &pb::NodeProto) -> Vec<i64> {
    let Some(value) = node.attribute.first() else {
        return Vec::new();
    };
    match (&value.t, value.floats.len().max(value.ints.len())) {
        (Some(t), _) => t.dims.clone(),
        (None, 0) => Vec::new(),
        (None, len) => vec![len as i64],
    }
}

/// Swaps the two-element (kernel, strides, dilations) and four-element (pads: begins then
/// ends) spatial attributes of a convolution or pool.
fn swap_attribute(a: &mut pb::AttributeProto) {
    match (a.name.as_str(), a.ints.len()) {
        ("kernel_shape" | "strides" | "dilations", 2) => a.ints.swap(0, 1),
        ("pads", 4) => {
            a.ints.swap(0, 1);
            a.ints.swap(2, 3);
        }
        _ => {}
    }
}

/// Transposes the last two axes of a float tensor (a convolution's kernels).
fn swap_last_axes_of(t: &mut pb::TensorProto) -> Result<(), String> {
    if t.data_type != DataType::Float as i32 || t.dims.len() != 4 {
        return Err(format!(
            "weights {:?} are not a 4-D float tensor (type {}, dims {:?})",
            t.name, t.data_type, t.dims
        ));
    }
    let (h, w) = (t.dims[2] as usize, t.dims[3] as usize);
    let transpose = |values: &[[u8; 4]]| -> Vec<[u8; 4]> {
        values
            .chunks_exact(h * w)
            .flat_map(|plane| (0..w).flat_map(move |x| (0..h).map(move |y| plane[y * w + x])))
            .collect()
    };
    if t.raw_data.is_empty() {
        let words: Vec<[u8; 4]> = t.float_data.iter().map(|f| f.to_le_bytes()).collect();
        t.float_data = transpose(&words)
            .into_iter()
            .map(f32::from_le_bytes)
            .collect();
    } else {
        let words: Vec<[u8; 4]> = t
            .raw_data
            .chunks_exact(4)
            .map(|b| [b[0], b[1], b[2], b[3]])
            .collect();
        t.raw_data = transpose(&words).concat();
    }
    t.dims.swap(2, 3);
    Ok(())
}

/// Swaps the image axes' entries of a Resize's roi (begins then ends), scales or sizes.
fn swap_resize_constant(t: &mut pb::TensorProto) -> Result<(), String> {
    let pairs: &[(usize, usize)] = match t.dims.as_slice() {
        [0] => &[],
        [4] => &[(2, 3)],
        [8] => &[(2, 3), (6, 7)],
        d => return Err(format!("Resize input {:?} has dims {d:?}", t.name)),
    };
    let width = match DataType::try_from(t.data_type) {
        Ok(DataType::Float) => 4,
        Ok(DataType::Int64) => 8,
        _ => {
            return Err(format!(
                "Resize input {:?} has type {}",
                t.name, t.data_type
            ))
        }
    };
    for &(a, b) in pairs {
        if !t.raw_data.is_empty() {
            for k in 0..width {
                t.raw_data.swap(a * width + k, b * width + k);
            }
        } else if width == 4 {
            t.float_data.swap(a, b);
        } else {
            t.int64_data.swap(a, b);
        }
    }
    Ok(())
}

fn swap_declared_shape(info: &mut pb::ValueInfoProto) {
    use pb::type_proto::Value;
    if let Some(Value::TensorType(tensor)) = info.r#type.as_mut().and_then(|t| t.value.as_mut()) {
        if let Some(shape) = tensor.shape.as_mut().filter(|s| s.dim.len() == 4) {
            shape.dim.swap(2, 3);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::test_graphs::{shaped_value_info, tensor};
    use tract_onnx::pb::attribute_proto::AttributeType;
    use tract_onnx::prelude::*;

    const FLOAT: i32 = DataType::Float as i32;
    const TALL: [usize; 4] = [1, 2, 9, 5];

    fn floats(name: &str, dims: &[i64], values: impl Fn(usize) -> f32) -> pb::TensorProto {
        let n = dims.iter().product::<i64>() as usize;
        let raw = (0..n).flat_map(|i| values(i).to_le_bytes()).collect();
        tensor(name, FLOAT, dims, raw)
    }

    fn ints(name: &str, ints: &[i64]) -> pb::AttributeProto {
        pb::AttributeProto {
            name: name.into(),
            r#type: AttributeType::Ints as i32,
            ints: ints.to_vec(),
            ..Default::default()
        }
    }

    fn int(name: &str, i: i64) -> pb::AttributeProto {
        pb::AttributeProto {
            name: name.into(),
            r#type: AttributeType::Int as i32,
            i,
            ..Default::default()
        }
    }

    fn op(
        op: &str,
        inputs: &[&str],
        output: &str,
        attribute: Vec<pb::AttributeProto>,
    ) -> pb::NodeProto {
        pb::NodeProto {
            op_type: op.into(),
            name: output.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.into()],
            attribute,
            ..Default::default()
        }
    }

    fn image(name: &str) -> pb::ValueInfoProto {
        let dims: Vec<i64> = TALL.iter().map(|&d| d as i64).collect();
        shaped_value_info(name, &dims)
    }

    /// Every operation the rewrite swaps, each with axes that differ: a strided, unevenly
    /// padded depthwise convolution, a full 3x2 convolution, a nearest resize by 2x3, a
    /// 2x1 pool, and element-wise operations with per-channel and scalar constants.
    fn mixed(extra: Vec<pb::NodeProto>, last: &str) -> pb::ModelProto {
        let mut node = vec![
            op(
                "Conv",
                &["x", "dw.w", "dw.b"],
                "dw",
                vec![
                    ints("kernel_shape", &[3, 3]),
                    ints("strides", &[2, 1]),
                    ints("pads", &[1, 0, 0, 1]),
                    int("group", 2),
                ],
            ),
            op("Resize", &["dw", "", "scales"], "up", vec![]),
            op(
                "Conv",
                &["x", "full.w"],
                "full",
                vec![ints("kernel_shape", &[3, 2]), ints("pads", &[2, 0, 0, 1])],
            ),
            op(
                "MaxPool",
                &["full"],
                "pool",
                vec![ints("kernel_shape", &[2, 1]), ints("strides", &[2, 1])],
            ),
            op("Add", &["pool", "per_channel"], "shifted", vec![]),
            op("Clip", &["shifted", "low", "high"], "clipped", vec![]),
        ];
        node.extend(extra);
        let mut m = crate::engine::test_graphs::model(
            vec![
                floats("dw.w", &[2, 1, 3, 3], |i| (i as f32 * 0.71).sin()),
                floats("dw.b", &[2], |i| i as f32 * 0.1),
                floats("full.w", &[3, 2, 3, 2], |i| (i as f32 * 1.3).cos()),
                floats("scales", &[4], |i| [1.0, 1.0, 2.0, 3.0][i]),
                floats("per_channel", &[1, 3, 1, 1], |i| i as f32 - 1.0),
                floats("low", &[], |_| -0.5),
                floats("high", &[], |_| 1.5),
            ],
            node,
        );
        m.opset_import = vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: 13,
        }];
        let graph = m.graph.as_mut().unwrap();
        graph.input = vec![image("x")];
        graph.output = vec![image("up"), image(last)];
        m
    }

    fn run(m: &pb::ModelProto, shape: &[usize], x: &[f32]) -> Vec<(Vec<usize>, Vec<f32>)> {
        let mut graph = tract_onnx::onnx().model_for_proto_model(m).unwrap();
        graph.set_input_fact(0, f32::fact(shape).into()).unwrap();
        let plan = graph.into_optimized().unwrap().into_runnable().unwrap();
        let x = tract_onnx::prelude::Tensor::from_shape(shape, x).unwrap();
        plan.run(tvec!(x.into()))
            .unwrap()
            .iter()
            .map(|t| {
                let view = t.to_plain_array_view::<f32>().unwrap();
                (view.shape().to_vec(), view.iter().copied().collect())
            })
            .collect()
    }

    #[test]
    fn a_swapped_graph_maps_the_transposed_image_to_the_transposed_outputs() {
        let m = mixed(vec![], "clipped");
        let x: Vec<f32> = (0..TALL.iter().product())
            .map(|i| (i as f32 * 0.37).sin())
            .collect();
        let before = run(&m, &TALL, &x);
        let swapped = axes_swapped(&m).unwrap();
        let (shape, xt) = image_axes_swapped(&TALL, &x);
        let after = run(&swapped, &shape, &xt);
        assert_eq!(before.len(), 2);
        for ((shape, a), (shape_t, b)) in before.iter().zip(&after) {
            let (back_shape, b) = image_axes_swapped(shape_t, b);
            assert_eq!(&back_shape, shape);
            assert_ne!(
                shape[2], shape[3],
                "the test needs outputs that are not square"
            );
            for (p, q) in a.iter().zip(&b) {
                assert!((p - q).abs() < 1e-5, "{a:?} vs {b:?}");
            }
        }
        assert_eq!(
            m.graph.unwrap().initializer[3].raw_data,
            floats("scales", &[4], |i| [1.0, 1.0, 2.0, 3.0][i]).raw_data,
            "the original graph is not touched"
        );
    }

    #[test]
    fn graphs_that_treat_the_axes_differently_are_left_alone() {
        let cases = [
            (op("Reshape", &["clipped", "shape"], "y", vec![]), "Reshape"),
            (
                op("Concat", &["clipped", "clipped"], "y", vec![int("axis", 2)]),
                "joins",
            ),
            (op("Mul", &["clipped", "rows"], "y", vec![]), "varies"),
        ];
        for (node, why) in cases {
            let mut m = mixed(vec![node], "y");
            let graph = m.graph.as_mut().unwrap();
            graph
                .initializer
                .push(floats("rows", &[9, 1], |i| i as f32));
            let err = axes_swapped(&m).unwrap_err();
            assert!(err.contains(why), "{err}");
        }
    }

    #[test]
    fn only_tall_image_inputs_run_swapped() {
        assert!(tall(&[
            ("x", vec![1, 3, 384, 288]),
            ("d", vec![1, 1, 384, 288])
        ]));
        assert!(!tall(&[("x", vec![1, 3, 288, 384])]));
        assert!(!tall(&[("x", vec![1, 3, 64, 64])]));
        assert!(!tall(&[
            ("x", vec![1, 3, 384, 288]),
            ("camera", vec![1, 3])
        ]));
        assert!(!tall(&[]));
    }
}
