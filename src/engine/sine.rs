//! Sin and Cos as polynomials, rewritten in the ONNX graph at load time.
//!
//! tract evaluates Sin and Cos one element at a time through the C library: the two
//! left in the reshading encoder after [`super::octaves`] (the lowest octave of its
//! frequency encoding of disparity) took 6 of its 13 ms at 256×192. Written as
//! element-wise arithmetic, which tract runs vectorised, they cost a fraction of that:
//! x = n·π + r with n the nearest integer to x/π and |r| ≤ π/2, then
//! sin x = (−1)ⁿ·sin r and cos x = (−1)ⁿ·cos r, with sin r and cos r from their Taylor
//! series to r¹¹ and r¹² (truncation below 6e-8 on |r| ≤ π/2). The error is a few f32
//! roundings of the result plus that of r, which grows with n (about 1e-7 per unit of
//! n): 2e-7 on the encoder's disparities, far below a level. Beyond |x| of about 4e6 the
//! rounding constant no longer gives the nearest integer; the results are then clamped
//! to [−1, 1], as meaningless as f32's own sine is out there.

use std::collections::BTreeMap;

use tract_onnx::pb;

use super::int8::ROUNDING_MAGIC;
use super::proto::scalar;

/// Odd Taylor coefficients of sin r after r: −1/3!, 1/5!, … , −1/11!.
const SIN: [f32; 5] = [
    -1.0 / 6.0,
    1.0 / 120.0,
    -1.0 / 5040.0,
    1.0 / 362_880.0,
    -1.0 / 39_916_800.0,
];
/// Even Taylor coefficients of cos r after 1: −1/2!, 1/4!, … , 1/12!.
const COS: [f32; 6] = [
    -0.5,
    1.0 / 24.0,
    -1.0 / 720.0,
    1.0 / 40_320.0,
    -1.0 / 3_628_800.0,
    1.0 / 479_001_600.0,
];
/// π split so that n·π is subtracted from x in two steps without losing r's digits.
const PI_HI: f32 = std::f32::consts::PI;
const PI_LO: f32 = -8.742_278e-8;

/// Replaces every Sin and Cos node; one range reduction serves a Sin and a Cos of the
/// same input. Returns how many nodes were replaced.
pub fn polynomial_sines(model: &mut pb::ModelProto) -> usize {
    let Some(graph) = model.graph.as_mut() else {
        return 0;
    };
    // Per input, the position of its first Sin or Cos, where the new nodes go (after
    // whatever computes the input).
    let mut first_reader: BTreeMap<String, usize> = BTreeMap::new();
    for (at, node) in graph.node.iter().enumerate() {
        if is_sine(node) {
            first_reader.entry(node.input[0].clone()).or_insert(at);
        }
    }
    if first_reader.is_empty() {
        return 0;
    }
    let mut reductions: BTreeMap<usize, String> =
        first_reader.into_iter().map(|(x, at)| (at, x)).collect();
    let mut replaced = 0;
    let nodes = std::mem::take(&mut graph.node);
    for (at, node) in nodes.into_iter().enumerate() {
        if let Some(x) = reductions.remove(&at) {
            let mut emit = Emitter::new(&x, graph);
            emit.reduction();
        }
        if !is_sine(&node) {
            graph.node.push(node);
            continue;
        }
        let mut emit = Emitter::new(&node.input[0], graph);
        let out = &node.output[0];
        let polynomial = if node.op_type == "Sin" {
            emit.sin(out)
        } else {
            emit.series("c", COS.len(), out)
        };
        emit.signed(&polynomial, out);
        replaced += 1;
    }
    replaced
}

fn is_sine(node: &pb::NodeProto) -> bool {
    matches!(node.op_type.as_str(), "Sin" | "Cos")
        && node.input.len() == 1
        && node.output.len() == 1
}

