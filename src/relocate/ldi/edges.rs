//! Depth discontinuities: where the mesh is cut.
//!
//! A step between two neighbouring pixels is a discontinuity when, in disparity, it is
//! large relative to the local disparity *and* not explained by the slope around it (a
//! plane's disparity is affine in the image, so a tilted floor has equal steps
//! everywhere and is never cut). Of a ramp a few pixels wide only the largest step is
//! kept. The nearer pixel of each step is an edge pixel; edge pixels are linked
//! 8-connectedly into contours, and contours shorter than a minimum are dropped as noise.

/// Which neighbouring pixel pairs are separated by a discontinuity.
pub(super) struct Cuts {
    pub width: usize,
    pub height: usize,
    /// Pair (x, y)–(x+1, y) at index y·width + x.
    pub horizontal: Vec<bool>,
    /// Pair (x, y)–(x, y+1) at index y·width + x.
    pub vertical: Vec<bool>,
    pub contours_kept: usize,
    pub contours_dropped: usize,
}

impl Cuts {
    /// Whether 4-neighbours `a` and `b` (pixel indices) are separated.
    pub fn between(&self, a: usize, b: usize) -> bool {
        let (lo, hi) = (a.min(b), a.max(b));
        if hi == lo + 1 {
            self.horizontal[lo]
        } else {
            self.vertical[lo]
        }
    }

    /// Every cut as (nearer pixel, farther pixel).
    pub fn pairs<'a>(&'a self, disparity: &'a [f32]) -> impl Iterator<Item = (usize, usize)> + 'a {
        let w = self.width;
        let h = self
            .horizontal
            .iter()
            .enumerate()
            .filter(|(_, &c)| c)
            .map(|(i, _)| (i, i + 1));
        let v = self
            .vertical
            .iter()
            .enumerate()
            .filter(|(_, &c)| c)
            .map(move |(i, _)| (i, i + w));
        h.chain(v).map(|(a, b)| {
            if disparity[a] >= disparity[b] {
                (a, b)
            } else {
                (b, a)
            }
        })
    }
}

/// Finds the discontinuities of a disparity map (`width`×`height`, rows top to bottom).
/// `threshold` is the smallest step, relative to the larger disparity of the pair, that
/// counts; `min_contour` the fewest edge pixels a contour needs to be kept.
pub(super) fn detect(
    disparity: &[f32],
    width: usize,
    height: usize,
    threshold: f32,
    min_contour: usize,
) -> Cuts {
    let mut horizontal = vec![false; width * height];
    let mut vertical = vec![false; width * height];
    let mut line = Vec::new();
    let mut marks = Vec::new();
    for y in 0..height {
        line.clear();
        line.extend_from_slice(&disparity[y * width..(y + 1) * width]);
        mark_line(&line, threshold, &mut marks);
        for (x, &m) in marks.iter().enumerate() {
            horizontal[y * width + x] = m;
        }
    }
    for x in 0..width {
        line.clear();
        line.extend((0..height).map(|y| disparity[y * width + x]));
        mark_line(&line, threshold, &mut marks);
        for (y, &m) in marks.iter().enumerate() {
            vertical[y * width + x] = m;
        }
    }
    let mut cuts = Cuts {
        width,
        height,
        horizontal,
        vertical,
        contours_kept: 0,
        contours_dropped: 0,
    };
    drop_short_contours(&mut cuts, disparity, min_contour);
    cuts
}

/// Marks the steps of one row or column; `marks[i]` is the step between i and i+1.
fn mark_line(d: &[f32], threshold: f32, marks: &mut Vec<bool>) {
    let n = d.len();
    marks.clear();
    marks.resize(n.saturating_sub(1), false);
    let step = |i: usize| d[i + 1] - d[i];
    for i in 0..n.saturating_sub(1) {
        let s = step(i);
        let limit = threshold * d[i].max(d[i + 1]);
        if s.abs() <= limit {
            continue;
        }
        // The slope two steps away on either side predicts this step on a plane.
        let mut residual = s.abs();
        if i >= 2 {
            residual = residual.min((s - step(i - 2)).abs());
        }
        if i + 2 < n - 1 {
            residual = residual.min((s - step(i + 2)).abs());
        }
        if residual <= limit {
            continue;
        }
        // Only the largest step of a same-signed ramp is the edge.
        let same_sign_larger = |j: usize, strict: bool| {
            let t = step(j);
            t.signum() == s.signum()
                && if strict {
                    t.abs() > s.abs()
                } else {
                    t.abs() >= s.abs()
                }
        };
        if (i >= 1 && same_sign_larger(i - 1, true))
            || (i + 2 < n && same_sign_larger(i + 1, false))
        {
            continue;
        }
        marks[i] = true;
    }
}

