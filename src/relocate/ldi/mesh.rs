//! The layered mesh: every sample (an original pixel, or a band pixel behind an
//! occluder) is a quad spanning its pixel, whose corners it shares with the samples it
//! is connected to. Samples of one surface therefore meet without cracks, and a cut
//! leaves each side with its own corners, so nothing is stretched across it. Thin
//! structures keep their full pixel width because a sample's quad does not depend on
//! its neighbours existing.

use super::band::{Band, NONE};
use super::edges::Cuts;

/// A quad corner: its ray in the build camera (x/z, y/z) and its disparity.
#[derive(Clone, Copy, Debug)]
pub(super) struct Vertex {
    pub ray: [f32; 2],
    pub disparity: f32,
}

/// One quad: corner vertices (top-left, top-right, bottom-left, bottom-right) and the
/// pixel whose colour it shows.
#[derive(Clone, Copy, Debug)]
pub(super) struct Sample {
    pub corners: [u32; 4],
    pub colour_from: u32,
}

pub(super) struct Mesh {
    pub vertices: Vec<Vertex>,
    /// Original pixels first (sample i is pixel i), then band samples.
    pub samples: Vec<Sample>,
    /// The vertices on the photo's outline, each with the side it lies on (a corner
    /// of the photo is listed once for each of its two sides).
    pub outline: Vec<(u32, Side)>,
}

/// A side of the photo's frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Side {
    Left,
    Right,
    Top,
    Bottom,
}

pub(super) struct MeshInput<'a> {
    pub width: usize,
    pub height: usize,
    pub disparity: &'a [f32],
    pub cuts: &'a Cuts,
    pub band: &'a Band,
    /// Whether two band/original disparities belong to one surface.
    pub link_threshold: f32,
    /// Build-camera pixel → ray.
    pub ray: &'a dyn Fn(f64, f64) -> [f32; 2],
    /// How far outside the photo the border corners are pushed, in pixels.
    pub border_margin: f64,
}

/// A sample before its corners are known: pixel and layer.
#[derive(Clone, Copy, PartialEq)]
struct Slot {
    pixel: usize,
    back: bool,
}

impl MeshInput<'_> {
    fn disparity_of(&self, s: Slot) -> f32 {
        if s.back {
            self.band.disparity[self.band.at[s.pixel] as usize]
        } else {
            self.disparity[s.pixel]
        }
    }

    fn connected(&self, a: Slot, b: Slot) -> bool {
        if !a.back && !b.back {
            return !self.cuts.between(a.pixel, b.pixel);
        }
        let (da, db) = (self.disparity_of(a), self.disparity_of(b));
        // Band samples inpainted from different sides of an occluder meet inside it
        // with slightly different extrapolations; a crack between them would be worse
        // than the slight bend joining them, while surfaces of nested occluders differ
        // by far more.
        let tolerance = if a.back && b.back { 3.0 } else { 1.0 } * self.link_threshold;
        (da - db).abs() <= tolerance * da.max(db)
    }

    fn slots(&self, pixel: usize) -> impl Iterator<Item = Slot> {
        let back = self.band.at[pixel] != NONE;
        [
            Some(Slot { pixel, back: false }),
            back.then_some(Slot { pixel, back: true }),
        ]
        .into_iter()
        .flatten()
    }

    fn sample_index(&self, s: Slot) -> usize {
        if s.back {
            self.width * self.height + self.band.at[s.pixel] as usize
        } else {
            s.pixel
        }
    }

    /// Position of corner (cx, cy) in build pixels, border corners pushed outwards.
    fn corner_position(&self, cx: usize, cy: usize) -> (f64, f64) {
        let push = |c: usize, n: usize| match c {
            0 => -self.border_margin,
            c if c == n => n as f64 + self.border_margin,
            c => c as f64,
        };
        (push(cx, self.width), push(cy, self.height))
    }
}

