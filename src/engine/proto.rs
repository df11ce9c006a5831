//! Reading ONNX protobuf tensors, for the graph rewrites done at load time.

use std::collections::HashMap;

use tract_onnx::pb::{self, tensor_proto::DataType};

const FLOAT: i32 = DataType::Float as i32;

/// The positions of the nodes that read each tensor, by name.
pub(super) fn readers(graph: &pb::GraphProto) -> HashMap<&String, Vec<usize>> {
    let mut readers: HashMap<&String, Vec<usize>> = HashMap::new();
    for (at, node) in graph.node.iter().enumerate() {
        for input in &node.input {
            readers.entry(input).or_default().push(at);
        }
    }
    readers
}

/// Each initializer's position in the graph, by name.
pub(super) fn initializer_index(graph: &pb::GraphProto) -> HashMap<String, usize> {
    graph
        .initializer
        .iter()
        .enumerate()
        .map(|(i, t)| (t.name.clone(), i))
        .collect()
}

pub(super) fn floats(t: &pb::TensorProto) -> Result<Vec<f32>, String> {
    words(
        t,
        FLOAT,
        "scale",
        "float",
        &t.float_data,
        f32::from_le_bytes,
    )
}

/// The values of a tensor of 4-byte elements of type `data_type`, from its raw bytes
/// (little-endian) or its typed field `typed`; `role` and `kind` name it in the error.
pub(super) fn words<T: Clone>(
    t: &pb::TensorProto,
    data_type: i32,
    role: &str,
    kind: &str,
    typed: &[T],
    from_le: fn([u8; 4]) -> T,
) -> Result<Vec<T>, String> {
    if t.data_type != data_type {
        return Err(format!(
            "{role} {:?} has element type {}; expected {kind}",
            t.name, t.data_type
        ));
    }
    if t.raw_data.is_empty() {
        return Ok(typed.to_vec());
    }
    Ok(t.raw_data
        .chunks_exact(4)
        .map(|b| from_le([b[0], b[1], b[2], b[3]]))
        .collect())
}

/// A float scalar initializer.
pub(super) fn scalar(name: String, value: f32) -> pb::TensorProto {
    pb::TensorProto {
        name,
        data_type: FLOAT,
        float_data: vec![value],
        ..Default::default()
    }
}
