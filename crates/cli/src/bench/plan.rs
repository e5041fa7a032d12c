//! The command line of `jointloc bench` and the plan it stands for once defaults are filled
//! in: which seeds, terrains, difficulties, matchers and tables.

use std::path::PathBuf;

use anyhow::bail;

const ALL_MATCHERS: [&str; 6] = [
    "orb",
    "xfeat-mnn",
    "xfeat-lighterglue",
    "aliked-lightglue",
    "disk-lightglue",
    "superpoint-mnn",
];

/// Tables `--tables` accepts; the envelope's 2 km maps make it opt-in.
const TABLES: [&str; 6] = [
    "matching",
    "localisation",
    "fusion",
    "area",
    "confidence",
    "envelope",
];
/// Tables run by default.
const DEFAULT_TABLES: [&str; 5] = ["matching", "localisation", "fusion", "area", "confidence"];

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output folder: report.md, report.json, figures/, logs/ (and datasets/ unless --datasets).
    #[arg(long)]
    pub(super) out: PathBuf,
    /// Short protocol for a first look (≤ 20 min on 2 cores): one seed, 60 m flights, easy only,
    /// the three fastest matchers in the matching table. Ablations are on the first terrain and
    /// difficulty in both protocols.
    #[arg(long)]
    quick: bool,
    /// Seeds per terrain and difficulty (default 3; 1 with --quick).
    #[arg(long, value_name = "N")]
    seeds: Option<u64>,
    /// First dataset seed (seeds are consecutive from it).
    #[arg(long, value_name = "S", default_value_t = 201)]
    first_seed: u64,
    /// Terrains, comma separated.
    #[arg(long, value_delimiter = ',', default_values_t = ["crater".to_string(), "gravel".to_string(), "mountain".to_string()])]
    terrains: Vec<String>,
    /// Difficulties, comma separated (default easy,medium; easy with --quick).
    #[arg(long, value_delimiter = ',')]
    difficulty: Option<Vec<String>>,
    /// Flight length in metres (default 150; 60 with --quick).
    #[arg(long, value_name = "M")]
    length_m: Option<f64>,
    /// Where datasets are generated, or reused when already there (default OUT/datasets).
    #[arg(long, value_name = "DIR")]
    pub(super) datasets: Option<PathBuf>,
    /// Matchers of the matching table, comma separated (default all six; with --quick orb,
    /// xfeat-mnn, xfeat-lighterglue).
    #[arg(long, value_delimiter = ',')]
    matchers: Option<Vec<String>>,
    /// Matcher of the JointLoc and absolute-only rows.
    #[arg(long, value_name = "M", default_value = "xfeat-lighterglue")]
    matcher: String,
    /// Absolute-only rows localise every K-th frame (the frames JointLoc fuses; the paper's
    /// baseline localises every frame, which gives the same error statistics at 10× the time).
    #[arg(long, value_name = "K", default_value_t = 10)]
    abs_every: usize,
    /// Image pairs per dataset in the matching table (so 10 × seeds per terrain and
    /// difficulty).
    #[arg(long, value_name = "N", default_value_t = 10)]
    pairs: usize,
    /// The real-time rows replay each flight at this multiple of its camera rate (`jointloc
    /// run --realtime S`); above 1 the absolute thread has less time per fix than in flight.
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    replay_speed: f64,
    /// Tables to produce, comma separated: matching, localisation, fusion, area, confidence
    /// (module timing and figures come with localisation), and envelope (not by default: the
    /// HiRISE-class preset at each altitude × sun change, see the `--envelope-*` options).
    #[arg(long, value_delimiter = ',', default_values_t = DEFAULT_TABLES.map(String::from))]
    tables: Vec<String>,
    /// Envelope table: flight altitudes, metres, comma separated.
    #[arg(long, value_delimiter = ',', value_name = "M", default_values_t = [10.0, 50.0, 100.0, 200.0])]
    envelope_altitudes: Vec<f64>,
    /// Envelope table: changes of the sun's azimuth between map and flight, degrees (0–180).
    #[arg(long, value_delimiter = ',', value_name = "DEG", default_values_t = [30.0, 90.0, 180.0])]
    envelope_sun_changes: Vec<f64>,
    /// Envelope table: side of the HiRISE-class map, metres (default 2000, the preset's; 500
    /// with --quick).
    #[arg(long, value_name = "M")]
    envelope_map_size_m: Option<f64>,
    /// An external trajectory to put beside ours, as `NAME=PATTERN`: the TUM file of each
    /// dataset, `{dataset}` standing for its name (`crater-easy-s201`), e.g.
    /// `orbslam3=runs/orbslam3/{dataset}.tum`. Sim(3)-aligned like the VO rows. Repeatable.
    #[arg(long, value_name = "NAME=PATTERN")]
    peer: Vec<String>,
    /// Replace an existing report in OUT.
    #[arg(long)]
    pub(super) force: bool,
    /// Go on with an interrupted (or extended) benchmark in OUT: runs that finished there
    /// before, with the same executable and command line (OUT/runs/journal.jsonl), are not
    /// repeated; their outputs are read again. Replaces the report.
    #[arg(long)]
    pub(super) resume: bool,
}

