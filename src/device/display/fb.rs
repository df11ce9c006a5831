//! Linux framebuffer output (`/dev/fbN`) through `libc`: the geometry comes from the
//! FBIOGET_VSCREENINFO / FBIOGET_FSCREENINFO ioctls on a device, or from an explicit
//! description when a regular file stands in for one (tests, image dumps); either way the
//! memory is mapped and frames are packed into it honouring the line stride, bits per
//! pixel and each channel's bit offset and length.

use std::fs::{File, OpenOptions};
use std::os::fd::AsRawFd;
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};

use image::RgbImage;

use super::{DisplayError, FrameSink};

const FBIOGET_VSCREENINFO: u32 = 0x4600;
const FBIOGET_FSCREENINFO: u32 = 0x4602;
const FB_TYPE_PACKED_PIXELS: u32 = 0;
const FB_VISUAL_TRUECOLOR: u32 = 2;
const FB_VISUAL_DIRECTCOLOR: u32 = 4;

/// One colour channel's place in a pixel value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Channel {
    pub offset: u32,
    pub length: u32,
}

impl Channel {
    const fn new(offset: u32, length: u32) -> Self {
        Self { offset, length }
    }

    /// An 8-bit value scaled to this channel's width, rounded, in place.
    fn pack(self, value: u8) -> u32 {
        if self.length == 0 {
            return 0;
        }
        let max = (1u32 << self.length) - 1;
        ((u32::from(value) * max + 127) / 255) << self.offset
    }
}

/// What the sink needs to know about a framebuffer's memory.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FbGeometry {
    /// The driver's identification (empty for a file).
    pub id: String,
    /// Visible resolution.
    pub width: u32,
    pub height: u32,
    /// Top-left of the visible area inside the (virtual) buffer.
    pub xoffset: u32,
    pub yoffset: u32,
    pub bits_per_pixel: u32,
    /// Bytes from one row to the next, padding included.
    pub line_length: u32,
    pub red: Channel,
    pub green: Channel,
    pub blue: Channel,
    /// Alpha, set opaque when present.
    pub transp: Channel,
    /// Bytes of framebuffer memory to map.
    pub mem_len: usize,
}

impl FbGeometry {
    /// A packed layout by name: `xrgb8888`, `rgb565` or `rgb888`; `stride` defaults to
    /// width × bytes per pixel.
    pub fn packed(
        width: u32,
        height: u32,
        format: &str,
        stride: Option<u32>,
    ) -> Result<Self, String> {
        let (bpp, red, green, blue) = match format.to_ascii_lowercase().as_str() {
            "xrgb8888" => (
                32,
                Channel::new(16, 8),
                Channel::new(8, 8),
                Channel::new(0, 8),
            ),
            "rgb565" => (
                16,
                Channel::new(11, 5),
                Channel::new(5, 6),
                Channel::new(0, 5),
            ),
            "rgb888" => (
                24,
                Channel::new(16, 8),
                Channel::new(8, 8),
                Channel::new(0, 8),
            ),
            other => {
                return Err(format!(
                    "unknown pixel format {other:?}; use xrgb8888, rgb565 or rgb888"
                ))
            }
        };
        let line_length = stride.unwrap_or(width * bpp / 8);
        let geometry = Self {
            id: String::new(),
            width,
            height,
            xoffset: 0,
            yoffset: 0,
            bits_per_pixel: bpp,
            line_length,
            red,
            green,
            blue,
            transp: Channel::new(0, 0),
            mem_len: line_length as usize * height as usize,
        };
        geometry.validate()?;
        Ok(geometry)
    }

