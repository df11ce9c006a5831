//! int8 weights as a storage format. The shipped int8 reshading graphs keep activations in
//! float and store each convolution's weights as int8 with a per-channel scale
//! (`DequantizeLinear` on initializers). tract 0.23.9 does not fold those constant
//! `DequantizeLinear` nodes into the convolutions: it dequantizes at every run and picks
//! slower kernels (1.24× fp32 per decoder run, 1.63× per encoder run, measured). Folding
//! them once at load gives the fp32 graph's shape with the int8 model's own weight values.
//!
//! Graphs that quantize activations too (any `QuantizeLinear`) are left alone: their
//! weight `DequantizeLinear` nodes are part of the QDQ pattern tract's int8 kernels match.
//!
//! Graphs of `QLinearConv` (int8 activations and weights, as the shipped int8 depth
//! network) run 14–35× slower in tract 0.23.9 than the fp32 graph of the same network,
//! on x86 where onnxruntime runs them as fast as fp32. [`unfuse_qlinear_convs`] turns each
//! into a float convolution between the same quantisation points.

use std::collections::{HashMap, HashSet};

use super::proto::{floats, initializer_index, readers, scalar, words};
use tract_onnx::pb::{self, tensor_proto::DataType};

const FLOAT: i32 = DataType::Float as i32;
const INT8: i32 = DataType::Int8 as i32;
const INT32: i32 = DataType::Int32 as i32;
const UINT8: i32 = DataType::Uint8 as i32;

/// Replaces every `DequantizeLinear` whose inputs are all initializers by the float
/// initializer it computes, in graphs whose activations stay float. Returns how many
/// nodes were folded.
pub fn fold_weight_dequantization(model: &mut pb::ModelProto) -> Result<usize, String> {
    let Some(graph) = model.graph.as_mut() else {
        return Ok(0);
    };
    let quantizes_activations = graph
        .node
        .iter()
        .any(|n| n.op_type == "QuantizeLinear" || n.op_type == "DynamicQuantizeLinear");
    if quantizes_activations {
        return Ok(0);
    }
    let initializers = initializer_index(graph);
    let mut folded = Vec::new();
    let mut kept = Vec::with_capacity(graph.node.len());
    for node in std::mem::take(&mut graph.node) {
        let constant = node.op_type == "DequantizeLinear"
            && node.input.iter().all(|i| initializers.contains_key(i));
        if constant {
            let tensors: Vec<&pb::TensorProto> = node
                .input
                .iter()
                .map(|i| &graph.initializer[initializers[i]])
                .collect();
            let axis = node
                .attribute
                .iter()
                .find(|a| a.name == "axis")
                .map_or(1, |a| a.i);
            let mut weights = dequantize(&tensors, axis)
                .map_err(|e| format!("DequantizeLinear node {:?}: {e}", node.name))?;
            weights.name = node.output.first().cloned().unwrap_or_default();
            folded.push((weights, node.input));
        } else {
            kept.push(node);
        }
    }
    graph.node = kept;
    let count = folded.len();
    let mut consumed: HashSet<String> = HashSet::new();
    for (weights, inputs) in folded {
        graph.initializer.push(weights);
        consumed.extend(inputs);
    }
    drop_unused(graph, consumed);
    Ok(count)
}

