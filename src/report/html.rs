//! The report page: one self-contained HTML file (styles inline, every picture a base64
//! `data:` URI), so it opens in any browser with no network and can be mailed as is.
//!
//! Its order: the summary table, one section per probe of a session of several (its
//! name as heading, its summary rows and plots), the figures the probes share, the
//! thumbnails, the events.
use std::fmt::Write as _;

/// A picture for the page, PNG-encoded.
pub struct Figure {
    pub title: String,
    pub png: Vec<u8>,
    pub caption: String,
}

/// One probe's part of the page (a session of several probes).
pub struct Section {
    /// The probe's name.
    pub heading: String,
    /// Its (quantity, value) rows.
    pub summary: Vec<(String, String)>,
    pub figures: Vec<Figure>,
}

/// What the page shows.
pub struct Page<'a> {
    pub title: String,
    pub subtitle: String,
    /// (quantity, value) rows of the summary table.
    pub summary: &'a [(String, String)],
    /// One per probe of a session of several; none for a lone probe.
    pub sections: &'a [Section],
    /// The figures of the whole session (of a lone probe: all of them).
    pub figures: &'a [Figure],
    /// Thumbnails: (PNG, caption lines).
    pub thumbnails: &'a [(Vec<u8>, Vec<String>)],
    pub notes: &'a [String],
    pub events: &'a [String],
}

const STYLE: &str =
    "body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:24px auto;\
max-width:1100px;color:#222;padding:0 16px}h1{font-size:1.6em;margin-bottom:0}\
.sub{color:#666;margin-top:4px}table{border-collapse:collapse;margin:12px 0}\
td{padding:4px 14px;border-bottom:1px solid #e4e4e4}td:first-child{color:#555}\
td:last-child{font-variant-numeric:tabular-nums}figure{margin:18px 0}\
figure img{max-width:100%;border:1px solid #ddd}figcaption{color:#555;font-size:.9em}\
.strip{display:flex;flex-wrap:wrap;gap:10px}.strip figure{margin:0;width:320px}\
.note{background:#fff7e0;border-left:4px solid #f0b400;padding:6px 10px}\
pre{background:#f6f6f6;padding:8px;max-height:240px;overflow:auto;font-size:.85em}";

/// The HTML text of the page.
pub fn render(page: &Page) -> String {
    let mut html = String::with_capacity(1 << 20);
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>{}</title><style>{STYLE}</style></head><body>\n<h1>{}</h1>\
         <p class=\"sub\">{}</p>\n",
        escape(&page.title),
        escape(&page.title),
        escape(&page.subtitle)
    );
    for note in page.notes {
        let _ = writeln!(html, "<p class=\"note\">{}</p>", escape(note));
    }
    html.push_str("<h2>Summary</h2>\n<table id=\"summary\">\n");
    rows(&mut html, page.summary);
    html.push_str("</table>\n");
    for section in page.sections {
        let name = escape(&section.heading);
        let _ = writeln!(
            html,
            "<section class=\"probe\" id=\"probe-{name}\">\n<h2>{name}</h2>\n\
             <table id=\"summary-{name}\">"
        );
        rows(&mut html, &section.summary);
        html.push_str("</table>\n");
        figures(&mut html, &section.figures, "h3");
        html.push_str("</section>\n");
    }
    figures(&mut html, page.figures, "h2");
    if !page.thumbnails.is_empty() {
        html.push_str(
            "<h2>Frames</h2>\n<p class=\"sub\">Found edges: red (beam), blue (pyramid back \
             face), green (front face); the yellow circle is the apex.</p>\n<div class=\"strip\">\n",
        );
        for (png, caption) in page.thumbnails {
            let lines: Vec<String> = caption.iter().map(|l| escape(l)).collect();
            let _ = writeln!(
                html,
                "<figure><img alt=\"{}\" src=\"data:image/png;base64,{}\">\
                 <figcaption>{}</figcaption></figure>",
                lines.join(" "),
                base64(png),
                lines.join("<br>")
            );
        }
        html.push_str("</div>\n");
    }
    if !page.events.is_empty() {
        html.push_str("<h2>Events</h2>\n<pre>");
        for line in page.events {
            let _ = writeln!(html, "{}", escape(line));
        }
        html.push_str("</pre>\n");
    }
    html.push_str("</body></html>\n");
    html
}

/// The (quantity, value) rows of a table.
fn rows(html: &mut String, rows: &[(String, String)]) {
    for (key, value) in rows {
        let _ = writeln!(
            html,
            "<tr><td>{}</td><td>{}</td></tr>",
            escape(key),
            escape(value)
        );
    }
}

/// Each figure under its title, a heading of level `heading`.
fn figures(html: &mut String, figures: &[Figure], heading: &str) {
    for f in figures {
        let _ = writeln!(
            html,
            "<{heading}>{}</{heading}>\n<figure><img alt=\"{}\" src=\"data:image/png;base64,{}\">\
             <figcaption>{}</figcaption></figure>",
            escape(&f.title),
            escape(&f.title),
            base64(&f.png),
            escape(&f.caption)
        );
    }
}

/// Text safe inside HTML elements and attribute values.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Standard base64 with padding (RFC 4648).
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(char::from(ALPHABET[(n >> (18 - 6 * k) & 63) as usize]));
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
    fn base64_matches_rfc_4648_vectors() {
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
        assert_eq!(base64(&[0xff, 0xfe, 0x00]), "//4A");
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(escape("a<b & \"c\"'"), "a&lt;b &amp; &quot;c&quot;&#39;");
        let page = Page {
            title: "<script>".into(),
            subtitle: String::new(),
            summary: &[("k".into(), "<v>".into())],
            sections: &[],
            figures: &[],
            thumbnails: &[],
            notes: &[],
            events: &["state a -> b".into()],
        };
        let html = render(&page);
        assert!(!html.contains("<script>"));
        assert!(html.contains("&lt;v&gt;") && html.contains("state a -&gt; b"));
    }
}
