//! Unit tests of `eval::bench`, beside it so that the module file holds the code only.

use super::compare::padded;
use super::models::reshade_manifests;
use super::*;

#[test]
fn vm_hwm_is_read_in_mib() {
    let status = "Name:\tx\nVmPeak:\t  9000 kB\nVmHWM:\t    2048 kB\nVmRSS:\t 1024 kB\n";
    assert_eq!(memory::parse_vm_hwm(status), Some(2.0));
    assert_eq!(memory::parse_vm_hwm("VmRSS: 1 kB"), None);
    assert!(memory::vm_hwm_mib().is_some_and(|m| m > 0.0));
}

fn names(paths: &[PathBuf]) -> Vec<String> {
    paths
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn the_peer_times_the_files_the_runtime_runs() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/fixtures");
    // Pairs exist for every precision, so no single graph is timed.
    let all = names(&reshade_manifests(&dir, None, Head::Residual).unwrap());
    assert_eq!(all.len(), 6, "{all:?}");
    assert!(all.iter().all(|n| n.contains("coder")), "{all:?}");
    let fp32 = names(&reshade_manifests(&dir, Some(Precision::Fp32), Head::Residual).unwrap());
    assert_eq!(
        fp32,
        [
            "reshade-fixture-fp32-decoder.json",
            "reshade-fixture-fp32-encoder.json"
        ]
    );
    let half = dir.join("reshade-fixture-int8-decoder.json");
    assert_eq!(
        names(&reshade_manifests(&half, None, Head::Residual).unwrap()),
        [
            "reshade-fixture-int8-encoder.json",
            "reshade-fixture-int8-decoder.json"
        ]
    );
    let single = dir.join("reshade-fixture-int8.json");
    assert_eq!(
        names(&reshade_manifests(&single, None, Head::Residual).unwrap()),
        ["reshade-fixture-int8.json"]
    );
}

#[test]
fn padding_rounds_up_to_the_multiple() {
    assert_eq!(padded(420, 32), 448);
    assert_eq!(padded(640, 32), 640);
}