/// Replaces every `QLinearConv` whose scales, zero points, weights and bias are
/// initializers by `DequantizeLinear` → `Conv` → `QuantizeLinear`, the weights and bias
/// dequantized once: the activations are rounded to the same int8 grid at the same
/// places, and only the accumulation in between runs in float (the bias in
/// x_scale · w_scale units, as QLinearConv reads it). Returns how many were replaced.
pub fn unfuse_qlinear_convs(model: &mut pb::ModelProto) -> Result<usize, String> {
    let Some(graph) = model.graph.as_mut() else {
        return Ok(0);
    };
    let initializers = initializer_index(graph);
    let mut nodes = Vec::with_capacity(graph.node.len());
    let mut added = Vec::new();
    let mut consumed: HashSet<String> = HashSet::new();
    let mut replaced = 0;
    for node in std::mem::take(&mut graph.node) {
        let constant = |k: usize| {
            node.input
                .get(k)
                .is_some_and(|i| initializers.contains_key(i))
        };
        let replaceable = node.op_type == "QLinearConv"
            && (8..=9).contains(&node.input.len())
            && (1..node.input.len()).all(constant);
        if !replaceable {
            nodes.push(node);
            continue;
        }
        let get = |k: usize| &graph.initializer[initializers[&node.input[k]]];
        let at = |e: String| format!("QLinearConv node {:?}: {e}", node.name);
        let base = format!("{}.unfused", node.output[0]);
        let mut weights = dequantize(&[get(3), get(4), get(5)], 0).map_err(at)?;
        weights.name = format!("{base}.w");
        let mut conv_inputs = vec![format!("{base}.x"), weights.name.clone()];
        if node.input.len() == 9 {
            let mut bias = dequantize_bias(get(8), get(1), get(4)).map_err(at)?;
            bias.name = format!("{base}.b");
            conv_inputs.push(bias.name.clone());
            added.push(bias);
        }
        added.push(weights);
        let op = |op_type: &str, inputs: Vec<String>, output: String, attribute| pb::NodeProto {
            op_type: op_type.into(),
            name: format!("{}.{op_type}", node.name),
            input: inputs,
            output: vec![output],
            attribute,
            ..Default::default()
        };
        let i = &node.input;
        nodes.push(op(
            "DequantizeLinear",
            vec![i[0].clone(), i[1].clone(), i[2].clone()],
            format!("{base}.x"),
            vec![],
        ));
        nodes.push(op(
            "Conv",
            conv_inputs,
            format!("{base}.y"),
            node.attribute.clone(),
        ));
        nodes.push(op(
            "QuantizeLinear",
            vec![format!("{base}.y"), i[6].clone(), i[7].clone()],
            node.output[0].clone(),
            vec![],
        ));
        consumed.extend([i[3].clone(), i[4].clone(), i[5].clone()]);
        consumed.extend(i.get(8).cloned());
        replaced += 1;
    }
    graph.node = nodes;
    graph.initializer.extend(added);
    drop_unused(graph, consumed);
    Ok(replaced)
}

/// One tensor's quantisation: a scalar scale and zero point, and the integer range.
#[derive(Clone, Copy, PartialEq)]
struct Grid {
    scale: f32,
    zero: i32,
    range: (i32, i32),
}

impl Grid {
    /// The grid of a QuantizeLinear or DequantizeLinear node whose scale and zero point
    /// are scalar initializers; None otherwise.
    fn of(
        node: &pb::NodeProto,
        graph: &pb::GraphProto,
        initializers: &HashMap<String, usize>,
    ) -> Option<Grid> {
        let get = |k: usize| {
            node.input
                .get(k)
                .and_then(|i| initializers.get(i))
                .map(|&at| &graph.initializer[at])
        };
        let scale = match floats(get(1)?).ok()?[..] {
            [s] if s.is_finite() && s > 0.0 => s,
            _ => return None,
        };
        let (zero, range) = match get(2) {
            None => (0, (0, 255)),
            Some(z) => {
                let range = match z.data_type {
                    UINT8 => (0, 255),
                    INT8 => (-128, 127),
                    _ => return None,
                };
                match integers(z).ok()?[..] {
                    [zero] => (zero, range),
                    _ => return None,
                }
            }
        };
        Some(Grid { scale, zero, range })
    }
}

/// 1.5 · 2²³: added to a float of magnitude below 2²² and taken away again, it rounds
/// that float to an integer, half to even (the sum's spacing is 1, and the constant is
/// even), in two vectorised additions; tract's Round is a scalar loop.
pub(super) const ROUNDING_MAGIC: f32 = 12_582_912.0;

