//! Frequency encodings evaluated by doubling, rewritten in the ONNX graph at load time.
//!
//! The reshading encoder expands disparity d into sin(2^k·d) and cos(2^k·d), k = 0..4.
//! tract evaluates Sin and Cos one element at a time, a quarter of the encoder's time
//! at 576×768. Past the lowest octave the others follow from the one below by
//! sin 2a = 2·sin a·cos a and cos 2a = (cos a − sin a)(cos a + sin a): element-wise
//! products that tract runs vectorised. Each doubling at most doubles the error of the
//! octave below, about 1e-6 after four octaves in f32, far below a level.

use std::collections::{HashMap, HashSet};

use tract_onnx::pb;

use super::proto::{floats, initializer_index, readers};

/// One Mul(x, c) whose product only Sin and Cos read: sin(c·x) and cos(c·x).
struct Octave {
    factor: f32,
    mul: usize,
    sin: usize,
    cos: usize,
}

/// Rewrites every octave of a frequency encoding whose factor is twice that of the
/// octave below (same input x) as products of the octave below. Returns how many
/// octaves were rewritten.
pub fn double_angle_octaves(model: &mut pb::ModelProto) -> usize {
    let Some(graph) = model.graph.as_mut() else {
        return 0;
    };
    let chains = find_chains(graph);
    if chains.is_empty() {
        return 0;
    }
    // Each rewritten octave's new nodes, emitted right after the nodes of the octave
    // below it are all in place (keeps the node list in topological order).
    let mut removed: HashSet<usize> = HashSet::new();
    let mut after: HashMap<usize, Vec<pb::NodeProto>> = HashMap::new();
    let mut rewritten = 0;
    for chain in &chains {
        let mut doubled = Vec::new();
        for pair in chain.windows(2) {
            let (below, octave) = (&pair[0], &pair[1]);
            let [s, c] = [below.sin, below.cos].map(|at| graph.node[at].output[0].clone());
            let [s2, c2] = [octave.sin, octave.cos].map(|at| graph.node[at].output[0].clone());
            doubled.extend(doubling(&s, &c, &s2, &c2));
            removed.extend([octave.mul, octave.sin, octave.cos]);
            rewritten += 1;
        }
        let last_of_base = chain[0].sin.max(chain[0].cos);
        after.insert(last_of_base, doubled);
    }
    let nodes = std::mem::take(&mut graph.node);
    for (at, node) in nodes.into_iter().enumerate() {
        if !removed.contains(&at) {
            graph.node.push(node);
        }
        if let Some(extra) = after.remove(&at) {
            graph.node.extend(extra);
        }
    }
    rewritten
}

/// sin 2a and cos 2a, written to `s2` and `c2`, from sin a and cos a in `s` and `c`.
fn doubling(s: &str, c: &str, s2: &str, c2: &str) -> [pb::NodeProto; 5] {
    let op = |op_type: &str, a: &str, b: &str, out: String| pb::NodeProto {
        op_type: op_type.into(),
        name: format!("{out}.{op_type}"),
        input: vec![a.into(), b.into()],
        output: vec![out],
        ..Default::default()
    };
    let half = format!("{s2}.half");
    let diff = format!("{c2}.diff");
    let sum = format!("{c2}.sum");
    [
        op("Mul", s, c, half.clone()),
        op("Add", &half, &half, s2.into()),
        op("Sub", c, s, diff.clone()),
        op("Add", c, s, sum.clone()),
        op("Mul", &diff, &sum, c2.into()),
    ]
}

/// The chains of octaves to rewrite: per input, octaves sorted by factor, each twice
/// the one before, whose base's Sin and Cos come before every later octave's node.
fn find_chains(graph: &pb::GraphProto) -> Vec<Vec<Octave>> {
    let scalars = scalar_constants(graph);
    let outputs: HashSet<&String> = graph.output.iter().map(|o| &o.name).collect();
    let readers = readers(graph);
    let mut by_input: HashMap<&String, Vec<Octave>> = HashMap::new();
    for (at, node) in graph.node.iter().enumerate() {
        if node.op_type != "Mul" || node.input.len() != 2 || node.output.len() != 1 {
            continue;
        }
        let (x, factor) = match (scalars.get(&node.input[0]), scalars.get(&node.input[1])) {
            (None, Some(&f)) => (&node.input[0], f),
            (Some(&f), None) => (&node.input[1], f),
            _ => continue,
        };
        if outputs.contains(&node.output[0]) {
            continue;
        }
        let reads = readers.get(&node.output[0]).map_or(&[][..], Vec::as_slice);
        let only = |op: &str| {
            let found: Vec<usize> = reads
                .iter()
                .copied()
                .filter(|&r| graph.node[r].op_type == op)
                .collect();
            (found.len() == 1).then(|| found[0])
        };
        if let (2, Some(sin), Some(cos)) = (reads.len(), only("Sin"), only("Cos")) {
            by_input.entry(x).or_default().push(Octave {
                factor,
                mul: at,
                sin,
                cos,
            });
        }
    }
    let mut chains = Vec::new();
    for (_, mut octaves) in by_input {
        octaves.sort_by(|a, b| a.factor.total_cmp(&b.factor));
        let mut chain: Vec<Octave> = Vec::new();
        for octave in octaves {
            let extends = chain.last().is_some_and(|last| {
                octave.factor == 2.0 * last.factor
                    && chain[0].sin.max(chain[0].cos) < octave.sin.min(octave.cos)
            });
            if !extends {
                if chain.len() > 1 {
                    chains.push(std::mem::take(&mut chain));
                }
                chain.clear();
            }
            chain.push(octave);
        }
        if chain.len() > 1 {
            chains.push(chain);
        }
    }
    chains
}

