//! The settings of `jointloc run`: the `--config` file, then the flags over it, validated
//! with the file named in the error.

use anyhow::{Context, bail};
use jointloc_system::JointLocConfig;

use super::Args;

pub(super) fn settings(args: &Args) -> anyhow::Result<JointLocConfig> {
    let mut config: JointLocConfig = match &args.config {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            toml::from_str(&text).with_context(|| format!("parsing {}", p.display()))?
        }
        None => JointLocConfig::default(),
    };
    if let Some(m) = &args.matcher {
        config.matcher = m.clone();
    }
    if let Some(k) = args.fusion_every {
        config.fusion_every = k;
    }
    if let Some(c) = args.confidence {
        config.absloc.confidence = c;
    }
    if let Some(f) = args.wrong_fixes {
        config.faults.wrong_fix_fraction = f;
    }
    if let Some(o) = &args.outage {
        let (start, duration) = number_pair(o, ':')
            .with_context(|| format!("--outage {o}: expected START:DURATION in seconds"))?;
        config.faults.outage_start_s = Some(start);
        config.faults.outage_duration_s = duration;
    }
    if let Some(b) = &args.blind {
        let (start, duration) = number_pair(b, ':')
            .with_context(|| format!("--blind {b}: expected START:DURATION in seconds"))?;
        config.faults.blind_start_s = Some(start);
        config.faults.blind_duration_s = duration;
    }
    if let Some(p) = &args.start {
        let (x, y) =
            number_pair(p, ',').with_context(|| format!("--start {p}: expected X,Y in metres"))?;
        config.start_position = Some([x, y]);
    }
    if let Some(dataset) = &args.dataset {
        crate::flight_sun::resolve(
            args.flight_sun.as_deref(),
            &mut config.absloc.relight.flight_sun,
            dataset,
        )?;
    }
    if let Some(speed) = args.realtime
        && !(speed.is_finite() && speed > 0.0)
    {
        bail!("--realtime {speed}: the replay speed must be a positive number");
    }
    config.validate().with_context(|| match &args.config {
        Some(p) => format!("invalid settings in {} or on the command line", p.display()),
        None => "invalid settings on the command line".to_string(),
    })?;
    Ok(config)
}

/// Two numbers separated by `separator` (`"60:30"`, `"36.5,-41"`).
fn number_pair(text: &str, separator: char) -> Option<(f64, f64)> {
    let (a, b) = text.split_once(separator)?;
    Some((a.trim().parse().ok()?, b.trim().parse().ok()?))
}

/// The CRS of the dataset's map, for `--out-crs map`.
pub(super) fn map_crs(dataset: &std::path::Path) -> anyhow::Result<jointloc_formats::MapCrs> {
    let path = dataset.join("map.toml");
    let map = jointloc_formats::MapInfo::read(&path)?;
    map.crs.ok_or_else(|| {
        anyhow::anyhow!(
            "{}: no [crs] section, so --out-crs map has no map coordinates to use (import the \
             map from GeoTIFF with `jointloc map import`, or use --out-crs local)",
            path.display()
        )
    })
}
