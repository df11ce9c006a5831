//! Average pooling as a depthwise convolution, rewritten in the ONNX graph at load time.
//!
//! The reshading encoder halves its resolution five times with 2×2 AveragePool. tract
//! runs AveragePool as a generic sum pool, about three times the time of a depthwise
//! convolution with a constant 2×2 kernel of ¼ over the same tensor (its vectorised
//! depthwise kernel), which computes the same means. A depthwise convolution needs the
//! channel count, which the graph states only in the weights of the convolution that
//! produced the pooled tensor; pools whose channels cannot be read there are left alone.

use std::collections::HashMap;

use tract_onnx::pb::{self, attribute_proto::AttributeType, tensor_proto::DataType};

use super::proto::initializer_index;

/// Element-wise ops that keep their input's channels, looked through to find the
/// convolution a pooled tensor comes from.
const SHAPE_KEEPING: [&str; 6] = ["LeakyRelu", "Relu", "Clip", "Sigmoid", "Tanh", "Identity"];

/// Replaces each AveragePool whose windows tile its input (kernel = strides, no
/// padding, 2-D) and whose channel count is known by the equivalent depthwise Conv.
/// Returns how many were replaced.
pub fn average_pools_as_depthwise(model: &mut pb::ModelProto) -> usize {
    let Some(graph) = model.graph.as_mut() else {
        return 0;
    };
    let initializers = initializer_index(graph);
    let producer: HashMap<String, usize> = graph
        .node
        .iter()
        .enumerate()
        .flat_map(|(at, n)| n.output.iter().map(move |o| (o.clone(), at)))
        .collect();
    let mut kernels = Vec::new();
    for at in 0..graph.node.len() {
        let node = &graph.node[at];
        if node.op_type != "AveragePool" || node.input.len() != 1 {
            continue;
        }
        let Some(kernel) = tiling_kernel(node) else {
            continue;
        };
        let Some(channels) = channels_of(&node.input[0], graph, &producer, &initializers) else {
            continue;
        };
        let weights = format!("{}.depthwise", node.output[0]);
        kernels.push(mean_kernel(&weights, channels, kernel));
        let node = &mut graph.node[at];
        node.op_type = "Conv".into();
        node.input.push(weights);
        node.attribute = vec![
            ints("kernel_shape", vec![kernel[0], kernel[1]]),
            ints("strides", vec![kernel[0], kernel[1]]),
            pb::AttributeProto {
                name: "group".into(),
                r#type: AttributeType::Int as i32,
                i: channels,
                ..Default::default()
            },
        ];
    }
    let replaced = kernels.len();
    graph.initializer.extend(kernels);
    replaced
}

/// The 2-D kernel of an AveragePool whose windows tile its input exactly: strides equal
/// to the kernel, no padding, no ceil mode (so `count_include_pad` cannot matter).
fn tiling_kernel(node: &pb::NodeProto) -> Option<[i64; 2]> {
    let mut kernel = None;
    let mut strides = None;
    for a in &node.attribute {
        match a.name.as_str() {
            "kernel_shape" => kernel = Some(a.ints.clone()),
            "strides" => strides = Some(a.ints.clone()),
            "pads" if a.ints.iter().any(|&p| p != 0) => return None,
            "ceil_mode" if a.i != 0 => return None,
            "auto_pad" if !matches!(&a.s[..], b"" | b"NOTSET" | b"VALID") => return None,
            "pads" | "ceil_mode" | "auto_pad" | "count_include_pad" => {}
            _ => return None,
        }
    }
    match (kernel?.as_slice(), strides?.as_slice()) {
        (&[kh, kw], &[sh, sw]) if kh == sh && kw == sw && kh > 0 && kw > 0 => Some([kh, kw]),
        _ => None,
    }
}

/// The channels of `tensor`: the output channels of the convolution it comes from,
/// through shape-keeping element-wise ops.
fn channels_of(
    tensor: &str,
    graph: &pb::GraphProto,
    producer: &HashMap<String, usize>,
    initializers: &HashMap<String, usize>,
) -> Option<i64> {
    let mut name = tensor;
    loop {
        let node = &graph.node[*producer.get(name)?];
        if SHAPE_KEEPING.contains(&node.op_type.as_str()) {
            name = node.input.first()?;
            continue;
        }
        if node.op_type != "Conv" {
            return None;
        }
        let weights = &graph.initializer[*initializers.get(node.input.get(1)?)?];
        return weights.dims.first().copied().filter(|&c| c > 0);
    }
}

/// A depthwise kernel of `channels` filters, each the mean over a window of `kernel`.
fn mean_kernel(name: &str, channels: i64, kernel: [i64; 2]) -> pb::TensorProto {
    let taps = kernel[0] * kernel[1];
    pb::TensorProto {
        name: name.into(),
        data_type: DataType::Float as i32,
        dims: vec![channels, 1, kernel[0], kernel[1]],
        float_data: vec![1.0 / taps as f32; (channels * taps) as usize],
        ..Default::default()
    }
}