/// What to run, after defaults.
#[derive(Debug, Clone)]
pub(super) struct Plan {
    pub(super) quick: bool,
    pub(super) seeds: Vec<u64>,
    pub(super) terrains: Vec<String>,
    pub(super) difficulties: Vec<String>,
    pub(super) length_m: f64,
    pub(super) matchers: Vec<String>,
    pub(super) matcher: String,
    pub(super) pairs: usize,
    /// Absolute-only: localise every K-th frame.
    pub(super) abs_every: usize,
    /// Real-time rows: replay speed, × the camera rate.
    pub(super) replay_speed: f64,
    pub(super) tables: Vec<String>,
    /// External trajectories: (name, file pattern with `{dataset}`).
    pub(super) peers: Vec<(String, String)>,
    pub(super) envelope: EnvelopePlan,
}

/// The flights of the envelope table: every altitude × sun change, per terrain and seed.
#[derive(Debug, Clone)]
pub(super) struct EnvelopePlan {
    pub(super) altitudes_m: Vec<f64>,
    pub(super) sun_changes_deg: Vec<f64>,
    pub(super) map_size_m: f64,
}

impl Plan {
    pub(super) fn wants(&self, table: &str) -> bool {
        self.tables.iter().any(|t| t == table)
    }
}

impl Plan {
    pub(super) fn from_args(a: &Args) -> anyhow::Result<Self> {
        let seeds = a.seeds.unwrap_or(if a.quick { 1 } else { 3 });
        if seeds == 0 {
            bail!("--seeds must be at least 1");
        }
        if a.abs_every == 0 {
            bail!("--abs-every must be at least 1");
        }
        if a.pairs == 0 {
            bail!("--pairs must be at least 1");
        }
        if !(a.replay_speed.is_finite() && a.replay_speed > 0.0) {
            bail!("--replay-speed must be a positive number");
        }
        let difficulties = a.difficulty.clone().unwrap_or_else(|| {
            if a.quick {
                vec!["easy".into()]
            } else {
                vec!["easy".into(), "medium".into()]
            }
        });
        let matchers = a.matchers.clone().unwrap_or_else(|| {
            let n = if a.quick { 3 } else { ALL_MATCHERS.len() };
            ALL_MATCHERS[..n].iter().map(|s| s.to_string()).collect()
        });
        for t in &a.terrains {
            if !["crater", "gravel", "mountain"].contains(&t.as_str()) {
                bail!("unknown terrain {t:?} (crater, gravel, mountain)");
            }
        }
        for d in &difficulties {
            if !["easy", "medium", "hard"].contains(&d.as_str()) {
                bail!("unknown difficulty {d:?} (easy, medium, hard)");
            }
        }
        for t in &a.tables {
            if !TABLES.contains(&t.as_str()) {
                bail!("unknown table {t:?} ({})", TABLES.join(", "));
            }
        }
        let mut peers = Vec::new();
        for p in &a.peer {
            let Some((name, pattern)) = p.split_once('=') else {
                bail!("--peer {p:?}: expected NAME=PATTERN, e.g. orbslam3=runs/{{dataset}}.tum");
            };
            if name.trim().is_empty() || !pattern.contains("{dataset}") {
                bail!(
                    "--peer {p:?}: needs a name and a file pattern with {{dataset}} (one file per dataset)"
                );
            }
            peers.push((name.trim().to_string(), pattern.to_string()));
        }
        let envelope = EnvelopePlan {
            altitudes_m: a.envelope_altitudes.clone(),
            sun_changes_deg: a.envelope_sun_changes.clone(),
            map_size_m: a
                .envelope_map_size_m
                .unwrap_or(if a.quick { 500.0 } else { 2000.0 }),
        };
        // The simulator states its own limits; these are the ones that would only show up
        // after the other tables have run.
        if envelope
            .altitudes_m
            .iter()
            .any(|v| !(v.is_finite() && *v > 0.0))
        {
            bail!("--envelope-altitudes must be positive numbers");
        }
        if (envelope.sun_changes_deg.iter()).any(|v| !(0.0..=180.0).contains(v)) {
            bail!("--envelope-sun-changes must lie in 0–180 degrees");
        }
        if !(envelope.map_size_m.is_finite() && envelope.map_size_m > 0.0) {
            bail!("--envelope-map-size-m must be a positive number");
        }
        let length_m = a.length_m.unwrap_or(if a.quick { 60.0 } else { 150.0 });
        if !(length_m.is_finite() && length_m >= 20.0) {
            bail!("--length-m must be at least 20");
        }
        Ok(Self {
            quick: a.quick,
            seeds: (a.first_seed..a.first_seed + seeds).collect(),
            terrains: a.terrains.clone(),
            difficulties,
            length_m,
            matchers,
            matcher: a.matcher.clone(),
            pairs: a.pairs,
            abs_every: a.abs_every,
            replay_speed: a.replay_speed,
            tables: a.tables.clone(),
            peers,
            envelope,
        })
    }
}

pub(super) fn plan_summary(p: &Plan) -> String {
    // The envelope's flights are the HiRISE-class preset whatever `--difficulties` says.
    let difficulty = match (p.wants("envelope"), p.tables.len()) {
        (true, 1) => "mars (the envelope's preset)".to_string(),
        (true, _) => format!("{} (envelope: mars)", p.difficulties.join(", ")),
        _ => p.difficulties.join(", "),
    };
    format!(
        "{}: terrains {}, difficulty {}, seeds {:?}, {} m flights, {} pairs per dataset, JointLoc/absolute matcher {}",
        if p.quick {
            "quick protocol"
        } else {
            "full protocol"
        },
        p.terrains.join(", "),
        difficulty,
        p.seeds,
        p.length_m,
        p.pairs,
        p.matcher
    )
}
