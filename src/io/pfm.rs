//! Portable Float Map: `Pf` (one channel) reading and writing. Rows are stored bottom to
//! top; a negative scale in the header means little-endian data.

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PfmError {
    #[error("not a PFM file (expected 'Pf' or 'PF' magic)")]
    Magic,
    #[error("colour PFM ('PF'); a depth map must be single-channel ('Pf')")]
    Colour,
    #[error("malformed header: {0}")]
    Header(String),
    #[error("size {0}x{1} is out of range")]
    Size(u64, u64),
    #[error("data holds {actual} bytes, the header promises {expected}")]
    DataLength { expected: usize, actual: usize },
    #[error(transparent)]
    Budget(#[from] crate::io::limits::TooLarge),
}

/// Refuse absurd sizes before allocating.
const MAX_SIDE: u64 = 1 << 15;

/// A single-channel map, rows top to bottom.
#[derive(Debug, PartialEq)]
pub struct Map {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

pub fn parse(bytes: &[u8]) -> Result<Map, PfmError> {
    let mut pos = 0;
    let mut field = |what: &str| next_field(bytes, &mut pos, what);
    let magic = field("magic")?;
    let width = field("width")?;
    let height = field("height")?;
    let scale = field("scale")?;
    match magic.as_str() {
        "Pf" => {}
        "PF" => return Err(PfmError::Colour),
        _ => return Err(PfmError::Magic),
    }
    let width: u64 = parse_num(&width, "width")?;
    let height: u64 = parse_num(&height, "height")?;
    let scale: f32 = parse_num(&scale, "scale")?;
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(PfmError::Size(width, height));
    }
    if scale == 0.0 || !scale.is_finite() {
        return Err(PfmError::Header(format!("scale {scale} must be non-zero")));
    }
    // Exactly one whitespace byte separates the header from the data.
    let data = bytes.get(pos + 1..).unwrap_or(&[]);
    let (width, height) = (width as usize, height as usize);
    let expected = width * height * 4;
    if data.len() != expected {
        return Err(PfmError::DataLength {
            expected,
            actual: data.len(),
        });
    }
    crate::io::limits::check_alloc(
        format!("a {width}x{height} map"),
        (width * height) as u64,
        4,
    )?;
    let little = scale < 0.0;
    let mut out = vec![0.0f32; width * height];
    for (i, chunk) in data.chunks_exact(4).enumerate() {
        let b: [u8; 4] = chunk.try_into().expect("4 bytes");
        let v = if little {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        };
        let (row_from_bottom, x) = (i / width, i % width);
        out[(height - 1 - row_from_bottom) * width + x] = v;
    }
    Ok(Map {
        width,
        height,
        data: out,
    })
}

/// Encodes rows given top to bottom as a little-endian `Pf` file.
pub fn encode(width: usize, height: usize, data: &[f32]) -> Vec<u8> {
    debug_assert_eq!(width * height, data.len());
    let mut out = format!("Pf\n{width} {height}\n-1.0\n").into_bytes();
    for row in data.chunks_exact(width).rev() {
        for v in row {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out
}

fn next_field(bytes: &[u8], pos: &mut usize, what: &str) -> Result<String, PfmError> {
    while *pos < bytes.len() && bytes[*pos].is_ascii_whitespace() {
        *pos += 1;
    }
    let start = *pos;
    while *pos < bytes.len() && !bytes[*pos].is_ascii_whitespace() && *pos - start < 32 {
        *pos += 1;
    }
    if start == *pos {
        return Err(PfmError::Header(format!("missing {what}")));
    }
    std::str::from_utf8(&bytes[start..*pos])
        .map(str::to_owned)
        .map_err(|_| PfmError::Magic)
}

fn parse_num<T: std::str::FromStr>(text: &str, what: &str) -> Result<T, PfmError> {
    text.parse()
        .map_err(|_| PfmError::Header(format!("{what} '{text}' is not a number")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_keeps_top_row_first() {
        let data = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let bytes = encode(3, 2, &data);
        assert!(bytes.starts_with(b"Pf\n3 2\n-1.0\n"));
        // The first stored row is the bottom one.
        assert_eq!(&bytes[12..16], &4.0f32.to_le_bytes());
        assert_eq!(parse(&bytes).unwrap().data, data);
    }

    #[test]
    fn reads_big_endian() {
        let mut bytes = b"Pf 2 1 1.0\n".to_vec();
        bytes.extend_from_slice(&1.5f32.to_be_bytes());
        bytes.extend_from_slice(&(-2.0f32).to_be_bytes());
        assert_eq!(parse(&bytes).unwrap().data, vec![1.5, -2.0]);
    }

    #[test]
    fn rejects_bad_headers_and_lengths() {
        assert_eq!(parse(b"P6\n1 1\n255\n"), Err(PfmError::Magic));
        assert_eq!(parse(b"PF\n1 1\n-1\n"), Err(PfmError::Colour));
        assert_eq!(parse(b"Pf\n0 1\n-1\n"), Err(PfmError::Size(0, 1)));
        assert_eq!(
            parse(b"Pf\n99999999 1\n-1\n"),
            Err(PfmError::Size(99999999, 1))
        );
        assert!(matches!(parse(b"Pf\nx 1\n-1\n"), Err(PfmError::Header(_))));
        assert!(matches!(parse(b"Pf\n2"), Err(PfmError::Header(_))));
        assert_eq!(
            parse(b"Pf\n2 1\n-1\n\0\0\0\0"),
            Err(PfmError::DataLength {
                expected: 8,
                actual: 4
            })
        );
    }
}
