//! Timing and memory harnesses for the LDI, ignored by default (one allocates a
//! 12-megapixel LDI). Table 1 is `reshader eval-relocation`. Run with
//! `cargo test -j 2 --test main ldi_eval:: -- --ignored --nocapture --test-threads 1`.

use std::time::Instant;

use reshader::depth::DepthMap;
use reshader::io::photo::SrgbImage;
use reshader::relocate::ldi::{Ldi, LdiConfig};
use reshader::views::{Intrinsics, ViewCamera};

fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// A textured, tilted wall with a grid of boxes at several depths: many edges.
fn busy_scene(w: usize, h: usize) -> (SrgbImage, DepthMap) {
    let mut colours = SrgbImage::new(w as u32, h as u32);
    let mut depth = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let cell = (x * 12 / w, y * 9 / h);
            let inside = (x * 12 % w) > w / 4 && (y * 9 % h) > h / 4;
            let z = if inside {
                1.0 + ((cell.0 + cell.1) % 4) as f32 * 0.4
            } else {
                4.0 + x as f32 / w as f32
            };
            depth[y * w + x] = z;
            let t = ((x / 7 + y / 5) % 3) as f32 / 2.0;
            colours.put(x as u32, y as u32, [t, z / 5.0, 1.0 - t]);
        }
    }
    (colours, DepthMap::new(w, h, depth))
}

fn time_build_and_views(w: usize, h: usize) {
    let (colours, depth) = busy_scene(w, h);
    let source = Intrinsics::from_hfov(w as u32, h as u32, 60.0);
    let before = peak_rss_mb();
    // A 48-view board with a 40° cone at focus 2: outermost camera 0.73 units off-axis.
    let reach = 2.0 * 20f64.to_radians().tan();
    let start = Instant::now();
    let ldi = Ldi::build(&colours, &depth, &source, &LdiConfig::default(), reach).unwrap();
    let build_s = start.elapsed().as_secs_f64();
    let after_build = peak_rss_mb();
    let start = Instant::now();
    let views = 3;
    for k in 0..views {
        let tx = reach * (2.0 * k as f64 / (views - 1) as f64 - 1.0);
        let view = ViewCamera::off_axis(&source, [tx, 0.0, 0.0], 2.0).unwrap();
        ldi.render(&colours, &view).unwrap();
    }
    let render_s = start.elapsed().as_secs_f64() / views as f64;
    println!(
        "{w}x{h}: build {build_s:.2} s, render {render_s:.3} s/view; LDI keeps {:.0} MB ({} band samples, {} vertices); \
         peak RSS {before:.0} MB before build, {after_build:.0} MB after build, {:.0} MB after rendering",
        ldi.stats().memory_bytes as f64 / 1e6,
        ldi.stats().band_samples,
        ldi.stats().vertices,
        peak_rss_mb()
    );
}

#[test]
#[ignore]
fn build_and_render_time_and_memory_at_12_megapixels() {
    time_build_and_views(4000, 3000);
}

#[test]
#[ignore]
fn build_and_render_time_at_view_size() {
    // Looking Glass Portrait-sized views, the size the pipeline fits the photo to.
    time_build_and_views(420, 560);
}