/// Replaces each `QuantizeLinear` whose every reader is a `DequantizeLinear` on the same
/// scalar grid by the float arithmetic the pair computes,
/// `scale · round(clip(x / scale, min − zero, max − zero))` (clipping to integers first
/// leaves the rounding unchanged and keeps it in [`ROUNDING_MAGIC`]'s range): the same
/// values, rounded to the same grid (both round half to even), in element-wise ops that
/// tract runs vectorised, where its QuantizeLinear is a scalar loop (56 % of the int8
/// depth network's time after [`unfuse_qlinear_convs`]). Returns how many were replaced.
pub fn fake_quantize_activations(model: &mut pb::ModelProto) -> Result<usize, String> {
    let Some(graph) = model.graph.as_mut() else {
        return Ok(0);
    };
    let initializers = initializer_index(graph);
    let outputs: HashSet<&String> = graph.output.iter().map(|o| &o.name).collect();
    let readers = readers(graph);
    // Each replaceable QuantizeLinear, by position, with its grid and its readers.
    let mut plans: HashMap<usize, (Grid, Vec<usize>)> = HashMap::new();
    for (at, node) in graph.node.iter().enumerate() {
        if node.op_type != "QuantizeLinear" || node.output.len() != 1 {
            continue;
        }
        let Some(grid) = Grid::of(node, graph, &initializers) else {
            continue;
        };
        let out = &node.output[0];
        let reads = readers.get(out).cloned().unwrap_or_default();
        let all_on_grid = !reads.is_empty()
            && reads.iter().all(|&r| {
                let reader = &graph.node[r];
                reader.op_type == "DequantizeLinear"
                    && reader.input.first() == Some(out)
                    && Grid::of(reader, graph, &initializers) == Some(grid)
            });
        if all_on_grid && !outputs.contains(out) {
            plans.insert(at, (grid, reads));
        }
    }
    let dequantizers: HashMap<usize, String> = plans
        .values()
        .flat_map(|(_, reads)| reads.iter())
        .map(|&r| (r, format!("{}.fq", graph.node[r].input[0])))
        .collect();
    let mut added = Vec::new();
    let mut consumed: HashSet<String> = HashSet::new();
    let mut nodes = Vec::with_capacity(graph.node.len() + 4 * plans.len());
    for (at, node) in std::mem::take(&mut graph.node).into_iter().enumerate() {
        if let Some((grid, _)) = plans.get(&at) {
            let base = node.output[0].clone();
            added.push(scalar(format!("{base}.fq.scale"), grid.scale));
            added.push(scalar(
                format!("{base}.fq.min"),
                (grid.range.0 - grid.zero) as f32,
            ));
            added.push(scalar(
                format!("{base}.fq.max"),
                (grid.range.1 - grid.zero) as f32,
            ));
            let op = |op_type: &str, inputs: Vec<String>, output: String| pb::NodeProto {
                op_type: op_type.into(),
                name: format!("{}.fq.{op_type}", node.name),
                input: inputs,
                output: vec![output],
                ..Default::default()
            };
            added.push(scalar(format!("{base}.fq.magic"), ROUNDING_MAGIC));
            let scale = format!("{base}.fq.scale");
            let magic = format!("{base}.fq.magic");
            let step = |name: &str| format!("{base}.fq.{name}");
            nodes.push(op(
                "Div",
                vec![node.input[0].clone(), scale.clone()],
                step("div"),
            ));
            nodes.push(op(
                "Clip",
                vec![step("div"), step("min"), step("max")],
                step("clip"),
            ));
            nodes.push(op(
                "Add",
                vec![step("clip"), magic.clone()],
                step("shifted"),
            ));
            nodes.push(op("Sub", vec![step("shifted"), magic], step("round")));
            nodes.push(op("Mul", vec![step("round"), scale], base + ".fq"));
            consumed.extend(node.input.iter().skip(1).cloned());
        } else if let Some(value) = dequantizers.get(&at) {
            consumed.extend(node.input.iter().skip(1).cloned());
            nodes.push(pb::NodeProto {
                op_type: "Identity".into(),
                name: format!("{}.fq", node.name),
                input: vec![value.clone()],
                output: node.output,
                ..Default::default()
            });
        } else {
            nodes.push(node);
        }
    }
    graph.node = nodes;
    graph.initializer.extend(added);
    drop_unused(graph, consumed);
    Ok(plans.len())
}

/// QLinearConv's int32 bias as float: bias · x_scale · w_scale (per output channel).
fn dequantize_bias(
    bias: &pb::TensorProto,
    x_scale: &pb::TensorProto,
    w_scale: &pb::TensorProto,
) -> Result<pb::TensorProto, String> {
    let values = int32s(bias)?;
    let x_scale = *floats(x_scale)?
        .first()
        .ok_or("an empty input scale".to_string())?;
    let w_scales = floats(w_scale)?;
    if w_scales.len() != 1 && w_scales.len() != values.len() {
        return Err(format!(
            "{} weight scales for a bias of {}",
            w_scales.len(),
            values.len()
        ));
    }
    let data = values
        .iter()
        .enumerate()
        .map(|(c, &b)| b as f32 * x_scale * w_scales[c.min(w_scales.len() - 1)])
        .collect();
    Ok(pb::TensorProto {
        dims: bias.dims.clone(),
        data_type: FLOAT,
        float_data: data,
        ..Default::default()
    })
}

