//! `--baseline`: this run's methods set against an earlier run's page (a `photos.md` this tool
//! wrote, e.g. the committed `tools/results/photos.md`), set by set.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result, bail};
use splineface::Real;

/// An earlier run's ratios to the mean face: per set label, per method, as its "Every set"
/// table prints them (two decimals; `None` where the method failed on the set).
pub struct Baseline {
    pub methods: Vec<String>,
    pub ratios: HashMap<String, Vec<Option<Real>>>,
}

/// One method of this run: its name, and per set its label and ratio to the mean face.
pub type Run<'a> = (&'a str, Vec<(&'a str, Option<Real>)>);

/// One set compared: this run's ratio, the baseline default's and its landmark fit's.
type Row = (Real, Option<Real>, Option<Real>);

/// The method a run is compared with, and the one whose sets count as "worse" when this run's
/// ratio exceeds theirs by more than [`WORSE`].
const DEFAULT: &str = "default";
const LANDMARKS: &str = "landmarks only";
/// A set is worse than the landmark fit when its ratio exceeds the landmark fit's by this
/// share (2%, as the refinement's documentation counts them).
const WORSE: Real = 1.02;
/// A set is better or worse than the baseline's default when the ratios differ by more than
/// this.
const DIFFERENT: Real = 0.005;

impl Baseline {
    /// Reads `path`'s "Every set" table.
    pub fn read(path: &Path) -> Result<Baseline> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading the baseline {}", path.display()))?;
        let mut lines = text
            .lines()
            .skip_while(|l| !l.starts_with("## Every set"))
            .skip(1)
            .skip_while(|l| l.trim().is_empty());
        let cells = |line: &str| -> Vec<String> {
            line.trim()
                .trim_matches('|')
                .split('|')
                .map(|c| c.trim().to_owned())
                .collect()
        };
        let Some(header) = lines.next() else {
            bail!("{}: no \"## Every set\" table", path.display());
        };
        let header = cells(header);
        if header.len() < 5 || header[0] != "set" || header[3] != "mean face" {
            bail!(
                "{}: the \"Every set\" table's header is not photo_eval's: {header:?}",
                path.display()
            );
        }
        let methods = header[4..].to_vec();
        let mut ratios = HashMap::new();
        for line in lines.skip(1).take_while(|l| l.starts_with('|')) {
            let row = cells(line);
            if row.len() != header.len() {
                bail!(
                    "{}: a row of {} cells under a header of {}: {line}",
                    path.display(),
                    row.len(),
                    header.len()
                );
            }
            // "1.08 (0.83)": the ratio is in the brackets; "failed: ..." has none.
            let parsed = row[4..]
                .iter()
                .map(|cell| {
                    cell.rsplit_once('(')
                        .and_then(|(_, r)| r.strip_suffix(')'))
                        .and_then(|r| r.parse::<Real>().ok())
                })
                .collect();
            ratios.insert(row[0].clone(), parsed);
        }
        if ratios.is_empty() {
            bail!("{}: the \"Every set\" table has no rows", path.display());
        }
        Ok(Baseline { methods, ratios })
    }

    fn column(&self, method: &str) -> Option<usize> {
        self.methods.iter().position(|m| m == method)
    }

    /// The page's section: for each of this run's methods (`name`, and per set its label and
    /// ratio), over the sets both runs scored, its mean ratio against the baseline default's
    /// on the same sets, its mean ratio to the baseline's landmark fit and the sets more than
    /// 2% worse than it, and the sets better and worse than the baseline's default. This
    /// run's ratios are rounded to two decimals first, as the baseline's are printed.
    pub fn section(&self, path: &Path, runs: &[Run<'_>]) -> Result<String> {
        let (default, landmarks) = (self.column(DEFAULT), self.column(LANDMARKS));
        let mut page = String::new();
        writeln!(
            page,
            "\n## Against the baseline `{}`\n\nOver the sets both runs scored; this run's ratios rounded to two decimals, as the baseline prints them. \
             \"Worse\": more than 2% worse than the baseline's `{LANDMARKS}`; better and worse than its `{DEFAULT}` by more than {DIFFERENT}.\n",
            path.display()
        )?;
        writeln!(
            page,
            "| method | sets | mean ratio | the baseline's {DEFAULT} | to the baseline's {LANDMARKS} | worse | better / worse than its {DEFAULT} |\n|---|---|---|---|---|---|---|"
        )?;
        for (name, sets) in runs {
            let mut rows = Vec::new();
            for &(label, ratio) in sets {
                let (Some(ratio), Some(base)) = (ratio, self.ratios.get(label)) else {
                    continue;
                };
                let ratio = (ratio * 100.0).round() / 100.0;
                let pick = |c: Option<usize>| c.and_then(|c| base[c]);
                rows.push((ratio, pick(default), pick(landmarks)));
            }
            let mean = |f: &dyn Fn(&Row) -> Option<Real>| {
                let v: Vec<Real> = rows.iter().filter_map(f).collect();
                if v.is_empty() {
                    "–".to_owned()
                } else {
                    format!("{:.3}", v.iter().sum::<Real>() / v.len() as Real)
                }
            };
            let worse = rows
                .iter()
                .filter(|(r, _, l)| l.is_some_and(|l| *r > WORSE * l))
                .count();
            let better_than = rows
                .iter()
                .filter(|(r, d, _)| d.is_some_and(|d| *r < d - DIFFERENT))
                .count();
            let worse_than = rows
                .iter()
                .filter(|(r, d, _)| d.is_some_and(|d| *r > d + DIFFERENT))
                .count();
            writeln!(
                page,
                "| {name} | {} | {} | {} | {} | {} | {} |",
                rows.len(),
                mean(&|(r, _, _)| Some(*r)),
                mean(&|(_, d, _)| *d),
                mean(&|(r, _, l)| l.map(|l| r / l)),
                if landmarks.is_some() {
                    worse.to_string()
                } else {
                    "–".to_owned()
                },
                if default.is_some() {
                    format!("{better_than} / {worse_than}")
                } else {
                    "–".to_owned()
                },
            )?;
        }
        Ok(page)
    }
}
