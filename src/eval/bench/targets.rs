//! The product's speed and memory targets, each beside the figure of a report that
//! measures it, so that one run says which are met. Computed from the report's data, so
//! a saved JSON report gives the same table.

use std::fmt::Write as _;

use super::report::{ms, Case, Report};

/// A photo of at least this many pixels counts as a 12-megapixel case (the synthetic
/// 4000×3000 photo and phone photos of about that size).
const TWELVE_MP: u64 = 11_500_000;
const PORTRAIT: &str = "looking-glass-portrait";
const GO: &str = "looking-glass-go";
/// The shipped example's file name, as the report labels it.
const EXAMPLE: &str = "pumpkin";
const MIB_TO_MB: f64 = 1.048_576;

/// One target: what is measured, the limit, and this report's figure where it has one.
#[derive(Clone, Debug, PartialEq)]
pub struct Target {
    pub what: &'static str,
    pub limit: f64,
    pub unit: &'static str,
    /// None: no case of this report measures it.
    pub figure: Option<f64>,
    /// Which case or graph the figure comes from.
    pub source: String,
}

impl Target {
    /// Met when the figure is at most the limit; None when not measured.
    pub fn met(&self) -> Option<bool> {
        self.figure.map(|f| f <= self.limit)
    }

    fn row(&self) -> String {
        let figure = self.figure.map_or("not measured".into(), |f| self.value(f));
        let met = match self.met() {
            Some(true) => "yes",
            Some(false) => "**no**",
            None => "–",
        };
        format!(
            "| {} | ≤ {} | {figure} | {met} | {} |",
            self.what,
            self.value(self.limit),
            self.source
        )
    }

    fn value(&self, v: f64) -> String {
        match self.unit {
            "×" => format!("{v:.2}×"),
            "MB" => format!("{v:.0} MB"),
            _ => format!("{} ms", ms(v)),
        }
    }
}

/// Every target, in the order the Markdown lists them.
pub fn targets(report: &Report) -> Vec<Target> {
    let mut out = vec![
        end_to_end(
            report,
            "12 MP photo → Portrait (48 views), end to end",
            2000.0,
            |c| is_12mp(c) && c.board == PORTRAIT,
        ),
        end_to_end(
            report,
            "12 MP photo → Go (66 views), end to end",
            2500.0,
            |c| is_12mp(c) && c.board == GO,
        ),
        end_to_end(
            report,
            "the example photo → Portrait, end to end",
            1000.0,
            |c| c.photo.contains(EXAMPLE) && c.board == PORTRAIT,
        ),
    ];
    out.push(memory(report));
    out.push(peer(report));
    out.push(worst(
        report,
        "reshading + relocation per view, Portrait view size",
        15.0,
        |c| {
            let views = c.views.max(1) as f64;
            let decoder = c.stage("reshade decoder × views")?.time?.median_ms;
            let render = c.stage("LDI render × views")?.time?.median_ms;
            Some((decoder + render) / views)
        },
    ));
    out.push(worst(report, "weave, one 1536×2048 frame", 5.0, |c| {
        Some(c.stage("weave")?.time?.median_ms)
    }));
    out
}

/// The Markdown section: a table of every target with its figure and whether it is met.
pub fn markdown(report: &Report) -> String {
    format!("## Targets\n\n{}\n", table(report))
}

/// The table of [`markdown`] alone (with the dev-profile warning when it applies).
pub fn table(report: &Report) -> String {
    let mut out =
        String::from("| target | limit | measured | met | from |\n|---|---|---|---|---|\n");
    for t in targets(report) {
        let _ = writeln!(out, "{}", t.row());
    }
    if report.profile != "release" {
        out.push_str("\nA dev-profile build: these figures say nothing about the targets.\n");
    }
    out
}

fn is_12mp(c: &Case) -> bool {
    u64::from(c.photo_size[0]) * u64::from(c.photo_size[1]) >= TWELVE_MP
}

fn case_name(c: &Case) -> String {
    format!("{} / {}", c.photo, c.board)
}

fn end_to_end(
    report: &Report,
    what: &'static str,
    limit: f64,
    pick: impl Fn(&Case) -> bool,
) -> Target {
    let case = report.cases.iter().find(|c| pick(c) && c.total.is_some());
    Target {
        what,
        limit,
        unit: "ms",
        figure: case.and_then(|c| c.total).map(|t| t.median_ms),
        source: case.map_or(String::new(), case_name),
    }
}

fn memory(report: &Report) -> Target {
    let case = report
        .cases
        .iter()
        .filter(|c| is_12mp(c))
        .filter_map(|c| Some((c, c.peak_rss_mib?)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    Target {
        what: "peak resident memory, 12 MP photo",
        limit: 600.0,
        unit: "MB",
        figure: case.map(|(_, mib)| mib * MIB_TO_MB),
        source: case.map_or(String::new(), |(c, _)| case_name(c)),
    }
}

fn peer(report: &Report) -> Target {
    let row = report
        .peer
        .iter()
        .filter_map(|r| Some((r, r.ratio()?)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    Target {
        what: "tract / onnxruntime, slowest shipped graph",
        limit: 1.5,
        unit: "×",
        figure: row.map(|(_, r)| r),
        source: row.map_or(String::new(), |(r, _)| r.model.clone()),
    }
}

/// The largest figure over the Portrait's cases (each photo is fitted to cover the views).
fn worst(
    report: &Report,
    what: &'static str,
    limit: f64,
    figure: impl Fn(&Case) -> Option<f64>,
) -> Target {
    let case = report
        .cases
        .iter()
        .filter(|c| c.board == PORTRAIT)
        .filter_map(|c| Some((c, figure(c)?)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    Target {
        what,
        limit,
        unit: "ms",
        figure: case.map(|(_, f)| f),
        source: case.map_or(String::new(), |(c, _)| case_name(c)),
    }
}