/// Removes the initializers among `consumed` that no node or graph output reads.
fn drop_unused(graph: &mut pb::GraphProto, consumed: HashSet<String>) {
    let still_used: HashSet<&String> = graph
        .node
        .iter()
        .flat_map(|n| &n.input)
        .chain(graph.output.iter().map(|o| &o.name))
        .collect();
    let unused: HashSet<String> = consumed
        .into_iter()
        .filter(|name| !still_used.contains(name))
        .collect();
    graph.initializer.retain(|t| !unused.contains(&t.name));
}

/// (x − zero point) · scale for int8/uint8 `x`, with a scalar scale or one per slice of
/// `axis`, as a float tensor of x's shape.
fn dequantize(tensors: &[&pb::TensorProto], axis: i64) -> Result<pb::TensorProto, String> {
    let (x, scale) = match tensors {
        [x, scale] | [x, scale, _] => (*x, *scale),
        _ => return Err(format!("has {} inputs; expected 2 or 3", tensors.len())),
    };
    let values = integers(x)?;
    let scales = floats(scale)?;
    let zeros = match tensors.get(2) {
        Some(z) => integers(z)?,
        None => vec![0; scales.len()],
    };
    if zeros.len() != scales.len() || scales.is_empty() {
        return Err(format!(
            "{} scales and {} zero points",
            scales.len(),
            zeros.len()
        ));
    }
    let shape: Vec<usize> = x.dims.iter().map(|&d| d.max(0) as usize).collect();
    let channel_of = channel_index(&shape, axis, scales.len())?;
    let data: Vec<f32> = values
        .iter()
        .enumerate()
        .map(|(i, &q)| {
            let c = channel_of(i);
            (q - zeros[c]) as f32 * scales[c]
        })
        .collect();
    Ok(pb::TensorProto {
        dims: x.dims.clone(),
        data_type: FLOAT,
        float_data: data,
        ..Default::default()
    })
}

/// Maps a flat element index to its scale's index: 0 for one scale, else the element's
/// coordinate along `axis`.
fn channel_index(
    shape: &[usize],
    axis: i64,
    scales: usize,
) -> Result<Box<dyn Fn(usize) -> usize>, String> {
    if scales == 1 {
        return Ok(Box::new(|_| 0));
    }
    let rank = shape.len() as i64;
    let axis = if axis < 0 { axis + rank } else { axis };
    let Some(&channels) = usize::try_from(axis).ok().and_then(|a| shape.get(a)) else {
        return Err(format!("axis {axis} is outside a tensor of rank {rank}"));
    };
    if channels != scales {
        return Err(format!(
            "{scales} scales for {channels} channels along axis {axis}"
        ));
    }
    let inner: usize = shape[axis as usize + 1..].iter().product();
    Ok(Box::new(move |i| (i / inner) % channels))
}

fn integers(t: &pb::TensorProto) -> Result<Vec<i32>, String> {
    match t.data_type {
        INT8 if !t.raw_data.is_empty() => {
            Ok(t.raw_data.iter().map(|&b| i32::from(b as i8)).collect())
        }
        UINT8 if !t.raw_data.is_empty() => Ok(t.raw_data.iter().map(|&b| i32::from(b)).collect()),
        INT8 | UINT8 => Ok(t.int32_data.clone()),
        other => Err(format!(
            "tensor {:?} has element type {other}; expected int8 or uint8",
            t.name
        )),
    }
}

