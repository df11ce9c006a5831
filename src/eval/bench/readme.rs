//! The targets table of a report written into a Markdown file (the README's headline
//! figures) between two marker lines, so that the figures a document quotes are the ones a
//! report measured, regenerated rather than copied by hand.

use std::path::{Path, PathBuf};

use super::report::Report;

/// The line that opens the block (anything may follow it on the line) and the one that
/// closes it.
pub const START: &str = "<!-- bench-targets";
pub const END: &str = "<!-- /bench-targets -->";

#[derive(Debug, thiserror::Error)]
pub enum ReadmeError {
    #[error("{path}: cannot read: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(
        "{path}: no block to write the targets into: put a line starting with `{START}` and, below it, a line `{END}` where the table belongs"
    )]
    NoBlock { path: PathBuf },
    #[error(transparent)]
    Write(#[from] crate::io::output::OutputError),
}

/// The block's contents for `report`, read from `source` (the report's file, or a
/// description of the run).
pub fn block(report: &Report, source: &str) -> String {
    let reshading = report
        .reshade_model
        .split(" (")
        .next()
        .unwrap_or(&report.reshade_model);
    format!(
        "From `reshader bench` ({}, {} threads on {}, {reshading}): {source}\n\n{}",
        report.profile,
        report.threads,
        report.cpu_name(),
        super::targets::table(report)
    )
}

/// `text` with the block between the markers replaced by `contents`, or None when it has
/// no such block.
pub fn replace_block(text: &str, contents: &str) -> Option<String> {
    let lines: Vec<&str> = text.lines().collect();
    let start = lines.iter().position(|l| l.starts_with(START))?;
    let end = start + lines[start..].iter().position(|l| l.trim() == END)?;
    let mut out = String::new();
    for line in &lines[..=start] {
        out.push_str(line);
        out.push('\n');
    }
    out.push_str(contents.trim_end());
    out.push('\n');
    for line in &lines[end..] {
        out.push_str(line);
        out.push('\n');
    }
    if !text.ends_with('\n') {
        out.pop();
    }
    Some(out)
}

/// Refuses a file that cannot take the targets, before anything is measured.
pub fn check(path: &Path) -> Result<(), ReadmeError> {
    filled(path, "").map(drop)
}

/// Writes `report`'s targets into the block of the Markdown file at `path` (atomically;
/// the file is left as it was on any error).
pub fn update(path: &Path, report: &Report, source: &str) -> Result<(), ReadmeError> {
    let updated = filled(path, &block(report, source))?;
    crate::io::output::write_atomic(path, updated.as_bytes())?;
    Ok(())
}

/// The text of the file at `path` with its block holding `contents`.
fn filled(path: &Path, contents: &str) -> Result<String, ReadmeError> {
    let text = std::fs::read_to_string(path).map_err(|source| ReadmeError::Read {
        path: path.to_owned(),
        source,
    })?;
    replace_block(&text, contents).ok_or_else(|| ReadmeError::NoBlock {
        path: path.to_owned(),
    })
}
