//! Capture through the frame-source interface without a camera: recordings of raw YUYV
//! and MJPEG frames generated here, replayed by the file source. The V4L2 device test
//! runs only where /dev/video* exists.

use std::io::Write;
use std::path::Path;
use std::time::Duration;

use image::{Rgb, RgbImage};
use reshader::device::capture::file::{FileSource, FrameWriter};
use reshader::device::capture::{ycbcr_to_rgb, CaptureError, FrameSource, PixelFormat};

/// BT.601 limited-range encoding of an RGB colour (the inverse the camera applies).
fn rgb_to_ycbcr([r, g, b]: [u8; 3]) -> [u8; 3] {
    let (r, g, b) = (f64::from(r), f64::from(g), f64::from(b));
    let y = 16.0 + (65.481 * r + 128.553 * g + 24.966 * b) / 255.0;
    let cb = 128.0 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255.0;
    let cr = 128.0 + (112.0 * r - 93.786 * g - 18.214 * b) / 255.0;
    [y.round() as u8, cb.round() as u8, cr.round() as u8]
}

/// A YUYV frame whose pixel pairs share one colour from `colours`, cycling.
fn yuyv_frame(width: u32, height: u32, colours: &[[u8; 3]]) -> Vec<u8> {
    let mut bytes = Vec::new();
    for i in 0..(width * height / 2) as usize {
        let [y, cb, cr] = rgb_to_ycbcr(colours[i % colours.len()]);
        bytes.extend_from_slice(&[y, cb, y, cr]);
    }
    bytes
}

fn jpeg(image: &RgbImage) -> Vec<u8> {
    let mut bytes = Vec::new();
    image
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Jpeg,
        )
        .unwrap();
    bytes
}

fn record(path: &Path, format: PixelFormat, w: u32, h: u32, frames: &[Vec<u8>], step_ms: u64) {
    let mut writer = FrameWriter::create(path, format, w, h).unwrap();
    for (i, frame) in frames.iter().enumerate() {
        writer
            .write_frame(Duration::from_millis(step_ms * i as u64), frame)
            .unwrap();
    }
    writer.finish().unwrap();
}

#[test]
fn yuyv_recording_decodes_to_the_encoded_colours() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("yuyv.rshfrm");
    let colours = [
        [255, 0, 0],
        [0, 255, 0],
        [0, 0, 255],
        [128, 128, 128],
        [255, 255, 255],
    ];
    let frames: Vec<Vec<u8>> = (0..3).map(|_| yuyv_frame(10, 4, &colours)).collect();
    record(&path, PixelFormat::Yuyv, 10, 4, &frames, 33);

    let mut source = FileSource::open(&path).unwrap();
    assert_eq!(source.size(), (10, 4));
    assert!(
        source.describe().contains("YUYV 10x4"),
        "{}",
        source.describe()
    );
    let mut count = 0;
    while let Some(frame) = source.next_frame().unwrap() {
        assert_eq!(frame.sequence, count);
        assert_eq!(frame.timestamp, Duration::from_millis(33 * count));
        for (i, pixel) in frame.image.pixels().enumerate() {
            let want = colours[(i / 2) % colours.len()];
            for c in 0..3 {
                let diff = (i32::from(pixel.0[c]) - i32::from(want[c])).abs();
                assert!(diff <= 2, "pixel {i}: {:?} vs {want:?}", pixel.0);
            }
        }
        count += 1;
    }
    assert_eq!(count, 3);
}