fn int32s(t: &pb::TensorProto) -> Result<Vec<i32>, String> {
    words(t, INT32, "bias", "int32", &t.int32_data, i32::from_le_bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::test_graphs::{model, node, run, tensor, value_info};

    /// Two output channels of a 2×1×1×2 weight, scales 0.5 and 0.25, zero points 0 and 2.
    fn weights_only_model() -> pb::ModelProto {
        let q: Vec<u8> = [1i8, -2, 4, 6].iter().map(|&v| v as u8).collect();
        let scales: Vec<u8> = [0.5f32, 0.25]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let zeros = vec![0u8, 2];
        model(
            vec![
                tensor("w_q", INT8, &[2, 1, 1, 2], q),
                tensor("w_scale", FLOAT, &[2], scales),
                tensor("w_zero", INT8, &[2], zeros),
            ],
            vec![
                node("DequantizeLinear", &["w_q", "w_scale", "w_zero"], "w"),
                node("Conv", &["x", "w"], "y"),
            ],
        )
    }

    #[test]
    fn constant_weight_dequantization_becomes_float_weights() {
        let mut model = weights_only_model();
        assert_eq!(fold_weight_dequantization(&mut model), Ok(1));
        let graph = model.graph.unwrap();
        assert_eq!(graph.node.len(), 1, "only the Conv is left");
        assert_eq!(graph.initializer.len(), 1, "the int8 tensors are gone");
        let w = &graph.initializer[0];
        assert_eq!((w.name.as_str(), w.data_type), ("w", FLOAT));
        assert_eq!(w.dims, [2, 1, 1, 2]);
        assert_eq!(w.float_data, [0.5, -1.0, 0.5, 1.0]);
    }

    #[test]
    fn graphs_that_quantize_activations_keep_their_qdq_pattern() {
        let mut model = weights_only_model();
        let graph = model.graph.as_mut().unwrap();
        graph
            .node
            .insert(0, node("QuantizeLinear", &["x0", "s", "z"], "xq"));
        assert_eq!(fold_weight_dequantization(&mut model), Ok(0));
        assert_eq!(model.graph.unwrap().node.len(), 3);
    }

    #[test]
    fn a_scale_count_that_does_not_match_the_channels_is_an_error() {
        let mut model = weights_only_model();
        let graph = model.graph.as_mut().unwrap();
        graph.initializer[0].dims = vec![1, 1, 1, 4];
        let err = fold_weight_dequantization(&mut model).unwrap_err();
        assert!(err.contains("2 scales for 1 channels"), "{err}");
    }
    /// x (uint8, scale 0.1, zero 128) convolved with two int8 1×1 filters (scales 0.5 and
    /// 0.25), bias 4 and −8 in x_scale · w_scale units, into y (scale 0.2, zero 3).
    fn qlinear_model() -> pb::ModelProto {
        let f = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        let bias: Vec<u8> = [4i32, -8].iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut conv = node(
            "QLinearConv",
            &["x", "xs", "xz", "w", "ws", "wz", "ys", "yz", "b"],
            "y",
        );
        conv.attribute = vec![pb::AttributeProto {
            name: "kernel_shape".into(),
            ints: vec![1, 1],
            ..Default::default()
        }];
        model(
            vec![
                tensor("xs", FLOAT, &[], f(&[0.1])),
                tensor("xz", UINT8, &[], vec![128]),
                tensor("w", INT8, &[2, 1, 1, 1], vec![3, (-2i8) as u8]),
                tensor("ws", FLOAT, &[2], f(&[0.5, 0.25])),
                tensor("wz", INT8, &[2], vec![0, 0]),
                tensor("ys", FLOAT, &[], f(&[0.2])),
                tensor("yz", UINT8, &[], vec![3]),
                tensor("b", INT32, &[2], bias),
            ],
            vec![conv],
        )
    }

    #[test]
    fn a_qlinear_conv_becomes_a_float_conv_between_its_quantisation_points() {
        let mut model = qlinear_model();
        assert_eq!(unfuse_qlinear_convs(&mut model), Ok(1));
        let graph = model.graph.unwrap();
        let ops: Vec<&str> = graph.node.iter().map(|n| n.op_type.as_str()).collect();
        assert_eq!(ops, ["DequantizeLinear", "Conv", "QuantizeLinear"]);
        let [dq, conv, q] = &graph.node[..] else {
            unreachable!()
        };
        assert_eq!(dq.input, ["x", "xs", "xz"]);
        assert_eq!(q.input[1..], ["ys", "yz"]);
        assert_eq!(q.output, ["y"], "the graph's names stay");
        assert_eq!(conv.attribute[0].name, "kernel_shape");
        let find = |name: &str| graph.initializer.iter().find(|t| t.name == name).unwrap();
        assert_eq!(find(&conv.input[1]).float_data, [1.5, -0.5]);
        let b = &find(&conv.input[2]).float_data;
        assert!(
            (b[0] - 0.2).abs() < 1e-6 && (b[1] + 0.2).abs() < 1e-6,
            "{b:?}"
        );
        for gone in ["w", "ws", "wz", "b"] {
            assert!(
                graph.initializer.iter().all(|t| t.name != gone),
                "{gone} kept"
            );
        }
    }

    /// x → QuantizeLinear (scale 0.5, zero 10, uint8) → two DequantizeLinear readers on
    /// the same grid (one with its own copies of the scale and zero point).
    fn quantize_model() -> pb::ModelProto {
        quantize_model_with(0.5)
    }

    fn quantize_model_with(scale: f32) -> pb::ModelProto {
        let f = |v: f32| v.to_le_bytes().to_vec();
        let mut q = node("QuantizeLinear", &["x", "s", "z"], "xq");
        q.attribute.clear();
        let mut a = node("DequantizeLinear", &["xq", "s", "z"], "a");
        a.attribute.clear();
        let mut b = node("DequantizeLinear", &["xq", "s2", "z2"], "b");
        b.attribute.clear();
        let mut m = model(
            vec![
                tensor("s", FLOAT, &[], f(scale)),
                tensor("z", UINT8, &[], vec![10]),
                tensor("s2", FLOAT, &[], f(scale)),
                tensor("z2", UINT8, &[], vec![10]),
            ],
            vec![q, a, b],
        );
        let graph = m.graph.as_mut().unwrap();
        graph.input = vec![value_info("x", 8)];
        graph.output = vec![value_info("a", 8), value_info("b", 8)];
        m.opset_import = vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: 13,
        }];
        m
    }

    #[test]
    fn quantize_dequantize_pairs_become_the_same_float_arithmetic() {
        let mut model = quantize_model();
        // Below the grid, ties both ways, between points, above the grid.
        let x = [-9.0, -4.75, 0.25, 0.75, 1.3, 2.6, 122.0, 200.0];
        let before = run(&model, &x);
        assert_eq!(fake_quantize_activations(&mut model), Ok(1));
        let graph = model.graph.as_ref().unwrap();
        let ops: Vec<&str> = graph.node.iter().map(|n| n.op_type.as_str()).collect();
        assert_eq!(
            ops,
            ["Div", "Clip", "Add", "Sub", "Mul", "Identity", "Identity"]
        );
        for gone in ["z", "s2", "z2"] {
            assert!(graph.initializer.iter().all(|t| t.name != gone), "{gone}");
        }
        let after = run(&model, &x);
        assert_eq!(before, after);
        // (0 − 10)·0.5 = −5 at the bottom, (255 − 10)·0.5 = 122.5 at the top, and 0.25 and
        // 0.75 are ties that round to the even 0 and 2 halves.
        assert_eq!(after[0], [-5.0, -5.0, 0.0, 1.0, 1.5, 2.5, 122.0, 122.5]);
    }

    #[test]
    fn a_scale_without_an_exact_reciprocal_rounds_as_tract_s_quantize_linear() {
        // Near every half step of a 0.1 grid, where x / 0.1 and x · (1 / 0.1) may differ
        // in the last bit and a tie may go either way.
        let x: Vec<f32> = (-40..2600)
            .flat_map(|k| {
                let tie = (k as f32 + 0.5) * 0.1;
                [
                    tie,
                    f32::from_bits(tie.to_bits() + 1),
                    f32::from_bits(tie.to_bits() - 1),
                ]
            })
            .collect();
        let original = quantize_model_with(0.1);
        let mut rewritten = original.clone();
        assert_eq!(fake_quantize_activations(&mut rewritten), Ok(1));
        for chunk in x.chunks_exact(8) {
            assert_eq!(run(&original, chunk), run(&rewritten, chunk), "{chunk:?}");
        }
    }

    #[test]
    fn a_quantized_tensor_read_by_anything_else_is_left_alone() {
        let mut model = quantize_model();
        let graph = model.graph.as_mut().unwrap();
        graph.initializer[2].float_data = vec![];
        graph.initializer[2].raw_data = 0.25f32.to_le_bytes().to_vec();
        assert_eq!(fake_quantize_activations(&mut model), Ok(0));
    }

    #[test]
    fn a_qlinear_conv_with_a_computed_scale_is_left_alone() {
        let mut model = qlinear_model();
        let graph = model.graph.as_mut().unwrap();
        graph.initializer.retain(|t| t.name != "ys");
        assert_eq!(unfuse_qlinear_convs(&mut model), Ok(0));
        assert_eq!(model.graph.unwrap().node[0].op_type, "QLinearConv");
    }
}
