//! Reports for people and for CI: `report.md`, a self-contained `report.html` (figures
//! inline) and each figure as its own `.svg`, all written atomically.

use crate::plot::escape;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use stride_output::fs::write_atomic;

/// A piece of a report.
#[derive(Debug, Clone, PartialEq)]
pub enum Block {
    /// A section heading.
    Heading(String),
    /// A paragraph of plain text.
    Paragraph(String),
    /// A table: header cells and rows of cells.
    Table {
        /// Column headers.
        headers: Vec<String>,
        /// Rows of cells.
        rows: Vec<Vec<String>>,
    },
    /// An SVG figure saved as `<name>.svg` beside the report.
    Figure {
        /// File stem of the SVG (letters, digits, `-`, `_`).
        name: String,
        /// The SVG document.
        svg: String,
        /// Caption.
        caption: String,
    },
    /// An image file already written beside the report (e.g. a PNG preview).
    Image {
        /// File name relative to the report folder.
        file: String,
        /// Caption.
        caption: String,
    },
    /// Preformatted text (commands, logs).
    Code(String),
}

/// A report under construction.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Report {
    /// Title of the document.
    pub title: String,
    /// Its content in order.
    pub blocks: Vec<Block>,
}

impl Report {
    /// An empty report with a title.
    pub fn new(title: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            blocks: Vec::new(),
        }
    }

    /// Appends a block.
    pub fn push(&mut self, block: Block) -> &mut Self {
        self.blocks.push(block);
        self
    }

    /// Appends a heading.
    pub fn heading(&mut self, text: impl Into<String>) -> &mut Self {
        self.push(Block::Heading(text.into()))
    }

    /// Appends a paragraph.
    pub fn paragraph(&mut self, text: impl Into<String>) -> &mut Self {
        self.push(Block::Paragraph(text.into()))
    }

    /// Appends a table.
    pub fn table(&mut self, headers: &[&str], rows: Vec<Vec<String>>) -> &mut Self {
        self.push(Block::Table {
            headers: headers.iter().map(|h| (*h).to_owned()).collect(),
            rows,
        })
    }

    /// Appends an SVG figure.
    pub fn figure(&mut self, name: &str, svg: String, caption: impl Into<String>) -> &mut Self {
        self.push(Block::Figure {
            name: name.to_owned(),
            svg,
            caption: caption.into(),
        })
    }

    /// Appends a reference to an image file placed beside the report.
    pub fn image(&mut self, file: &str, caption: impl Into<String>) -> &mut Self {
        self.push(Block::Image {
            file: file.to_owned(),
            caption: caption.into(),
        })
    }

    /// Appends preformatted text.
    pub fn code(&mut self, text: impl Into<String>) -> &mut Self {
        self.push(Block::Code(text.into()))
    }

    /// The report as Markdown; figures are linked as `<name>.svg`.
    pub fn to_markdown(&self) -> String {
        let mut md = format!("# {}\n\n", self.title);
        for b in &self.blocks {
            match b {
                Block::Heading(t) => {
                    let _ = write!(md, "## {t}\n\n");
                }
                Block::Paragraph(t) => {
                    let _ = write!(md, "{t}\n\n");
                }
                Block::Table { headers, rows } => {
                    let cell = |s: &String| s.replace('|', "\\|");
                    let _ = writeln!(
                        md,
                        "| {} |",
                        headers.iter().map(cell).collect::<Vec<_>>().join(" | ")
                    );
                    let _ = writeln!(
                        md,
                        "|{}",
                        headers.iter().map(|_| "---|").collect::<String>()
                    );
                    for r in rows {
                        let _ = writeln!(
                            md,
                            "| {} |",
                            r.iter().map(cell).collect::<Vec<_>>().join(" | ")
                        );
                    }
                    md.push('\n');
                }
                Block::Figure { name, caption, .. } => {
                    let _ = write!(md, "![{caption}]({name}.svg)\n\n*{caption}*\n\n");
                }
                Block::Image { file, caption } => {
                    let _ = write!(md, "![{caption}]({file})\n\n*{caption}*\n\n");
                }
                Block::Code(t) => {
                    let _ = write!(md, "```\n{t}\n```\n\n");
                }
            }
        }
        md
    }

    /// The report as one HTML page: figures inline, [`Block::Image`]s linked to their files
    /// ([`Report::write`] embeds them instead).
    pub fn to_html(&self) -> String {
        self.html(&mut |file| Ok(escape(file)))
            .unwrap_or_else(|e: std::io::Error| e.to_string())
    }

    /// The HTML page with each image's `src` given by `image_src` (a path or a data URI).
    fn html(
        &self,
        image_src: &mut dyn FnMut(&str) -> std::io::Result<String>,
    ) -> std::io::Result<String> {
        let mut h = String::new();
        let _ = write!(
            h,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\
             <style>body{{font-family:Helvetica,Arial,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}}\
             table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:4px 10px;text-align:right}}\
             th{{background:#f0f0f0}}td:first-child,th:first-child{{text-align:left}}figure{{margin:1.5em 0}}\
             figcaption{{color:#555;font-size:90%}}pre{{background:#f5f5f5;padding:8px;overflow-x:auto}}\
             img{{max-width:100%}}</style></head><body>\n<h1>{t}</h1>\n",
            t = escape(&self.title)
        );
        for b in &self.blocks {
            match b {
                Block::Heading(t) => {
                    let _ = writeln!(h, "<h2>{}</h2>", escape(t));
                }
                Block::Paragraph(t) => {
                    let _ = writeln!(h, "<p>{}</p>", escape(t));
                }
                Block::Table { headers, rows } => {
                    h.push_str("<table><tr>");
                    for c in headers {
                        let _ = write!(h, "<th>{}</th>", escape(c));
                    }
                    h.push_str("</tr>\n");
                    for r in rows {
                        h.push_str("<tr>");
                        for c in r {
                            let _ = write!(h, "<td>{}</td>", escape(c));
                        }
                        h.push_str("</tr>\n");
                    }
                    h.push_str("</table>\n");
                }
                Block::Figure { svg, caption, .. } => {
                    let _ = writeln!(
                        h,
                        "<figure>{svg}<figcaption>{}</figcaption></figure>",
                        escape(caption)
                    );
                }
                Block::Image { file, caption } => {
                    let _ = writeln!(
                        h,
                        "<figure><img src=\"{}\" alt=\"{c}\"><figcaption>{c}</figcaption></figure>",
                        image_src(file)?,
                        c = escape(caption)
                    );
                }
                Block::Code(t) => {
                    let _ = writeln!(h, "<pre>{}</pre>", escape(t));
                }
            }
        }
        h.push_str("</body></html>\n");
        Ok(h)
    }

    /// Writes `report.md`, `report.html` and one `.svg` per figure into `dir` (created if
    /// missing). Every file is written atomically. report.html is self-contained: the
    /// images, read from their files in `dir` (which must exist), are embedded as data
    /// URIs, so the page can be mailed alone. Returns the paths written.
    pub fn write(&self, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
        std::fs::create_dir_all(dir)?;
        let mut written = Vec::new();
        for b in &self.blocks {
            if let Block::Figure { name, svg, .. } = b {
                let p = dir.join(format!("{name}.svg"));
                write_atomic(&p, svg.as_bytes())?;
                written.push(p);
            }
        }
        let html = self.html(&mut |file| data_uri(&dir.join(file)))?;
        for (name, text) in [("report.md", self.to_markdown()), ("report.html", html)] {
            let p = dir.join(name);
            write_atomic(&p, text.as_bytes())?;
            written.push(p);
        }
        Ok(written)
    }
}

/// The file at `path` as a `data:` URI (PNG, JPEG or SVG by its extension); an error naming
/// the file when it cannot be read.
fn data_uri(path: &Path) -> std::io::Result<String> {
    use base64::Engine as _;
    let mime = match path.extension().and_then(|e| e.to_str()) {
        Some("png") => "image/png",
        Some("jpg" | "jpeg") => "image/jpeg",
        Some("svg") => "image/svg+xml",
        _ => "application/octet-stream",
    };
    let bytes = std::fs::read(path).map_err(|e| {
        std::io::Error::new(
            e.kind(),
            format!("embedding {} in the report: {e}", path.display()),
        )
    })?;
    Ok(format!(
        "data:{mime};base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_and_html_hold_every_block() {
        let mut r = Report::new("ATE <test>");
        r.heading("Numbers")
            .paragraph("a & b")
            .table(&["k", "v"], vec![vec!["rmse".into(), "0.1|2".into()]])
            .figure("ate", "<svg></svg>".into(), "the plot")
            .code("stride eval ate");
        let md = r.to_markdown();
        assert!(md.starts_with("# ATE <test>"));
        assert!(md.contains("| rmse | 0.1\\|2 |"));
        assert!(md.contains("![the plot](ate.svg)"));
        let html = r.to_html();
        assert!(html.contains("<h1>ATE &lt;test&gt;</h1>"));
        assert!(html.contains("<p>a &amp; b</p>"));
        assert!(html.contains("<figure><svg></svg>"));
        let dir = std::env::temp_dir().join(format!("stride-report-{}", std::process::id()));
        let files = r.write(&dir).unwrap();
        assert_eq!(files.len(), 3);
        assert!(dir.join("ate.svg").is_file() && dir.join("report.html").is_file());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn written_pages_embed_their_images_and_a_missing_one_is_an_error() {
        let dir = std::env::temp_dir().join(format!("stride-report-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("map.png"), b"\x89PNG bytes").unwrap();
        let mut r = Report::new("map");
        r.image("map.png", "the map");
        r.write(&dir).unwrap();
        let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
        assert!(
            html.contains("src=\"data:image/png;base64,iVBORyBieXRlcw==\""),
            "{html}"
        );
        r.image("gone.png", "not there");
        let err = r.write(&dir).unwrap_err();
        assert!(err.to_string().contains("gone.png"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
