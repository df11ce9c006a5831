//! The benchmark's results as data: statistics over runs, the per-stage table, the peer
//! and naive comparisons, and their Markdown, JSON and run-to-run comparison forms.
//! Nothing here measures anything, so all of it is tested without timing.

use std::fmt::Write as _;

use serde::{Deserialize, Serialize};

use super::{CANDIDATE_KEY_VIEWS, CANDIDATE_SCALE};

/// Identifies the JSON layout; `--compare` refuses other formats.
pub const FORMAT: &str = "reshader-bench/1";

/// Rows of the per-stage table, in pipeline order. Every case reports every row, so a
/// stage that is not built yet shows up as such instead of vanishing from the table.
pub const STAGES: &[&str] = &[
    "decode",
    "depth",
    "depth refinement",
    "fit to view size",
    "LDI build + inpainting",
    "reshade encoder",
    "reshade decoder × views",
    "LDI render × views",
    "weave table",
    "weave",
    "encode/write",
];

/// Median, minimum and maximum of a set of timings in milliseconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stat {
    pub median_ms: f64,
    pub min_ms: f64,
    pub max_ms: f64,
    pub runs: usize,
}

impl Stat {
    /// None for no samples; the median of an even count is the mean of the middle two.
    pub fn of(samples: &[f64]) -> Option<Stat> {
        if samples.is_empty() {
            return None;
        }
        let mut s = samples.to_vec();
        s.sort_by(f64::total_cmp);
        let n = s.len();
        let median = if n % 2 == 1 {
            s[n / 2]
        } else {
            (s[n / 2 - 1] + s[n / 2]) / 2.0
        };
        Some(Stat {
            median_ms: median,
            min_ms: s[0],
            max_ms: s[n - 1],
            runs: n,
        })
    }

    fn cell(&self) -> String {
        format!(
            "{} ({}–{})",
            ms(self.median_ms),
            ms(self.min_ms),
            ms(self.max_ms)
        )
    }
}

/// Milliseconds with precision that suits their size.
pub fn ms(v: f64) -> String {
    if v >= 100.0 {
        format!("{v:.0}")
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StageRow {
    pub stage: String,
    /// What ran (model, implementation), or why nothing did.
    pub detail: String,
    /// None: the stage is not built in this runtime yet.
    pub time: Option<Stat>,
}

/// One photo converted for one board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Case {
    pub photo: String,
    pub photo_size: [u32; 2],
    pub board: String,
    pub views: usize,
    pub view_size: [u32; 2],
    /// The size photo and depth were fitted to (reshading and relocation run at it).
    pub work_size: [u32; 2],
    pub stages: Vec<StageRow>,
    /// Per-run sums of the stages (the median of sums, not the sum of medians).
    pub total: Option<Stat>,
    /// Peak resident memory during this case's runs (None where the kernel cannot reset it).
    pub peak_rss_mib: Option<f64>,
    /// Encoder + decoder × views with the candidate per-view cost options (not part of
    /// the total: the runtime does not run it).
    #[serde(default)]
    pub candidate_reshading: Option<Stat>,
}

impl Case {
    pub fn stage(&self, name: &str) -> Option<&StageRow> {
        self.stages.iter().find(|s| s.stage == name)
    }

    fn key(&self) -> String {
        format!("{} / {}", self.photo, self.board)
    }
}

/// The same ONNX file run by tract and by onnxruntime at the same input shapes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PeerRow {
    pub model: String,
    pub shapes: String,
    pub tract: Option<Stat>,
    pub onnxruntime: Option<Stat>,
    /// Why a side has no time.
    pub note: Option<String>,
}

impl PeerRow {
    /// tract time over onnxruntime time (above 1: tract is slower).
    pub fn ratio(&self) -> Option<f64> {
        Some(self.tract?.median_ms / self.onnxruntime?.median_ms)
    }
}

