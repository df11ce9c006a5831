//! `reshader bench`: the table, JSON and comparison logic on hand-made reports, and a tiny
//! real run that must report every stage row. No test looks at how long anything took.

use std::path::PathBuf;

use reshader::engine::manifest::Precision;
use reshader::eval::bench::report::{self, Case, NaiveRow, PeerRow, Report, StageRow, Stat};
use reshader::eval::bench::{self as bench, BenchConfig, ModelChoice};
use reshader::reshade::net::choice::ReshadeConfig;

fn stat(median: f64) -> Stat {
    Stat {
        median_ms: median,
        min_ms: median * 0.9,
        max_ms: median * 1.2,
        runs: 3,
    }
}

fn case(board: &str, scale: f64, ldi: bool) -> Case {
    let stages = report::STAGES
        .iter()
        .map(|&s| StageRow {
            stage: s.into(),
            detail: format!("{s} detail"),
            time: (s != "LDI build + inpainting" || ldi).then(|| stat(10.0 * scale)),
        })
        .collect();
    Case {
        photo: "photo.jpg".into(),
        photo_size: [400, 300],
        board: board.into(),
        views: 48,
        view_size: [420, 560],
        work_size: [747, 560],
        stages,
        total: Some(stat(100.0 * scale)),
        peak_rss_mib: Some(123.0),
        candidate_reshading: Some(stat(20.0 * scale)),
    }
}

fn report(cases: Vec<Case>) -> Report {
    Report {
        format: report::FORMAT.into(),
        command: "reshader bench".into(),
        profile: "release".into(),
        threads: 2,
        runs: 3,
        load_average: Some([1.5, 1.0, 0.5]),
        cpu: Some("Fixture CPU".into()),
        reshade_model: "reshade-fixture-int8 — FIXTURE STAND-IN".into(),
        depth_model: "tiefenrausch-int8".into(),
        cases,
        peak_rss_mib: Some(456.0),
        peer: vec![PeerRow {
            model: "depth tiefenrausch-int8".into(),
            shapes: "image 1×3×288×384".into(),
            tract: Some(stat(300.0)),
            onnxruntime: Some(stat(100.0)),
            note: None,
        }],
        naive: vec![NaiveRow {
            board: "looking-glass-portrait".into(),
            views: 48,
            network_size: [448, 576],
            per_view: Some(stat(1000.0)),
            timed_views: 2,
            runtime_ms: Some(480.0),
            candidate_ms: Some(96.0),
            note: None,
        }],
        wall_s: 12.0,
    }
}

#[test]
fn stats_take_the_median_min_and_max() {
    let s = Stat::of(&[5.0, 1.0, 3.0]).unwrap();
    assert_eq!(
        (s.median_ms, s.min_ms, s.max_ms, s.runs),
        (3.0, 1.0, 5.0, 3)
    );
    assert_eq!(Stat::of(&[4.0, 1.0, 2.0, 3.0]).unwrap().median_ms, 2.5);
    assert!(Stat::of(&[]).is_none());
}

#[test]
fn stage_stats_sum_repeated_stages_and_mark_missing_ones() {
    let runs = vec![
        vec![("decode", 2.0), ("weave", 1.0), ("weave", 1.0)],
        vec![("decode", 4.0), ("weave", 3.0)],
    ];
    let (rows, total) = bench::stage_stats(&runs);
    assert_eq!(rows.len(), report::STAGES.len());
    let get = |name: &str| rows.iter().find(|(s, _)| *s == name).unwrap().1;
    assert_eq!(get("decode").unwrap().median_ms, 3.0);
    assert_eq!(get("weave").unwrap().min_ms, 2.0);
    assert!(get("LDI build + inpainting").is_none());
    // Per-run sums 4 and 7: the median of sums, not the sum of medians (3 + 2.5).
    assert_eq!(total.unwrap().median_ms, 5.5);
}

#[test]
fn markdown_lists_every_stage_and_marks_unbuilt_ones() {
    let md = report(vec![case("looking-glass-portrait", 1.0, false)]).to_markdown();
    for stage in report::STAGES {
        assert!(md.contains(&format!("| {stage} |")), "missing row {stage}");
    }
    assert!(md.contains("| LDI build + inpainting | n/a (not built) |"));
    assert!(md.contains("FIXTURE STAND-IN"));
    // Peer ratio and naive saving are computed from the rows, not copied.
    assert!(md.contains("| 3.00× |"), "{md}");
    assert!(
        md.contains("| 48000 | 480 | 100.0× | 96.0 | 500.0× |"),
        "{md}"
    );
    assert!(md.contains("456 MiB"));
}

