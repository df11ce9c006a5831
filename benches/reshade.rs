//! `cargo bench --bench reshade -- --model models/<dir> [--size 640x384] [--views 48]
//! [--engines tract,ort] [--precisions fp32,fp16,int8] [--threads 2] [--timed-views 8]
//! [--lobes-model FILE]` prints the reshading benchmark tables (see
//! `reshader::eval::reshade`).

use std::path::PathBuf;

use clap::Parser;
use reshader::engine::manifest::Precision;
use reshader::eval::reshade::BenchConfig;

/// The reshading benchmark's flags; each default is `BenchConfig`'s.
#[derive(Parser)]
#[command(name = "reshade benchmark")]
struct Args {
    /// A reshading model folder or manifest.
    #[arg(long)]
    model: Option<PathBuf>,
    /// The lobe-head model timed in the "lobes" rows [default: --model, when it holds one].
    #[arg(long)]
    lobes_model: Option<PathBuf>,
    /// The test photo's size, WxH.
    #[arg(long, value_parser = parse_size)]
    size: Option<(u32, u32)>,
    #[arg(long)]
    views: Option<usize>,
    /// Views timed per precision and engine row.
    #[arg(long)]
    timed_views: Option<usize>,
    #[arg(long)]
    threads: Option<usize>,
    /// The view cone, degrees.
    #[arg(long)]
    cone: Option<f64>,
    #[arg(long, value_delimiter = ',')]
    engines: Vec<String>,
    #[arg(long, value_delimiter = ',', value_parser = |s: &str| s.parse::<Precision>())]
    precisions: Vec<Precision>,
    /// Passed by `cargo bench`.
    #[arg(long, hide = true)]
    bench: bool,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once('x').ok_or("--size wants WxH")?;
    let num = |v: &str| v.parse::<u32>().map_err(|e| format!("--size {s}: {e}"));
    Ok((num(w)?, num(h)?))
}

impl Args {
    fn config(self) -> BenchConfig {
        let d = BenchConfig::default();
        let (width, height) = self.size.unwrap_or((d.width, d.height));
        BenchConfig {
            model: self.model.unwrap_or(d.model),
            lobes_model: self.lobes_model,
            width,
            height,
            views: self.views.unwrap_or(d.views),
            timed_views: self.timed_views.unwrap_or(d.timed_views),
            threads: self.threads.unwrap_or(d.threads),
            cone_deg: self.cone.unwrap_or(d.cone_deg),
            engines: if self.engines.is_empty() {
                d.engines
            } else {
                self.engines
            },
            precisions: if self.precisions.is_empty() {
                d.precisions
            } else {
                self.precisions
            },
        }
    }
}

fn main() {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    match reshader::eval::reshade::run(&Args::parse().config()) {
        Ok(text) => println!("{text}"),
        Err(e) => {
            eprintln!("reshade benchmark: {e}");
            std::process::exit(2);
        }
    }
}
