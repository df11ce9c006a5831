//! Unit tests of `device::display::fb`, beside it so that the module file holds the code only.

use super::*;

fn var_fix(bpp: u32, stride: u32) -> (FbVarScreeninfo, FbFixScreeninfo) {
    let mut var = FbVarScreeninfo {
        xres: 4,
        yres: 2,
        bits_per_pixel: bpp,
        ..Default::default()
    };
    var.red = FbBitfield {
        offset: 16,
        length: 8,
        msb_right: 0,
    };
    var.green = FbBitfield {
        offset: 8,
        length: 8,
        msb_right: 0,
    };
    var.blue = FbBitfield {
        offset: 0,
        length: 8,
        msb_right: 0,
    };
    let mut fix = FbFixScreeninfo {
        smem_len: stride * 2,
        visual: FB_VISUAL_TRUECOLOR,
        line_length: stride,
        ..Default::default()
    };
    fix.id[..4].copy_from_slice(b"test");
    (var, fix)
}

#[test]
fn screeninfo_structs_match_the_kernel_abi() {
    assert_eq!(std::mem::size_of::<FbVarScreeninfo>(), 160);
    let fix = if cfg!(target_pointer_width = "64") {
        80
    } else {
        68
    };
    assert_eq!(std::mem::size_of::<FbFixScreeninfo>(), fix);
}

#[test]
fn driver_geometry_is_read_and_checked() {
    let (var, fix) = var_fix(32, 20);
    let g = geometry_from_screeninfo(&var, &fix).unwrap();
    assert_eq!(g.id, "test");
    assert_eq!(
        (g.width, g.height, g.line_length, g.mem_len),
        (4, 2, 20, 40)
    );
    assert_eq!(g.pack([1, 2, 3]), 0x0001_0203);

    let (var, mut fix) = var_fix(32, 12);
    fix.smem_len = 24;
    let err = geometry_from_screeninfo(&var, &fix)
        .unwrap_err()
        .to_string();
    assert!(err.contains("line length 12 B"), "{err}");

    let (var, mut fix) = var_fix(8, 4);
    fix.visual = 3; // pseudo-colour: a palette, not packed RGB
    let err = geometry_from_screeninfo(&var, &fix)
        .unwrap_err()
        .to_string();
    assert!(err.contains("true-colour"), "{err}");
}

#[test]
fn channels_scale_with_rounding() {
    let g = FbGeometry::packed(1, 1, "rgb565", None).unwrap();
    assert_eq!(g.pack([255, 0, 0]), 0xF800);
    assert_eq!(g.pack([0, 255, 0]), 0x07E0);
    assert_eq!(g.pack([0, 0, 255]), 0x001F);
    // 128/255 of 31 is 15.56 → 16; of 63 is 31.6 → 32.
    assert_eq!(g.pack([128, 128, 128]), (16 << 11) | (32 << 5) | 16);
}

#[test]
fn geometry_specs_parse_and_refuse_nonsense() {
    let g = FbGeometry::parse("640x480:xrgb8888:2600").unwrap();
    assert_eq!(
        (g.width, g.height, g.line_length, g.bits_per_pixel),
        (640, 480, 2600, 32)
    );
    assert!(FbGeometry::parse("640x480:xrgb8888:100")
        .unwrap_err()
        .contains("shorter"));
    assert!(FbGeometry::parse("640x480:yuv")
        .unwrap_err()
        .contains("unknown"));
    assert!(FbGeometry::parse("640:xrgb8888").is_err());
}
