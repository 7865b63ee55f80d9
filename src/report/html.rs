//! A small builder for one self-contained HTML report: inline CSS, pictures as base64 data URIs
//! or inline SVG, tables and sections. No scripts, no external resources, so the file opens
//! the same anywhere (e-mail attachment, archive, offline lab PC).
//!
//! Every piece of text given to the builder is escaped; only [`Page::raw`] takes markup as is
//! (for fragments this module or plotters produced).

use base64::Engine;

/// Escapes text for HTML element content and attribute values.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

/// A table: header cells and rows of text cells; numeric cells are right-aligned.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    pub caption: Option<String>,
    pub header: Vec<String>,
    pub rows: Vec<Vec<String>>,
}

impl Table {
    pub fn new<S: Into<String>>(header: impl IntoIterator<Item = S>) -> Self {
        Table {
            caption: None,
            header: header.into_iter().map(Into::into).collect(),
            rows: Vec::new(),
        }
    }

    pub fn caption(mut self, c: impl Into<String>) -> Self {
        self.caption = Some(c.into());
        self
    }

    pub fn row<S: Into<String>>(&mut self, cells: impl IntoIterator<Item = S>) -> &mut Self {
        self.rows.push(cells.into_iter().map(Into::into).collect());
        self
    }

    fn render(&self) -> String {
        // The box scrolls sideways when the table is wider than the page, so no table widens
        // the page past its 1180 px column (a 1280 px window).
        let mut h = String::from("<div class=\"tablebox\"><table>");
        if let Some(c) = &self.caption {
            h.push_str(&format!("<caption>{}</caption>", escape(c)));
        }
        h.push_str("<thead><tr>");
        for c in &self.header {
            h.push_str(&format!("<th>{}</th>", escape(c)));
        }
        h.push_str("</tr></thead><tbody>");
        for r in &self.rows {
            h.push_str("<tr>");
            for c in r {
                let class = if looks_numeric(c) {
                    " class=\"num\""
                } else {
                    ""
                };
                h.push_str(&format!("<td{class}>{}</td>", escape(c)));
            }
            h.push_str("</tr>");
        }
        h.push_str("</tbody></table></div>\n");
        h
    }
}

fn looks_numeric(s: &str) -> bool {
    let t = s.trim().trim_end_matches('%').trim();
    let t = t.split(" \u{b1} ").next().unwrap_or(t);
    !t.is_empty() && t.parse::<f64>().is_ok()
}

/// One HTML document under construction.
#[derive(Debug, Clone, PartialEq)]
pub struct Page {
    title: String,
    body: Vec<String>,
}

const CSS: &str = "\
body{font-family:'DejaVu Sans',Verdana,Arial,sans-serif;margin:24px auto;max-width:1180px;\
color:#222;background:#fff;line-height:1.4;padding:0 16px}\
h1{font-size:1.6em;border-bottom:2px solid #0072b2;padding-bottom:4px}\
h2{font-size:1.3em;margin-top:1.8em;border-bottom:1px solid #ccc}\
h3{font-size:1.1em;margin-top:1.2em}\
div.tablebox{max-width:100%;overflow-x:auto;margin:0.6em 0 1.2em 0}\
table{border-collapse:collapse;font-size:0.92em}\
caption{text-align:left;font-weight:bold;padding:4px 0}\
th,td{border:1px solid #bbb;padding:3px 8px}th{background:#eef3f8}\
td.num{text-align:right;font-variant-numeric:tabular-nums}\
figure{display:inline-block;margin:6px 10px 12px 0;vertical-align:top}\
figcaption{font-size:0.85em;color:#555;max-width:800px}\
img,svg{max-width:100%;height:auto}\
p.note{color:#555;font-size:0.9em}\
pre{background:#f6f6f6;padding:8px;overflow-x:auto;font-size:0.85em}";

impl Page {
    pub fn new(title: impl Into<String>) -> Self {
        let title = title.into();
        let body = vec![format!("<h1>{}</h1>\n", escape(&title))];
        Page { title, body }
    }

    /// A section heading (`<h2>`).
    pub fn section(&mut self, title: &str) -> &mut Self {
        self.body.push(format!("<h2>{}</h2>\n", escape(title)));
        self
    }

    /// A sub-section heading (`<h3>`).
    pub fn subsection(&mut self, title: &str) -> &mut Self {
        self.body.push(format!("<h3>{}</h3>\n", escape(title)));
        self
    }

