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

use crate::depth::net::{DepthNet, DepthNetError};
use crate::engine::manifest::{self, ManifestError, Precision, Task};
use crate::engine::{self, EngineError};
use crate::io::output::OutputError;
use crate::io::photo::PhotoError;
use crate::pipeline::progress::Progress;
use crate::relocate::{RelocateArgs, RelocateError, Relocator};
use crate::reshade::net::cli::{Head, ReshadeArgs, DEFAULT_MODEL_DIR};
use crate::reshade::net::lobes::LobeReshader;
use crate::reshade::net::{NetError, NetOptions, NetReshader};
use crate::reshade::Reshader;
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
  cargo run --release -- bench --boards looking-glass-portrait --compare bench.json

The reshading model timed is --model, else models/reshade (or $RESHADER_MODEL) when it
has the --precision asked for, else an untrained export of the shipped architecture
made once into the cache by bench/export_untrained.py, else the tiny test fixture; a
stand-in is labelled as such in every table. See bench/README.md.";

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
    /// The reshading network and its options, as `render` takes them.
    #[command(flatten)]
    pub reshade: ReshadeArgs,
    /// The relocator, as `render` takes it.
    #[command(flatten)]
    pub relocate: RelocateArgs,
    /// Precision of the shipped depth model (models/depth), as `render --depth-precision`.
    #[arg(long, default_value = "fp32")]
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
    /// Threads for inference (unless --reshade-threads) and weaving.
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
    /// Where the untrained exports (naive network, reshading stand-in) are cached, never
    /// committed [default: ~/.cache/reshader/bench].
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
        crate::io::output::write_atomic(out, text.as_bytes())?;
    }
    Ok(report)
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
pub fn run(args: &BenchArgs, command: &str) -> Result<Report, BenchError> {
    args.check()?;
    let started = Instant::now();
    let load_average = load_average();
    let depth = DepthNet::shipped(
        args.depth_precision,
        engine::by_name("tract", args.threads)?,
    )?;
    let model = choose_model(args)?;
    let r = &args.reshade;
    let threads = r.reshade_threads.unwrap_or(args.threads);
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

/// --model, else $RESHADER_MODEL, else models/reshade when it has the precision asked
/// for, else the untrained stand-in (exported once), else the fixture.
pub fn choose_model(args: &BenchArgs) -> Result<ModelChoice, BenchError> {
    let precision = args.reshade.precision_for(args.reshade.model.as_deref());
    if let Some(p) = args
        .reshade
        .model
        .clone()
        .or_else(|| std::env::var_os("RESHADER_MODEL").map(PathBuf::from))
    {
        return Ok(ModelChoice::Given(p));
    }
    let shipped = source_path(DEFAULT_MODEL_DIR);
    let head = args
        .reshade
        .head
        .unwrap_or(crate::reshade::net::cli::DEFAULT_HEAD);
    if shipped.is_dir() && !reshade_manifests(&shipped, Some(precision), head)?.is_empty() {
        return Ok(ModelChoice::Shipped(shipped));
    }
    log::warn!(
        "no {precision} {head}-head reshading model in {}: timing a stand-in",
        shipped.display()
    );
    // The untrained stand-in is the residual head's architecture.
    if precision != Precision::Int8 && head == Head::Residual {
        match untrained_model(args, precision) {
            Ok(path) => return Ok(ModelChoice::Untrained(path)),
            Err(e) => log::warn!("untrained stand-in not available ({e}); using the fixture"),
        }
    }
    Ok(ModelChoice::Fixture(source_path("models/fixtures")))
}

/// A path relative to the working directory, else to the source tree.
fn source_path(rel: &str) -> PathBuf {
    let local = PathBuf::from(rel);
    if local.exists() {
        local
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
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
    source_path(&format!("bench/{name}"))
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

/// The reshading manifests of `model` at `precision` (None: every precision) for `head`.
/// For a directory: its manifests of that head, leaving out a precision's single graph
/// when the pair of that precision is there (the runtime runs the pair). For a manifest:
/// it and, for one half of a pair, the other half beside it.
fn reshade_manifests(
    model: &Path,
    precision: Option<Precision>,
    head: Head,
) -> Result<Vec<PathBuf>, BenchError> {
    if model.is_file() {
        let mut files = vec![model.to_owned()];
        let name = model
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let partner = if name.contains("decoder") {
            name.replace("decoder", "encoder")
        } else {
            name.replace("encoder", "decoder")
        };
        let partner = model.with_file_name(&partner);
        if partner != model && partner.is_file() {
            files.insert(0, partner);
        }
        return Ok(files);
    }
    let mut found: Vec<(PathBuf, manifest::Manifest)> = std::fs::read_dir(model)
        .map_err(io_err(model))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .filter_map(|p| manifest::Manifest::load(&p).ok().map(|m| (p, m)))
        .filter(|(_, m)| {
            precision.is_none_or(|p| m.precision == p)
                && match head {
                    Head::Residual => crate::reshade::net::is_residual(m.task),
                    Head::Lobes => m.task == Task::ReshadeLobes,
                }
        })
        .collect();
    let split: Vec<Precision> = found
        .iter()
        .filter(|(_, m)| m.task == Task::ReshadeDecoder)
        .map(|(_, m)| m.precision)
        .collect();
    found.retain(|(_, m)| m.task != Task::Reshade || !split.contains(&m.precision));
    let mut paths: Vec<PathBuf> = found.into_iter().map(|(p, _)| p).collect();
    paths.sort();
    Ok(paths)
}

fn padded(v: u32, multiple: usize) -> usize {
    (v as usize).div_ceil(multiple.max(1)) * multiple.max(1)
}

/// tract and onnxruntime on the depth models (at the network size the synthetic photo
/// gets) and on every precision of the reshading model's files (at the size the first
/// board's last case reshaded at).
fn peer_rows(
    args: &BenchArgs,
    ctx: &Context,
    model: &Path,
    head: Head,
    cases: &[Case],
) -> Result<Vec<PeerRow>, BenchError> {
    let mut jobs = Vec::new();
    let (dw, dh) = ctx.depth.network_size(args.synthetic.0, args.synthetic.1)?;
    for precision in [Precision::Int8, Precision::Fp32] {
        let path = source_path(&format!(
            "{}/{}-{precision}.json",
            crate::depth::net::DEFAULT_MODEL_DIR,
            crate::depth::net::DEFAULT_MODEL
        ));
        let model = manifest::load_verified(&path)?;
        jobs.push(Job::for_manifest(
            &format!("depth {}", model.manifest.name),
            &model,
            dh,
            dw,
        )?);
    }
    if let Some(case) = cases
        .iter()
        .rev()
        .find(|c| Some(&c.board) == cases.first().map(|f| &f.board))
    {
        let [ww, wh] = case.work_size;
        for path in reshade_manifests(model, None, head)? {
            let model = manifest::load_verified(&path)?;
            let m = model.manifest.size_multiple as usize;
            let label = format!("{} {}", model.manifest.task, model.manifest.name);
            jobs.push(Job::for_manifest(
                &label,
                &model,
                padded(wh, m),
                padded(ww, m),
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
    Ok(jobs
        .iter()
        .map(|job| peer_row(args, job, &ort, version.as_deref()))
        .collect())
}

fn peer_row(
    args: &BenchArgs,
    job: &Job,
    ort: &[(String, Result<Stat, String>)],
    version: Option<&str>,
) -> PeerRow {
    let tract = peer::time_tract(job, args.threads, args.runs.max(3));
    let ort_time = ort
        .iter()
        .find(|(l, _)| *l == job.label)
        .map(|(_, r)| r.clone());
    let mut notes = Vec::new();
    if let Err(e) = &tract {
        notes.push(format!("tract: {e}"));
    }
    match (&ort_time, version) {
        (Some(Err(e)), _) => notes.push(format!("onnxruntime: {e}")),
        (None, _) => notes.push("onnxruntime not run (see log)".into()),
        (Some(Ok(_)), Some(v)) => notes.push(format!("onnxruntime {v}")),
        (Some(Ok(_)), None) => {}
    }
    PeerRow {
        model: job.label.clone(),
        shapes: job.shapes_text(),
        tract: tract.ok(),
        onnxruntime: ort_time.and_then(Result::ok),
        note: Some(notes.join("; ")),
    }
}

/// The shipped architecture's size, for the untrained stand-in.
const STAND_IN_SIZE: &str = "lite";

/// The untrained stand-in's decoder manifest (its encoder is found beside it).
fn untrained_model(args: &BenchArgs, precision: Precision) -> Result<PathBuf, BenchError> {
    let stem = cached_export(args, STAND_IN_SIZE, true, precision)?;
    Ok(stem.with_file_name(format!(
        "{}-decoder.json",
        stem.file_stem().unwrap_or_default().to_string_lossy()
    )))
}

/// A randomly initialised network of `size` exported once into the cache by
/// bench/export_untrained.py; the single graph's manifest.
fn cached_export(
    args: &BenchArgs,
    size: &str,
    split: bool,
    precision: Precision,
) -> Result<PathBuf, BenchError> {
    let dir = args
        .cache
        .clone()
        .unwrap_or_else(|| cache_home().join("bench"));
    let stem = format!("reshade-{size}-untrained-{precision}");
    let manifest = dir.join(format!("{stem}.json"));
    let decoder = dir.join(format!("{stem}-decoder.json"));
    if manifest.is_file() && (!split || decoder.is_file()) {
        return Ok(manifest);
    }
    let py = python(args)?;
    let exporter = script("export_untrained.py");
    log::info!(
        "exporting an untrained {size} network to {} (once)",
        dir.display()
    );
    let mut command = std::process::Command::new(&py);
    command
        .arg(&exporter)
        .arg("--out")
        .arg(&dir)
        .arg("--size")
        .arg(size)
        .arg("--precision")
        .arg(precision.to_string());
    if split {
        command.arg("--split");
    }
    let status = command.status().map_err(io_err(&py))?;
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
    let model = match cached_export(args, "full", false, Precision::Fp32) {
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
                    candidate_ms: None,
                    note: Some(format!("not run: {e}")),
                })
                .collect());
        }
    };
    let m = model.manifest.size_multiple as usize;
    let mut rows = Vec::new();
    for board in boards {
        let Some(runtime) = runtime_reshading(cases, board.name()) else {
            continue;
        };
        let [ww, wh] = runtime.work_size;
        let (pw, ph) = (padded(ww, m), padded(wh, m));
        let job = Job::for_manifest("naive", &model, ph, pw)?;
        let per_view = peer::time_tract(&job, args.threads, args.naive_views);
        rows.push(NaiveRow {
            board: board.name().into(),
            views: board.views(),
            network_size: [pw, ph],
            per_view: per_view.as_ref().ok().copied(),
            timed_views: args.naive_views,
            runtime_ms: Some(runtime.ms),
            candidate_ms: runtime.candidate_ms,
            note: Some(match per_view {
                Err(e) => format!("failed: {e}"),
                Ok(_) => format!("runtime figure from {}", runtime.photo),
            }),
        });
    }
    Ok(rows)
}

/// The runtime's reshading stage for one board.
struct RuntimeReshading {
    ms: f64,
    candidate_ms: Option<f64>,
    photo: String,
    work_size: [u32; 2],
}

/// Encoder + decoder × views medians for `board`, preferring the synthetic photo's case
/// (the largest), with the photo it came from and the size it reshaded at.
fn runtime_reshading(cases: &[Case], board: &str) -> Option<RuntimeReshading> {
    cases
        .iter()
        .rev()
        .filter(|c| c.board == board)
        .find_map(|c| {
            let enc = c.stage("reshade encoder")?.time?;
            let dec = c.stage("reshade decoder × views")?.time?;
            Some(RuntimeReshading {
                ms: enc.median_ms + dec.median_ms,
                candidate_ms: c.candidate_reshading.map(|s| s.median_ms),
                photo: c.photo.clone(),
                work_size: c.work_size,
            })
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
mod tests;
