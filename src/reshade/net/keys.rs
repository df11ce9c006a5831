//! Key views (option (b)): the network runs for K of the N cameras and the residual of
//! every other view is interpolated linearly between the two key views around it, along
//! the line the cameras lie on (a panel's cameras sit on a horizontal line).

/// Where each view's residual comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum Source {
    /// Run the network for this view.
    Key,
    /// `(1 - t) · residual[a] + t · residual[b]`, `a` and `b` being key views.
    Blend { a: usize, b: usize, t: f32 },
}

/// Chooses up to `k` key views (always the two outermost) among `centres` and says how
/// each other view is made from them. `k >= n` (or `k < 2`) makes every view a key.
pub fn plan(centres: &[[f64; 3]], k: usize) -> Vec<Source> {
    let n = centres.len();
    if k >= n || k < 2 {
        return vec![Source::Key; n];
    }
    let pos = positions(centres);
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| pos[a].total_cmp(&pos[b]));
    let (lo, hi) = (pos[order[0]], pos[order[n - 1]]);
    let mut keys: Vec<usize> = (0..k)
        .map(|j| {
            let target = lo + (hi - lo) * j as f64 / (k - 1) as f64;
            *order
                .iter()
                .min_by(|&&a, &&b| (pos[a] - target).abs().total_cmp(&(pos[b] - target).abs()))
                .expect("at least two views")
        })
        .collect();
    keys.sort_by(|&a, &b| pos[a].total_cmp(&pos[b]));
    keys.dedup();
    (0..n)
        .map(|v| {
            if keys.contains(&v) {
                return Source::Key;
            }
            let right = keys
                .iter()
                .position(|&key| pos[key] >= pos[v])
                .unwrap_or(keys.len() - 1)
                .max(1);
            let (a, b) = (keys[right - 1], keys[right]);
            let span = pos[b] - pos[a];
            let t = if span > 0.0 {
                ((pos[v] - pos[a]) / span).clamp(0.0, 1.0)
            } else {
                0.0
            };
            Source::Blend { a, b, t: t as f32 }
        })
        .collect()
}

/// Each camera's coordinate along the direction from the first camera to the farthest one.
fn positions(centres: &[[f64; 3]]) -> Vec<f64> {
    let origin = centres[0];
    let far = centres
        .iter()
        .map(|c| sub(*c, origin))
        .max_by(|a, b| dot(*a, *a).total_cmp(&dot(*b, *b)))
        .unwrap_or([0.0; 3]);
    let len = dot(far, far).sqrt();
    if len == 0.0 {
        return vec![0.0; centres.len()];
    }
    centres
        .iter()
        .map(|c| dot(sub(*c, origin), far) / len)
        .collect()
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize) -> Vec<[f64; 3]> {
        (0..n).map(|i| [i as f64 * 0.1 - 0.35, 0.0, 0.0]).collect()
    }

    #[test]
    fn all_views_are_keys_when_k_covers_them() {
        assert_eq!(plan(&line(5), 5), vec![Source::Key; 5]);
        assert_eq!(plan(&line(5), 0), vec![Source::Key; 5]);
    }

    #[test]
    fn outer_views_are_keys_and_the_middle_blends() {
        let sources = plan(&line(8), 2);
        assert_eq!(sources[0], Source::Key);
        assert_eq!(sources[7], Source::Key);
        for (i, s) in sources.iter().enumerate().take(7).skip(1) {
            let Source::Blend { a, b, t } = s else {
                panic!("view {i} should blend")
            };
            assert_eq!((*a, *b), (0, 7));
            assert!((t - i as f32 / 7.0).abs() < 1e-6);
        }
    }

    #[test]
    fn key_count_is_respected_and_order_does_not_matter() {
        let mut cams = line(9);
        cams.reverse();
        let sources = plan(&cams, 3);
        let keys: Vec<usize> = (0..9).filter(|&i| sources[i] == Source::Key).collect();
        assert_eq!(keys, vec![0, 4, 8]);
        assert_eq!(sources[2], Source::Blend { a: 0, b: 4, t: 0.5 });
    }
}
