//! Progress bars for long work (`convert`'s photos, `render`'s views, `watch`'s queue,
//! `bench`'s cases), drawn on stderr for a person watching a terminal and nowhere else:
//! not when stderr is piped or redirected (scripts and logs get no control characters),
//! not in `--json` mode (a program reads the output), not with `-v` (its log lines are
//! the progress then, and would tear the bar), not on a dumb terminal.

use std::borrow::Cow;
use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressFinish, ProgressStyle};

static VERBOSE: AtomicBool = AtomicBool::new(false);

/// Says whether the process logs progress itself (`-v`); set once by the command line.
pub fn set_verbose(verbose: bool) {
    VERBOSE.store(verbose, Ordering::Relaxed);
}

/// Whether a bar is drawn, from everything that decides it: stderr is a terminal, the
/// command is not in `--json` mode, no `-v` log, and `$TERM` is not `dumb`.
pub fn wanted(stderr_is_terminal: bool, json: bool, verbose: bool, term: Option<&str>) -> bool {
    stderr_is_terminal && !json && !verbose && term != Some("dumb")
}

/// A bar, or nothing when none is wanted; clones share one bar.
#[derive(Clone, Debug)]
pub struct Progress(Option<ProgressBar>);

impl Progress {
    pub fn hidden() -> Self {
        Self(None)
    }

    /// A bar over `len` steps of `unit` ("photos", "views"), drawn if [`wanted`] for this
    /// process; `json` is the command's `--json`.
    pub fn start(len: u64, unit: &str, json: bool) -> Self {
        let term = std::env::var("TERM").ok();
        if !wanted(
            std::io::stderr().is_terminal(),
            json,
            VERBOSE.load(Ordering::Relaxed),
            term.as_deref(),
        ) {
            return Self::hidden();
        }
        let template =
            format!("{{msg}} [{{bar:30}}] {{pos}}/{{len}} {unit}, {{elapsed}} (left {{eta}})");
        let style = ProgressStyle::with_template(&template)
            .expect("the template is valid")
            .progress_chars("=> ");
        let bar = ProgressBar::new(len)
            .with_style(style)
            .with_finish(ProgressFinish::AndClear);
        // Redrawn every so often even without a step, so that a long step shows time
        // passing.
        bar.enable_steady_tick(Duration::from_millis(250));
        Self(Some(bar))
    }

    pub fn set_message(&self, message: impl Into<Cow<'static, str>>) {
        if let Some(bar) = &self.0 {
            bar.set_message(message);
        }
    }

    pub fn inc(&self, steps: u64) {
        if let Some(bar) = &self.0 {
            bar.inc(steps);
        }
    }

    /// More steps to go: a queue that grew.
    pub fn grow(&self, steps: u64) {
        if let Some(bar) = &self.0 {
            bar.inc_length(steps);
        }
    }

    /// Runs `f` (which writes to the terminal) with the bar out of the way.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        match &self.0 {
            Some(bar) => bar.suspend(f),
            None => f(),
        }
    }

    /// Removes the bar from the terminal.
    pub fn finish(&self) {
        if let Some(bar) = &self.0 {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bar_only_for_a_person_at_a_terminal() {
        assert!(wanted(true, false, false, Some("xterm-256color")));
        assert!(wanted(true, false, false, None));
        assert!(!wanted(false, false, false, Some("xterm")), "piped");
        assert!(!wanted(true, true, false, Some("xterm")), "--json");
        assert!(!wanted(true, false, true, Some("xterm")), "-v");
        assert!(!wanted(true, false, false, Some("dumb")), "dumb terminal");
    }

    #[test]
    fn a_hidden_bar_does_nothing_and_runs_what_it_suspends() {
        let bar = Progress::hidden();
        bar.grow(3);
        bar.inc(1);
        bar.set_message("x");
        assert_eq!(bar.suspend(|| 7), 7);
        bar.finish();
    }
}
