//! Replays, without cargo-fuzz, every input the fuzz targets once crashed on
//! (tests/fuzz_regressions/<target>/*), the committed seeds (fuzz/seeds/<target>/*) and
//! the minimised corpora the fuzzing grew (fuzz/corpus-min/<target>/*, scripts/fuzz-cmin)
//! through the same checks the targets run (fuzz/fuzz_targets/checks.rs): each must
//! return normally now.

#[path = "../fuzz/fuzz_targets/checks.rs"]
mod checks;

use std::path::Path;

/// Runs every file under `root/<target>/` through its target's check; returns how many.
fn replay(root: &Path) -> usize {
    let Ok(targets) = std::fs::read_dir(root) else {
        return 0;
    };
    let mut count = 0;
    for target in targets.map(Result::unwrap) {
        let name = target.file_name().to_string_lossy().into_owned();
        let check = checks::by_name(&name)
            .unwrap_or_else(|| panic!("{}: no fuzz target {name}", root.display()));
        for input in std::fs::read_dir(target.path()).unwrap() {
            let path = input.unwrap().path();
            let data = std::fs::read(&path).unwrap();
            let result = std::panic::catch_unwind(|| check(&data));
            assert!(
                result.is_ok(),
                "{} crashes its target again",
                path.display()
            );
            count += 1;
        }
    }
    count
}

#[test]
fn crash_inputs_found_by_fuzzing_stay_fixed() {
    replay(&Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz_regressions"));
}

#[test]
fn seed_corpora_pass_their_targets() {
    let count = replay(&Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds"));
    assert!(count >= 30, "only {count} seeds");
}

/// The seeds at the limits are valid (the limits are inclusive), so the checks above
/// run their mapping and buffer assertions on them rather than stopping at a refusal.
#[test]
fn seeds_at_the_limits_load() {
    let seeds = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/seeds");
    let read = |p: &str| std::fs::read_to_string(seeds.join(p)).unwrap();
    for name in ["limit-sizes.toml", "limit-lenses.toml"] {
        let board = interleave::Board::from_toml_str(&read(&format!("board_toml/{name}")), name)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(board.views(), 256, "{name}");
    }
    for name in ["limit-screen.json", "limit-low.json"] {
        let cal = interleave::Calibration::from_json_str(
            &read(&format!("calibration_json/{name}")),
            name,
        )
        .unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut board = interleave::Board::builtin("looking-glass-portrait").unwrap();
        board
            .apply_calibration(&cal)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}

#[test]
fn minimised_fuzz_corpora_pass_their_targets() {
    let count = replay(&Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz/corpus-min"));
    assert!(count >= 1000, "only {count} corpus inputs");
}

/// An allocation bomb the replay above cannot see (nothing limits memory here): a
/// Transpose whose `perm` holds 2^26 made tract allocate 512 MiB while loading.
#[test]
fn transpose_perm_that_is_no_permutation_is_refused_before_tract() {
    use reshader::engine::{tract::TractEngine, Engine, ModelSource};
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fuzz_regressions/onnx_model/transpose-perm-allocates-512mib.onnx");
    let bytes = std::fs::read(&path).unwrap();
    let model = ModelSource {
        path: &path,
        bytes: &bytes,
        precision: reshader::engine::manifest::Precision::Fp32,
    };
    let err = TractEngine::new(1)
        .plan(model, &[("image", vec![1, 8, 12, 3])], &["depth"])
        .err()
        .expect("the graph is refused");
    let text = err.to_string();
    assert!(
        text.contains("Transpose") && text.contains("perm"),
        "{text}"
    );
    assert!(
        text.contains("transpose-perm-allocates-512mib.onnx"),
        "{text}"
    );
}
