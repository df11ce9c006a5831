//! `reshader reshade` and `reshader view`: one camera's reshaded photo, or its novel view.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use reshader::io::output;
use reshader::pipeline::{self, ViewRequest};

use crate::args::{parse_vec3, RelocateArgs, SceneArgs};

pub const RESHADE_ABOUT: &str = "\
Reshade the photo as seen from --camera, keeping the input camera's frame: the pixels
stay where they are and only their shading changes (highlights slide). With --model none
the photo comes back unchanged.

Examples:
  reshader reshade photo.jpg --camera 0.1,0,0 --out reshaded.png
  reshader reshade photo.jpg --depth depth.npy --camera 0.1,0,0 --out reshaded.png";

pub const VIEW_ABOUT: &str = "\
Render the novel view from --camera: reshade (unless --no-reshade), then relocate the
pixels with the depth. The projection is sheared so the zero-parallax plane (--focus)
stays put, as in `render`: for a photo of the board's view size, a render's view k
equals `view` with run.json's camera k.

Examples:
  reshader view photo.jpg --camera -0.2,0,0 --out view.exr
  reshader view photo.jpg --depth depth.npy --camera -0.2,0,0 --out view.exr";

#[derive(Args)]
pub struct SingleViewArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Novel camera centre TX,TY,TZ in the input camera's frame (OpenCV: x right, y down,
    /// z forward), in depth-map units.
    #[arg(long, value_parser = parse_vec3, allow_hyphen_values = true)]
    pub camera: [f64; 3],
    /// Output image: .png (8-bit), .exr or .npy (float).
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Args)]
pub struct ViewArgs {
    #[command(flatten)]
    pub single: SingleViewArgs,
    /// Skip reshading: relocate the photo's own colours.
    #[arg(long)]
    pub no_reshade: bool,
    #[command(flatten)]
    pub relocate: RelocateArgs,
}

/// Refuses a single view at the photo's resolution that would not fit --max-memory.
pub fn check_single_view_memory(args: &SceneArgs, reshading: bool) -> Result<()> {
    let Some(photo) = reshader::io::photo::header_size(&args.photo) else {
        return Ok(());
    };
    let size = reshader::pipeline::preflight::single_view_size(
        photo,
        reshading.then_some(&args.reshade.config()),
        args.estimates_depth(),
    );
    reshader::pipeline::preflight::check_memory(
        format!("a view of a {}x{} photo", photo.0, photo.1),
        &reshader::pipeline::preflight::estimate(&size),
        reshader::pipeline::preflight::VIEW_HINT,
    )?;
    Ok(())
}

/// Runs `reshader reshade`.
pub fn reshade(args: SingleViewArgs) -> Result<()> {
    output::FileFormat::require(&args.out, output::IMAGE_FORMATS)?;
    output::check_output_file(&args.out)?;
    args.scene.reshade.check_model()?;
    check_single_view_memory(&args.scene, true)?;
    let scene = args.scene.load(None)?;
    let req = ViewRequest {
        scene: &scene,
        camera: args.camera,
        focus: args.scene.focus,
    };
    let reshader = args.scene.reshade.config().build()?;
    let image = pipeline::reshade_photo(&req, &*reshader)?;
    pipeline::write_image(&args.out, &image)?;
    Ok(())
}

/// Runs `reshader view`.
pub fn view(args: ViewArgs) -> Result<()> {
    let single = args.single;
    output::FileFormat::require(&single.out, output::IMAGE_FORMATS)?;
    output::check_output_file(&single.out)?;
    if !args.no_reshade {
        single.scene.reshade.check_model()?;
    }
    check_single_view_memory(&single.scene, !args.no_reshade)?;
    let scene = single.scene.load(None)?;
    let req = ViewRequest {
        scene: &scene,
        camera: single.camera,
        focus: single.scene.focus,
    };
    let reshader = if args.no_reshade {
        None
    } else {
        Some(single.scene.reshade.config().build()?)
    };
    let reshader = reshader
        .as_deref()
        .map(|r| r as &dyn reshader::reshade::Reshader);
    let image = pipeline::render_view(&req, reshader, &*args.relocate.config().build())?;
    pipeline::write_image(&single.out, &image)?;
    Ok(())
}
