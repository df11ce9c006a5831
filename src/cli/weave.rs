//! `reshader weave` and `reshader boards`: views or a quilt woven for a panel, and the
//! built-in boards.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use reshader::interleave::Board;
use reshader::io::output;
use reshader::pipeline;

use crate::args::FilterArgs;

#[derive(Args)]
pub struct WeaveArgs {
    /// A directory holding view_00.png … view_{N-1}.png, or a quilt image: its layout
    /// from its PNG metadata, else from its name (…_qs8x6a0.75.png).
    pub input: PathBuf,
    #[arg(long)]
    pub board: String,
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    #[command(flatten)]
    pub filter: FilterArgs,
    /// Output panel image (.png).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `reshader weave`.
pub fn weave(args: WeaveArgs) -> Result<()> {
    output::FileFormat::require(&args.out, &[output::FileFormat::Png])?;
    output::check_output_file(&args.out)?;
    let mut board = pipeline::load_board(&args.board, args.calibration.as_deref())?;
    args.filter.apply(&mut board)?;
    reshader::pipeline::preflight::check_memory(
        format!("weaving for {}", board.name()),
        &reshader::pipeline::preflight::weave_estimate(&board),
        "",
    )?;
    let panel = if args.input.is_dir() {
        pipeline::weave_dir(&args.input, &board)?
    } else {
        reshader::io::quilt_file::weave(&args.input, &board)?
    };
    let bytes = output::encode_png(&args.out, &panel)?;
    output::write_atomic(&args.out, &bytes)?;
    Ok(())
}

/// Runs `reshader boards`.
pub fn list_boards() {
    for name in Board::builtin_names() {
        match Board::builtin(name) {
            Ok(b) => {
                let (w, h) = b.panel_size();
                let (vw, vh) = b.view_size();
                println!(
                    "{name:<26} {w}x{h}, {} views of {vw}x{vh}, {}° cone — {}",
                    b.views(),
                    b.view_cone_deg(),
                    b.description()
                );
            }
            Err(e) => println!("{name:<26} (invalid: {e})"),
        }
    }
}
