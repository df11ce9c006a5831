//! Recorded camera streams: raw YUYV or MJPEG frames exactly as a camera delivers them,
//! in a minimal container, so the capture path can be replayed and tested without a
//! camera.
//!
//! Layout (little-endian): the 8-byte magic `RSHFRM01`, the V4L2 fourcc (`YUYV` or
//! `MJPG`), width and height as u32; then per frame its timestamp in microseconds since
//! the first frame (u64), its length in bytes (u32) and the bytes.

use std::fs::File;
use std::io::{BufReader, BufWriter, ErrorKind, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::{check_frame_size, decode_frame, CaptureError, Frame, FrameSource, PixelFormat};

pub const MAGIC: &[u8; 8] = b"RSHFRM01";
const HEADER_LEN: usize = 20;
const FRAME_HEADER_LEN: usize = 12;

/// Replays a recording. Unpaced, it yields frames as fast as they are asked for; paced,
/// it releases each frame at its recorded time and skips frames the consumer was too
/// slow for, as a live camera does.
pub struct FileSource {
    path: PathBuf,
    reader: BufReader<File>,
    format: PixelFormat,
    width: u32,
    height: u32,
    next_index: u64,
    paced: bool,
    started: Option<Instant>,
    dropped: u64,
    /// A frame read ahead (paced mode) to learn whether the current one is stale.
    lookahead: Option<RawFrame>,
}

struct RawFrame {
    index: u64,
    timestamp: Duration,
    bytes: Vec<u8>,
}

impl FileSource {
    pub fn open(path: &Path) -> Result<Self, CaptureError> {
        let io_err = |source| CaptureError::Io {
            path: path.into(),
            source,
        };
        let mut reader = BufReader::new(File::open(path).map_err(io_err)?);
        let mut header = [0u8; HEADER_LEN];
        reader.read_exact(&mut header).map_err(|e| match e.kind() {
            ErrorKind::UnexpectedEof => bad(path, "file is shorter than the 20-byte header"),
            _ => io_err(e),
        })?;
        if &header[..8] != MAGIC {
            return Err(bad(path, "missing RSHFRM01 magic"));
        }
        let fourcc: [u8; 4] = header[8..12].try_into().expect("4 bytes");
        let format = PixelFormat::from_fourcc(fourcc).ok_or_else(|| {
            bad(
                path,
                &format!(
                    "pixel format {:?} is not YUYV or MJPG",
                    String::from_utf8_lossy(&fourcc)
                ),
            )
        })?;
        let width = u32::from_le_bytes(header[12..16].try_into().expect("4 bytes"));
        let height = u32::from_le_bytes(header[16..20].try_into().expect("4 bytes"));
        check_frame_size(format, width, height).map_err(|reason| bad(path, &reason))?;
        Ok(Self {
            path: path.into(),
            reader,
            format,
            width,
            height,
            next_index: 0,
            paced: false,
            started: None,
            dropped: 0,
            lookahead: None,
        })
    }

    pub fn paced(mut self, paced: bool) -> Self {
        self.paced = paced;
        self
    }

    pub fn format(&self) -> PixelFormat {
        self.format
    }

    fn max_frame_len(&self) -> usize {
        match self.format {
            PixelFormat::Yuyv => self.width as usize * self.height as usize * 2,
            PixelFormat::Mjpeg => super::MAX_MJPEG_BYTES,
        }
    }

    fn read_raw(&mut self) -> Result<Option<RawFrame>, CaptureError> {
        let index = self.next_index;
        let mut head = [0u8; FRAME_HEADER_LEN];
        match read_full(&mut self.reader, &mut head).map_err(|e| self.io_err(e))? {
            0 => return Ok(None),
            FRAME_HEADER_LEN => {}
            _ => return Err(self.bad_frame(index, "recording ends inside a frame header".into())),
        }
        let micros = u64::from_le_bytes(head[..8].try_into().expect("8 bytes"));
        let len = u32::from_le_bytes(head[8..].try_into().expect("4 bytes")) as usize;
        if len == 0 || len > self.max_frame_len() {
            // Lengths delimit frames: after a bad one nothing that follows can be trusted,
            // so this ends the recording rather than skipping one frame.
            return Err(bad(
                &self.path,
                &format!(
                    "frame {index} claims {len} bytes (1..={} allowed for {} {}x{})",
                    self.max_frame_len(),
                    self.format,
                    self.width,
                    self.height
                ),
            ));
        }
        let mut bytes = vec![0; len];
        let got = read_full(&mut self.reader, &mut bytes).map_err(|e| self.io_err(e))?;
        if got < len {
            return Err(self.bad_frame(
                index,
                format!("recording is truncated: {got} of {len} bytes"),
            ));
        }
        self.next_index += 1;
        Ok(Some(RawFrame {
            index,
            timestamp: Duration::from_micros(micros),
            bytes,
        }))
    }

    fn io_err(&self, source: std::io::Error) -> CaptureError {
        CaptureError::Io {
            path: self.path.clone(),
            source,
        }
    }

    fn bad_frame(&self, index: u64, reason: String) -> CaptureError {
        CaptureError::BadFrame {
            origin: self.path.display().to_string(),
            index,
            reason,
        }
    }

    /// The newest frame whose time has come, skipping older ones, after waiting for the
    /// first one's time if none has come yet.
    fn latest_due(&mut self, mut current: RawFrame) -> Result<RawFrame, CaptureError> {
        let start = *self.started.get_or_insert_with(Instant::now);
        loop {
            self.lookahead = self.read_raw()?;
            match &self.lookahead {
                Some(next) if start + next.timestamp <= Instant::now() => {
                    self.dropped += 1;
                    current = self.lookahead.take().expect("checked above");
                }
                _ => break,
            }
        }
        if let Some(wait) = (start + current.timestamp).checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        Ok(current)
    }
}

impl FrameSource for FileSource {
    fn describe(&self) -> String {
        format!(
            "recording {} ({} {}x{}{})",
            self.path.display(),
            self.format,
            self.width,
            self.height,
            if self.paced { ", paced" } else { "" }
        )
    }

    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    fn next_frame(&mut self) -> Result<Option<Frame>, CaptureError> {
        let current = match self.lookahead.take() {
            Some(frame) => frame,
            None => match self.read_raw()? {
                Some(frame) => frame,
                None => return Ok(None),
            },
        };
        let raw = if self.paced {
            self.latest_due(current)?
        } else {
            current
        };
        let started = Instant::now();
        let image = decode_frame(self.format, self.width, self.height, &raw.bytes)
            .map_err(|reason| self.bad_frame(raw.index, reason))?;
        Ok(Some(Frame {
            image,
            timestamp: raw.timestamp,
            sequence: raw.index,
            decode_time: started.elapsed(),
        }))
    }

    fn dropped(&self) -> u64 {
        self.dropped
    }

    fn realtime(&self) -> bool {
        self.paced
    }
}

fn bad(path: &Path, reason: &str) -> CaptureError {
    CaptureError::BadRecording {
        path: path.into(),
        reason: reason.into(),
    }
}

/// Like `read_exact`, but reports how much was read instead of failing at end of file.
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

/// Writes a recording through a temporary file that [`FrameWriter::finish`] renames into
/// place, so an interrupted recording never leaves a truncated file under the real name.
pub struct FrameWriter {
    path: PathBuf,
    tmp: PathBuf,
    writer: BufWriter<File>,
    format: PixelFormat,
    width: u32,
    height: u32,
}

impl FrameWriter {
    pub fn create(
        path: &Path,
        format: PixelFormat,
        width: u32,
        height: u32,
    ) -> Result<Self, CaptureError> {
        check_frame_size(format, width, height).map_err(|reason| bad(path, &reason))?;
        let tmp = crate::io::output::temp_name(path);
        let io_err = |source| CaptureError::Io {
            path: path.into(),
            source,
        };
        let mut writer = BufWriter::new(File::create(&tmp).map_err(io_err)?);
        let mut header = Vec::with_capacity(HEADER_LEN);
        header.extend_from_slice(MAGIC);
        header.extend_from_slice(&format.fourcc());
        header.extend_from_slice(&width.to_le_bytes());
        header.extend_from_slice(&height.to_le_bytes());
        writer.write_all(&header).map_err(io_err)?;
        Ok(Self {
            path: path.into(),
            tmp,
            writer,
            format,
            width,
            height,
        })
    }

    /// Appends one raw frame; YUYV frames must be exactly width·height·2 bytes.
    pub fn write_frame(&mut self, timestamp: Duration, bytes: &[u8]) -> Result<(), CaptureError> {
        let expected = self.width as usize * self.height as usize * 2;
        if self.format == PixelFormat::Yuyv && bytes.len() != expected {
            return Err(bad(
                &self.path,
                &format!("YUYV frame of {} bytes, expected {expected}", bytes.len()),
            ));
        }
        let len = u32::try_from(bytes.len())
            .ok()
            .filter(|&l| l > 0 && (l as usize) <= super::MAX_MJPEG_BYTES)
            .ok_or_else(|| bad(&self.path, &format!("frame of {} bytes", bytes.len())))?;
        let micros = u64::try_from(timestamp.as_micros()).unwrap_or(u64::MAX);
        let io_err = |source| CaptureError::Io {
            path: self.path.clone(),
            source,
        };
        self.writer
            .write_all(&micros.to_le_bytes())
            .map_err(io_err)?;
        self.writer.write_all(&len.to_le_bytes()).map_err(io_err)?;
        self.writer.write_all(bytes).map_err(io_err)
    }

    pub fn finish(self) -> Result<PathBuf, CaptureError> {
        let io_err = |source| CaptureError::Io {
            path: self.path.clone(),
            source,
        };
        let file = self
            .writer
            .into_inner()
            .map_err(|e| io_err(e.into_error()))?;
        file.sync_all().map_err(io_err)?;
        std::fs::rename(&self.tmp, &self.path).map_err(io_err)?;
        Ok(self.path)
    }
}
