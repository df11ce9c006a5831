//! JPEG segment walk: the XMP packets of the APP1 segments (standard and Extended XMP)
//! and where the primary image ends (after its EOI marker), with every length checked.

use super::xml::Element;

const XMP_SIG: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";
const EXT_SIG: &[u8] = b"http://ns.adobe.com/xmp/extension/\0";
const NS_XMP_NOTE: &str = "http://ns.adobe.com/xmp/note/";
/// Extended XMP larger than this is refused before allocating it.
const MAX_EXTENDED: usize = 64 << 20;

pub struct Layout {
    pub standard_xmp: Option<Vec<u8>>,
    pub extended: Vec<ExtendedChunk>,
    /// Offset just past the primary image's EOI marker.
    pub primary_end: usize,
}

pub struct ExtendedChunk {
    guid: String,
    full_length: usize,
    offset: usize,
    data: Vec<u8>,
}

pub fn is_jpeg(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0xFF, 0xD8, 0xFF])
}

/// Walks the marker segments of the primary image up to its EOI.
pub fn scan(bytes: &[u8]) -> Result<Layout, String> {
    let mut layout = Layout {
        standard_xmp: None,
        extended: Vec::new(),
        primary_end: 0,
    };
    let mut pos = 2;
    loop {
        if bytes.get(pos) != Some(&0xFF) {
            return Err(match bytes.get(pos) {
                None => "JPEG is truncated: it ends before its end-of-image marker".into(),
                Some(b) => format!("JPEG: expected a marker at byte {pos}, found {b:#04x}"),
            });
        }
        while bytes.get(pos) == Some(&0xFF) {
            pos += 1;
        }
        let Some(&marker) = bytes.get(pos) else {
            return Err("JPEG is truncated inside a marker".into());
        };
        pos += 1;
        match marker {
            0xD9 => {
                layout.primary_end = pos;
                return Ok(layout);
            }
            0x01 | 0xD0..=0xD7 => continue,
            _ => {}
        }
        let len = bytes
            .get(pos..pos + 2)
            .map(|b| usize::from(u16::from_be_bytes([b[0], b[1]])))
            .ok_or("JPEG is truncated inside a segment header")?;
        if len < 2 || pos + len > bytes.len() {
            return Err(format!(
                "JPEG segment {marker:#04x} at byte {} claims {len} bytes, beyond the file",
                pos - 2
            ));
        }
        let payload = &bytes[pos + 2..pos + len];
        pos += len;
        if marker == 0xE1 {
            read_app1(payload, &mut layout)?;
        }
        if marker == 0xDA {
            pos = entropy_end(bytes, pos);
        }
    }
}

/// The first marker after entropy-coded data (stuffed 0xFF00 and restarts are data).
fn entropy_end(bytes: &[u8], mut pos: usize) -> usize {
    while pos + 1 < bytes.len() {
        if bytes[pos] == 0xFF && bytes[pos + 1] != 0 && !(0xD0..=0xD7).contains(&bytes[pos + 1]) {
            return pos;
        }
        pos += 1;
    }
    bytes.len()
}

fn read_app1(payload: &[u8], layout: &mut Layout) -> Result<(), String> {
    if let Some(xmp) = payload.strip_prefix(XMP_SIG) {
        if layout.standard_xmp.is_none() {
            layout.standard_xmp = Some(xmp.to_vec());
        }
    } else if let Some(ext) = payload.strip_prefix(EXT_SIG) {
        if ext.len() < 40 {
            return Err(format!(
                "Extended XMP segment of {} bytes is too short for its header",
                ext.len()
            ));
        }
        let guid = std::str::from_utf8(&ext[..32])
            .map_err(|_| "Extended XMP GUID is not ASCII".to_string())?
            .to_owned();
        let word =
            |i: usize| u32::from_be_bytes([ext[i], ext[i + 1], ext[i + 2], ext[i + 3]]) as usize;
        layout.extended.push(ExtendedChunk {
            guid,
            full_length: word(32),
            offset: word(36),
            data: ext[40..].to_vec(),
        });
    }
    Ok(())
}

/// Reassembles the Extended XMP the standard packet points to (xmpNote:HasExtendedXMP).
pub fn extended_xmp(
    chunks: &[ExtendedChunk],
    standard: &Element,
) -> Result<Option<Vec<u8>>, String> {
    let declared = standard.find_prop(&[NS_XMP_NOTE], "HasExtendedXMP");
    let Some(guid) = declared.or_else(|| chunks.first().map(|c| c.guid.clone())) else {
        return Ok(None);
    };
    let mine: Vec<&ExtendedChunk> = chunks.iter().filter(|c| c.guid == guid).collect();
    let Some(first) = mine.first() else {
        return Err(format!(
            "the XMP announces Extended XMP {guid} but the file has no segment of it"
        ));
    };
    let full = first.full_length;
    if full > MAX_EXTENDED {
        return Err(format!(
            "Extended XMP claims {full} bytes (limit {MAX_EXTENDED})"
        ));
    }
    let present: usize = mine.iter().map(|c| c.data.len()).sum();
    if present < full {
        return Err(format!(
            "Extended XMP {guid} is incomplete: its {} chunks hold {present} of {full} bytes",
            mine.len()
        ));
    }
    let mut packet = vec![0u8; full];
    let mut spans = Vec::with_capacity(mine.len());
    for c in &mine {
        let end = c.offset.checked_add(c.data.len()).filter(|&e| e <= full);
        let Some(end) = end.filter(|_| c.full_length == full) else {
            return Err(format!(
                "Extended XMP chunk at offset {} ({} bytes, total {}) does not fit the {full}-byte packet",
                c.offset,
                c.data.len(),
                c.full_length
            ));
        };
        packet[c.offset..end].copy_from_slice(&c.data);
        spans.push((c.offset, end));
    }
    spans.sort_unstable();
    let covered = spans.iter().try_fold(0usize, |reach, &(s, e)| {
        (s <= reach).then_some(reach.max(e))
    });
    match covered {
        Some(reach) if reach == full => Ok(Some(packet)),
        _ => Err(format!(
            "Extended XMP {guid} is incomplete: its {} chunks do not cover all {full} bytes",
            mine.len()
        )),
    }
}