#[test]
fn json_round_trips_and_rejects_other_formats() {
    let r = report(vec![case("generic-8view", 1.0, true)]);
    let back = Report::from_json("x.json", &r.to_json()).unwrap();
    assert_eq!(back, r);
    assert!(r.to_markdown().contains("2 threads on Fixture CPU"));
    // Reports saved before the processor was recorded still load.
    let old = r.to_json().replace("\"cpu\": \"Fixture CPU\",", "");
    assert_eq!(Report::from_json("old.json", &old).unwrap().cpu, None);
    let other = r.to_json().replace(report::FORMAT, "something-else/9");
    let err = Report::from_json("old.json", &other)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("old.json") && err.contains("something-else/9"),
        "{err}"
    );
    let err = Report::from_json("bad.json", "{").unwrap_err().to_string();
    assert!(err.contains("bad.json"), "{err}");
}

#[test]
fn compare_reports_the_change_per_stage() {
    let before = report(vec![
        case("looking-glass-portrait", 1.0, false),
        case("looking-glass-go", 1.0, true),
    ]);
    let mut now = report(vec![
        case("looking-glass-portrait", 2.0, true),
        case("generic-8view", 1.0, true),
    ]);
    assert!(!now.compare(&before).contains("differs"));
    now.depth_model = "tiefenrausch-fp32".into();
    let text = now.compare(&before);
    assert!(
        text.contains(
            "| (setup) | depth model differs | tiefenrausch-int8 | tiefenrausch-fp32 | |"
        ),
        "{text}"
    );
    // Times from another processor, or one a report did not record, do not compare.
    let mut older = before.clone();
    older.cpu = None;
    let text = now.compare(&older);
    assert!(
        text.contains("| (setup) | processor differs | an unrecorded processor | Fixture CPU | |"),
        "{text}"
    );
    assert!(
        text.contains(
            "| photo.jpg / looking-glass-portrait | decode | 10.0 | 20.0 | +100.0% (2.00×) |"
        ),
        "{text}"
    );
    assert!(text.contains("| photo.jpg / looking-glass-portrait | LDI build + inpainting | n/a | 20.0 | newly built |"), "{text}");
    assert!(
        text.contains("| **total** | 100 | 200 | +100.0% (2.00×) |"),
        "{text}"
    );
    assert!(
        text.contains("photo.jpg / generic-8view | (all) | not in previous"),
        "{text}"
    );
    assert!(
        text.contains("photo.jpg / looking-glass-go | (all) | | not in this run"),
        "{text}"
    );
}

/// A small, quick benchmark: the fixture model, a 96x64 synthetic photo, one board.
fn tiny_args() -> BenchConfig {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    BenchConfig {
        reshade: ReshadeConfig {
            model: Some(root.join("models/fixtures")),
            precision: Some(Precision::Int8),
            ..ReshadeConfig::default()
        },
        photo: root.join("examples/pumpkin/pumpkin.jpg"),
        synthetic: (96, 64),
        boards: vec!["generic-8view".into()],
        runs: 1,
        threads: 1,
        no_peer: true,
        no_naive: true,
        ..BenchConfig::default()
    }
}

#[test]
fn the_defaults_are_the_issue_s_cases() {
    let args = BenchConfig::default();
    assert_eq!(
        args.boards,
        [
            "looking-glass-portrait",
            "looking-glass-go",
            "generic-8view"
        ]
    );
    assert_eq!(args.synthetic, (4000, 3000));
    assert!(args.runs >= 3);
    // The reshading options are render's own, so the bench times what render runs.
    assert_eq!(args.reshade.precision_for(None), Precision::Int8);
    assert!(args.reshade.model.is_none());
}

#[test]
fn a_named_model_is_used_as_given() {
    let args = tiny_args();
    let choice = bench::choose_model(&args).unwrap();
    assert_eq!(
        choice,
        ModelChoice::Given(args.reshade.model.clone().unwrap())
    );
}

