//! NumPy `.npy` reading (little-endian f32/f16/f64/u16/u8, C order) and f32 writing.
//!
//! The header is a Python dict literal; it is parsed with a small tokenizer rather than
//! string searches so that odd spacing, key order or hostile input cannot confuse it.

use half::f16;

/// numpy itself refuses headers above 10 kB by default; allow some slack, no more.
const MAX_HEADER_LEN: usize = 65_536;
const MAGIC: &[u8] = b"\x93NUMPY";

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum NpyError {
    #[error("not a .npy file (missing the \\x93NUMPY magic)")]
    Magic,
    #[error("unsupported .npy format version {0}.{1}")]
    Version(u8, u8),
    #[error("file ends inside the header")]
    Truncated,
    #[error("header length {0} is larger than the allowed {MAX_HEADER_LEN} bytes")]
    HeaderTooLong(usize),
    #[error("malformed header: {0}")]
    Header(String),
    #[error("unsupported dtype '{0}' (supported: <f4, <f2, <f8, <u2, |u1)")]
    Dtype(String),
    #[error("Fortran-ordered arrays are not supported (save with np.ascontiguousarray)")]
    FortranOrder,
    #[error("shape {0:?} is not a 2-D map (size-1 axes are allowed around it)")]
    Shape(Vec<usize>),
    #[error("shape {0:?} is too large")]
    TooLarge(Vec<usize>),
    #[error(transparent)]
    Budget(#[from] crate::io::limits::TooLarge),
    #[error("data holds {actual} bytes, the header promises {expected}")]
    DataLength { expected: usize, actual: usize },
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Dtype {
    F32,
    F16,
    F64,
    U16,
    U8,
}

impl Dtype {
    fn parse(descr: &str) -> Result<Self, NpyError> {
        match descr {
            "<f4" => Ok(Self::F32),
            "<f2" => Ok(Self::F16),
            "<f8" => Ok(Self::F64),
            "<u2" => Ok(Self::U16),
            "|u1" | "<u1" => Ok(Self::U8),
            other => Err(NpyError::Dtype(other.into())),
        }
    }

    fn size(self) -> usize {
        match self {
            Self::F32 => 4,
            Self::F16 | Self::U16 => 2,
            Self::F64 => 8,
            Self::U8 => 1,
        }
    }

    fn decode(self, bytes: &[u8]) -> f32 {
        match self {
            Self::F32 => f32::from_le_bytes(bytes.try_into().expect("4 bytes")),
            Self::F16 => f16::from_le_bytes(bytes.try_into().expect("2 bytes")).to_f32(),
            Self::F64 => f64::from_le_bytes(bytes.try_into().expect("8 bytes")) as f32,
            Self::U16 => f32::from(u16::from_le_bytes(bytes.try_into().expect("2 bytes"))),
            Self::U8 => f32::from(bytes[0]),
        }
    }
}

/// A 2-D array as rows × columns of f32, whatever the stored dtype.
#[derive(Debug, PartialEq)]
pub struct Array2 {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f32>,
}

pub fn parse(bytes: &[u8]) -> Result<Array2, NpyError> {
    let (header, data) = split_header(bytes)?;
    let header = parse_header(header)?;
    if header.fortran_order {
        return Err(NpyError::FortranOrder);
    }
    let dtype = Dtype::parse(&header.descr)?;
    let (rows, cols) = map_shape(&header.shape)?;
    let expected = rows
        .checked_mul(cols)
        .and_then(|n| n.checked_mul(dtype.size()))
        .ok_or_else(|| NpyError::TooLarge(header.shape.clone()))?;
    if data.len() != expected {
        return Err(NpyError::DataLength {
            expected,
            actual: data.len(),
        });
    }
    crate::io::limits::check_alloc(format!("a {rows}x{cols} map"), (rows * cols) as u64, 4)?;
    let data = data
        .chunks_exact(dtype.size())
        .map(|c| dtype.decode(c))
        .collect();
    Ok(Array2 { rows, cols, data })
}

/// Encodes a C-ordered little-endian f32 array (format version 1.0).
pub fn encode_f32(shape: &[usize], data: &[f32]) -> Vec<u8> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_text}, }}");
    // Pad so that the data starts on a 64-byte boundary, header ending in '\n'.
    let unpadded = MAGIC.len() + 2 + 2 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 4);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

