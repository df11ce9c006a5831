//! `reshader bench`: one photo to a woven frame, stage by stage, for several boards, with
//! peak memory, the onnxruntime peer on the same ONNX files and the naive configuration
//! (paper-size network per view) for scale. See bench/README.md for how to read it.
//!
//! Every stage row is always reported: a stage this runtime does not have yet says
//! "n/a (not built)" rather than disappearing, so tables from different builds line up.

mod compare;
mod models;
pub mod peer;
pub mod readme;
pub mod report;
mod stages;
pub mod targets;

pub use models::choose_model;

use std::path::{Path, PathBuf};
use std::time::Instant;

use interleave::{Board, BoardError, WeaveError};

use crate::depth::net::{DepthNet, DepthNetError};
use crate::engine::manifest::{ManifestError, Precision};
use crate::engine::{self, EngineError};
use crate::io::output::OutputError;
use crate::io::photo::PhotoError;
use crate::pipeline::progress::Progress;
use crate::relocate::{RelocateConfig, RelocateError, Relocator};
use crate::reshade::net::choice::{Head, ReshadeConfig};
use crate::reshade::net::lobes::LobeReshader;
use crate::reshade::net::{NetError, NetOptions, NetReshader};
use crate::reshade::Reshader;
use crate::views::ViewError;

use compare::{naive_rows, peer_rows};
use report::{CompareError, Report, Stat, FORMAT};

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
    Pipeline(#[from] crate::pipeline::PipelineError),
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
    #[error(transparent)]
    Readme(#[from] readme::ReadmeError),
    #[error("{0}")]
    Usage(String),
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> BenchError + '_ {
    move |source| BenchError::Io {
        path: path.to_owned(),
        source,
    }
}

/// What `reshader bench` measures and where it writes.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    /// The reshading network and its options, as `render` takes them.
    pub reshade: ReshadeConfig,
    /// The relocator, as `render` takes it.
    pub relocate: RelocateConfig,
    /// Precision of the shipped depth model.
    pub depth_precision: Precision,
    /// The real photo to convert.
    pub photo: PathBuf,
    /// Size of the synthetic photo generated at run time.
    pub synthetic: (u32, u32),
    /// Built-in board names or board files.
    pub boards: Vec<String>,
    /// Timed runs per photo and board (after one untimed warm-up run).
    pub runs: usize,
    /// Threads for inference (unless the reshading threads are given), relocation and
    /// weaving.
    pub threads: usize,
    /// Report files: .md for Markdown, .json for the comparable form.
    pub out: Vec<PathBuf>,
    /// A previous run's JSON to compare every stage with.
    pub compare: Option<PathBuf>,
    /// Instead of measuring, take this saved JSON report (for --out, --compare, --readme).
    pub from: Option<PathBuf>,
    /// A Markdown file whose targets block (see [`readme`]) gets this report's targets.
    pub readme: Option<PathBuf>,
    pub no_peer: bool,
    pub no_naive: bool,
    /// Views the naive configuration really runs per board (the rest is extrapolated).
    pub naive_views: usize,
    /// Python with onnxruntime and the training toolchain (`None`: `$RESHADER_PYTHON`,
    /// else ~/.cache/reshader/venv/bin/python, else what scripts/python-env prints).
    pub python: Option<PathBuf>,
    /// Where the untrained exports are cached (`None`: ~/.cache/reshader/bench).
    pub cache: Option<PathBuf>,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            reshade: ReshadeConfig::default(),
            relocate: RelocateConfig::default(),
            depth_precision: Precision::Fp32,
            photo: PathBuf::from(DEFAULT_PHOTO),
            synthetic: (4000, 3000),
            boards: DEFAULT_BOARDS.split(',').map(String::from).collect(),
            runs: 3,
            threads: 2,
            out: Vec::new(),
            compare: None,
            from: None,
            readme: None,
            no_peer: false,
            no_naive: false,
            naive_views: 2,
            python: None,
            cache: None,
        }
    }
}

/// The real photo converted by default.
pub const DEFAULT_PHOTO: &str = "examples/pumpkin/pumpkin.jpg";

/// The smallest side of the synthetic photo.
pub const MIN_SYNTHETIC_SIDE: u32 = 32;

