//! Lookup-table build and weave times for a Looking Glass Portrait frame.
//!
//! `cargo bench -p interleave` prints one table row per view filter and thread count: a
//! 1536x2048 panel woven from 48 views at the Portrait quilt tile size (420x560), with
//! nearest, linear and Gaussian blending, and Gaussian with edge dimming. "weave" reuses
//! one frame, as a display loop does; "new frame" allocates it, as a one-off render does.

use std::time::{Duration, Instant};

use image::{Rgb, RgbImage};
use interleave::{Blend, Board, ViewFilter, Weaver};

const RUNS: usize = 7;

fn main() {
    let board = Board::builtin("looking-glass-portrait").expect("built-in board");
    let (vw, vh) = board.view_size();
    let views: Vec<RgbImage> = (0..board.views())
        .map(|i| {
            RgbImage::from_fn(vw, vh, |x, y| {
                Rgb([(x + i as u32) as u8, (y * 3) as u8, (i * 5) as u8])
            })
        })
        .collect();
    let (pw, ph) = board.panel_size();
    println!(
        "{} panel {pw}x{ph}, {} views of {vw}x{vh}, {RUNS} runs each (median / min / max, ms)",
        board.name(),
        board.views()
    );
    println!(
        "{:<15} {:>7} {:>26} {:>26} {:>26}",
        "filter", "threads", "LUT build", "weave", "new frame"
    );
    let dimmed = ViewFilter {
        blend: Blend::Gaussian,
        dim_edges: 0.1,
        ..ViewFilter::default()
    };
    let filters = [
        ("nearest", Blend::Nearest.into()),
        ("linear", Blend::Linear.into()),
        ("gaussian", Blend::Gaussian.into()),
        ("gaussian+dim", dimmed),
    ];
    for ((name, filter), threads) in filters.iter().flat_map(|f| [(f, 1), (f, 2)]) {
        let mapping = board.mapping();
        let mut weaver = None;
        let build =
            time_runs(|| weaver = Some(Weaver::from_mapping(&mapping, vw, vh, *filter, threads)));
        let weaver = weaver.expect("built at least once");
        let mut frame = RgbImage::new(pw, ph);
        let weave = time_runs(|| {
            weaver
                .weave_into(&views, &mut frame)
                .expect("views match the weaver")
        });
        std::hint::black_box(&frame);
        let fresh = time_runs(|| {
            let frame = weaver.weave(&views).expect("views match the weaver");
            std::hint::black_box(&frame);
        });
        println!(
            "{:<15} {:>7} {:>26} {:>26} {:>26}",
            name,
            threads,
            summary(&build),
            summary(&weave),
            summary(&fresh)
        );
    }
}

fn time_runs(mut f: impl FnMut()) -> Vec<Duration> {
    let mut times: Vec<Duration> = (0..RUNS)
        .map(|_| {
            let start = Instant::now();
            f();
            start.elapsed()
        })
        .collect();
    times.sort();
    times
}

fn summary(sorted: &[Duration]) -> String {
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    format!(
        "{:.1} / {:.1} / {:.1}",
        ms(sorted[sorted.len() / 2]),
        ms(sorted[0]),
        ms(sorted[sorted.len() - 1])
    )
}
