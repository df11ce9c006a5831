//! V4L2 cameras through the `v4l` crate: memory-mapped streaming of YUYV or MJPEG.

use std::path::Path;
use std::time::{Duration, Instant};

use v4l::buffer::Type;
use v4l::format::FourCC;
use v4l::framesize::FrameSizeEnum;
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::Device;

use super::{
    check_frame_size, decode_frame, CameraRequest, CaptureError, FormatInfo, Frame, FrameSource,
    PixelFormat,
};

/// Few buffers: with many, the driver fills them all while a frame is processed and the
/// next one dequeued is already old.
const BUFFERS: u32 = 3;

/// How long a frame may take to arrive before the camera counts as stalled.
const FRAME_TIMEOUT: Duration = Duration::from_secs(5);

pub struct V4l2Source {
    device: String,
    stream: MmapStream<'static>,
    format: PixelFormat,
    width: u32,
    height: u32,
    first_timestamp: Option<Duration>,
    last_sequence: Option<u32>,
    dropped: u64,
    sequence: u64,
}

impl V4l2Source {
    pub fn open(path: &Path, request: &CameraRequest) -> Result<Self, CaptureError> {
        let device = path.display().to_string();
        let dev = Device::with_path(path).map_err(|e| device_error(&device, e))?;
        let (format, width, height) = negotiate(&dev, &device, request)?;
        if let Some(fps) = request.fps {
            // Best effort: many cameras accept only their listed intervals and pick the
            // nearest, which the log reports through `describe`.
            let _ = dev.set_params(&v4l::video::capture::Parameters::with_fps(fps));
        }
        let mut stream = MmapStream::with_buffers(&dev, Type::VideoCapture, BUFFERS)
            .map_err(|e| device_error(&device, e))?;
        stream.set_timeout(FRAME_TIMEOUT);
        Ok(Self {
            device,
            stream,
            format,
            width,
            height,
            first_timestamp: None,
            last_sequence: None,
            dropped: 0,
            sequence: 0,
        })
    }

    /// Whether another filled buffer is waiting, i.e. the one just dequeued is stale.
    fn more_ready(&self) -> Result<bool, CaptureError> {
        self.stream
            .handle()
            .poll(libc::POLLIN, 0)
            .map(|n| n > 0)
            .map_err(|e| device_error(&self.device, e))
    }
}

impl FrameSource for V4l2Source {
    fn describe(&self) -> String {
        format!(
            "camera {} ({} {}x{})",
            self.device, self.format, self.width, self.height
        )
    }

    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, CaptureError> {
        let mut skipped = 0u64;
        let (bytes, meta) = loop {
            let (buf, meta) =
                CaptureStream::next(&mut self.stream).map_err(|e| device_error(&self.device, e))?;
            let used = (meta.bytesused as usize).min(buf.len());
            let frame = (buf[..used].to_vec(), *meta);
            if !self.more_ready()? {
                break frame;
            }
            skipped += 1;
        };
        // The driver's sequence numbers also count frames it dropped itself when all
        // buffers were full.
        if let Some(last) = self.last_sequence {
            self.dropped += u64::from(meta.sequence.wrapping_sub(last).saturating_sub(1));
        } else {
            self.dropped += skipped;
        }
        self.last_sequence = Some(meta.sequence);
        let stamp = Duration::new(meta.timestamp.sec.max(0) as u64, 0)
            + Duration::from_micros(meta.timestamp.usec.max(0) as u64);
        let first = *self.first_timestamp.get_or_insert(stamp);
        let index = self.sequence;
        self.sequence += 1;
        let started = Instant::now();
        let image =
            decode_frame(self.format, self.width, self.height, &bytes).map_err(|reason| {
                CaptureError::BadFrame {
                    origin: self.device.clone(),
                    index,
                    reason,
                }
            })?;
        Ok(Some(Frame {
            image,
            timestamp: stamp.saturating_sub(first),
            sequence: u64::from(meta.sequence),
            decode_time: started.elapsed(),
        }))
    }

    fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// Picks the requested format, else the device's current one when decodable, else MJPEG
/// (cheaper over USB at high resolutions) or YUYV, and applies the requested size.
fn negotiate(
    dev: &Device,
    device: &str,
    request: &CameraRequest,
) -> Result<(PixelFormat, u32, u32), CaptureError> {
    let current = dev.format().map_err(|e| device_error(device, e))?;
    let offered: Vec<PixelFormat> = dev
        .enum_formats()
        .map_err(|e| device_error(device, e))?
        .iter()
        .filter_map(|d| PixelFormat::from_fourcc(d.fourcc.repr))
        .collect();
    let wanted = match request.format {
        Some(f) if offered.contains(&f) => f,
        Some(f) => {
            return Err(CaptureError::Unsupported {
                device: device.into(),
                reason: format!("does not offer {f} (see --list-formats)"),
            })
        }
        None => match PixelFormat::from_fourcc(current.fourcc.repr) {
            Some(f) if request.size.is_none() => f,
            _ => [PixelFormat::Mjpeg, PixelFormat::Yuyv]
                .into_iter()
                .find(|f| offered.contains(f))
                .ok_or_else(|| CaptureError::Unsupported {
                    device: device.into(),
                    reason: "offers neither YUYV nor MJPEG".into(),
                })?,
        },
    };
    let (w, h) = request.size.unwrap_or((current.width, current.height));
    let mut fmt = current;
    fmt.fourcc = FourCC::new(&wanted.fourcc());
    fmt.width = w;
    fmt.height = h;
    let granted = dev.set_format(&fmt).map_err(|e| device_error(device, e))?;
    let format =
        PixelFormat::from_fourcc(granted.fourcc.repr).ok_or_else(|| CaptureError::Unsupported {
            device: device.into(),
            reason: format!("switched to undecodable format {}", granted.fourcc),
        })?;
    check_frame_size(format, granted.width, granted.height).map_err(|reason| {
        CaptureError::Unsupported {
            device: device.into(),
            reason,
        }
    })?;
    Ok((format, granted.width, granted.height))
}

/// The device's formats with their discrete sizes and frame rates.
pub fn list_formats(path: &Path) -> Result<Vec<FormatInfo>, CaptureError> {
    let device = path.display().to_string();
    let dev = Device::with_path(path).map_err(|e| device_error(&device, e))?;
    let descriptions = dev.enum_formats().map_err(|e| device_error(&device, e))?;
    let mut formats = Vec::new();
    for desc in descriptions {
        let mut sizes = Vec::new();
        for size in dev.enum_framesizes(desc.fourcc).unwrap_or_default() {
            if let FrameSizeEnum::Discrete(d) = size.size {
                let rates = dev
                    .enum_frameintervals(desc.fourcc, d.width, d.height)
                    .unwrap_or_default()
                    .into_iter()
                    .filter_map(|i| match i.interval {
                        v4l::frameinterval::FrameIntervalEnum::Discrete(f) if f.numerator > 0 => {
                            Some(f64::from(f.denominator) / f64::from(f.numerator))
                        }
                        _ => None,
                    })
                    .collect();
                sizes.push((d.width, d.height, rates));
            }
        }
        formats.push(FormatInfo {
            fourcc: desc.fourcc.to_string(),
            description: desc.description.clone(),
            sizes,
            supported: PixelFormat::from_fourcc(desc.fourcc.repr).is_some(),
        });
    }
    Ok(formats)
}

/// ENODEV (and its relatives) mean the camera was unplugged or its driver unbound.
fn device_error(device: &str, source: std::io::Error) -> CaptureError {
    let gone = matches!(
        source.raw_os_error(),
        Some(libc::ENODEV) | Some(libc::ENXIO) | Some(libc::ESHUTDOWN)
    );
    if gone {
        CaptureError::DeviceGone {
            device: device.into(),
            source,
        }
    } else {
        CaptureError::Device {
            device: device.into(),
            source,
        }
    }
}
