//! fp16 as a storage format: x86 CPUs without fp16 arithmetic run fp16 graphs slowly or
//! not at all (tract fails type unification at Gemm and Resize), so an fp16 model is
//! widened to f32 once at load — weights converted with `half` (F16C where the CPU has
//! it), casts and declared types rewritten — and computed in f32.

use half::f16;
use half::slice::HalfFloatSliceExt;
use tract_onnx::pb::{self, tensor_proto::DataType, type_proto};

const FLOAT: i32 = DataType::Float as i32;
const FLOAT16: i32 = DataType::Float16 as i32;

/// Rewrites every f16 tensor, cast and declared type in `model` to f32; returns how many
/// f16 tensors were converted.
pub fn widen_to_f32(model: &mut pb::ModelProto) -> usize {
    model.graph.as_mut().map_or(0, widen_graph)
}

fn widen_graph(graph: &mut pb::GraphProto) -> usize {
    let mut converted = 0;
    for t in &mut graph.initializer {
        converted += widen_tensor(t);
    }
    for node in &mut graph.node {
        for attr in &mut node.attribute {
            converted += widen_attribute(&node.op_type, attr);
        }
    }
    for info in graph
        .input
        .iter_mut()
        .chain(&mut graph.output)
        .chain(&mut graph.value_info)
    {
        if let Some(pb::TypeProto {
            value: Some(type_proto::Value::TensorType(t)),
            ..
        }) = info.r#type.as_mut()
        {
            if t.elem_type == FLOAT16 {
                t.elem_type = FLOAT;
            }
        }
    }
    converted
}

fn widen_attribute(op: &str, attr: &mut pb::AttributeProto) -> usize {
    // Cast(to=float16) would narrow again what was just widened.
    if op == "Cast" && attr.name == "to" && attr.i == i64::from(FLOAT16) {
        attr.i = i64::from(FLOAT);
    }
    let mut converted = 0;
    if let Some(t) = attr.t.as_mut() {
        converted += widen_tensor(t);
    }
    for t in &mut attr.tensors {
        converted += widen_tensor(t);
    }
    if let Some(g) = attr.g.as_mut() {
        converted += widen_graph(g);
    }
    for g in &mut attr.graphs {
        converted += widen_graph(g);
    }
    converted
}

fn widen_tensor(t: &mut pb::TensorProto) -> usize {
    if t.data_type != FLOAT16 {
        return 0;
    }
    let halves: Vec<f16> = if t.raw_data.is_empty() {
        // The typed-field storage keeps each half's bits in the low 16 bits of an int32.
        t.int32_data
            .iter()
            .map(|&bits| f16::from_bits(bits as u16))
            .collect()
    } else {
        t.raw_data
            .chunks_exact(2)
            .map(|b| f16::from_bits(u16::from_le_bytes([b[0], b[1]])))
            .collect()
    };
    let mut floats = vec![0.0f32; halves.len()];
    halves.convert_to_f32_slice(&mut floats);
    t.data_type = FLOAT;
    t.int32_data.clear();
    t.raw_data.clear();
    t.float_data = floats;
    1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_and_typed_f16_tensors_widen_exactly() {
        let values = [1.5f32, -0.25, 65504.0];
        let raw: Vec<u8> = values
            .iter()
            .flat_map(|&v| f16::from_f32(v).to_bits().to_le_bytes())
            .collect();
        let mut a = pb::TensorProto {
            data_type: FLOAT16,
            dims: vec![3],
            raw_data: raw,
            ..Default::default()
        };
        let mut b = pb::TensorProto {
            data_type: FLOAT16,
            dims: vec![3],
            int32_data: values
                .iter()
                .map(|&v| i32::from(f16::from_f32(v).to_bits()))
                .collect(),
            ..Default::default()
        };
        assert_eq!(widen_tensor(&mut a), 1);
        assert_eq!(widen_tensor(&mut b), 1);
        for t in [a, b] {
            assert_eq!(t.data_type, FLOAT);
            assert_eq!(t.float_data, values);
            assert!(t.raw_data.is_empty() && t.int32_data.is_empty());
        }
    }

    #[test]
    fn casts_to_f16_become_casts_to_f32() {
        let mut node = pb::NodeProto {
            op_type: "Cast".into(),
            attribute: vec![pb::AttributeProto {
                name: "to".into(),
                i: i64::from(FLOAT16),
                ..Default::default()
            }],
            ..Default::default()
        };
        widen_attribute("Cast", &mut node.attribute[0]);
        assert_eq!(node.attribute[0].i, i64::from(FLOAT));
    }
}