impl BenchConfig {
    fn check(&self) -> Result<(), BenchError> {
        if self.runs == 0 || self.threads == 0 || self.naive_views == 0 {
            return Err(BenchError::Usage(
                "--runs, --threads and --naive-views must be at least 1".into(),
            ));
        }
        if self.synthetic.0 < MIN_SYNTHETIC_SIDE || self.synthetic.1 < MIN_SYNTHETIC_SIDE {
            return Err(BenchError::Usage(format!(
                "--synthetic {}x{}: each side must be at least {MIN_SYNTHETIC_SIDE}",
                self.synthetic.0, self.synthetic.1
            )));
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

/// Measures, then writes every `--out` file; returns the report and the text to show
/// (the Markdown report, and the comparison with `--compare`'s run).
pub fn run_and_write(args: &BenchConfig, command: &str) -> Result<(Report, String), BenchError> {
    args.check()?;
    if let Some(readme) = &args.readme {
        readme::check(readme)?;
    }
    let previous = args.compare.as_deref().map(Report::load).transpose()?;
    let report = match &args.from {
        Some(saved) => Report::load(saved)?,
        None => run(args, command)?,
    };
    let markdown = report.to_markdown();
    let mut shown = markdown.clone();
    let comparison = previous.map(|p| report.compare(&p));
    if let Some(text) = &comparison {
        shown.push('\n');
        shown.push_str(text);
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
        crate::io::output::write_atomic(out, text.as_bytes())?;
    }
    if let Some(readme) = &args.readme {
        readme::update(readme, &report, &report_source(args))?;
    }
    Ok((report, shown))
}

/// Where a README's targets block says its figures come from: the saved report read or
/// written, else the run itself.
fn report_source(args: &BenchConfig) -> String {
    let json = args
        .from
        .iter()
        .chain(
            args.out
                .iter()
                .filter(|o| o.extension().is_some_and(|e| e == "json")),
        )
        .next();
    match json {
        Some(path) => format!("[`{0}`]({0})", path.display()),
        None => "a run whose report was not saved".into(),
    }
}

/// The reshading model timed: either head, as `render` would load it.
pub(crate) enum BenchReshader {
    Residual(NetReshader),
    Lobes(LobeReshader),
}

impl BenchReshader {
    pub fn options(&self) -> &NetOptions {
        match self {
            BenchReshader::Residual(net) => net.options(),
            BenchReshader::Lobes(net) => net.options(),
        }
    }

    pub fn description(&self) -> String {
        match self {
            BenchReshader::Residual(net) => net.description(),
            BenchReshader::Lobes(net) => net.description(),
        }
    }

    pub fn as_reshader(&self) -> &dyn crate::reshade::Reshader {
        match self {
            BenchReshader::Residual(net) => net,
            BenchReshader::Lobes(net) => net,
        }
    }

    pub fn head(&self) -> Head {
        match self {
            BenchReshader::Residual(_) => Head::Residual,
            BenchReshader::Lobes(_) => Head::Lobes,
        }
    }
}

/// Everything the stages share across photos and boards.
pub(crate) struct Context {
    pub threads: usize,
    pub depth: DepthNet,
    pub reshader: BenchReshader,
    pub reshade_label: String,
    pub relocator: Box<dyn Relocator>,
    /// The same model with the per-view cost options (a)+(b) of the reshading design,
    /// timed beside the runtime's reshading for the naive comparison.
    pub candidate: Option<NetReshader>,
    pub work_dir: TempDir,
}

/// Working resolution and key views of the candidate design timed against the naive
/// configuration (docs/benchmarks.md, "Per-view cost options": ×0.5 and 8 key views).
pub const CANDIDATE_SCALE: f64 = 0.5;
pub const CANDIDATE_KEY_VIEWS: usize = 8;

/// The reshading model the benchmark times, and whether it stands in for the shipped one.
#[derive(Clone, Debug, PartialEq)]
pub enum ModelChoice {
    /// Named with --model or $RESHADER_MODEL.
    Given(PathBuf),
    /// models/reshade: the shipped model.
    Shipped(PathBuf),
    /// The shipped architecture with random weights, exported into the cache.
    Untrained(PathBuf),
    /// The tiny test network.
    Fixture(PathBuf),
}

impl ModelChoice {
    pub fn path(&self) -> &Path {
        match self {
            ModelChoice::Given(p)
            | ModelChoice::Shipped(p)
            | ModelChoice::Untrained(p)
            | ModelChoice::Fixture(p) => p,
        }
    }
}

/// Measures every case and the comparisons; writes nothing but its scratch directory.
pub fn run(args: &BenchConfig, command: &str) -> Result<Report, BenchError> {
    args.check()?;
    let started = Instant::now();
    let load_average = load_average();
    let depth = DepthNet::shipped(
        args.depth_precision,
        engine::by_name("tract", args.threads)?,
    )?;
    let model = choose_model(args)?;
    let r = &args.reshade;
    let threads = r.threads.unwrap_or(args.threads);
    let per_view = (threads / r.parallel_views.max(1)).max(1);
    let precision = r.precision_for(Some(model.path()));
    let head = r.head_for(model.path())?;
    let reshader = match head {
        Head::Residual => BenchReshader::Residual(NetReshader::load(
            model.path(),
            precision,
            engine::by_name(&r.engine, per_view)?,
            r.options(),
        )?),
        Head::Lobes => BenchReshader::Lobes(LobeReshader::load(
            model.path(),
            precision,
            engine::by_name(&r.engine, threads)?,
            r.options(),
        )?),
    };
    let reshade_label = reshade_label(&reshader.description());
    let candidate_options = NetOptions {
        scale: CANDIDATE_SCALE,
        key_views: Some(CANDIDATE_KEY_VIEWS),
        ..r.options()
    };
    // The candidate options cut the residual head's network runs per view; the lobe head
    // has none to cut.
    let candidate = if args.no_naive || candidate_options == r.options() || head == Head::Lobes {
        None
    } else {
        Some(NetReshader::load(
            model.path(),
            precision,
            engine::by_name(&r.engine, per_view)?,
            candidate_options,
        )?)
    };
    let ctx = Context {
        threads: args.threads,
        depth,
        reshader,
        reshade_label,
        relocator: args.relocate.build(),
        candidate,
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
    // The whole run's peak is the largest case's: generating the synthetic photo is
    // not part of a conversion, and the peer and naive models are not the runtime's.
    let mut peak = None;
    let mut cases = Vec::new();
    let progress = Progress::start((photos.len() * boards.len()) as u64, "cases", false);
    for (label, path) in &photos {
        for board in &boards {
            progress.set_message(format!("{label} / {}", board.name()));
            let reset = memory::reset_peak();
            let mut case = stages::run_case(&ctx, label, path, board, args.runs)?;
            let case_peak = memory::vm_hwm_mib();
            case.peak_rss_mib = if reset { case_peak } else { None };
            peak = max_opt(peak, case_peak);
            log::info!("{label} / {}: done", board.name());
            cases.push(case);
            progress.inc(1);
        }
    }
    progress.finish();
    let peer = if args.no_peer {
        Vec::new()
    } else {
        peer_rows(args, &ctx, model.path(), head, &cases)?
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
        cpu: cpu_model(),
        depth_model: depth_label(&ctx.depth),
        reshade_model: ctx.reshade_label.clone(),
        cases,
        peak_rss_mib: peak,
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

/// The model's own description, with a loud label on a stand-in (told by the name the
/// exporter gave it, however it was chosen).
fn reshade_label(description: &str) -> String {
    let description = description.to_owned();
    if description.contains("fixture") {
        format!(
            "{description} — FIXTURE STAND-IN (tiny test network: its times say nothing about a trained reshading model)"
        )
    } else if description.contains("untrained") {
        format!(
            "{description} — UNTRAINED STAND-IN (the shipped architecture with random weights: a trained model's cost, not its pictures)"
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

/// The processor's model name, from Linux's `/proc/cpuinfo`.
fn cpu_model() -> Option<String> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    text.lines()
        .find_map(|line| line.strip_prefix("model name")?.split_once(':'))
        .map(|(_, name)| name.trim().to_owned())
}

fn load_average() -> Option<[f64; 3]> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut it = text.split_whitespace().map(|v| v.parse::<f64>().ok());
    Some([it.next()??, it.next()??, it.next()??])
}

mod memory {
    /// Resets the kernel's peak-RSS counter for this process (Linux `clear_refs` 5), so
    /// each case's peak is its own, after handing back what earlier cases freed (which
    /// the allocator would otherwise keep resident).
    pub fn reset_peak() -> bool {
        crate::io::limits::release_freed_memory();
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
mod tests;