#[test]
fn yuyv_hand_computed_pixels() {
    // (Y, Cb, Cr) = (120, 100, 150): R = 1.164·104 + 1.596·22 = 156.1,
    // G = 1.164·104 − 0.392·(−28) − 0.813·22 = 114.1, B = 1.164·104 + 2.017·(−28) = 64.6.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hand.rshfrm");
    record(
        &path,
        PixelFormat::Yuyv,
        2,
        1,
        &[vec![120, 100, 16, 150]],
        0,
    );
    let frame = FileSource::open(&path)
        .unwrap()
        .next_frame()
        .unwrap()
        .unwrap();
    assert_eq!(frame.image.get_pixel(0, 0).0, [156, 114, 65]);
    // Y = 16 with the same chroma: R = 35.1, G = −6.5 → 0, B = −56.5 → 0.
    assert_eq!(frame.image.get_pixel(1, 0).0, [35, 0, 0]);
    assert_eq!(ycbcr_to_rgb(120, 100, 150), [156, 114, 65]);
}

#[test]
fn mjpeg_recording_decodes_each_frame() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mjpeg.rshfrm");
    let frames: Vec<RgbImage> = (0..4u8)
        .map(|i| RgbImage::from_pixel(32, 16, Rgb([i * 60, 100, 200 - i * 40])))
        .collect();
    let encoded: Vec<Vec<u8>> = frames.iter().map(jpeg).collect();
    record(&path, PixelFormat::Mjpeg, 32, 16, &encoded, 40);
    let mut source = FileSource::open(&path).unwrap();
    for want in &frames {
        let got = source.next_frame().unwrap().unwrap();
        let (g, w) = (got.image.get_pixel(16, 8).0, want.get_pixel(16, 8).0);
        for c in 0..3 {
            assert!(
                (i32::from(g[c]) - i32::from(w[c])).abs() <= 3,
                "{g:?} vs {w:?}"
            );
        }
    }
    assert!(source.next_frame().unwrap().is_none());
}

#[test]
fn a_corrupt_mjpeg_frame_is_reported_and_the_stream_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("corrupt.rshfrm");
    let good = jpeg(&RgbImage::new(16, 16));
    let frames = vec![good.clone(), b"garbage, not a jpeg".to_vec(), good];
    record(&path, PixelFormat::Mjpeg, 16, 16, &frames, 40);
    let mut source = FileSource::open(&path).unwrap();
    assert!(source.next_frame().unwrap().is_some());
    let err = source.next_frame().unwrap_err();
    assert!(!err.is_fatal());
    let msg = err.to_string();
    assert!(
        msg.contains("corrupt.rshfrm") && msg.contains("frame 1"),
        "{msg}"
    );
    assert_eq!(source.next_frame().unwrap().unwrap().sequence, 2);
}

#[test]
fn broken_recordings_are_refused_with_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, Vec<u8>, &str); 4] = [
        ("empty", Vec::new(), "shorter than the 20-byte header"),
        (
            "magic",
            b"NOTFRAMESYUYV\x02\0\0\0\x02\0\0\0".to_vec(),
            "magic",
        ),
        ("fourcc", header(b"NV12", 4, 4), "not YUYV or MJPG"),
        (
            "huge",
            header(b"YUYV", 100_000, 100_000),
            "outside 1..=8192",
        ),
    ];
    for (name, bytes, want) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let err = FileSource::open(&path).err().unwrap().to_string();
        assert!(err.contains(want) && err.contains(name), "{name}: {err}");
    }

    // A frame claiming more bytes than a YUYV frame has ends the recording.
    let path = dir.path().join("long");
    let mut bytes = header(b"YUYV", 2, 2);
    bytes.extend_from_slice(&0u64.to_le_bytes());
    bytes.extend_from_slice(&1_000_000u32.to_le_bytes());
    std::fs::write(&path, bytes).unwrap();
    let err = FileSource::open(&path).unwrap().next_frame().unwrap_err();
    assert!(
        err.is_fatal() && err.to_string().contains("claims 1000000 bytes"),
        "{err}"
    );

    // A recording cut inside a frame reports the truncation.
    let path = dir.path().join("cut");
    let mut file = std::fs::File::create(&path).unwrap();
    file.write_all(&header(b"YUYV", 2, 2)).unwrap();
    file.write_all(&0u64.to_le_bytes()).unwrap();
    file.write_all(&8u32.to_le_bytes()).unwrap();
    file.write_all(&[16, 128, 16]).unwrap();
    drop(file);
    let err = FileSource::open(&path).unwrap().next_frame().unwrap_err();
    assert!(err.to_string().contains("truncated: 3 of 8 bytes"), "{err}");
}