    /// `WIDTHxHEIGHT:FORMAT[:STRIDE]`, as in `--display fb:FILE:1920x1080:xrgb8888`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let parts: Vec<&str> = text.split(':').collect();
        let usage = || format!("geometry {text:?} is not WIDTHxHEIGHT:FORMAT[:STRIDE]");
        if !(2..=3).contains(&parts.len()) {
            return Err(usage());
        }
        let (w, h) = parts[0].split_once('x').ok_or_else(usage)?;
        let num = |s: &str| s.parse::<u32>().map_err(|_| usage());
        let stride = parts.get(2).map(|s| num(s)).transpose()?;
        Self::packed(num(w)?, num(h)?, parts[1], stride)
    }

    pub fn bytes_per_pixel(&self) -> usize {
        self.bits_per_pixel as usize / 8
    }

    /// Checks that the layout is one this sink can pack and that the visible area fits
    /// the memory, so writes can never leave the mapping.
    pub fn validate(&self) -> Result<(), String> {
        if ![16, 24, 32].contains(&self.bits_per_pixel) {
            return Err(format!(
                "{} bits per pixel is not supported (16, 24 or 32)",
                self.bits_per_pixel
            ));
        }
        for (name, c) in [
            ("red", self.red),
            ("green", self.green),
            ("blue", self.blue),
        ] {
            if c.length == 0 || c.length > 16 || c.offset + c.length > self.bits_per_pixel {
                return Err(format!(
                    "{name} channel at bit {} length {} does not fit a {}-bit pixel",
                    c.offset, c.length, self.bits_per_pixel
                ));
            }
        }
        if self.transp.length > 0 && self.transp.offset + self.transp.length > self.bits_per_pixel {
            return Err("alpha channel does not fit the pixel".into());
        }
        if self.width == 0 || self.height == 0 {
            return Err("visible size is 0".into());
        }
        let row_bytes = (self.xoffset as usize + self.width as usize) * self.bytes_per_pixel();
        if (self.line_length as usize) < row_bytes {
            return Err(format!(
                "line length {} B is shorter than {} visible pixels of {} B",
                self.line_length,
                self.width,
                self.bytes_per_pixel()
            ));
        }
        let needed = (self.yoffset as usize + self.height as usize) * self.line_length as usize;
        if self.mem_len < needed {
            return Err(format!(
                "{} B of memory cannot hold {} rows of {} B",
                self.mem_len,
                self.yoffset + self.height,
                self.line_length
            ));
        }
        Ok(())
    }

    /// The pixel value for an RGB colour.
    pub fn pack(&self, rgb: [u8; 3]) -> u32 {
        let alpha = if self.transp.length > 0 {
            ((1u32 << self.transp.length) - 1) << self.transp.offset
        } else {
            0
        };
        self.red.pack(rgb[0]) | self.green.pack(rgb[1]) | self.blue.pack(rgb[2]) | alpha
    }
}

impl std::fmt::Display for FbGeometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ch = |c: Channel| format!("{}:{}", c.offset, c.length);
        if !self.id.is_empty() {
            write!(f, "'{}' ", self.id)?;
        }
        write!(
            f,
            "{}x{} visible at +{}+{}, {} bpp, stride {} B, R {} G {} B {} A {}, {} B mapped",
            self.width,
            self.height,
            self.xoffset,
            self.yoffset,
            self.bits_per_pixel,
            self.line_length,
            ch(self.red),
            ch(self.green),
            ch(self.blue),
            ch(self.transp),
            self.mem_len
        )
    }
}

/// Frames written straight into mapped framebuffer memory. A frame of another size than
/// the screen is placed at the top-left, cropped or bordered in black, never resampled:
/// resampling a woven frame would mix the views its subpixels belong to.
pub struct FramebufferSink {
    path: PathBuf,
    geometry: FbGeometry,
    map: Mapping,
    /// One packed row, reused between frames.
    row: Vec<u8>,
    /// Each channel's 256 packed values (alpha in red's), built once: packing a panel
    /// frame is then three lookups and an OR per pixel.
    tables: Box<[[u32; 256]; 3]>,
    size_warned: bool,
    _file: File,
}

impl FramebufferSink {
    /// Opens a framebuffer device and reads its geometry from the driver.
    pub fn open(path: &Path) -> Result<Self, DisplayError> {
        let file = open_rw(path)?;
        let kind = file
            .metadata()
            .map_err(|e| device_err(path, e))?
            .file_type();
        if !kind.is_char_device() {
            return Err(unsupported(
                path,
                "is not a framebuffer device; for a file standing in for one give its \
                 geometry: fb:PATH:WIDTHxHEIGHT:FORMAT[:STRIDE]",
            ));
        }
        let geometry = query_geometry(&file).map_err(|e| device_err(path, e))??;
        Self::map(path, file, geometry)
    }

    /// Uses a regular file (or a device) with the given geometry instead of asking the
    /// driver.
    pub fn open_with_geometry(path: &Path, geometry: FbGeometry) -> Result<Self, DisplayError> {
        geometry.validate().map_err(|r| unsupported(path, &r))?;
        let file = open_rw(path)?;
        let meta = file.metadata().map_err(|e| device_err(path, e))?;
        if meta.file_type().is_file() && meta.len() < geometry.mem_len as u64 {
            return Err(unsupported(
                path,
                &format!(
                    "file has {} B, the geometry needs {} B",
                    meta.len(),
                    geometry.mem_len
                ),
            ));
        }
        Self::map(path, file, geometry)
    }