/// Links the nearer pixels of the cuts into 8-connected contours and removes the cuts
/// of contours with fewer than `min_contour` pixels.
fn drop_short_contours(cuts: &mut Cuts, disparity: &[f32], min_contour: usize) {
    let (w, h) = (cuts.width, cuts.height);
    let mut edge = vec![false; w * h];
    for (near, _) in cuts.pairs(disparity) {
        edge[near] = true;
    }
    let mut label = vec![u32::MAX; w * h];
    let mut keep = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if !edge[start] || label[start] != u32::MAX {
            continue;
        }
        let id = keep.len() as u32;
        let mut size = 0;
        label[start] = id;
        stack.push(start);
        while let Some(p) = stack.pop() {
            size += 1;
            let (x, y) = ((p % w) as i64, (p / w) as i64);
            for (dx, dy) in NEIGHBOURS_8 {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                    continue;
                }
                let q = ny as usize * w + nx as usize;
                if edge[q] && label[q] == u32::MAX {
                    label[q] = id;
                    stack.push(q);
                }
            }
        }
        keep.push(size >= min_contour);
    }
    cuts.contours_kept = keep.iter().filter(|&&k| k).count();
    cuts.contours_dropped = keep.len() - cuts.contours_kept;
    let kept = |a: usize, b: usize| {
        let near = if disparity[a] >= disparity[b] { a } else { b };
        keep[label[near] as usize]
    };
    for i in 0..w * h {
        if cuts.horizontal[i] && !kept(i, i + 1) {
            cuts.horizontal[i] = false;
        }
        if cuts.vertical[i] && !kept(i, i + w) {
            cuts.vertical[i] = false;
        }
    }
}

const NEIGHBOURS_8: [(i64, i64); 8] = [
    (-1, -1),
    (0, -1),
    (1, -1),
    (-1, 0),
    (1, 0),
    (-1, 1),
    (0, 1),
    (1, 1),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn marks(d: &[f32]) -> Vec<bool> {
        let mut m = Vec::new();
        mark_line(d, 0.05, &mut m);
        m
    }

    #[test]
    fn a_step_is_cut_once_a_slope_never() {
        assert_eq!(
            marks(&[0.25, 0.25, 1.0, 1.0, 1.0]),
            vec![false, true, false, false]
        );
        let slope: Vec<f32> = (0..10).map(|i| 0.2 + 0.05 * i as f32).collect();
        assert!(marks(&slope).iter().all(|&m| !m));
        // A step smeared over two pixels is cut at its larger half only.
        assert_eq!(
            marks(&[0.25, 0.25, 0.5, 1.0, 1.0, 1.0]),
            vec![false, false, true, false, false]
        );
    }

    #[test]
    fn a_one_pixel_spike_is_cut_on_both_sides() {
        assert_eq!(
            marks(&[0.25, 0.25, 1.0, 0.25, 0.25]),
            vec![false, true, true, false]
        );
    }

    #[test]
    fn short_contours_are_dropped() {
        let (w, h) = (20, 20);
        let mut d = vec![0.25f32; w * h];
        // A lone near pixel (1-pixel contour) and a 10-pixel-tall near bar.
        d[3 * w + 3] = 1.0;
        for y in 5..15 {
            d[y * w + 12] = 1.0;
        }
        let cuts = detect(&d, w, h, 0.05, 4);
        assert_eq!((cuts.contours_kept, cuts.contours_dropped), (1, 1));
        assert!(!cuts.between(3 * w + 3, 3 * w + 4));
        assert!(cuts.between(7 * w + 12, 7 * w + 13));
        assert!(cuts.between(7 * w + 11, 7 * w + 12));
    }
}
