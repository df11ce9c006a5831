//! JPEGs with depth embedded by our own code (Google GDepth XMP in Extended XMP chunks,
//! Android Dynamic Depth items after the image), shared by the depth tests.

#![allow(dead_code)]

use std::io::Cursor;

use image::{ImageBuffer, ImageFormat, Luma, RgbImage};

pub const GUID: &str = "0123456789ABCDEF0123456789ABCDEF";
pub const NS: &str = r#"xmlns:x="adobe:ns:meta/""#;
pub const RDF: &str = r#"xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#""#;

pub fn photo_jpeg(w: u32, h: u32) -> Vec<u8> {
    let img = RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 4) as u8, (y * 4) as u8, 90]));
    let mut buf = Cursor::new(Vec::new());
    img.write_to(&mut buf, ImageFormat::Jpeg).unwrap();
    buf.into_inner()
}

/// A 16-bit depth PNG whose normalised values we know.
pub fn depth_png(w: u32, h: u32) -> (Vec<u8>, Vec<f32>) {
    let values: Vec<u16> = (0..w * h).map(|i| ((i * 977) % 65536) as u16).collect();
    let img: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(w, h, values.clone()).unwrap();
    let mut buf = Cursor::new(Vec::new());
    img.write_to(&mut buf, ImageFormat::Png).unwrap();
    let normalised = values.iter().map(|&v| f32::from(v) / 65535.0).collect();
    (buf.into_inner(), normalised)
}

pub fn base64(bytes: &[u8]) -> String {
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

pub fn app1(payload: &[u8]) -> Vec<u8> {
    let len = u16::try_from(payload.len() + 2).expect("segment fits");
    let mut seg = vec![0xFF, 0xE1];
    seg.extend_from_slice(&len.to_be_bytes());
    seg.extend_from_slice(payload);
    seg
}

pub fn standard_xmp(body: &str) -> Vec<u8> {
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
pub fn extended_xmp(packet: &[u8], chunk: usize, reverse: bool) -> Vec<Vec<u8>> {
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
pub fn with_segments(jpeg: &[u8], segments: &[Vec<u8>]) -> Vec<u8> {
    let mut out = jpeg[..2].to_vec();
    for s in segments {
        out.extend_from_slice(s);
    }
    out.extend_from_slice(&jpeg[2..]);
    out
}

pub fn gdepth_jpeg(data_b64: &str, format: &str, chunk: usize) -> Vec<u8> {
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

pub fn dynamic_depth_jpeg(depth_png: &[u8], depth_length: usize) -> Vec<u8> {
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