/// Appends the nodes and constants of one input's evaluation to the graph, naming
/// every tensor after the input.
struct Emitter<'g> {
    x: String,
    graph: &'g mut pb::GraphProto,
}

impl<'g> Emitter<'g> {
    fn new(x: &str, graph: &'g mut pb::GraphProto) -> Self {
        Emitter {
            x: x.to_owned(),
            graph,
        }
    }

    fn name(&self, what: &str) -> String {
        format!("{}.sine.{what}", self.x)
    }

    fn constant(&mut self, what: &str, value: f32) -> String {
        let name = self.name(what);
        self.graph.initializer.push(scalar(name.clone(), value));
        name
    }

    fn op(&mut self, op_type: &str, inputs: &[&str], output: String) -> String {
        self.graph.node.push(pb::NodeProto {
            op_type: op_type.into(),
            name: format!("{output}.{op_type}"),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.clone()],
            ..Default::default()
        });
        output
    }

    /// round(v) by adding and taking away [`ROUNDING_MAGIC`].
    fn round(&mut self, v: &str, what: &str) -> String {
        let magic = self.name("magic");
        let shifted = self.op("Add", &[v, &magic], self.name(&format!("{what}.shifted")));
        self.op("Sub", &[&shifted, &magic], self.name(what))
    }

    /// n, r, r² and the sign (−1)ⁿ, and the constants they and the polynomials use.
    fn reduction(&mut self) {
        self.constant("magic", ROUNDING_MAGIC);
        let x = self.x.clone();
        let inv_pi = self.constant("inv_pi", std::f32::consts::FRAC_1_PI);
        let q = self.op("Mul", &[&x, &inv_pi], self.name("q"));
        let n = self.round(&q, "n");
        let pi_hi = self.constant("pi_hi", PI_HI);
        let pi_lo = self.constant("pi_lo", PI_LO);
        let n_hi = self.op("Mul", &[&n, &pi_hi], self.name("n_hi"));
        let r_hi = self.op("Sub", &[&x, &n_hi], self.name("r_hi"));
        let n_lo = self.op("Mul", &[&n, &pi_lo], self.name("n_lo"));
        let r = self.op("Sub", &[&r_hi, &n_lo], self.name("r"));
        self.op("Mul", &[&r, &r], self.name("r2"));
        // floor(n/2) = round(n/2 − 1/4) for integer n; n − 2·floor(n/2) is its parity.
        let half = self.constant("half", 0.5);
        let quarter = self.constant("quarter", 0.25);
        let two = self.constant("two", 2.0);
        let one = self.constant("one", 1.0);
        let n_half = self.op("Mul", &[&n, &half], self.name("n_half"));
        let below = self.op("Sub", &[&n_half, &quarter], self.name("n_half_below"));
        let pairs = self.round(&below, "pairs");
        let even = self.op("Mul", &[&pairs, &two], self.name("even"));
        let parity = self.op("Sub", &[&n, &even], self.name("parity"));
        let twice = self.op("Mul", &[&parity, &two], self.name("parity2"));
        self.op("Sub", &[&one, &twice], self.name("sign"));
        for (k, &c) in SIN.iter().enumerate() {
            self.constant(&format!("s{k}"), c);
        }
        for (k, &c) in COS.iter().enumerate() {
            self.constant(&format!("c{k}"), c);
        }
        self.constant("minus_one", -1.0);
    }

    /// Horner's rule in r²: 1 + r²·(c0 + r²·(c1 + …)) with the constants `prefix`k;
    /// its tensors are named after `out`, the output it serves.
    fn series(&mut self, prefix: &str, terms: usize, out: &str) -> String {
        let r2 = self.name("r2");
        let mut acc = self.name(&format!("{prefix}{}", terms - 1));
        for k in (0..terms - 1).rev() {
            let c = self.name(&format!("{prefix}{k}"));
            let scaled = self.op("Mul", &[&acc, &r2], format!("{out}.series.m{k}"));
            acc = self.op("Add", &[&scaled, &c], format!("{out}.series.a{k}"));
        }
        let scaled = self.op("Mul", &[&acc, &r2], format!("{out}.series.m"));
        let one = self.name("one");
        self.op("Add", &[&scaled, &one], format!("{out}.series"))
    }

    /// r·(1 + r²·(…)): the odd series.
    fn sin(&mut self, out: &str) -> String {
        let series = self.series("s", SIN.len(), out);
        let r = self.name("r");
        self.op("Mul", &[&series, &r], format!("{out}.odd"))
    }

    /// (−1)ⁿ·`polynomial`, clamped to [−1, 1], into `output`.
    fn signed(&mut self, polynomial: &str, output: &str) {
        let sign = self.name("sign");
        let signed = self.op("Mul", &[polynomial, &sign], format!("{output}.signed"));
        let (low, high) = (self.name("minus_one"), self.name("one"));
        let below = self.op("Min", &[&signed, &high], format!("{output}.below"));
        self.op("Max", &[&below, &low], output.to_owned());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::test_graphs::{model, run, value_info};

    fn unary(op: &str, input: &str, output: &str) -> pb::NodeProto {
        pb::NodeProto {
            op_type: op.into(),
            name: output.into(),
            input: vec![input.into()],
            output: vec![output.into()],
            ..Default::default()
        }
    }

    /// x → sin x, cos x, and the sine of −x, which gets its own reduction.
    fn sines(len: i64) -> pb::ModelProto {
        let mut m = model(
            vec![],
            vec![
                unary("Sin", "x", "s"),
                unary("Neg", "x", "minus"),
                unary("Cos", "x", "c"),
                unary("Sin", "minus", "s_minus"),
            ],
        );
        let graph = m.graph.as_mut().unwrap();
        graph.input = vec![value_info("x", len)];
        graph.output = ["s", "c", "s_minus"].map(|o| value_info(o, len)).to_vec();
        m
    }

    #[test]
    fn polynomial_sines_match_the_true_ones_to_a_few_roundings() {
        let mut x: Vec<f32> = (-4000..=4000).map(|i| i as f32 * 0.0125).collect();
        let pi = std::f32::consts::PI;
        x.extend([0.0, pi / 2.0, pi, -pi, 1e3, 123.456, 1e-30, -0.0]);
        let mut m = sines(x.len() as i64);
        let before = run(&m, &x);
        assert_eq!(polynomial_sines(&mut m), 3);
        let ops: Vec<&str> = m
            .graph
            .as_ref()
            .unwrap()
            .node
            .iter()
            .map(|n| n.op_type.as_str())
            .collect();
        assert!(!ops.contains(&"Sin") && !ops.contains(&"Cos"), "{ops:?}");
        let after = run(&m, &x);
        let truth: [fn(f64) -> f64; 3] = [f64::sin, f64::cos, |v| (-v).sin()];
        for ((got, libm), truth) in after.iter().zip(&before).zip(truth) {
            for ((&v, &g), &l) in x.iter().zip(got).zip(libm) {
                let want = truth(f64::from(v));
                let turns = (f64::from(v) / std::f64::consts::PI).abs().round();
                let allowed = 3e-7 * (1.0 + turns);
                assert!(
                    (f64::from(g) - want).abs() <= allowed,
                    "x = {v}: {g} against {want}"
                );
                assert!(
                    (g - l).abs() <= 2.0 * allowed as f32 + 1e-6,
                    "x = {v}: {g} against libm's {l}"
                );
            }
        }
    }

    #[test]
    fn results_stay_within_one_where_the_reduction_breaks_down() {
        let x = vec![1e9f32, -3e12, f32::MAX];
        let mut m = sines(x.len() as i64);
        polynomial_sines(&mut m);
        for output in run(&m, &x) {
            assert!(output.iter().all(|v| v.abs() <= 1.0), "{output:?}");
        }
    }
}
