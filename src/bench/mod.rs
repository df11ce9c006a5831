//! `reshader bench`: one photo to a woven frame, stage by stage, for several boards, with
//! peak memory, the onnxruntime peer on the same ONNX files and the naive configuration
//! (paper-size network per view) for scale. See bench/README.md for how to read it.
//!
//! Every stage row is always reported: a stage this runtime does not have yet says
//! "n/a (not built)" rather than disappearing, so tables from different builds line up.

pub mod peer;
pub mod report;
mod stages;

use std::path::{Path, PathBuf};
use std::time::Instant;

use interleave::{Board, BoardError, WeaveError};

use crate::depth_net::{DepthNet, DepthNetError};
use crate::engine::{self, EngineError};
use crate::manifest::{self, ManifestError, Precision, Task};
use crate::output::OutputError;
use crate::photo::PhotoError;
use crate::relocate::RelocateError;
use crate::reshade::Reshader;
use crate::reshade_net::{NetError, NetOptions, NetReshader};
use crate::views::ViewError;

use peer::Job;
use report::{Case, CompareError, NaiveRow, PeerRow, Report, Stat, FORMAT};

pub const BENCH_ABOUT: &str = "\
Time the conversion of a photo to a woven frame, stage by stage (median and min-max of
--runs runs), for the shipped example photo and a synthetic 12 MP photo on each board,
with peak memory, tract vs onnxruntime on the same ONNX files, and the paper-size network
run per view (the naive configuration) for comparison. Build with --release: dev-profile
times are not representative.

Examples:
  cargo run --release -- bench --out bench.md --out bench.json
  cargo run --release -- bench --model models/reshade --compare bench.json

The reshading model timed is --model (default: the tiny test fixture, labelled as a
stand-in in every table). See bench/README.md.";

