//! Depth embedded in JPEGs: fixtures written here by embedding a known 16-bit depth PNG
//! as Google GDepth XMP (in Extended XMP chunks, out of order) and as an Android Dynamic
//! Depth container (items appended after the JPEG), read back by the runtime; corrupt
//! metadata and containers must give errors that say what is wrong.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{ImageBuffer, ImageFormat, Luma, RgbImage};
use reshader::embedded_depth::{self, Container, EmbeddedError, RangeFormat};

const GUID: &str = "0123456789ABCDEF0123456789ABCDEF";
const NS: &str = r#"xmlns:x="adobe:ns:meta/""#;
const RDF: &str = r#"xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#""#;

fn photo_jpeg(w: u32, h: u32) -> Vec<u8> {
    let img = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 4) as u8, (y * 4) as u8, 90]));
    let mut buf = Cursor::new(Vec::new());
    img.write_to(&mut buf, ImageFormat::Jpeg).unwrap();
    buf.into_inner()
}

/// A 16-bit depth PNG whose normalised values we know.
fn depth_png(w: u32, h: u32) -> (Vec<u8>, Vec<f32>) {
    let values: Vec<u16> = (0..w * h).map(|i| ((i * 977) % 65536) as u16).collect();
    let img: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(w, h, values.clone()).unwrap();
    let mut buf = Cursor::new(Vec::new());
    img.write_to(&mut buf, ImageFormat::Png).unwrap();
    let normalised = values.iter().map(|&v| f32::from(v) / 65535.0).collect();
    (buf.into_inner(), normalised)
}