fn ints(name: &str, ints: Vec<i64>) -> pb::AttributeProto {
    pb::AttributeProto {
        name: name.into(),
        r#type: AttributeType::Ints as i32,
        ints,
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::test_graphs::{model, node, tensor};
    use tract_onnx::prelude::*;

    const FLOAT: i32 = DataType::Float as i32;

    /// x (1×1×4×6) → Conv to 3 channels (1×1 kernel, weights 1, 2, 3) → LeakyRelu →
    /// AveragePool with `pool` attributes.
    fn pooled(pool: Vec<pb::AttributeProto>) -> pb::ModelProto {
        let w: Vec<u8> = [1.0f32, 2.0, 3.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let mut conv = node("Conv", &["x", "w"], "c");
        conv.attribute.clear();
        let mut relu = node("LeakyRelu", &["c"], "r");
        relu.attribute.clear();
        let mut avg = node("AveragePool", &["r"], "y");
        avg.attribute = pool;
        let mut m = model(
            vec![tensor("w", FLOAT, &[3, 1, 1, 1], w)],
            vec![conv, relu, avg],
        );
        let graph = m.graph.as_mut().unwrap();
        graph.input = vec![info("x", &[1, 1, 4, 6])];
        graph.output = vec![info("y", &[])];
        m.opset_import = vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: 13,
        }];
        m
    }

    fn info(name: &str, dims: &[i64]) -> pb::ValueInfoProto {
        use pb::tensor_shape_proto::{dimension::Value, Dimension};
        let dim = dims
            .iter()
            .map(|&d| Dimension {
                value: Some(Value::DimValue(d)),
                ..Default::default()
            })
            .collect();
        pb::ValueInfoProto {
            name: name.into(),
            r#type: Some(pb::TypeProto {
                value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                    elem_type: FLOAT,
                    shape: (!dims.is_empty()).then_some(pb::TensorShapeProto { dim }),
                })),
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    fn run(m: &pb::ModelProto) -> Vec<f32> {
        let plan = tract_onnx::onnx()
            .model_for_proto_model(m)
            .unwrap()
            .into_optimized()
            .unwrap()
            .into_runnable()
            .unwrap();
        let x: Vec<f32> = (0..24).map(|i| (i as f32 * 0.37).sin()).collect();
        let x = tract_ndarray::Array4::from_shape_vec((1, 1, 4, 6), x).unwrap();
        let out = plan.run(tvec!(x.into_tensor().into())).unwrap();
        out[0]
            .to_plain_array_view::<f32>()
            .unwrap()
            .iter()
            .copied()
            .collect()
    }

    #[test]
    fn a_tiling_average_pool_becomes_a_depthwise_mean() {
        for kernel in [vec![2, 2], vec![2, 3]] {
            let mut m = pooled(vec![
                ints("kernel_shape", kernel.clone()),
                ints("strides", kernel.clone()),
            ]);
            let before = run(&m);
            assert_eq!(average_pools_as_depthwise(&mut m), 1);
            let pool = &m.graph.as_ref().unwrap().node[2];
            assert_eq!(pool.op_type, "Conv");
            assert_eq!(pool.attribute[2].i, 3, "one group per channel");
            let after = run(&m);
            assert_eq!(before.len(), 3 * 24 / (kernel[0] * kernel[1]) as usize);
            for (a, b) in before.iter().zip(&after) {
                assert!((a - b).abs() < 1e-6, "{kernel:?}: {before:?} vs {after:?}");
            }
        }
    }

    #[test]
    fn overlapping_or_padded_pools_are_left_alone() {
        let overlapping = vec![
            ints("kernel_shape", vec![3, 3]),
            ints("strides", vec![1, 1]),
        ];
        let padded = vec![
            ints("kernel_shape", vec![2, 2]),
            ints("strides", vec![2, 2]),
            ints("pads", vec![1, 1, 1, 1]),
        ];
        for attributes in [overlapping, padded] {
            let mut m = pooled(attributes);
            assert_eq!(average_pools_as_depthwise(&mut m), 0);
            assert_eq!(m.graph.unwrap().node[2].op_type, "AveragePool");
        }
    }

    #[test]
    fn a_pool_of_unknown_channels_is_left_alone() {
        let mut m = pooled(vec![
            ints("kernel_shape", vec![2, 2]),
            ints("strides", vec![2, 2]),
        ]);
        let graph = m.graph.as_mut().unwrap();
        graph.node[2].input = vec!["x".into()];
        assert_eq!(average_pools_as_depthwise(&mut m), 0);
    }
}