    fn map(path: &Path, file: File, geometry: FbGeometry) -> Result<Self, DisplayError> {
        let map = Mapping::new(&file, geometry.mem_len).map_err(|e| device_err(path, e))?;
        log::info!("framebuffer {}: {geometry}", path.display());
        Ok(Self {
            path: path.into(),
            row: vec![0; geometry.width as usize * geometry.bytes_per_pixel()],
            tables: channel_tables(&geometry),
            geometry,
            map,
            size_warned: false,
            _file: file,
        })
    }

    pub fn geometry(&self) -> &FbGeometry {
        &self.geometry
    }

    fn pack_row(&mut self, frame: &RgbImage, y: u32) {
        let bpp = self.geometry.bytes_per_pixel();
        let [r, g, b] = &*self.tables;
        let black = (r[0] | g[0] | b[0]).to_le_bytes();
        let shown = if y < frame.height() {
            frame.width().min(self.geometry.width) as usize
        } else {
            0
        };
        let (inside, beyond) = self.row.split_at_mut(shown * bpp);
        let start = y as usize * frame.width() as usize * 3;
        let pixels = frame.as_raw().get(start..start + shown * 3).unwrap_or(&[]);
        // Pixels are little-endian in framebuffer memory on the platforms served (x86,
        // ARM), so a 24-bit pixel is the value's low three bytes.
        for (out, px) in inside.chunks_exact_mut(bpp).zip(pixels.chunks_exact(3)) {
            let value = r[usize::from(px[0])] | g[usize::from(px[1])] | b[usize::from(px[2])];
            out.copy_from_slice(&value.to_le_bytes()[..bpp]);
        }
        for out in beyond.chunks_exact_mut(bpp) {
            out.copy_from_slice(&black[..bpp]);
        }
    }
}

/// `geometry.pack` of every value of each channel, the alpha bits in red's table.
fn channel_tables(geometry: &FbGeometry) -> Box<[[u32; 256]; 3]> {
    let mut tables = Box::new([[0u32; 256]; 3]);
    for v in 0..=255u8 {
        let i = usize::from(v);
        tables[0][i] = geometry.pack([v, 0, 0]);
        tables[1][i] = geometry.green.pack(v);
        tables[2][i] = geometry.blue.pack(v);
    }
    tables
}

impl FrameSink for FramebufferSink {
    fn describe(&self) -> String {
        format!("framebuffer {}: {}", self.path.display(), self.geometry)
    }

    fn show(&mut self, frame: &RgbImage) -> Result<(), DisplayError> {
        let (w, h) = (self.geometry.width, self.geometry.height);
        if frame.dimensions() != (w, h) && !self.size_warned {
            log::warn!(
                "{}: frame is {}x{} but the screen is {w}x{h}; placing it at the top-left \
                 unscaled (choose a board whose panel matches the screen)",
                self.path.display(),
                frame.width(),
                frame.height()
            );
            self.size_warned = true;
        }
        let stride = self.geometry.line_length as usize;
        let x0 = self.geometry.xoffset as usize * self.geometry.bytes_per_pixel();
        for y in 0..h {
            self.pack_row(frame, y);
            let start = (self.geometry.yoffset + y) as usize * stride + x0;
            self.map.bytes_mut()[start..start + self.row.len()].copy_from_slice(&self.row);
        }
        Ok(())
    }
}

fn open_rw(path: &Path) -> Result<File, DisplayError> {
    OpenOptions::new()
        .read(true)
        .write(true)
        .open(path)
        .map_err(|e| device_err(path, e))
}

fn device_err(path: &Path, source: std::io::Error) -> DisplayError {
    DisplayError::Device {
        path: path.into(),
        source,
    }
}

fn unsupported(path: &Path, reason: &str) -> DisplayError {
    DisplayError::Unsupported {
        path: path.into(),
        reason: reason.into(),
    }
}

#[repr(C)]
#[derive(Default)]
struct FbBitfield {
    offset: u32,
    length: u32,
    msb_right: u32,
}

/// `struct fb_var_screeninfo` from linux/fb.h.
#[repr(C)]
#[derive(Default)]
struct FbVarScreeninfo {
    xres: u32,
    yres: u32,
    xres_virtual: u32,
    yres_virtual: u32,
    xoffset: u32,
    yoffset: u32,
    bits_per_pixel: u32,
    grayscale: u32,
    red: FbBitfield,
    green: FbBitfield,
    blue: FbBitfield,
    transp: FbBitfield,
    nonstd: u32,
    activate: u32,
    height: u32,
    width: u32,
    accel_flags: u32,
    timings: [u32; 11],
    reserved: [u32; 4],
}