fn split_header(bytes: &[u8]) -> Result<(&str, &[u8]), NpyError> {
    if bytes.len() < MAGIC.len() + 2 || &bytes[..MAGIC.len()] != MAGIC {
        return Err(NpyError::Magic);
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (len_size, start) = match major {
        1 => (2, 10),
        2 | 3 => (4, 12),
        _ => return Err(NpyError::Version(major, minor)),
    };
    let len_bytes = bytes.get(8..8 + len_size).ok_or(NpyError::Truncated)?;
    let header_len = len_bytes
        .iter()
        .rev()
        .fold(0usize, |acc, &b| (acc << 8) | usize::from(b));
    if header_len > MAX_HEADER_LEN {
        return Err(NpyError::HeaderTooLong(header_len));
    }
    let header = bytes
        .get(start..start + header_len)
        .ok_or(NpyError::Truncated)?;
    let header =
        std::str::from_utf8(header).map_err(|_| NpyError::Header("header is not text".into()))?;
    Ok((header, &bytes[start + header_len..]))
}

#[derive(Debug, PartialEq)]
struct Header {
    descr: String,
    fortran_order: bool,
    shape: Vec<usize>,
}

#[derive(Debug, PartialEq)]
enum Token {
    Punct(char),
    Str(String),
    Word(String),
}

fn tokenize(text: &str) -> Result<Vec<Token>, NpyError> {
    let mut tokens = Vec::new();
    let mut chars = text.chars().peekable();
    while let Some(&c) = chars.peek() {
        match c {
            c if c.is_whitespace() => {
                chars.next();
            }
            '{' | '}' | '(' | ')' | ':' | ',' => {
                tokens.push(Token::Punct(c));
                chars.next();
            }
            '\'' | '"' => {
                chars.next();
                let s: String = chars.by_ref().take_while(|&ch| ch != c).collect();
                tokens.push(Token::Str(s));
            }
            c if c.is_ascii_alphanumeric() || c == '_' => {
                let mut word = String::new();
                while let Some(&ch) = chars.peek() {
                    if !(ch.is_ascii_alphanumeric() || ch == '_') {
                        break;
                    }
                    word.push(ch);
                    chars.next();
                }
                tokens.push(Token::Word(word));
            }
            other => return Err(NpyError::Header(format!("unexpected character {other:?}"))),
        }
    }
    Ok(tokens)
}

struct Cursor {
    tokens: std::vec::IntoIter<Token>,
}

impl Cursor {
    fn next(&mut self) -> Result<Token, NpyError> {
        self.tokens
            .next()
            .ok_or_else(|| NpyError::Header("header ends early".into()))
    }

    fn expect(&mut self, c: char) -> Result<(), NpyError> {
        match self.next()? {
            Token::Punct(p) if p == c => Ok(()),
            other => Err(NpyError::Header(format!("expected '{c}', found {other:?}"))),
        }
    }
}

fn parse_header(text: &str) -> Result<Header, NpyError> {
    let mut cur = Cursor {
        tokens: tokenize(text)?.into_iter(),
    };
    cur.expect('{')?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    loop {
        let key = match cur.next()? {
            Token::Punct('}') => break,
            Token::Str(key) => key,
            other => return Err(NpyError::Header(format!("expected a key, found {other:?}"))),
        };
        cur.expect(':')?;
        match key.as_str() {
            "descr" => descr = Some(parse_str(&mut cur)?),
            "fortran_order" => fortran = Some(parse_bool(&mut cur)?),
            "shape" => shape = Some(parse_shape(&mut cur)?),
            other => return Err(NpyError::Header(format!("unknown key '{other}'"))),
        }
        match cur.next()? {
            Token::Punct(',') => {}
            Token::Punct('}') => break,
            other => {
                return Err(NpyError::Header(format!(
                    "expected ',' or '}}', found {other:?}"
                )))
            }
        }
    }
    let missing = |k: &str| NpyError::Header(format!("missing key '{k}'"));
    Ok(Header {
        descr: descr.ok_or_else(|| missing("descr"))?,
        fortran_order: fortran.ok_or_else(|| missing("fortran_order"))?,
        shape: shape.ok_or_else(|| missing("shape"))?,
    })
}

fn parse_str(cur: &mut Cursor) -> Result<String, NpyError> {
    match cur.next()? {
        Token::Str(s) => Ok(s),
        other => Err(NpyError::Header(format!(
            "expected a string, found {other:?}"
        ))),
    }
}

fn parse_bool(cur: &mut Cursor) -> Result<bool, NpyError> {
    match cur.next()? {
        Token::Word(w) if w == "True" => Ok(true),
        Token::Word(w) if w == "False" => Ok(false),
        other => Err(NpyError::Header(format!(
            "expected True/False, found {other:?}"
        ))),
    }
}

fn parse_shape(cur: &mut Cursor) -> Result<Vec<usize>, NpyError> {
    cur.expect('(')?;
    let mut dims = Vec::new();
    loop {
        match cur.next()? {
            Token::Punct(')') => return Ok(dims),
            Token::Word(w) => {
                let dim = w
                    .parse()
                    .map_err(|_| NpyError::Header(format!("bad dimension '{w}'")))?;
                dims.push(dim);
            }
            other => return Err(NpyError::Header(format!("bad shape entry {other:?}"))),
        }
        match cur.next()? {
            Token::Punct(',') => {}
            Token::Punct(')') => return Ok(dims),
            other => return Err(NpyError::Header(format!("bad shape separator {other:?}"))),
        }
    }
}

/// Accepts (H, W) and the same with size-1 axes around it, such as (1, H, W) or
/// (H, W, 1): leading, then trailing size-1 axes are dropped down to two.
fn map_shape(shape: &[usize]) -> Result<(usize, usize), NpyError> {
    let mut dims = shape;
    while dims.len() > 2 && dims[0] == 1 {
        dims = &dims[1..];
    }
    while dims.len() > 2 && dims[dims.len() - 1] == 1 {
        dims = &dims[..dims.len() - 1];
    }
    match dims {
        [h, w] => Ok((*h, *w)),
        _ => Err(NpyError::Shape(shape.to_vec())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy_with_header(header: &str, data: &[u8]) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend_from_slice(&[1, 0]);
        out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(data);
        out
    }

    #[test]
    fn f32_roundtrip() {
        let data = [1.0, -2.5, 3.25, 4.0, 5.0, 6.5];
        let bytes = encode_f32(&[2, 3], &data);
        assert_eq!((bytes.len() - data.len() * 4) % 64, 0);
        let arr = parse(&bytes).unwrap();
        assert_eq!((arr.rows, arr.cols), (2, 3));
        assert_eq!(arr.data, data);
    }

    #[test]
    fn reads_f16_and_u16() {
        let half: Vec<u8> = [0.5f32, 2.0]
            .iter()
            .flat_map(|&v| f16::from_f32(v).to_le_bytes())
            .collect();
        let arr = parse(&npy_with_header(
            "{'descr':'<f2','fortran_order':False,'shape':(1,2)}\n",
            &half,
        ))
        .unwrap();
        assert_eq!(arr.data, vec![0.5, 2.0]);
        let u: Vec<u8> = [7u16, 65535].iter().flat_map(|v| v.to_le_bytes()).collect();
        let arr = parse(&npy_with_header(
            "{\"shape\": (2, 1, 1), \"descr\": \"<u2\", \"fortran_order\": False}",
            &u,
        ))
        .unwrap();
        assert_eq!((arr.rows, arr.cols, arr.data), (2, 1, vec![7.0, 65535.0]));
    }

    #[test]
    fn squeezes_unit_axes() {
        assert_eq!(map_shape(&[1, 4, 5]), Ok((4, 5)));
        assert_eq!(map_shape(&[4, 5, 1]), Ok((4, 5)));
        assert!(map_shape(&[3, 4, 5]).is_err());
        assert!(map_shape(&[20]).is_err());
    }

    #[test]
    fn rejects_bad_files() {
        let hdr = |h: &str| npy_with_header(h, &[0; 8]);
        assert_eq!(parse(b"PK\x03\x04 zip"), Err(NpyError::Magic));
        assert_eq!(
            parse(&hdr(
                "{'descr': '>f4', 'fortran_order': False, 'shape': (1, 2), }"
            )),
            Err(NpyError::Dtype(">f4".into()))
        );
        assert_eq!(
            parse(&hdr(
                "{'descr': '<f4', 'fortran_order': True, 'shape': (1, 2), }"
            )),
            Err(NpyError::FortranOrder)
        );
        assert_eq!(
            parse(&hdr(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2), }"
            )),
            Err(NpyError::DataLength {
                expected: 16,
                actual: 8
            })
        );
        assert!(matches!(
            parse(&hdr("{'descr': '<f4', 'shape': (1, 2), }")),
            Err(NpyError::Header(_))
        ));
        assert!(matches!(
            parse(&hdr(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999, 99999999999), }"
            )),
            Err(NpyError::TooLarge(_))
        ));
        assert!(matches!(
            parse(&hdr(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 2), __import__"
            )),
            Err(NpyError::Header(_))
        ));
    }

    #[test]
    fn rejects_truncated_and_oversized_headers() {
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&[1, 0, 200, 0, b'{']);
        assert_eq!(parse(&bytes), Err(NpyError::Truncated));
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&[2, 0, 0, 0, 0, 1]);
        assert_eq!(parse(&bytes), Err(NpyError::HeaderTooLong(1 << 24)));
    }
}