/// The paper-size network run per view at the view size, against the runtime's
/// reshading stage for the same board.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NaiveRow {
    pub board: String,
    pub views: usize,
    pub network_size: [usize; 2],
    /// Per view, over the views actually run.
    pub per_view: Option<Stat>,
    pub timed_views: usize,
    /// Reshading stage of the runtime (encoder + decoder × views) for the same board.
    pub runtime_ms: Option<f64>,
    /// The same with the candidate per-view cost options.
    #[serde(default)]
    pub candidate_ms: Option<f64>,
    pub note: Option<String>,
}

impl NaiveRow {
    pub fn extrapolated_ms(&self) -> Option<f64> {
        Some(self.per_view?.median_ms * self.views as f64)
    }

    /// How many times cheaper the runtime's reshading is than the naive configuration.
    pub fn saving(&self) -> Option<f64> {
        Some(self.extrapolated_ms()? / self.runtime_ms?)
    }

    /// The same for the candidate options.
    pub fn candidate_saving(&self) -> Option<f64> {
        Some(self.extrapolated_ms()? / self.candidate_ms?)
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub format: String,
    pub command: String,
    /// "release" or "dev": dev-profile times are not representative.
    pub profile: String,
    pub threads: usize,
    pub runs: usize,
    pub load_average: Option<[f64; 3]>,
    /// The processor's model name (`/proc/cpuinfo`): times from another processor do
    /// not compare. None in reports from before it was recorded.
    #[serde(default)]
    pub cpu: Option<String>,
    pub reshade_model: String,
    pub depth_model: String,
    pub cases: Vec<Case>,
    /// Peak resident memory of the conversions: the largest case's `VmHWM`, which
    /// includes the loaded models (peer and naive runs come after and do not count).
    pub peak_rss_mib: Option<f64>,
    pub peer: Vec<PeerRow>,
    pub naive: Vec<NaiveRow>,
    pub wall_s: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: not a benchmark JSON: {source}")]
    Json {
        path: String,
        source: serde_json::Error,
    },
    #[error("{path}: format {found:?}, expected {FORMAT:?}")]
    Format { path: String, found: String },
}

impl Report {
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("report serialises")
    }

    pub fn from_json(path: &str, text: &str) -> Result<Report, CompareError> {
        let report: Report = serde_json::from_str(text).map_err(|source| CompareError::Json {
            path: path.into(),
            source,
        })?;
        if report.format != FORMAT {
            return Err(CompareError::Format {
                path: path.into(),
                found: report.format,
            });
        }
        Ok(report)
    }