pub const DEFAULT_BOARDS: &str = "looking-glass-portrait,looking-glass-go,generic-8view";

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Manifest(#[from] ManifestError),
    #[error(transparent)]
    Engine(#[from] EngineError),
    #[error(transparent)]
    Depth(#[from] DepthNetError),
    #[error("reshading model: {0}")]
    Reshade(#[from] NetError),
    #[error(transparent)]
    Photo(#[from] PhotoError),
    #[error(transparent)]
    Board(#[from] BoardError),
    #[error("weaving failed: {0}")]
    Weave(#[from] WeaveError),
    #[error(transparent)]
    Relocate(#[from] RelocateError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error(transparent)]
    View(#[from] ViewError),
    #[error(transparent)]
    Compare(#[from] CompareError),
    #[error("{path}: {problem}")]
    Model { path: PathBuf, problem: String },
    #[error("peer script {script}: {problem}")]
    Peer { script: PathBuf, problem: String },
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0}")]
    Usage(String),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BenchError + '_ {
    move |source| BenchError::Io {
        path: path.to_owned(),
        source,
    }
}

/// Options of `reshader bench`.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchArgs {
    /// Reshading model: a manifest (.json) or a directory of them. The default is the
    /// tiny test fixture, a stand-in that the tables label as such.
    #[arg(long, default_value = "models/fixtures")]
    pub model: PathBuf,
    /// Precision of the reshading model.
    #[arg(long, default_value = "int8")]
    pub precision: Precision,
    /// Precision of the shipped depth model (models/depth).
    #[arg(long, default_value = "int8")]
    pub depth_precision: Precision,
    /// The real photo to convert (JPEG or PNG).
    #[arg(long, default_value = "examples/pumpkin/pumpkin.jpg")]
    pub photo: PathBuf,
    /// Size of the synthetic photo generated at run time (WxH; 4000x3000 is 12 MP).
    #[arg(long, default_value = "4000x3000", value_parser = parse_size)]
    pub synthetic: (u32, u32),
    /// Boards (built-in names or .toml files), comma-separated.
    #[arg(long, default_value = DEFAULT_BOARDS, value_delimiter = ',')]
    pub boards: Vec<String>,
    /// Timed runs per photo and board (after one untimed warm-up run).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Threads for inference and weaving.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Write the report: .md for Markdown, .json for the comparable form (repeatable).
    #[arg(long)]
    pub out: Vec<PathBuf>,
    /// A previous run's JSON: print the change of every stage against it.
    #[arg(long)]
    pub compare: Option<PathBuf>,
    /// Skip the onnxruntime peer.
    #[arg(long)]
    pub no_peer: bool,
    /// Skip the naive configuration (paper-size network per view).
    #[arg(long)]
    pub no_naive: bool,
    /// Views the naive configuration really runs per board (the rest is extrapolated).
    #[arg(long, default_value_t = 2)]
    pub naive_views: usize,
    /// Python with onnxruntime and the training toolchain [default: $RESHADER_PYTHON,
    /// else ~/.cache/reshader/venv/bin/python, else what scripts/python-env prints].
    #[arg(long)]
    pub python: Option<PathBuf>,
    /// Where the exported naive network is cached (never committed) [default:
    /// ~/.cache/reshader/bench].
    #[arg(long)]
    pub cache: Option<PathBuf>,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| format!("expected WxH, got '{s}'"))?;
    let num = |t: &str| {
        t.parse::<u32>()
            .ok()
            .filter(|&v| v >= 32)
            .ok_or_else(|| format!("'{t}' is not a size of at least 32"))
    };
    Ok((num(w)?, num(h)?))
}

impl BenchArgs {
    fn check(&self) -> Result<(), BenchError> {
        if self.runs == 0 || self.threads == 0 || self.naive_views == 0 {
            return Err(BenchError::Usage(
                "--runs, --threads and --naive-views must be at least 1".into(),
            ));
        }
        for out in &self.out {
            if !matches!(
                out.extension().and_then(|e| e.to_str()),
                Some("md" | "json")
            ) {
                return Err(BenchError::Usage(format!(
                    "--out {}: the name must end in .md or .json",
                    out.display()
                )));
            }
        }
        Ok(())
    }
}

/// Runs `reshader bench`: prints the Markdown report (and the comparison), writes --out.
pub fn main(args: &BenchArgs, command: &str) -> Result<Report, BenchError> {
    args.check()?;
    let previous = args.compare.as_deref().map(Report::load).transpose()?;
    let report = run(args, command)?;
    let markdown = report.to_markdown();
    println!("{markdown}");
    let comparison = previous.map(|p| report.compare(&p));
    if let Some(text) = &comparison {
        println!("{text}");
    }
    for out in &args.out {
        let text = if out.extension().is_some_and(|e| e == "json") {
            report.to_json()
        } else {
            let mut md = markdown.clone();
            if let Some(text) = &comparison {
                md.push_str(text);
            }
            md
        };
        crate::output::write_atomic(out, text.as_bytes())?;
    }
    Ok(report)
}

/// Everything the stages share across photos and boards.
pub(crate) struct Context {
    pub threads: usize,
    pub depth: DepthNet,
    pub reshader: NetReshader,
    pub reshade_label: String,
    pub work_dir: TempDir,
}

/// Measures every case and the comparisons; writes nothing but its scratch directory.
pub fn run(args: &BenchArgs, command: &str) -> Result<Report, BenchError> {
    args.check()?;
    let started = Instant::now();
    let load_average = load_average();
    let engine = engine::by_name("tract", args.threads)?;
    let depth = DepthNet::shipped(args.depth_precision, engine.clone())?;
    let reshader = NetReshader::load(&args.model, args.precision, engine, NetOptions::default())?;
    let reshade_label = reshade_label(&reshader);
    let ctx = Context {
        threads: args.threads,
        depth,
        reshader,
        reshade_label,
        work_dir: TempDir::new()?,
    };
    let boards = args
        .boards
        .iter()
        .map(|b| Board::resolve(b))
        .collect::<Result<Vec<_>, _>>()?;
    let synthetic = stages::write_synthetic_photo(&ctx.work_dir.0, args.synthetic)?;
    let photos = [
        (args.photo.display().to_string(), args.photo.clone()),
        (
            format!("synthetic {}x{}", args.synthetic.0, args.synthetic.1),
            synthetic,
        ),
    ];
    let mut peak = memory::vm_hwm_mib();
    let mut cases = Vec::new();
    for (label, path) in &photos {
        for board in &boards {
            peak = max_opt(peak, memory::vm_hwm_mib());
            let reset = memory::reset_peak();
            let mut case = stages::run_case(&ctx, label, path, board, args.runs)?;
            let case_peak = memory::vm_hwm_mib();
            case.peak_rss_mib = if reset { case_peak } else { None };
            peak = max_opt(peak, case_peak);
            log::info!("{label} / {}: done", board.name());
            cases.push(case);
        }
    }
    let peer = if args.no_peer {
        Vec::new()
    } else {
        peer_rows(args, &ctx, &boards)?
    };
    let naive = if args.no_naive {
        Vec::new()
    } else {
        naive_rows(args, &boards, &cases)?
    };
    Ok(Report {
        format: FORMAT.into(),
        command: command.into(),
        profile: if cfg!(debug_assertions) {
            "dev"
        } else {
            "release"
        }
        .into(),
        threads: args.threads,
        runs: args.runs,
        load_average,
        depth_model: depth_label(&ctx.depth),
        reshade_model: ctx.reshade_label.clone(),
        cases,
        peak_rss_mib: max_opt(peak, memory::vm_hwm_mib()),
        peer,
        naive,
        wall_s: started.elapsed().as_secs_f64(),
    })
}

fn max_opt(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.max(b)),
        (a, b) => a.or(b),
    }
}

/// The model's own description, and a loud label when it is the test fixture: its
/// times say nothing about what a trained reshading model costs.
fn reshade_label(net: &NetReshader) -> String {
    let description = net.description();
    if description.contains("fixture") {
        format!(
            "{description} — FIXTURE STAND-IN (tiny test network, not a trained reshading model)"
        )
    } else {
        description
    }
}

fn depth_label(net: &DepthNet) -> String {
    let m = net.manifest();
    format!(
        "{} {} ({}, {} x{} threads)",
        m.name,
        m.version,
        m.precision,
        net.engine().name(),
        net.engine().threads()
    )
}

/// A scratch directory removed when the benchmark ends.
pub(crate) struct TempDir(pub PathBuf);

impl TempDir {
    fn new() -> Result<TempDir, BenchError> {
        // Benchmarks may run side by side in one process (tests), each with its own directory.
        static NEXT: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let path = std::env::temp_dir().join(format!("reshader-bench-{}-{n}", std::process::id()));
        std::fs::create_dir_all(&path).map_err(io_err(&path))?;
        Ok(TempDir(path))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn load_average() -> Option<[f64; 3]> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = text.split_whitespace().map(|v| v.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

mod memory {
    /// Resets the kernel's peak-RSS counter for this process (Linux `clear_refs` 5), so
    /// each case's peak is its own.
    pub fn reset_peak() -> bool {
        std::fs::write("/proc/self/clear_refs", "5").is_ok()
    }

    /// Peak resident memory since start or the last reset (`VmHWM`).
    pub fn vm_hwm_mib() -> Option<f64> {
        let status = std::fs::read_to_string("/proc/self/status").ok()?;
        parse_vm_hwm(&status)
    }

    pub fn parse_vm_hwm(status: &str) -> Option<f64> {
        let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
        let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
        Some(kib / 1024.0)
    }
}

/// The source tree's copy of a benchmark script.
fn script(name: &str) -> PathBuf {
    let local = Path::new("bench").join(name);
    if local.is_file() {
        local
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("bench")
            .join(name)
    }
}

fn cache_home() -> PathBuf {
    std::env::var_os("HOME")
        .map_or_else(std::env::temp_dir, PathBuf::from)
        .join(".cache/reshader")
}

fn python(args: &BenchArgs) -> Result<PathBuf, BenchError> {
    if let Some(p) = args
        .python
        .clone()
        .or_else(|| std::env::var_os("RESHADER_PYTHON").map(PathBuf::from))
    {
        return Ok(p);
    }
    let venv = cache_home().join("venv/bin/python");
    if venv.is_file() {
        return Ok(venv);
    }
    let env_script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/python-env");
    let out = std::process::Command::new(&env_script)
        .output()
        .map_err(io_err(&env_script))?;
    let venv = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    if !out.status.success() || venv.is_empty() {
        return Err(BenchError::Usage(format!(
            "no Python with onnxruntime: {} failed; pass --python or --no-peer --no-naive",
            env_script.display()
        )));
    }
    Ok(PathBuf::from(venv).join("bin/python"))
}

/// The reshading model's files at the benchmark's precision: the manifest given, or
/// every reshading manifest of the directory given.
fn reshade_manifests(model: &Path, precision: Precision) -> Result<Vec<PathBuf>, BenchError> {
    if model.is_file() {
        return Ok(vec![model.to_owned()]);
    }
    let mut found: Vec<PathBuf> = std::fs::read_dir(model)
        .map_err(io_err(model))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .filter(|p| {
            manifest::Manifest::load(p).is_ok_and(|m| {
                m.precision == precision
                    && matches!(
                        m.task,
                        Task::Reshade | Task::ReshadeEncoder | Task::ReshadeDecoder
                    )
            })
        })
        .collect();
    found.sort();
    Ok(found)
}

fn padded(v: u32, multiple: usize) -> usize {
    (v as usize).div_ceil(multiple.max(1)) * multiple.max(1)
}

/// tract and onnxruntime on the depth models (at the network size the synthetic photo
/// gets) and on the reshading files (at the first board's padded view size).
fn peer_rows(
    args: &BenchArgs,
    ctx: &Context,
    boards: &[Board],
) -> Result<Vec<PeerRow>, BenchError> {
    let mut jobs = Vec::new();
    let (dw, dh) = ctx.depth.network_size(args.synthetic.0, args.synthetic.1)?;
    for precision in [Precision::Int8, Precision::Fp32] {
        let path = Path::new(crate::depth_net::DEFAULT_MODEL_DIR).join(format!(
            "{}-{precision}.json",
            crate::depth_net::DEFAULT_MODEL
        ));
        let path = if path.is_file() {
            path
        } else {
            Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
        };
        let model = manifest::load_verified(&path)?;
        jobs.push(Job::for_manifest(
            &format!("depth {}", model.manifest.name),
            &model,
            dh,
            dw,
        )?);
    }
    if let Some(board) = boards.first() {
        let (vw, vh) = board.view_size();
        for path in reshade_manifests(&args.model, args.precision)? {
            let model = manifest::load_verified(&path)?;
            let m = model.manifest.size_multiple as usize;
            let label = format!("{} {}", model.manifest.task, model.manifest.name);
            jobs.push(Job::for_manifest(
                &label,
                &model,
                padded(vh, m),
                padded(vw, m),
            )?);
        }
    }
    let (version, ort) = match python(args).and_then(|py| {
        peer::time_onnxruntime(
            &py,
            &script("peer_onnxruntime.py"),
            &jobs,
            args.threads,
            args.runs.max(3),
        )
    }) {
        Ok((v, r)) => (Some(v), r),
        Err(e) => {
            log::warn!("onnxruntime peer not run: {e}");
            (None, Vec::new())
        }
    };
    let mut rows = Vec::new();
    for job in &jobs {
        let tract = peer::time_tract(job, args.threads, args.runs.max(3));
        let ort_time = ort
            .iter()
            .find(|(l, _)| *l == job.label)
            .map(|(_, r)| r.clone());
        let mut notes = Vec::new();
        if let Err(e) = &tract {
            notes.push(format!("tract: {e}"));
        }
        match (&ort_time, &version) {
            (Some(Err(e)), _) => notes.push(format!("onnxruntime: {e}")),
            (None, _) => notes.push("onnxruntime not run (see log)".into()),
            (Some(Ok(_)), Some(v)) => notes.push(format!("onnxruntime {v}")),
            (Some(Ok(_)), None) => {}
        }
        rows.push(PeerRow {
            model: job.label.clone(),
            shapes: job.shapes_text(),
            tract: tract.ok(),
            onnxruntime: ort_time.and_then(Result::ok),
            note: Some(notes.join("; ")),
        });
    }
    Ok(rows)
}

const NAIVE_STEM: &str = "reshade-full-naive-fp32";

/// The randomly initialised paper-size network, exported once into the cache.
fn naive_model(args: &BenchArgs) -> Result<PathBuf, BenchError> {
    let dir = args
        .cache
        .clone()
        .unwrap_or_else(|| cache_home().join("bench"));
    let manifest = dir.join(format!("{NAIVE_STEM}.json"));
    if manifest.is_file() {
        return Ok(manifest);
    }
    let py = python(args)?;
    let exporter = script("export_naive.py");
    log::info!(
        "exporting the paper-size network to {} (once)",
        dir.display()
    );
    let status = std::process::Command::new(&py)
        .arg(&exporter)
        .arg("--out")
        .arg(&dir)
        .arg("--stem")
        .arg(NAIVE_STEM)
        .status()
        .map_err(io_err(&py))?;
    if !status.success() || !manifest.is_file() {
        return Err(BenchError::Peer {
            script: exporter,
            problem: format!(
                "exited with {status} without writing {}",
                manifest.display()
            ),
        });
    }
    Ok(manifest)
}

fn naive_rows(
    args: &BenchArgs,
    boards: &[Board],
    cases: &[Case],
) -> Result<Vec<NaiveRow>, BenchError> {
    let model = match naive_model(args) {
        Ok(path) => manifest::load_verified(&path)?,
        Err(e) => {
            log::warn!("naive configuration not run: {e}");
            return Ok(boards
                .iter()
                .map(|b| NaiveRow {
                    board: b.name().into(),
                    views: b.views(),
                    network_size: [0, 0],
                    per_view: None,
                    timed_views: 0,
                    runtime_ms: None,
                    note: Some(format!("not run: {e}")),
                })
                .collect());
        }
    };
    let m = model.manifest.size_multiple as usize;
    let mut rows = Vec::new();
    for board in boards {
        let (vw, vh) = board.view_size();
        let (pw, ph) = (padded(vw, m), padded(vh, m));
        let job = Job::for_manifest("naive", &model, ph, pw)?;
        let per_view = peer::time_tract(&job, args.threads, args.naive_views);
        let runtime = runtime_reshading(cases, board.name());
        rows.push(NaiveRow {
            board: board.name().into(),
            views: board.views(),
            network_size: [pw, ph],
            per_view: per_view.as_ref().ok().copied(),
            timed_views: args.naive_views,
            runtime_ms: runtime.as_ref().map(|(ms, _)| *ms),
            note: match (per_view, runtime) {
                (Err(e), _) => Some(format!("failed: {e}")),
                (Ok(_), Some((_, photo))) => Some(format!("runtime figure from {photo}")),
                (Ok(_), None) => None,
            },
        });
    }
    Ok(rows)
}

/// Encoder + decoder × views medians for `board`, preferring the synthetic photo's case
/// (the largest), with the photo it came from.
fn runtime_reshading(cases: &[Case], board: &str) -> Option<(f64, String)> {
    cases
        .iter()
        .rev()
        .filter(|c| c.board == board)
        .find_map(|c| {
            let enc = c.stage("reshade encoder")?.time?;
            let dec = c.stage("reshade decoder × views")?.time?;
            Some((enc.median_ms + dec.median_ms, c.photo.clone()))
        })
}

/// Median/min/max per stage over runs, in [`report::STAGES`] order; `None` rows are
/// stages the runtime has not built.
pub fn stage_stats(
    runs: &[Vec<(&'static str, f64)>],
) -> (Vec<(&'static str, Option<Stat>)>, Option<Stat>) {
    let rows = report::STAGES
        .iter()
        .map(|&stage| {
            let samples: Vec<f64> = runs
                .iter()
                .filter_map(|run| {
                    let times: Vec<f64> = run
                        .iter()
                        .filter(|(s, _)| *s == stage)
                        .map(|(_, t)| *t)
                        .collect();
                    (!times.is_empty()).then(|| times.iter().sum())
                })
                .collect();
            (stage, Stat::of(&samples))
        })
        .collect();
    let totals: Vec<f64> = runs
        .iter()
        .map(|run| run.iter().map(|(_, t)| t).sum())
        .collect();
    (rows, Stat::of(&totals))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vm_hwm_is_read_in_mib() {
        let status = "Name:\tx\nVmPeak:\t  9000 kB\nVmHWM:\t    2048 kB\nVmRSS:\t 1024 kB\n";
        assert_eq!(memory::parse_vm_hwm(status), Some(2.0));
        assert_eq!(memory::parse_vm_hwm("VmRSS: 1 kB"), None);
        assert!(memory::vm_hwm_mib().is_some_and(|m| m > 0.0));
    }

    #[test]
    fn sizes_parse_and_reject_nonsense() {
        assert_eq!(parse_size("4000x3000"), Ok((4000, 3000)));
        assert!(parse_size("4000").is_err());
        assert!(parse_size("8x8").is_err());
    }

    #[test]
    fn padding_rounds_up_to_the_multiple() {
        assert_eq!(padded(420, 32), 448);
        assert_eq!(padded(640, 32), 640);
    }
}