pub(super) fn build(input: &MeshInput) -> Mesh {
    let (w, h) = (input.width, input.height);
    let count = w * h + input.band.disparity.len();
    let mut samples = vec![
        Sample {
            corners: [0; 4],
            colour_from: 0,
        };
        count
    ];
    for (i, s) in samples.iter_mut().enumerate().take(w * h) {
        s.colour_from = i as u32;
    }
    for (k, &src) in input.band.source.iter().enumerate() {
        samples[w * h + k].colour_from = src;
    }
    let mut vertices = Vec::with_capacity(count + w + h);
    let mut outline = Vec::with_capacity(4 * (w + h + 2));
    for cy in 0..=h {
        for cx in 0..=w {
            let first = vertices.len() as u32;
            add_corner(input, cx, cy, &mut vertices, &mut samples);
            let sides = [
                (cx == 0, Side::Left),
                (cx == w, Side::Right),
                (cy == 0, Side::Top),
                (cy == h, Side::Bottom),
            ];
            for (_, side) in sides.into_iter().filter(|&(on, _)| on) {
                outline.extend((first..vertices.len() as u32).map(|v| (v, side)));
            }
        }
    }
    Mesh {
        vertices,
        samples,
        outline,
    }
}

/// Groups the samples around corner (cx, cy) into connected sets and gives each set a
/// vertex at its mean disparity. Which corner of each pixel's quad this is follows
/// from where the pixel lies: top-left pixel → its corner 3 (bottom-right), etc.
fn add_corner(
    input: &MeshInput,
    cx: usize,
    cy: usize,
    vertices: &mut Vec<Vertex>,
    samples: &mut [Sample],
) {
    let (w, h) = (input.width, input.height);
    // (pixel, which corner of that pixel's quad), for the up to four pixels around.
    let around: [Option<(usize, usize)>; 4] = [
        (cx > 0 && cy > 0).then(|| ((cy - 1) * w + cx - 1, 3)),
        (cx < w && cy > 0).then(|| ((cy - 1) * w + cx, 2)),
        (cx > 0 && cy < h).then(|| (cy * w + cx - 1, 1)),
        (cx < w && cy < h).then(|| (cy * w + cx, 0)),
    ];
    let mut slots: Vec<(Slot, usize, usize)> = Vec::with_capacity(8);
    for (pos, entry) in around.iter().enumerate() {
        if let Some((pixel, corner)) = *entry {
            slots.extend(input.slots(pixel).map(|s| (s, corner, pos)));
        }
    }
    let mut parent: Vec<usize> = (0..slots.len()).collect();
    // Positions 0–1 and 2–3 are horizontal neighbours, 0–2 and 1–3 vertical ones.
    for a in 0..slots.len() {
        for b in a + 1..slots.len() {
            let (pa, pb) = (slots[a].2, slots[b].2);
            let adjacent = matches!((pa, pb), (0, 1) | (2, 3) | (0, 2) | (1, 3));
            if adjacent && input.connected(slots[a].0, slots[b].0) {
                let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
                parent[ra] = rb;
            }
        }
    }
    let (u, v) = input.corner_position(cx, cy);
    let ray = (input.ray)(u, v);
    let mut group_vertex = vec![u32::MAX; slots.len()];
    for a in 0..slots.len() {
        let root = find(&mut parent, a);
        if group_vertex[root] == u32::MAX {
            let members: Vec<f32> = (0..slots.len())
                .filter(|&b| find(&mut parent, b) == root)
                .map(|b| input.disparity_of(slots[b].0))
                .collect();
            group_vertex[root] = vertices.len() as u32;
            vertices.push(Vertex {
                ray,
                disparity: members.iter().sum::<f32>() / members.len() as f32,
            });
        }
        let (slot, corner, _) = slots[a];
        samples[input.sample_index(slot)].corners[corner] = group_vertex[root];
    }
}

fn find(parent: &mut [usize], mut a: usize) -> usize {
    while parent[a] != a {
        parent[a] = parent[parent[a]];
        a = parent[a];
    }
    a
}