    pub fn load(path: &std::path::Path) -> Result<Report, CompareError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| CompareError::Io {
            path: name.clone(),
            source,
        })?;
        Report::from_json(&name, &text)
    }

    pub fn to_markdown(&self) -> String {
        let mut out = String::new();
        self.header(&mut out);
        out.push_str(&super::targets::markdown(self));
        for case in &self.cases {
            case_table(case, &mut out);
        }
        self.summary(&mut out);
        self.peer_table(&mut out);
        self.naive_table(&mut out);
        out
    }

    fn header(&self, out: &mut String) {
        let load = self.load_average.map_or("unknown".into(), |l| {
            format!("{:.2} {:.2} {:.2}", l[0], l[1], l[2])
        });
        let _ = writeln!(out, "# reshader bench\n");
        let _ = writeln!(out, "- command: `{}`", self.command);
        let _ = writeln!(
            out,
            "- build profile: {}{}",
            self.profile,
            if self.profile == "release" {
                ""
            } else {
                " — times are NOT representative; run `cargo run --release -- bench`"
            }
        );
        let _ = writeln!(
            out,
            "- {} threads on {}, median (min–max) of {} runs, ms; load average at start: {load}",
            self.threads,
            self.cpu_name(),
            self.runs
        );
        let _ = writeln!(out, "- reshading model: {}", self.reshade_model);
        let _ = writeln!(out, "- depth model: {}", self.depth_model);
        let _ = writeln!(
            out,
            "- peak resident memory of the conversions (largest case, models loaded): {}; wall time {:.0} s\n",
            mib(self.peak_rss_mib),
            self.wall_s
        );
    }

    /// One line per case: the end-to-end time and the share of its largest stage,
    /// ratios that survive a noisy machine better than the absolute times.
    fn summary(&self, out: &mut String) {
        let _ = writeln!(
            out,
            "## Summary\n\n| photo | board | views | total ms | ms per view | largest stage (share) | peak RSS |\n|---|---|---|---|---|---|---|"
        );
        for case in &self.cases {
            let Some(total) = case.total else { continue };
            let largest = case
                .stages
                .iter()
                .filter_map(|s| Some((s, s.time?.median_ms)))
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .map_or("–".into(), |(s, t)| {
                    format!("{} ({:.0}%)", s.stage, 100.0 * t / total.median_ms)
                });
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} | {largest} | {} |",
                case.photo,
                case.board,
                case.views,
                total.cell(),
                ms(total.median_ms / case.views as f64),
                mib(case.peak_rss_mib)
            );
        }
        out.push('\n');
    }

    fn peer_table(&self, out: &mut String) {
        let _ = writeln!(
            out,
            "## Peer: tract vs onnxruntime on the same ONNX files\n\n| model | input shapes | tract ms | onnxruntime ms | tract / onnxruntime | note |\n|---|---|---|---|---|---|"
        );
        if self.peer.is_empty() {
            let _ = writeln!(out, "| (not run: --no-peer) | | | | | |");
        }
        for row in &self.peer {
            let _ = writeln!(
                out,
                "| {} | {} | {} | {} | {} | {} |",
                row.model,
                row.shapes,
                cell(row.tract),
                cell(row.onnxruntime),
                row.ratio().map_or("–".into(), |r| format!("{r:.2}×")),
                row.note.as_deref().unwrap_or("")
            );
        }
        out.push('\n');
    }

    fn naive_table(&self, out: &mut String) {
        let _ = writeln!(
            out,
            "## Naive configuration: paper-size network per view, full working resolution, fp32\n\n\
             The runtime's reshading stage (encoder once + decoder × views, model above) \
             against running the randomly initialised `full` network once per view at the \
             same working size; the naive time is measured on a few views and multiplied \
             by the view count. The candidate column is the same model with \
             `--reshade-scale {CANDIDATE_SCALE} --key-views {CANDIDATE_KEY_VIEWS}` (per-view cost options (a)+(b)), \
             timed in the same run.\n\n\
             | board | views | network input | naive ms/view | views timed | naive total (extrapolated) ms | runtime reshading ms | saving | candidate ms | candidate saving | note |\n|---|---|---|---|---|---|---|---|---|---|---|"
        );
        if self.naive.is_empty() {
            let _ = writeln!(out, "| (not run: --no-naive) | | | | | | | | | | |");
        }
        for row in &self.naive {
            let _ = writeln!(
                out,
                "| {} | {} | {}x{} | {} | {} | {} | {} | {} | {} | {} | {} |",
                row.board,
                row.views,
                row.network_size[0],
                row.network_size[1],
                cell(row.per_view),
                row.timed_views,
                row.extrapolated_ms().map_or("–".into(), ms),
                row.runtime_ms.map_or("–".into(), ms),
                row.saving().map_or("–".into(), |s| format!("{s:.1}×")),
                row.candidate_ms.map_or("–".into(), ms),
                row.candidate_saving()
                    .map_or("–".into(), |s| format!("{s:.1}×")),
                row.note.as_deref().unwrap_or("")
            );
        }
        out.push('\n');
    }

    /// Markdown table of the change of every stage's median from `previous` to `self`;
    /// cases and stages present on one side only are listed as such.
    /// The processor, or "an unrecorded processor".
    pub fn cpu_name(&self) -> &str {
        self.cpu.as_deref().unwrap_or("an unrecorded processor")
    }

    pub fn compare(&self, previous: &Report) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "## Change against the previous run\n\nprevious: `{}` ({}, load {}), now: `{}` ({}, load {})\n\n\
             | photo / board | stage | previous ms | now ms | change |\n|---|---|---|---|---|",
            previous.command,
            previous.profile,
            load_text(previous.load_average),
            self.command,
            self.profile,
            load_text(self.load_average),
        );
        for (what, old, new) in [
            ("processor", previous.cpu_name(), self.cpu_name()),
            ("depth model", &previous.depth_model, &self.depth_model),
            (
                "reshading model",
                previous.reshade_model.as_str(),
                self.reshade_model.as_str(),
            ),
        ] {
            if old != new {
                let _ = writeln!(out, "| (setup) | {what} differs | {old} | {new} | |");
            }
        }
        for case in &self.cases {
            let before = previous.cases.iter().find(|c| c.key() == case.key());
            let Some(before) = before else {
                let _ = writeln!(out, "| {} | (all) | not in previous | | |", case.key());
                continue;
            };
            for row in &case.stages {
                let old = before.stage(&row.stage).and_then(|r| r.time);
                let _ = writeln!(
                    out,
                    "| {} | {} | {} | {} | {} |",
                    case.key(),
                    row.stage,
                    median_cell(old),
                    median_cell(row.time),
                    change(old, row.time)
                );
            }
            let _ = writeln!(
                out,
                "| {} | **total** | {} | {} | {} |",
                case.key(),
                median_cell(before.total),
                median_cell(case.total),
                change(before.total, case.total)
            );
        }
        for before in &previous.cases {
            if !self.cases.iter().any(|c| c.key() == before.key()) {
                let _ = writeln!(out, "| {} | (all) | | not in this run | |", before.key());
            }
        }
        let _ = writeln!(
            out,
            "\npeak resident memory: {} → {}",
            mib(previous.peak_rss_mib),
            mib(self.peak_rss_mib)
        );
        out
    }
}