#[test]
fn a_tiny_run_reports_every_stage_for_both_photos() {
    let r = bench::run(&tiny_args(), "test").unwrap();
    assert_eq!(r.cases.len(), 2);
    assert!(
        r.reshade_model.contains("FIXTURE STAND-IN"),
        "{}",
        r.reshade_model
    );
    for case in &r.cases {
        let names: Vec<&str> = case.stages.iter().map(|s| s.stage.as_str()).collect();
        assert_eq!(names, report::STAGES);
        for row in &case.stages {
            assert!(row.time.is_some(), "{row:?}");
        }
        assert_eq!(case.views, 8);
        assert!(case.total.is_some());
    }
    assert_eq!(r.cases[1].photo_size, [96, 64]);
    assert!(r.peak_rss_mib.is_some_and(|m| m > 0.0));
    assert!(r.peer.is_empty() && r.naive.is_empty());
}

#[test]
fn bad_options_fail_before_measuring() {
    let mut args = tiny_args();
    args.out = vec![PathBuf::from("bench.txt")];
    let err = bench::run(&args, "test").err().unwrap().to_string();
    assert!(
        err.contains("bench.txt") && err.contains(".md or .json"),
        "{err}"
    );
    let mut args = tiny_args();
    args.boards = vec!["no-such-board".into()];
    assert!(bench::run(&args, "test").is_err());
    let mut args = tiny_args();
    args.compare = Some(PathBuf::from("/nonexistent/previous.json"));
    let err = bench::run_and_write(&args, "test")
        .err()
        .unwrap()
        .to_string();
    assert!(err.contains("/nonexistent/previous.json"), "{err}");
}

#[test]
fn the_reshade_bench_reports_the_lobe_head_s_cost_per_view() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let config = reshader::eval::reshade::BenchConfig {
        model: root.join("models/fixtures"),
        width: 64,
        height: 32,
        views: 4,
        timed_views: 2,
        threads: 1,
        engines: vec!["tract".into()],
        precisions: vec![Precision::Fp32, Precision::Int8],
        ..Default::default()
    };
    let text = reshader::eval::reshade::run(&config).unwrap();
    for precision in ["fp32", "int8"] {
        let row = text
            .lines()
            .find(|l| l.starts_with(&format!("| tract | {precision} lobes |")))
            .unwrap_or_else(|| panic!("no {precision} lobes row in:\n{text}"));
        let cells: Vec<&str> = row.split('|').map(str::trim).collect();
        let once: f64 = cells[3].parse().unwrap_or_else(|_| panic!("{row}"));
        let per_view: f64 = cells[4].parse().unwrap_or_else(|_| panic!("{row}"));
        assert!(once > 0.0 && per_view > 0.0, "{row}");
    }
    assert!(text.contains("closed form per view"), "{text}");
    // The residual rows and tables are still there.
    assert!(text.contains("| tract | fp32 | "), "{text}");
    assert!(text.contains("### Per-view cost options"), "{text}");

    // A lobe manifest alone: its row only.
    let alone = reshader::eval::reshade::BenchConfig {
        model: root.join("models/fixtures/reshade-fixture-fp32-lobes.json"),
        precisions: vec![Precision::Fp32],
        ..config
    };
    let text = reshader::eval::reshade::run(&alone).unwrap();
    assert!(text.contains("| tract | fp32 lobes |"), "{text}");
    assert!(!text.contains("| tract | fp32 | "), "{text}");
}

#[test]
fn reshader_bench_times_the_lobe_head_in_the_reshading_rows() {
    let mut args = tiny_args();
    args.reshade.head = Some(reshader::reshade::net::choice::Head::Lobes);
    args.reshade.precision = Some(Precision::Fp32);
    let r = bench::run(&args, "test").unwrap();
    assert!(
        r.reshade_model.contains("head lobes"),
        "{}",
        r.reshade_model
    );
    for case in &r.cases {
        let row = case
            .stages
            .iter()
            .find(|s| s.stage == "reshade decoder × views")
            .unwrap();
        assert!(row.detail.contains("closed form"), "{row:?}");
        assert!(row.time.is_some_and(|t| t.median_ms > 0.0), "{row:?}");
        let once = case
            .stages
            .iter()
            .find(|s| s.stage == "reshade encoder")
            .unwrap();
        assert!(
            once.detail.contains("lobe network once per photo"),
            "{once:?}"
        );
    }
}