/// `struct fb_fix_screeninfo` from linux/fb.h.
#[repr(C)]
#[derive(Default)]
struct FbFixScreeninfo {
    id: [u8; 16],
    smem_start: libc::c_ulong,
    smem_len: u32,
    type_: u32,
    type_aux: u32,
    visual: u32,
    xpanstep: u16,
    ypanstep: u16,
    ywrapstep: u16,
    line_length: u32,
    mmio_start: libc::c_ulong,
    mmio_len: u32,
    accel: u32,
    capabilities: u16,
    reserved: [u16; 2],
}

/// Reads the driver's geometry. The outer error is the ioctl failing, the inner one a
/// layout this sink cannot drive.
fn query_geometry(file: &File) -> std::io::Result<Result<FbGeometry, DisplayError>> {
    let mut var = FbVarScreeninfo::default();
    let mut fix = FbFixScreeninfo::default();
    // SAFETY: both requests fill exactly the struct passed, which mirrors the kernel's
    // layout (repr(C), same field types), and the fd is open for the call's duration.
    unsafe {
        if libc::ioctl(file.as_raw_fd(), FBIOGET_VSCREENINFO as _, &mut var) < 0 {
            return Err(std::io::Error::last_os_error());
        }
        if libc::ioctl(file.as_raw_fd(), FBIOGET_FSCREENINFO as _, &mut fix) < 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(geometry_from_screeninfo(&var, &fix))
}

fn geometry_from_screeninfo(
    var: &FbVarScreeninfo,
    fix: &FbFixScreeninfo,
) -> Result<FbGeometry, DisplayError> {
    let id_len = fix.id.iter().position(|&b| b == 0).unwrap_or(fix.id.len());
    let id = String::from_utf8_lossy(&fix.id[..id_len]).into_owned();
    let refuse = |reason: String| DisplayError::Unsupported {
        path: PathBuf::from(format!("'{id}'")),
        reason,
    };
    if fix.type_ != FB_TYPE_PACKED_PIXELS
        || !(fix.visual == FB_VISUAL_TRUECOLOR || fix.visual == FB_VISUAL_DIRECTCOLOR)
        || var.grayscale != 0
        || var.nonstd != 0
    {
        return Err(refuse(format!(
            "type {} visual {} grayscale {} nonstd {}: only packed true-colour pixels are \
             supported",
            fix.type_, fix.visual, var.grayscale, var.nonstd
        )));
    }
    if [&var.red, &var.green, &var.blue, &var.transp]
        .iter()
        .any(|c| c.msb_right != 0)
    {
        return Err(refuse(
            "bit-reversed (msb_right) channels are not supported".into(),
        ));
    }
    let ch = |b: &FbBitfield| Channel::new(b.offset, b.length);
    let geometry = FbGeometry {
        id: id.clone(),
        width: var.xres,
        height: var.yres,
        xoffset: var.xoffset,
        yoffset: var.yoffset,
        bits_per_pixel: var.bits_per_pixel,
        line_length: fix.line_length,
        red: ch(&var.red),
        green: ch(&var.green),
        blue: ch(&var.blue),
        transp: ch(&var.transp),
        mem_len: fix.smem_len as usize,
    };
    geometry.validate().map_err(refuse)?;
    Ok(geometry)
}

/// A shared, writable memory mapping, unmapped on drop.
struct Mapping {
    ptr: *mut u8,
    len: usize,
}

impl Mapping {
    fn new(file: &File, len: usize) -> std::io::Result<Self> {
        // SAFETY: a fresh shared mapping of `len` bytes of an fd open read-write; the
        // result is checked against MAP_FAILED before use.
        let ptr = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                len,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_SHARED,
                file.as_raw_fd(),
                0,
            )
        };
        if ptr == libc::MAP_FAILED {
            return Err(std::io::Error::last_os_error());
        }
        Ok(Self {
            ptr: ptr.cast(),
            len,
        })
    }

    fn bytes_mut(&mut self) -> &mut [u8] {
        // SAFETY: `ptr` is a live mapping of `len` bytes owned by self; `&mut self`
        // makes this the only slice over it.
        unsafe { std::slice::from_raw_parts_mut(self.ptr, self.len) }
    }
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: unmaps exactly the region mapped in `new`; no slice outlives self.
        unsafe {
            libc::munmap(self.ptr.cast(), self.len);
        }
    }
}

// SAFETY: the mapping is plain memory owned by this value; nothing else aliases it.
unsafe impl Send for Mapping {}

#[cfg(test)]
mod tests;
