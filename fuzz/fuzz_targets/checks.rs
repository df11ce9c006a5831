//! What each fuzz target does with its input, shared with tests/fuzz_regressions.rs so
//! that the crash inputs found here are replayed by `cargo test` exactly as the fuzzer
//! ran them. Every function must return normally for any input; the assertions state
//! what a successful parse promises.

#![allow(dead_code)]

use std::path::Path;
use std::sync::Once;

use interleave::{Board, Calibration};
use reshader::depth::net::DepthSpec;
use reshader::engine::manifest::{check_reshade, Manifest, Precision, Task};
use reshader::engine::tract::TractEngine;
use reshader::engine::{Engine, ModelSource};

/// A small memory ceiling, so that inputs within the limits still decode quickly, and a
/// limit that does not hold shows up as an allocation far above it (the fuzz script's
/// -malloc_limit_mb).
pub fn init() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| reshader::io::limits::set_max_memory(256 << 20));
}

/// The check for the target called `name`.
pub fn by_name(name: &str) -> Option<fn(&[u8])> {
    Some(match name {
        "photo" => photo,
        "depth_npy" => |d| depth("npy", d),
        "depth_pfm" => |d| depth("pfm", d),
        "depth_png" => |d| depth("png", d),
        "depth_exr" => |d| depth("exr", d),
        "embedded_depth" => embedded_depth,
        "board_toml" => board_toml,
        "calibration_json" => calibration_json,
        "manifest" => manifest,
        "onnx_model" => onnx_model,
        _ => return None,
    })
}

/// Photo decoding through `image` (format guessed from the content) and the EXIF read
/// that gives the field of view.
pub fn photo(data: &[u8]) {
    init();
    if let Ok(img) = reshader::io::photo::decode_rgb8(Path::new("fuzz-photo"), data) {
        assert!(img.width() > 0 && img.height() > 0);
        assert!(img.width() <= reshader::io::photo::MAX_PHOTO_SIDE);
    }
    if let Some(fov) = reshader::io::photo::exif_hfov(data, 4032, 3024) {
        assert!(fov > 0.0 && fov < 180.0, "{fov}");
    }
}

/// A depth file of the given extension, through the same entry point as `--depth`.
pub fn depth(ext: &str, data: &[u8]) {
    init();
    let name = format!("fuzz.{ext}");
    if let Ok(raw) = reshader::depth::parse_raw(Path::new(&name), data) {
        assert_eq!(raw.values.len(), raw.width * raw.height);
        assert!(raw.width > 0 && raw.height > 0);
    }
}

/// Depth embedded in JPEGs: segment walk, XMP and Extended XMP, GDepth and Dynamic
/// Depth directories, base64 and the embedded depth image.
pub fn embedded_depth(data: &[u8]) {
    init();
    if let Ok(Some(depth)) = reshader::depth::embedded::parse(data) {
        let map = &depth.map;
        assert_eq!(map.values.len(), map.width * map.height);
        let upright = reshader::depth::embedded::apply_orientation(map, depth.orientation);
        assert_eq!(upright.values.len(), map.values.len());
    }
}

/// Board TOML: parsing, validation, and the subpixel-to-view mapping of what validates.
pub fn board_toml(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(board) = Board::from_toml_str(text, "fuzz") {
        check_mapping(&board);
    }
}

/// Looking Glass calibration JSON (visual.json), applied to the built-in boards that
/// take one.
pub fn calibration_json(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(cal) = Calibration::from_json_str(text, "fuzz") else {
        return;
    };
    for name in Board::builtin_names() {
        let mut board = Board::builtin(name).expect("built-in boards load");
        if board.apply_calibration(&cal).is_ok() {
            check_mapping(&board);
        }
    }
}

/// Every corner subpixel of a valid board maps to an existing view and source pixel, and
/// the memory estimate counts every buffer the board implies.
fn check_mapping(board: &Board) {
    check_buffers_fit(board);
    let mapping = board.mapping();
    let (w, h) = board.panel_size();
    let (vw, vh) = board.view_size();
    for (x, y) in [
        (0, 0),
        (w - 1, 0),
        (0, h - 1),
        (w - 1, h - 1),
        (w / 2, h / 2),
    ] {
        for c in 0..3 {
            let view = mapping.view_index(x, y, c);
            assert!(view < board.views(), "view {view} of {}", board.views());
        }
        assert!(mapping.source_x(x, vw) < vw);
        assert!(mapping.source_y(y, vh) < vh);
    }
}

/// Model manifests: parsing and the checks of the depth and reshading stages.
pub fn manifest(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.json");
    let Ok(manifest) = Manifest::from_json_str(text, path) else {
        return;
    };
    if let Ok(spec) = DepthSpec::from_manifest(path, &manifest) {
        for (w, h) in [(1, 1), (4032, 3024), (3024, 4032), (16384, 1)] {
            if let Some((nw, nh)) = spec.size.network_size(w, h) {
                assert!(nw > 0 && nh > 0);
            }
        }
    }
    for task in [Task::Reshade, Task::ReshadeEncoder, Task::ReshadeDecoder] {
        let _ = check_reshade(path, &manifest, task, manifest.precision);
    }
}

/// The model loader on corrupt ONNX files: protobuf decoding, fp16 widening, name
/// checks, shape analysis and optimisation in tract, as `--depth-model` runs them.
pub fn onnx_model(data: &[u8]) {
    // The engine turns panics inside tract into errors, but libFuzzer's panic hook
    // aborts at the panic itself: back to the default hook, which only prints. A panic
    // that escapes the engine still fails the run.
    static DEFAULT_HOOK: Once = Once::new();
    DEFAULT_HOOK.call_once(|| drop(std::panic::take_hook()));
    let engine = TractEngine::new(1);
    // Odd lengths take the fp16 path, which rewrites the graph's tensors before loading.
    let precision = if data.len() % 2 == 0 {
        Precision::Fp32
    } else {
        Precision::Fp16
    };
    let model = ModelSource {
        path: Path::new("fuzz.onnx"),
        bytes: data,
        precision,
    };
    let _ = engine.plan(model, &[("image", vec![1, 8, 12, 3])], &["depth"]);
}

/// What `weave` estimates for a board covers its views and its panel at their exact
/// sizes, so that a board passing the estimate cannot allocate beyond it, however near
/// the limits its sizes are (fuzz/seeds/*/limit-*).
fn check_buffers_fit(board: &Board) {
    let estimate = reshader::pipeline::preflight::weave_estimate(board).total();
    let (w, h) = board.panel_size();
    let (vw, vh) = board.view_size();
    let panel = u64::from(w) * u64::from(h) * 3;
    let views = u64::from(vw) * u64::from(vh) * 3 * board.views() as u64;
    assert!(
        estimate >= panel + views,
        "estimate {estimate} below panel {panel} + views {views} bytes"
    );
}