fn case_table(case: &Case, out: &mut String) {
    let _ = writeln!(
        out,
        "## {} ({}x{}) → {} ({} views of {}x{}; working size {}x{})\n\n| stage | ms median (min–max) | share | what ran |\n|---|---|---|---|",
        case.photo,
        case.photo_size[0],
        case.photo_size[1],
        case.board,
        case.views,
        case.view_size[0],
        case.view_size[1],
        case.work_size[0],
        case.work_size[1]
    );
    let total = case.total.map(|t| t.median_ms);
    for row in &case.stages {
        let share = match (row.time, total) {
            (Some(t), Some(total)) if total > 0.0 => format!("{:.0}%", 100.0 * t.median_ms / total),
            _ => "".into(),
        };
        let time = row.time.map_or("n/a (not built)".into(), |t| t.cell());
        let _ = writeln!(out, "| {} | {time} | {share} | {} |", row.stage, row.detail);
    }
    let _ = writeln!(
        out,
        "| **total** | **{}** | 100% | peak RSS {} |\n",
        case.total.map_or("–".into(), |t| t.cell()),
        mib(case.peak_rss_mib)
    );
}

fn cell(stat: Option<Stat>) -> String {
    stat.map_or("–".into(), |s| s.cell())
}

fn median_cell(stat: Option<Stat>) -> String {
    stat.map_or("n/a".into(), |s| ms(s.median_ms))
}

/// Relative change of the medians, with the ratio now/previous.
pub fn change(old: Option<Stat>, new: Option<Stat>) -> String {
    match (old, new) {
        (Some(o), Some(n)) if o.median_ms > 0.0 => {
            let pct = 100.0 * (n.median_ms - o.median_ms) / o.median_ms;
            format!("{pct:+.1}% ({:.2}×)", n.median_ms / o.median_ms)
        }
        (None, Some(_)) => "newly built".into(),
        (Some(_), None) => "no longer measured".into(),
        _ => "–".into(),
    }
}

fn mib(v: Option<f64>) -> String {
    v.map_or("unknown".into(), |m| format!("{m:.0} MiB"))
}

fn load_text(l: Option<[f64; 3]>) -> String {
    l.map_or("unknown".into(), |l| format!("{:.2}", l[0]))
}