fn base64(bytes: &[u8]) -> String {
    const T: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(T[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn app1(payload: &[u8]) -> Vec<u8> {
    let len = u16::try_from(payload.len() + 2).expect("segment fits");
    let mut seg = vec![0xFF, 0xE1];
    seg.extend_from_slice(&len.to_be_bytes());
    seg.extend_from_slice(payload);
    seg
}

fn standard_xmp(body: &str) -> Vec<u8> {
    let packet = format!(
        "<?xpacket begin=\"\u{feff}\" id=\"W5M0MpCehiHzreSzNTczkc9d\"?><x:xmpmeta {NS}><rdf:RDF {RDF}>{body}</rdf:RDF></x:xmpmeta><?xpacket end=\"w\"?>"
    );
    app1(
        &[
            b"http://ns.adobe.com/xap/1.0/\0".as_slice(),
            packet.as_bytes(),
        ]
        .concat(),
    )
}

/// Extended XMP segments of at most `chunk` bytes each, in the order given by `order`.
fn extended_xmp(packet: &[u8], chunk: usize, reverse: bool) -> Vec<Vec<u8>> {
    let mut segs: Vec<Vec<u8>> = packet
        .chunks(chunk)
        .enumerate()
        .map(|(i, data)| {
            let mut p = b"http://ns.adobe.com/xmp/extension/\0".to_vec();
            p.extend_from_slice(GUID.as_bytes());
            p.extend_from_slice(&(packet.len() as u32).to_be_bytes());
            p.extend_from_slice(&((i * chunk) as u32).to_be_bytes());
            p.extend_from_slice(data);
            app1(&p)
        })
        .collect();
    if reverse {
        segs.reverse();
    }
    segs
}

/// The JPEG with `segments` inserted right after its SOI marker.
fn with_segments(jpeg: &[u8], segments: &[Vec<u8>]) -> Vec<u8> {
    let mut out = jpeg[..2].to_vec();
    for s in segments {
        out.extend_from_slice(s);
    }
    out.extend_from_slice(&jpeg[2..]);
    out
}

fn gdepth_jpeg(data_b64: &str, format: &str, chunk: usize) -> Vec<u8> {
    let desc = format!(
        r#"<rdf:Description rdf:about="" xmlns:GDepth="http://ns.google.com/photos/1.0/depthmap/" xmlns:xmpNote="http://ns.adobe.com/xmp/note/" GDepth:Format="{format}" GDepth:Near="0.5" GDepth:Far="4.25" GDepth:Mime="image/png" GDepth:Units="m" xmpNote:HasExtendedXMP="{GUID}"/>"#
    );
    let ext = format!(
        r#"<x:xmpmeta {NS}><rdf:RDF {RDF}><rdf:Description rdf:about="" xmlns:GDepth="http://ns.google.com/photos/1.0/depthmap/" GDepth:Data="{data_b64}"/></rdf:RDF></x:xmpmeta>"#
    );
    let mut segments = vec![standard_xmp(&desc)];
    segments.extend(extended_xmp(ext.as_bytes(), chunk, true));
    with_segments(&photo_jpeg(40, 30), &segments)
}

fn dynamic_depth_jpeg(depth_png: &[u8], depth_length: usize) -> Vec<u8> {
    let decoy = photo_jpeg(8, 6);
    let body = format!(
        r#"<rdf:Description rdf:about=""
          xmlns:Device="http://ns.google.com/photos/dd/1.0/device/"
          xmlns:Container="http://ns.google.com/photos/dd/1.0/container/"
          xmlns:Item="http://ns.google.com/photos/dd/1.0/item/"
          xmlns:Camera="http://ns.google.com/photos/dd/1.0/camera/"
          xmlns:DepthMap="http://ns.google.com/photos/dd/1.0/depthmap/">
        <Device:Container><Container:Directory><rdf:Seq>
          <rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="image/jpeg" Item:Semantic="Primary"/></rdf:li>
          <rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="image/jpeg" Item:Semantic="Original" Item:Length="{}"/></rdf:li>
          <rdf:li rdf:parseType="Resource"><Container:Item Item:Mime="image/png" Item:Semantic="Depth" Item:Length="{depth_length}" Item:Padding="3"/></rdf:li>
        </rdf:Seq></Container:Directory></Device:Container>
        <Device:Cameras><rdf:Seq><rdf:li rdf:parseType="Resource"><Device:Camera rdf:parseType="Resource">
          <Camera:DepthMap rdf:parseType="Resource">
            <DepthMap:Format>RangeLinear</DepthMap:Format><DepthMap:Near>0.25</DepthMap:Near>
            <DepthMap:Far>8</DepthMap:Far><DepthMap:Units>Meters</DepthMap:Units>
            <DepthMap:ItemSemantic>Depth</DepthMap:ItemSemantic>
          </Camera:DepthMap></Device:Camera></rdf:li></rdf:Seq></Device:Cameras>
        </rdf:Description>"#,
        decoy.len()
    );
    let mut file = with_segments(&photo_jpeg(40, 30), &[standard_xmp(&body)]);
    file.extend_from_slice(&decoy);
    file.extend_from_slice(depth_png);
    file.extend_from_slice(&[0, 0, 0]);
    file
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}

fn expected(normalised: &[f32], format: RangeFormat, near: f32, far: f32) -> Vec<f32> {
    normalised
        .iter()
        .map(|&v| match format {
            RangeFormat::RangeLinear => near + v * (far - near),
            RangeFormat::RangeInverse => far * near / (far - v * (far - near)),
        })
        .collect()
}

fn assert_close(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() <= 1e-6 * w, "pixel {i}: {g} vs {w}");
    }
}

#[test]
fn gdepth_in_extended_xmp_reads_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (png, normalised) = depth_png(20, 15);
    for format in [RangeFormat::RangeInverse, RangeFormat::RangeLinear] {
        let name = format!("{format:?}");
        // 700-byte chunks: several segments, written last first.
        let path = write(dir.path(), "g.jpg", &gdepth_jpeg(&base64(&png), &name, 700));
        let found = embedded_depth::read(&path).unwrap().expect("depth found");
        assert_eq!(found.container, Container::GDepth);
        assert_eq!(found.format, format);
        assert_eq!((found.near, found.far), (0.5, 4.25));
        assert_eq!(found.units.as_deref(), Some("m"));
        assert_eq!((found.map.width, found.map.height), (20, 15));
        assert_close(&found.map.values, &expected(&normalised, format, 0.5, 4.25));
    }
}