#[test]
fn targets_sit_beside_the_figures_that_measure_them() {
    use reshader::eval::bench::targets::{markdown, targets};
    let mut big = case("looking-glass-portrait", 15.0, true);
    big.photo = "synthetic 4000x3000".into();
    big.photo_size = [4000, 3000];
    let mut go = case("looking-glass-go", 30.0, true);
    go.photo = big.photo.clone();
    go.photo_size = big.photo_size;
    let small = case("looking-glass-portrait", 1.0, true);
    let r = report(vec![small, big, go]);
    let t = targets(&r);
    let find = |what: &str| t.iter().find(|t| t.what.starts_with(what)).unwrap();
    // 12 MP → Portrait: total 1500 ms against 2000; → Go: 3000 against 2500.
    assert_eq!(find("12 MP photo → Portrait").figure, Some(1500.0));
    assert_eq!(find("12 MP photo → Portrait").met(), Some(true));
    assert_eq!(find("12 MP photo → Go").met(), Some(false));
    // No case of the example photo: not measured rather than met.
    assert_eq!(find("the example photo").figure, None);
    assert_eq!(find("the example photo").met(), None);
    // Memory of the 12 MP cases only, in MB: 123 MiB.
    let mem = find("peak resident memory").figure.unwrap();
    assert!((mem - 123.0 * 1.048_576).abs() < 1e-9, "{mem}");
    // The peer's worst ratio, 3×.
    assert_eq!(find("tract / onnxruntime").met(), Some(false));
    // Per view: (decoder 150 + LDI render 150) / 48 views on the worst Portrait case.
    let per_view = find("reshading + relocation").figure.unwrap();
    assert!((per_view - 300.0 / 48.0).abs() < 1e-9, "{per_view}");
    assert_eq!(find("weave").figure, Some(150.0));
    assert_eq!(find("weave").met(), Some(false));
    let md = markdown(&r);
    assert!(
        md.contains("| weave, one 1536×2048 frame | ≤ 5.00 ms | 150 ms | **no** |"),
        "{md}"
    );
    assert!(md.contains("| not measured | – |"), "{md}");
    assert!(r.to_markdown().contains("## Targets"));
}

#[test]
fn a_readme_block_gets_a_saved_report_s_targets_and_nothing_else_changes() {
    use reshader::eval::bench::readme;
    let dir = tempfile::tempdir().unwrap();
    let mut big = case("looking-glass-portrait", 15.0, true);
    big.photo = "synthetic 4000x3000".into();
    big.photo_size = [4000, 3000];
    let saved = dir.path().join("saved.json");
    std::fs::write(&saved, report(vec![big]).to_json()).unwrap();
    let path = dir.path().join("README.md");
    let before = "# title\n\ntext\n\n<!-- bench-targets: generated -->\nold figures\n<!-- /bench-targets -->\n\nmore\n";
    std::fs::write(&path, before).unwrap();
    let args = BenchConfig {
        from: Some(saved.clone()),
        readme: Some(path.clone()),
        ..BenchConfig::default()
    };
    // Measures nothing: the saved report is the one written.
    bench::run_and_write(&args, "reshader bench --from saved.json").unwrap();
    let after = std::fs::read_to_string(&path).unwrap();
    assert!(after.starts_with("# title\n\ntext\n\n<!-- bench-targets: generated -->\n"));
    assert!(
        after.ends_with("<!-- /bench-targets -->\n\nmore\n"),
        "{after}"
    );
    assert!(!after.contains("old figures"));
    assert!(
        after.contains(&format!("[`{}`]", saved.display())),
        "{after}"
    );
    assert!(
        after.contains(
            "| 12 MP photo → Portrait (48 views), end to end | ≤ 2000 ms | 1500 ms | yes |"
        ),
        "{after}"
    );
    // Writing again changes nothing.
    bench::run_and_write(&args, "again").unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), after);

    // Without the closing marker: an error naming the file, and the file as it was.
    let broken = "# title\n<!-- bench-targets -->\nno end\n";
    std::fs::write(&path, broken).unwrap();
    let err = bench::run_and_write(&args, "x").unwrap_err().to_string();
    assert!(
        err.contains("README.md") && err.contains(readme::END),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&path).unwrap(), broken);
    // Found before anything is measured: a run with that file (and a photo that would
    // fail the measuring) names the README.
    let run = BenchConfig {
        readme: Some(path.clone()),
        photo: dir.path().join("no-such-photo.jpg"),
        ..tiny_args()
    };
    let err = bench::run_and_write(&run, "x").unwrap_err().to_string();
    assert!(err.contains("no block to write the targets into"), "{err}");
    assert_eq!(std::fs::read_to_string(&path).unwrap(), broken);
}
