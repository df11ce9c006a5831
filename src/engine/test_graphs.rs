//! Small ONNX graphs for the unit tests of the graph rewrites: tensors, nodes and models
//! built by hand, and a run of a model in tract.

use tract_onnx::pb;

const FLOAT: i32 = pb::tensor_proto::DataType::Float as i32;

pub(super) fn tensor(name: &str, data_type: i32, dims: &[i64], raw: Vec<u8>) -> pb::TensorProto {
    pb::TensorProto {
        name: name.into(),
        data_type,
        dims: dims.to_vec(),
        raw_data: raw,
        ..Default::default()
    }
}

pub(super) fn node(op: &str, inputs: &[&str], output: &str) -> pb::NodeProto {
    pb::NodeProto {
        op_type: op.into(),
        name: format!("{op}_{output}"),
        input: inputs.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        attribute: vec![pb::AttributeProto {
            name: "axis".into(),
            i: 0,
            ..Default::default()
        }],
        ..Default::default()
    }
}

pub(super) fn model(initializer: Vec<pb::TensorProto>, node: Vec<pb::NodeProto>) -> pb::ModelProto {
    pb::ModelProto {
        graph: Some(pb::GraphProto {
            initializer,
            node,
            ..Default::default()
        }),
        ..Default::default()
    }
}

/// A float vector of `len` elements.
pub(super) fn value_info(name: &str, len: i64) -> pb::ValueInfoProto {
    shaped_value_info(name, &[len])
}

/// A float tensor of shape `dims`.
pub(super) fn shaped_value_info(name: &str, dims: &[i64]) -> pb::ValueInfoProto {
    let dim = |v: i64| pb::tensor_shape_proto::Dimension {
        value: Some(pb::tensor_shape_proto::dimension::Value::DimValue(v)),
        ..Default::default()
    };
    pb::ValueInfoProto {
        name: name.into(),
        r#type: Some(pb::TypeProto {
            value: Some(pb::type_proto::Value::TensorType(pb::type_proto::Tensor {
                elem_type: FLOAT,
                shape: Some(pb::TensorShapeProto {
                    dim: dims.iter().map(|&d| dim(d)).collect(),
                }),
            })),
            ..Default::default()
        }),
        ..Default::default()
    }
}

/// A run's outputs as flat float vectors.
pub(super) fn flat_outputs(outputs: &[tract_onnx::prelude::TValue]) -> Vec<Vec<f32>> {
    outputs
        .iter()
        .map(|t| {
            t.to_plain_array_view::<f32>()
                .unwrap()
                .iter()
                .copied()
                .collect()
        })
        .collect()
}

pub(super) fn run(model: &pb::ModelProto, x: &[f32]) -> Vec<Vec<f32>> {
    use tract_onnx::prelude::*;
    let plan = tract_onnx::onnx()
        .model_for_proto_model(model)
        .unwrap()
        .into_optimized()
        .unwrap()
        .into_runnable()
        .unwrap();
    let input = tract_ndarray::Array1::from_vec(x.to_vec()).into_tensor();
    flat_outputs(&plan.run(tvec!(input.into())).unwrap())
}
