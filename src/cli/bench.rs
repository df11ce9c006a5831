//! `reshader bench`: a photo to a woven frame, timed stage by stage.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use reshader::engine::manifest::Precision;
use reshader::eval::bench::{run_and_write, BenchConfig, DEFAULT_BOARDS, DEFAULT_PHOTO};

use crate::args::{parse_size, RelocateArgs, ReshadeArgs};

pub const BENCH_ABOUT: &str = "\
Time the conversion of a photo to a woven frame, stage by stage (median and min-max of
--runs runs), for the shipped example photo and a synthetic 12 MP photo on each board,
with peak memory, tract vs onnxruntime on the same ONNX files, and the paper-size network
run per view (the naive configuration) for comparison. Build with --release: dev-profile
times are not representative.

Examples:
  cargo run --release -- bench --out bench.md --out bench.json
  cargo run --release -- bench --boards looking-glass-portrait --compare bench.json
  # the README's targets table from a saved report, measuring nothing
  reshader bench --from bench/results/bench-2026-12-04b.json --readme README.md

The reshading model timed is --model, else models/reshade (or $RESHADER_MODEL) when it
has the --precision asked for, else an untrained export of the shipped architecture
made once into the cache by bench/export_untrained.py, else the tiny test fixture; a
stand-in is labelled as such in every table. See bench/README.md.";

/// `reshader bench`'s arguments.
#[derive(Clone, Debug, Args)]
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
    #[arg(long, default_value = DEFAULT_PHOTO)]
    pub photo: PathBuf,
    /// Size of the synthetic photo generated at run time (WxH; 4000x3000 is 12 MP).
    #[arg(long, default_value = "4000x3000", value_parser = synthetic_size)]
    pub synthetic: (u32, u32),
    /// Boards (built-in names or .toml files), comma-separated.
    #[arg(long, default_value = DEFAULT_BOARDS, value_delimiter = ',')]
    pub boards: Vec<String>,
    /// Timed runs per photo and board (after one untimed warm-up run).
    #[arg(long, default_value_t = 3)]
    pub runs: usize,
    /// Threads for inference (unless --reshade-threads), relocation and weaving.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Write the report: .md for Markdown, .json for the comparable form (repeatable).
    #[arg(long)]
    pub out: Vec<PathBuf>,
    /// A previous run's JSON: print the change of every stage against it.
    #[arg(long)]
    pub compare: Option<PathBuf>,
    /// Measure nothing: take this saved JSON report and write --out, --compare and
    /// --readme from it.
    #[arg(long, value_name = "REPORT.json")]
    pub from: Option<PathBuf>,
    /// Write the report's targets table into this Markdown file (the README's headline
    /// figures), between a line starting `<!-- bench-targets` and a line
    /// `<!-- /bench-targets -->`.
    #[arg(long, value_name = "FILE.md")]
    pub readme: Option<PathBuf>,
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

fn synthetic_size(s: &str) -> Result<(u32, u32), String> {
    parse_size(s, reshader::eval::bench::MIN_SYNTHETIC_SIDE, u32::MAX)
}

impl BenchArgs {
    fn config(&self) -> BenchConfig {
        BenchConfig {
            reshade: self.reshade.config(),
            relocate: self.relocate.config(),
            depth_precision: self.depth_precision,
            photo: self.photo.clone(),
            synthetic: self.synthetic,
            boards: self.boards.clone(),
            runs: self.runs,
            threads: self.threads,
            out: self.out.clone(),
            compare: self.compare.clone(),
            from: self.from.clone(),
            readme: self.readme.clone(),
            no_peer: self.no_peer,
            no_naive: self.no_naive,
            naive_views: self.naive_views,
            python: self.python.clone(),
            cache: self.cache.clone(),
        }
    }
}

/// Runs `reshader bench`: prints the Markdown report (and the comparison), writes --out.
pub fn bench(args: &BenchArgs) -> Result<()> {
    let command: Vec<String> = std::env::args().collect();
    let (_, shown) = run_and_write(&args.config(), &command.join(" "))?;
    println!("{shown}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flags_defaults_are_the_library_s() {
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            bench: BenchArgs,
        }
        let cli = <Cli as clap::Parser>::try_parse_from(["bench"]).unwrap();
        let (parsed, default) = (cli.bench.config(), BenchConfig::default());
        assert_eq!(format!("{parsed:?}"), format!("{default:?}"));
    }
}