/// The graph's scalar float constants, by name: initializers and Constant nodes.
fn scalar_constants(graph: &pb::GraphProto) -> HashMap<String, f32> {
    let scalar = |t: &pb::TensorProto| match floats(t).ok()?[..] {
        [v] if v.is_finite() => Some(v),
        _ => None,
    };
    let mut found: HashMap<String, f32> = initializer_index(graph)
        .into_iter()
        .filter_map(|(name, at)| Some((name, scalar(&graph.initializer[at])?)))
        .collect();
    for node in &graph.node {
        if node.op_type != "Constant" || node.output.len() != 1 {
            continue;
        }
        let value = node.attribute.iter().find(|a| a.name == "value");
        if let Some(v) = value.and_then(|a| a.t.as_ref()).and_then(scalar) {
            found.insert(node.output[0].clone(), v);
        }
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::test_graphs::{model, node, run, tensor, value_info};

    const FLOAT: i32 = pb::tensor_proto::DataType::Float as i32;

    /// x → Mul by each factor → Sin and Cos → Concat, factors as initializers.
    fn encoding(factors: &[f32]) -> pb::ModelProto {
        let mut nodes = Vec::new();
        let mut inits = Vec::new();
        let mut parts = Vec::new();
        for (k, f) in factors.iter().enumerate() {
            inits.push(tensor(
                &format!("f{k}"),
                FLOAT,
                &[],
                f.to_le_bytes().to_vec(),
            ));
            let mut mul = node("Mul", &["x", &format!("f{k}")], &format!("m{k}"));
            mul.attribute.clear();
            nodes.push(mul);
            for op in ["Sin", "Cos"] {
                let mut n = node(op, &[&format!("m{k}")], &format!("{op}{k}"));
                n.attribute.clear();
                nodes.push(n);
                parts.push(format!("{op}{k}"));
            }
        }
        let parts: Vec<&str> = parts.iter().map(String::as_str).collect();
        let mut concat = node("Concat", &parts, "y");
        concat.attribute[0].r#type = pb::attribute_proto::AttributeType::Int as i32;
        nodes.push(concat);
        let mut m = model(inits, nodes);
        let graph = m.graph.as_mut().unwrap();
        graph.input = vec![value_info("x", 8)];
        graph.output = vec![value_info("y", 16 * factors.len() as i64)];
        m.opset_import = vec![pb::OperatorSetIdProto {
            domain: String::new(),
            version: 13,
        }];
        m
    }

    fn ops(m: &pb::ModelProto, op: &str) -> usize {
        let graph = m.graph.as_ref().unwrap();
        graph.node.iter().filter(|n| n.op_type == op).count()
    }

    #[test]
    fn doubled_octaves_become_products_of_the_lowest() {
        let mut m = encoding(&[1.0, 2.0, 4.0, 8.0, 16.0]);
        let x = [0.0, 0.03, 0.2, 0.37, 0.5, 0.71, 0.9, 1.0];
        let before = run(&m, &x);
        assert_eq!(double_angle_octaves(&mut m), 4);
        assert_eq!((ops(&m, "Sin"), ops(&m, "Cos"), ops(&m, "Mul")), (1, 1, 9));
        let after = run(&m, &x);
        let worst = before[0]
            .iter()
            .zip(&after[0])
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 4e-6, "largest difference {worst}");
    }

    #[test]
    fn factors_that_do_not_double_are_left_alone() {
        let mut m = encoding(&[1.0, 3.0, 6.0]);
        // 3 → 6 doubles, but 1 → 3 does not: only the chain from 3 is rewritten.
        assert_eq!(double_angle_octaves(&mut m), 1);
        assert_eq!((ops(&m, "Sin"), ops(&m, "Cos")), (2, 2));
        let mut m = encoding(&[1.0, 3.0]);
        assert_eq!(double_angle_octaves(&mut m), 0);
        let mut m = encoding(&[2.0]);
        assert_eq!(double_angle_octaves(&mut m), 0);
    }
}