    pub fn paragraph(&mut self, text: &str) -> &mut Self {
        self.body.push(format!("<p>{}</p>\n", escape(text)));
        self
    }

    /// A de-emphasised remark (conventions, caveats).
    pub fn note(&mut self, text: &str) -> &mut Self {
        self.body
            .push(format!("<p class=\"note\">{}</p>\n", escape(text)));
        self
    }

    pub fn preformatted(&mut self, text: &str) -> &mut Self {
        self.body.push(format!("<pre>{}</pre>\n", escape(text)));
        self
    }

    pub fn table(&mut self, t: &Table) -> &mut Self {
        self.body.push(t.render());
        self
    }

    /// A PNG picture embedded as a base64 data URI, with alternative text and a caption.
    pub fn png(&mut self, png: &[u8], alt: &str, caption: &str) -> &mut Self {
        let b64 = base64::engine::general_purpose::STANDARD.encode(png);
        self.body.push(format!(
            "<figure><img alt=\"{}\" src=\"data:image/png;base64,{b64}\"><figcaption>{}</figcaption></figure>\n",
            escape(alt),
            escape(caption)
        ));
        self
    }

    /// An SVG picture inlined in the document (any XML prolog is dropped).
    pub fn svg(&mut self, svg: &str, caption: &str) -> &mut Self {
        let start = svg.find("<svg").unwrap_or(0);
        self.body.push(format!(
            "<figure>{}<figcaption>{}</figcaption></figure>\n",
            &svg[start..],
            escape(caption)
        ));
        self
    }

    /// Markup inserted as is: only for fragments produced by trusted code.
    pub fn raw(&mut self, html: &str) -> &mut Self {
        self.body.push(html.to_string());
        self
    }

    /// The whole document.
    pub fn render(&self) -> String {
        let mut h =
            String::from("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n");
        h.push_str("<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n");
        h.push_str(&format!(
            "<title>{}</title>\n<style>{CSS}</style>\n</head>\n<body>\n",
            escape(&self.title)
        ));
        for b in &self.body {
            h.push_str(b);
        }
        h.push_str("</body>\n</html>\n");
        h
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_text_everywhere() {
        assert_eq!(
            escape("<a href=\"x\">&'</a>"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;&lt;/a&gt;"
        );
        let mut p = Page::new("T <script>");
        p.section("S & s").paragraph("<b>bold?</b>");
        let mut t = Table::new(["name", "value"]).caption("cap <i>");
        t.row(["<x>", "1.5"]);
        p.table(&t);
        let h = p.render();
        assert!(
            !h.contains("<script>")
                && !h.contains("<b>")
                && !h.contains("<x>")
                && !h.contains("<i>")
        );
        assert!(h.contains("T &lt;script&gt;") && h.contains("S &amp; s"));
        assert!(h.contains("<td class=\"num\">1.5</td>"));
    }

    #[test]
    fn png_is_inlined_as_base64_that_decodes_back() {
        let bytes = [137u8, 80, 78, 71, 1, 2, 3, 255];
        let mut p = Page::new("t");
        p.png(&bytes, "alt", "cap");
        let h = p.render();
        let start = h.find("base64,").unwrap() + 7;
        let end = start + h[start..].find('"').unwrap();
        let back = base64::engine::general_purpose::STANDARD
            .decode(&h[start..end])
            .unwrap();
        assert_eq!(back, bytes);
        assert!(
            !h.contains("http://") && !h.contains("https://"),
            "no external resources"
        );
    }

    #[test]
    fn svg_prolog_is_dropped_and_document_is_well_formed() {
        let mut p = Page::new("t");
        p.svg("<?xml version=\"1.0\"?>\n<svg width=\"1\"></svg>", "c");
        let h = p.render();
        assert!(!h.contains("<?xml"));
        assert!(h.starts_with("<!DOCTYPE html>") && h.trim_end().ends_with("</html>"));
        assert_eq!(
            h.matches("<figure>").count(),
            h.matches("</figure>").count()
        );
    }

    #[test]
    fn numeric_detection() {
        assert!(looks_numeric("11.67 %"));
        assert!(looks_numeric("-3e-2"));
        assert!(looks_numeric("1.2 \u{b1} 0.3"));
        assert!(!looks_numeric("original"));
        assert!(!looks_numeric(""));
    }
}
