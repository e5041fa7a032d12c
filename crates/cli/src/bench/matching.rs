//! Table V: every matcher on each dataset's image pairs (`jointloc match`).

use std::path::Path;

use anyhow::Context;

use super::exec::Runner;
use super::plan::Plan;
use super::report::{Dataset, MatchRow, Report};

pub(super) fn matching_table(
    plan: &Plan,
    datasets: &[Dataset],
    out: &Path,
    runner: &mut Runner,
    rep: &mut Report,
) -> anyhow::Result<()> {
    for d in datasets {
        let json = out.join("runs").join(format!("{}-match.json", d.name()));
        let done = runner.run(
            &format!("match-{}", d.name()),
            &args![
                "match",
                "--dataset",
                d.path.display(),
                "--matcher",
                plan.matchers.join(","),
                "--pairs",
                plan.pairs,
                "--seed",
                d.seed,
                "--json",
                json.display(),
                "--force"
            ],
        )?;
        let parsed = done
            .outcome
            .clone()
            .and_then(|()| read_match_json(&json).map_err(|e| format!("{e:#}")));
        match parsed {
            Ok(rows) => {
                for (matcher, accuracy, ms) in rows {
                    rep.matching.push(MatchRow {
                        dataset: d.key(),
                        matcher,
                        accuracy,
                        ms_median: ms,
                        command: done.command.clone(),
                        failed: None,
                    });
                }
            }
            Err(reason) => {
                for m in &plan.matchers {
                    rep.matching.push(MatchRow {
                        dataset: d.key(),
                        matcher: m.clone(),
                        accuracy: Default::default(),
                        ms_median: f64::NAN,
                        command: done.command.clone(),
                        failed: Some(reason.clone()),
                    });
                }
            }
        }
    }
    Ok(())
}

type MatchJsonRow = (String, std::collections::BTreeMap<String, f64>, f64);

fn read_match_json(path: &Path) -> anyhow::Result<Vec<MatchJsonRow>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text)?;
    let mut rows = Vec::new();
    for m in v["matchers"].as_array().context("no \"matchers\" array")? {
        let name = m["matcher"].as_str().unwrap_or("?").to_string();
        let acc = m["accuracy"]
            .as_object()
            .map(|o| {
                o.iter()
                    .filter_map(|(k, v)| Some((k.clone(), v.as_f64()?)))
                    .collect()
            })
            .unwrap_or_default();
        rows.push((name, acc, m["ms_median"].as_f64().unwrap_or(f64::NAN)));
    }
    Ok(rows)
}