#[test]
fn dynamic_depth_container_reads_back_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let (png, normalised) = depth_png(20, 15);
    let path = write(dir.path(), "dd.jpg", &dynamic_depth_jpeg(&png, png.len()));
    let found = embedded_depth::read(&path).unwrap().expect("depth found");
    assert_eq!(found.container, Container::DynamicDepth);
    assert_eq!(found.format, RangeFormat::RangeLinear);
    assert_eq!(found.units.as_deref(), Some("Meters"));
    assert_close(
        &found.map.values,
        &expected(&normalised, RangeFormat::RangeLinear, 0.25, 8.0),
    );
}

#[test]
fn photo_without_depth_gives_none() {
    let dir = tempfile::tempdir().unwrap();
    let plain = write(dir.path(), "plain.jpg", &photo_jpeg(16, 16));
    assert!(embedded_depth::read(&plain).unwrap().is_none());
    let other_xmp = with_segments(
        &photo_jpeg(16, 16),
        &[standard_xmp(
            r#"<rdf:Description xmlns:dc="http://purl.org/dc/elements/1.1/" dc:format="image/jpeg"/>"#,
        )],
    );
    let path = write(dir.path(), "xmp.jpg", &other_xmp);
    assert!(embedded_depth::read(&path).unwrap().is_none());
}

fn error_of(dir: &Path, bytes: &[u8]) -> String {
    let path = write(dir, "bad.jpg", bytes);
    match embedded_depth::read(&path) {
        Err(e @ EmbeddedError::Malformed { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains("bad.jpg"),
                "error does not name the file: {text}"
            );
            text
        }
        other => panic!("expected a malformed-depth error, got {other:?}"),
    }
}

#[test]
fn corrupt_metadata_and_containers_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let dir = dir.path();
    let (png, _) = depth_png(20, 15);
    let b64 = base64(&png);

    let bad_b64 = gdepth_jpeg(&b64.replacen('A', "*", 1), "RangeLinear", 700);
    assert!(error_of(dir, &bad_b64).contains("not base64"));

    let bad_format = gdepth_jpeg(&b64, "Squared", 700);
    assert!(error_of(dir, &bad_format).contains("GDepth:Format is \"Squared\""));

    // Drop one Extended XMP chunk: the packet has a hole.
    let full = gdepth_jpeg(&b64, "RangeLinear", 700);
    let marker = b"http://ns.adobe.com/xmp/extension/\0";
    let at = full
        .windows(marker.len())
        .position(|w| w == marker)
        .unwrap()
        - 4;
    let len = usize::from(u16::from_be_bytes([full[at + 2], full[at + 3]])) + 2;
    let holed = [&full[..at], &full[at + len..]].concat();
    assert!(error_of(dir, &holed).contains("incomplete"));

    let not_png = gdepth_jpeg(&base64(b"definitely not a png"), "RangeLinear", 700);
    assert!(error_of(dir, &not_png).contains("cannot decode the depth image"));

    let unclosed = with_segments(
        &photo_jpeg(16, 16),
        &[standard_xmp(
            r#"<rdf:Description xmlns:GDepth="http://ns.google.com/photos/1.0/depthmap/"><GDepth:Format>RangeLinear"#,
        )],
    );
    assert!(error_of(dir, &unclosed).contains("XMP"));

    let too_long = dynamic_depth_jpeg(&png, png.len() + 10_000);
    assert!(error_of(dir, &too_long).contains("more bytes than"));

    let mut truncated_segment = photo_jpeg(16, 16)[..2].to_vec();
    truncated_segment.extend_from_slice(&[0xFF, 0xE1, 0x40, 0x00, b'h', b't']);
    assert!(error_of(dir, &truncated_segment).contains("beyond the file"));
}
