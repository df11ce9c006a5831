//! The HTML preview, `preview.html`: one file, its views inside it as JPEG `data:` URIs,
//! so that it opens from disk, from a mail or a chat with no network and nothing beside
//! it. It shows the view under the pointer or a finger ([`view_at`]); `#x=F` after its
//! address places a pointer at fraction F of the picture's width. JPEG at quality
//! [`QUALITY`] keeps the page for a Portrait's 48 views near 3.4 MB (a base64 data URI
//! is a third larger than its bytes) where PNG would take several times that.

use std::fmt::Write as _;
use std::path::Path;

use image::codecs::jpeg::JpegEncoder;
use image::RgbImage;

use super::PreviewError;

pub const QUALITY: u8 = 85;

const TEMPLATE: &str = include_str!("page.html");

/// The view the page shows for a pointer at `fraction` of the picture's width (0 = left
/// edge, 1 = right edge) among `views` views: equal strips, view 0 leftmost, positions
/// outside the picture clamped to its edges. The page's script computes the same.
pub fn view_at(fraction: f64, views: usize) -> usize {
    let strip = (fraction * views as f64).floor();
    strip.clamp(0.0, views.saturating_sub(1) as f64) as usize
}

/// The page for `frames` (the views, view 0 leftmost), titled `title`; `path` names
/// the file in errors.
pub fn render(path: &Path, title: &str, frames: &[RgbImage]) -> Result<String, PreviewError> {
    let title = escape(title);
    let mut images = String::new();
    for (view, frame) in frames.iter().enumerate() {
        let mut jpeg = Vec::new();
        JpegEncoder::new_with_quality(&mut jpeg, QUALITY)
            .encode_image(frame)
            .map_err(|source| PreviewError::Jpeg {
                path: path.into(),
                view,
                source,
            })?;
        let _ = writeln!(
            images,
            r#"<img src="data:image/jpeg;base64,{}" width="{}" height="{}" alt="view {view}" draggable="false">"#,
            base64(&jpeg),
            frame.width(),
            frame.height(),
        );
    }
    // The title last, so that a photo's name cannot bring in a placeholder.
    Ok(TEMPLATE
        .replace("{{images}}", &images)
        .replace("{{count}}", &frames.len().to_string())
        .replace("{{title}}", &title))
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Standard base64 with padding (RFC 4648), as `data:` URIs want.
fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let bits = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(bits >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pointer_positions_map_to_equal_strips_left_to_right() {
        assert_eq!(view_at(0.0, 48), 0);
        assert_eq!(view_at(1.0 / 48.0 - 1e-9, 48), 0);
        assert_eq!(view_at(1.0 / 48.0, 48), 1);
        assert_eq!(view_at(0.5, 48), 24);
        assert_eq!(view_at(0.999, 48), 47);
        assert_eq!(view_at(1.0, 48), 47, "the right edge is the last view");
        assert_eq!(view_at(-0.2, 6), 0);
        assert_eq!(view_at(1.7, 6), 5);
        for k in 0..6 {
            assert_eq!(view_at((k as f64 + 0.5) / 6.0, 6), k);
        }
    }

    #[test]
    fn base64_matches_rfc_4648() {
        let cases = [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ];
        for (plain, encoded) in cases {
            assert_eq!(base64(plain.as_bytes()), encoded);
        }
    }

    #[test]
    fn the_page_holds_every_view_in_order_and_needs_no_network() {
        let frames: Vec<RgbImage> = (0..3u8)
            .map(|v| RgbImage::from_pixel(8, 6, image::Rgb([80 * v, 40, 200])))
            .collect();
        let html = render(Path::new("preview.html"), "a <b> & c", &frames).unwrap();
        assert!(html.contains("<title>a &lt;b&gt; &amp; c: reshader preview</title>"));
        let sources: Vec<&str> = html
            .split(r#"<img src="data:image/jpeg;base64,"#)
            .skip(1)
            .map(|s| &s[..s.find('"').unwrap()])
            .collect();
        assert_eq!(sources.len(), 3);
        for (v, src) in sources.iter().enumerate() {
            let jpeg = decode_base64(src);
            let image = image::load_from_memory(&jpeg).unwrap().to_rgb8();
            assert_eq!(image.dimensions(), (8, 6));
            let red = image.get_pixel(4, 3)[0];
            assert!(red.abs_diff(80 * v as u8) <= 6, "view {v}: red {red}");
        }
        assert_eq!(
            html.matches(" src=").count(),
            3,
            "only the views are loaded"
        );
        for remote in ["http", "href", "url(", "import"] {
            assert!(!html.contains(remote), "the page refers to {remote}");
        }
    }

    fn decode_base64(text: &str) -> Vec<u8> {
        let value = |c: u8| match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' => 62,
            _ => 63,
        };
        let digits: Vec<u8> = text.bytes().filter(|&c| c != b'=').map(value).collect();
        let mut out = Vec::new();
        for chunk in digits.chunks(4) {
            let bits = chunk
                .iter()
                .enumerate()
                .fold(0u32, |acc, (k, &d)| acc | u32::from(d) << (18 - 6 * k));
            out.extend_from_slice(&bits.to_be_bytes()[1..chunk.len()]);
        }
        out
    }
}
