//! The animated preview, `preview.gif`: the views swept left to right and back, forever,
//! one sweep in about [`SWEEP_CS`] hundredths of a second.
//!
//! GIF rather than APNG: every browser, chat app, mail client and image viewer plays a
//! GIF, where many viewers still show an APNG as a still picture. Its 256 colours are
//! chosen once for all frames (NeuQuant, trained on the outermost and middle views), so
//! a colour that does not move keeps its index and nothing flickers between frames; no
//! dithering, for the same reason. Each frame after the first stores only the pixels
//! that change visibly (the rest transparent, cropped to where changes are):
//! neighbouring views differ mostly along depth edges, so this keeps the file several
//! times smaller.

use std::borrow::Cow;
use std::path::Path;

use color_quant::NeuQuant;
use gif::{DisposalMethod, Encoder, Frame, Repeat};
use image::RgbImage;

use super::PreviewError;

/// One sweep across the views takes about this long, in hundredths of a second (GIF's
/// unit).
pub const SWEEP_CS: usize = 200;

/// Frame delays stay within these bounds, in hundredths of a second: browsers slow down
/// faster GIFs, and boards with few views should still move.
const DELAY_CS: (usize, usize) = (3, 25);

/// The palette's colours; the last index of 256 is the transparent one.
const COLOURS: usize = 255;
const TRANSPARENT: u8 = 255;

/// The views shown, in order, for `n` views: 0 … n−1, then back down to 1, so that the
/// loop returns to view 0 without showing either end twice.
pub fn sweep(n: usize) -> Vec<usize> {
    (0..n).chain((1..n.saturating_sub(1)).rev()).collect()
}

/// The delay of every frame for `n` views, in hundredths of a second.
pub fn frame_delay_cs(n: usize) -> u16 {
    let delay = (SWEEP_CS / n.saturating_sub(1).max(1)).clamp(DELAY_CS.0, DELAY_CS.1);
    delay as u16
}

/// Encodes `frames` (at least one, all of one size of at most 65535 pixels a side) as a
/// looping GIF sweeping them; `path` names the file in errors.
pub fn encode(path: &Path, frames: &[RgbImage]) -> Result<Vec<u8>, PreviewError> {
    let err = |source| PreviewError::Gif {
        path: path.into(),
        source,
    };
    let (w, h) = frames[0].dimensions();
    let mut palette = Palette::train(frames);
    let indexed: Vec<Vec<u8>> = frames.iter().map(|f| palette.index(f)).collect();
    let mut encoder = Encoder::new(Vec::new(), w as u16, h as u16, &palette.rgb).map_err(err)?;
    encoder.set_repeat(Repeat::Infinite).map_err(err)?;
    let delay = frame_delay_cs(frames.len());
    // What a player shows after each frame, as palette indices.
    let mut canvas = indexed[0].clone();
    for (k, i) in sweep(frames.len()).into_iter().enumerate() {
        let mut frame = if k == 0 {
            Frame {
                width: w as u16,
                height: h as u16,
                buffer: Cow::Borrowed(&indexed[0]),
                ..Frame::default()
            }
        } else {
            let view = Target {
                colours: &frames[i],
                indices: &indexed[i],
            };
            changes(&mut canvas, view, &palette.rgb)
        };
        frame.delay = delay;
        frame.dispose = DisposalMethod::Keep;
        encoder.write_frame(&frame).map_err(err)?;
    }
    encoder.into_inner().map_err(err)
}

/// A view to show: its colours and their nearest palette indices.
struct Target<'a> {
    colours: &'a RgbImage,
    indices: &'a [u8],
}

/// How much worse than its nearest palette colour (in the sum of the three channels'
/// differences) a pixel already shown may be and still stay: reshading moves the
/// shading a little between views almost everywhere, and redrawing every pixel whose
/// nearest colour flips costs bytes for no visible change. On the example photo for the
/// Portrait this takes the GIF from 3.7 to 2.5 MB, the mean error from 3.1 to 4.1
/// levels. Measured against the view's own colours, so the error never builds up over
/// frames.
const KEEP_WITHIN: u32 = 20;