fn header(fourcc: &[u8; 4], w: u32, h: u32) -> Vec<u8> {
    let mut bytes = reshader::device::capture::file::MAGIC.to_vec();
    bytes.extend_from_slice(fourcc);
    bytes.extend_from_slice(&w.to_le_bytes());
    bytes.extend_from_slice(&h.to_le_bytes());
    bytes
}

#[test]
fn writer_refuses_wrong_sized_yuyv_and_leaves_no_partial_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rec.rshfrm");
    let mut writer = FrameWriter::create(&path, PixelFormat::Yuyv, 4, 2).unwrap();
    let err = writer.write_frame(Duration::ZERO, &[0; 5]).unwrap_err();
    assert!(err.to_string().contains("expected 16"), "{err}");
    assert!(
        !path.exists(),
        "nothing appears under the real name before finish"
    );
    writer.write_frame(Duration::ZERO, &[16; 16]).unwrap();
    writer.finish().unwrap();
    assert!(path.exists());
}

#[test]
fn paced_replay_skips_frames_the_consumer_is_too_slow_for() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("paced.rshfrm");
    // Frame 0 at 0 ms, frames 1..=5 from 100 ms on: a consumer that comes back at 300 ms
    // must get the newest frame, not the next one.
    let mut writer = FrameWriter::create(&path, PixelFormat::Yuyv, 2, 1).unwrap();
    for (i, ms) in [0u64, 100, 101, 102, 103, 104].into_iter().enumerate() {
        let frame = yuyv_frame(2, 1, &[[i as u8 * 40, 0, 0]]);
        writer
            .write_frame(Duration::from_millis(ms), &frame)
            .unwrap();
    }
    writer.finish().unwrap();
    let mut source = FileSource::open(&path).unwrap().paced(true);
    assert_eq!(source.next_frame().unwrap().unwrap().sequence, 0);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(source.next_frame().unwrap().unwrap().sequence, 5);
    assert_eq!(source.dropped(), 4);
    assert!(source.next_frame().unwrap().is_none());
}

#[test]
fn missing_camera_is_a_clear_error() {
    let err = reshader::device::capture::open_source(
        Path::new("/dev/video-does-not-exist"),
        &Default::default(),
    )
    .err()
    .unwrap();
    assert!(
        matches!(err, CaptureError::Device { .. }),
        "unexpected error: {err}"
    );
    assert!(
        err.to_string().contains("/dev/video-does-not-exist"),
        "{err}"
    );
}

/// Exercises a real camera where one exists; elsewhere says it was skipped.
#[test]
fn v4l2_device_when_present() {
    let devices: Vec<_> = std::fs::read_dir("/dev")
        .map(|d| {
            d.flatten()
                .map(|e| e.path())
                .filter(|p| p.to_string_lossy().starts_with("/dev/video"))
                .collect()
        })
        .unwrap_or_default();
    let Some(device) = devices.first() else {
        eprintln!("SKIPPED v4l2_device_when_present: no /dev/video* on this machine");
        return;
    };
    if !cfg!(feature = "camera") {
        eprintln!(
            "SKIPPED v4l2_device_when_present: {} exists but this build lacks \
             --features camera",
            device.display()
        );
        return;
    }
    let formats = reshader::device::capture::list_formats(device).unwrap();
    assert!(!formats.is_empty(), "{} lists no formats", device.display());
    if !formats.iter().any(|f| f.supported) {
        eprintln!(
            "SKIPPED capture: {} offers neither YUYV nor MJPEG",
            device.display()
        );
        return;
    }
    let mut source = reshader::device::capture::open_source(device, &Default::default()).unwrap();
    let frame = source.next_frame().unwrap().unwrap();
    assert_eq!(frame.image.dimensions(), source.size());
}