/// The frame that brings `canvas` (indices) to `target` and updates it: the bounding
/// box of the pixels to redraw, the others inside it transparent.
fn changes(canvas: &mut [u8], target: Target<'_>, palette: &[u8]) -> Frame<'static> {
    let width = target.colours.width() as usize;
    let distance = |index: u8, colour: &[u8]| -> u32 {
        let entry = &palette[3 * usize::from(index)..][..3];
        (0..3)
            .map(|c| u32::from(entry[c].abs_diff(colour[c])))
            .sum()
    };
    let redraw: Vec<bool> = canvas
        .iter()
        .zip(target.indices)
        .zip(target.colours.pixels())
        .map(|((&shown, &nearest), colour)| {
            shown != nearest
                && distance(shown, &colour.0) > distance(nearest, &colour.0) + KEEP_WITHIN
        })
        .collect();
    let height = canvas.len() / width;
    let (mut x0, mut y0, mut x1, mut y1) = (width, height, 0, 0);
    for (i, _) in redraw.iter().enumerate().filter(|(_, &r)| r) {
        let (x, y) = (i % width, i / width);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
    }
    if x0 >= x1 {
        // Nothing to redraw: one transparent pixel keeps the frame's delay.
        (x0, y0, x1, y1) = (0, 0, 1, 1);
    }
    let mut buffer = Vec::with_capacity((x1 - x0) * (y1 - y0));
    for y in y0..y1 {
        for i in y * width + x0..y * width + x1 {
            if redraw[i] {
                canvas[i] = target.indices[i];
                buffer.push(target.indices[i]);
            } else {
                buffer.push(TRANSPARENT);
            }
        }
    }
    Frame {
        left: x0 as u16,
        top: y0 as u16,
        width: (x1 - x0) as u16,
        height: (y1 - y0) as u16,
        transparent: Some(TRANSPARENT),
        buffer: Cow::Owned(buffer),
        ..Frame::default()
    }
}

/// One palette for every frame, and a cache from colours (6 bits a channel) to indices:
/// NeuQuant's search is slow beside a table look-up, and a frame has far fewer distinct
/// colours than pixels.
struct Palette {
    quant: NeuQuant,
    /// 256 colours, RGB; the transparent one last.
    rgb: Vec<u8>,
    cache: Vec<u8>,
    known: Vec<bool>,
}

impl Palette {
    fn train(frames: &[RgbImage]) -> Palette {
        let n = frames.len();
        let mut rgba = Vec::new();
        for i in [0, n / 2, n - 1] {
            rgba.extend(frames[i].pixels().flat_map(|p| [p[0], p[1], p[2], 255]));
        }
        let quant = NeuQuant::new(10, COLOURS, &rgba);
        let mut rgb = quant.color_map_rgb();
        rgb.resize(3 * 256, 0);
        Palette {
            quant,
            rgb,
            cache: vec![0; 1 << 18],
            known: vec![false; 1 << 18],
        }
    }

    fn index(&mut self, frame: &RgbImage) -> Vec<u8> {
        frame
            .pixels()
            .map(|p| {
                let key = (usize::from(p[0] >> 2) << 12)
                    | (usize::from(p[1] >> 2) << 6)
                    | usize::from(p[2] >> 2);
                if !self.known[key] {
                    // The middle of the cell, so that the cache errs by at most 2 levels.
                    let colour = [p[0] | 2, p[1] | 2, p[2] | 2, 255];
                    self.cache[key] = self.quant.index_of(&colour) as u8;
                    self.known[key] = true;
                }
                self.cache[key]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    #[test]
    fn the_sweep_goes_out_and_back_without_repeating_the_ends() {
        assert_eq!(sweep(1), [0]);
        assert_eq!(sweep(2), [0, 1]);
        assert_eq!(sweep(4), [0, 1, 2, 3, 2, 1]);
        assert_eq!(frame_delay_cs(48), 4);
        assert_eq!(frame_delay_cs(66), 3);
        assert_eq!(frame_delay_cs(2), 25);
    }

    /// Decodes a GIF into its composed frames, as a player shows them.
    fn play(bytes: &[u8]) -> Vec<(RgbImage, u16)> {
        let mut options = gif::DecodeOptions::new();
        options.set_color_output(gif::ColorOutput::RGBA);
        let mut decoder = options.read_info(bytes).unwrap();
        let (w, h) = (u32::from(decoder.width()), u32::from(decoder.height()));
        let mut canvas = RgbImage::new(w, h);
        let mut shown = Vec::new();
        while let Some(frame) = decoder.read_next_frame().unwrap() {
            for y in 0..u32::from(frame.height) {
                for x in 0..u32::from(frame.width) {
                    let i = 4 * (y * u32::from(frame.width) + x) as usize;
                    let p = &frame.buffer[i..i + 4];
                    if p[3] != 0 {
                        let (cx, cy) = (x + u32::from(frame.left), y + u32::from(frame.top));
                        canvas.put_pixel(cx, cy, Rgb([p[0], p[1], p[2]]));
                    }
                }
            }
            shown.push((canvas.clone(), frame.delay));
        }
        shown
    }

    #[test]
    fn a_player_shows_each_view_in_sweep_order() {
        // Three views: a red square moving right over a grey gradient.
        let views: Vec<RgbImage> = (0..3)
            .map(|v| {
                RgbImage::from_fn(40, 30, |x, y| {
                    if (10 + 5 * v..20 + 5 * v).contains(&x) && (10..20).contains(&y) {
                        Rgb([220, 30, 30])
                    } else {
                        let g = (x * 6) as u8;
                        Rgb([g, g, 100])
                    }
                })
            })
            .collect();
        let bytes = encode(Path::new("preview.gif"), &views).unwrap();
        let shown = play(&bytes);
        assert_eq!(shown.len(), 4);
        for ((frame, delay), view) in shown.iter().zip(sweep(3)) {
            assert_eq!(*delay, frame_delay_cs(3));
            let worst = frame
                .pixels()
                .zip(views[view].pixels())
                .flat_map(|(a, b)| (0..3).map(move |c| a[c].abs_diff(b[c])))
                .max()
                .unwrap();
            assert!(
                u32::from(worst) <= KEEP_WITHIN + 4,
                "view {view} is off by {worst} levels"
            );
        }
    }
}
