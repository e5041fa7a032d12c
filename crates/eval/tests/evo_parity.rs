//! Parity with evo: every statistic and every per-pose error of our APE/RPE must equal what the
//! pinned evo release computes on the same files, within 1e-6 relative.
//!
//! The first run creates a Python virtual environment with `pip install evo==EVO_VERSION` under
//! cargo's per-target temp dir (kept between runs; set `JOINTLOC_EVO_VENV` to use another
//! place). Network access to PyPI is needed once; without it the test fails and says why.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use jointloc_eval::{
    AlignMode, AssociationConfig, DeltaUnit, EvalConfig, EvalReport, PoseRelation, RpeConfig,
    align_estimate, ape, associate, evaluate, rpe, rpe_pairs,
};
use jointloc_geometry::trajectory::Trajectory;
use jointloc_geometry::{CameraToWorld, Sim3};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde_json::{Value, json};

/// The evo release our numbers are checked against.
const EVO_VERSION: &str = "1.38.1";
/// Largest accepted relative difference.
const REL_TOL: f64 = 1e-6;

/// Path of a Python interpreter with evo installed; creates the venv on first use.
fn evo_python() -> &'static Path {
    static PYTHON: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    match PYTHON.get_or_init(setup_venv) {
        Ok(p) => p,
        Err(e) => panic!("evo parity test: could not set up evo {EVO_VERSION}: {e}"),
    }
}

fn setup_venv() -> Result<PathBuf, String> {
    let venv = std::env::var_os("JOINTLOC_EVO_VENV")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("evo-venv-{EVO_VERSION}"))
        });
    let python = venv.join("bin").join("python");
    let marker = venv.join("jointloc-evo-installed");
    if marker.exists() {
        return Ok(python);
    }
    let start = std::time::Instant::now();
    if venv.exists() {
        // A half-made venv from an interrupted run.
        std::fs::remove_dir_all(&venv).map_err(|e| format!("removing {}: {e}", venv.display()))?;
    }
    let run = |cmd: &mut Command, what: &str| -> Result<(), String> {
        let out = cmd
            .output()
            .map_err(|e| format!("{what}: cannot run {cmd:?}: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!(
                "{what} failed ({}):\n{}{}",
                out.status,
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ))
        }
    };
    run(
        Command::new("python3").arg("-m").arg("venv").arg(&venv),
        "python3 -m venv (needs Python 3 with the venv module)",
    )?;
    run(
        Command::new(&python).args([
            "-m",
            "pip",
            "install",
            "--disable-pip-version-check",
            "--no-input",
            "--quiet",
            &format!("evo=={EVO_VERSION}"),
        ]),
        "pip install evo (needs network access to PyPI)",
    )?;
    std::fs::write(&marker, EVO_VERSION).map_err(|e| e.to_string())?;
    eprintln!(
        "evo {EVO_VERSION} venv created at {} in {:.1} s",
        venv.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(python)
}

/// Runs evo on the cases and returns `{name: {"stats": {...}, "errors": [...], ...}}`.
fn run_evo(dir: &Path, cases: &[Value]) -> Value {
    let cases_file = dir.join("cases.json");
    let out_file = dir.join("evo_results.json");
    std::fs::write(&cases_file, serde_json::to_string(cases).unwrap()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/evo_parity.py");
    let out = Command::new(evo_python())
        .arg(&script)
        .arg(&cases_file)
        .arg(&out_file)
        .env("MPLBACKEND", "Agg")
        .output()
        .expect("running the evo parity script");
    assert!(
        out.status.success(),
        "evo parity script failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(&out_file).unwrap()).unwrap()
}

/// A smooth flight: a figure-eight at varying altitude, heading along the path, with gentle
/// roll and pitch, sampled at `rate` Hz from `t0` with a little timestamp jitter.
fn ground_truth(rng: &mut ChaCha8Rng, n: usize, rate: f64, t0: f64) -> Trajectory {
    let jitter = Normal::new(0.0, 0.0005 / rate).unwrap();
    let mut stamps = Vec::with_capacity(n);
    let mut poses = Vec::with_capacity(n);
    for i in 0..n {
        let t = i as f64 / rate;
        let w = 0.05;
        let pos = Vector3::new(
            60.0 * (w * t).sin(),
            35.0 * (2.0 * w * t).sin(),
            80.0 + 6.0 * (0.3 * w * t).sin(),
        );
        let vel = Vector3::new(
            60.0 * w * (w * t).cos(),
            70.0 * w * (2.0 * w * t).cos(),
            0.0,
        );
        let yaw = vel.y.atan2(vel.x);
        let rot =
            UnitQuaternion::from_euler_angles(0.08 * (0.7 * t).sin(), 0.05 * (0.4 * t).cos(), yaw);
        stamps.push(t0 + t + jitter.sample(rng));
        poses.push(CameraToWorld::from_rotation_translation(rot, pos));
    }
    Trajectory::new(stamps, poses).unwrap()
}

/// A noisy, drifting copy of `gt` sampled at every `step`-th pose, mapped by `g` (the estimate
/// lives in its own frame), with the estimate's clock ahead by `clock_offset` seconds and
/// Gaussian timestamp jitter of `stamp_jitter` seconds.
fn estimate_of(
    rng: &mut ChaCha8Rng,
    gt: &Trajectory,
    step: usize,
    g: &Sim3,
    clock_offset: f64,
    stamp_jitter: f64,
) -> Trajectory {
    let jitter = Normal::new(0.0, stamp_jitter).unwrap();
    let pos_noise = Normal::new(0.0, 0.15).unwrap();
    let rot_noise = Normal::new(0.0, 0.6f64.to_radians()).unwrap();
    let drift_step = Normal::new(0.0, 0.05).unwrap();
    let mut drift = Vector3::zeros();
    let mut yaw_drift = 0.0;
    let mut stamps = Vec::new();
    let mut poses = Vec::new();
    for i in (0..gt.len()).step_by(step) {
        drift += Vector3::new(
            drift_step.sample(rng),
            drift_step.sample(rng),
            0.3 * drift_step.sample(rng),
        );
        yaw_drift += 0.0004;
        let p = &gt.poses[i];
        let noise = UnitQuaternion::from_euler_angles(
            rot_noise.sample(rng),
            rot_noise.sample(rng),
            rot_noise.sample(rng) + yaw_drift,
        );
        let noisy = CameraToWorld::from_rotation_translation(
            p.rotation() * noise,
            p.translation()
                + drift
                + Vector3::new(
                    pos_noise.sample(rng),
                    pos_noise.sample(rng),
                    pos_noise.sample(rng),
                ),
        );
        stamps.push(gt.timestamps[i] + clock_offset + jitter.sample(rng));
        poses.push(g.inverse().transform_pose(&noisy));
    }
    Trajectory::new(stamps, poses).unwrap()
}

/// Writes EuRoC ground truth (integer nanoseconds, qw first) as the EuRoC MAV dataset does.
fn write_euroc(traj: &Trajectory, path: &Path) {
    let mut text = String::from(
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], \
         q_RS_z [], v_RS_R_x [m s^-1]\n",
    );
    for (t, pose) in traj.timestamps.iter().zip(&traj.poses) {
        let (p, q) = pose.to_translation_quaternion();
        let ns = (t * 1e9).round() as i64;
        text.push_str(&format!(
            "{ns},{},{},{},{},{},{},{},0.0\n",
            p[0], p[1], p[2], q[3], q[0], q[1], q[2]
        ));
    }
    std::fs::write(path, text).unwrap();
}

/// One evaluation set-up, run through our library and through evo's CLI code.
struct Case {
    name: &'static str,
    /// evo's sub-command and file arguments, e.g. `["tum", ref, est]`.
    files: Vec<String>,
    reference: Trajectory,
    estimate: Trajectory,
    config: EvalConfig,
}

impl Case {
    /// evo flags for alignment, association and RPE pairing equivalent to `self.config`.
    fn evo_flags(&self, tool: &str) -> Vec<String> {
        let c = &self.config;
        let mut flags: Vec<String> = match c.align {
            AlignMode::None => vec![],
            AlignMode::Se3 => vec!["-a".into()],
            AlignMode::Sim3 => vec!["-a".into(), "-s".into()],
            AlignMode::Scale => vec!["-s".into()],
            AlignMode::Origin => vec!["--align_origin".into()],
        };
        flags.extend([
            "--t_max_diff".into(),
            c.association.max_diff.to_string(),
            format!("--t_offset={}", c.association.offset),
        ]);
        if let Some(n) = c.n_to_align {
            flags.extend(["--n_to_align".into(), n.to_string()]);
        }
        if tool == "rpe" {
            flags.extend([
                "--delta".into(),
                c.rpe.delta.to_string(),
                "--delta_unit".into(),
                match c.rpe.unit {
                    DeltaUnit::Frames => "f".into(),
                    DeltaUnit::Meters => "m".into(),
                },
                "--delta_tol".into(),
                c.rpe.rel_delta_tol.to_string(),
            ]);
            if c.rpe.all_pairs {
                flags.push("--all_pairs".into());
            }
        }
        flags
    }
}

fn relation_flag(r: PoseRelation) -> &'static str {
    match r {
        PoseRelation::TranslationPart => "trans_part",
        PoseRelation::RotationAngleDeg => "angle_deg",
        PoseRelation::RotationAngleRad => "angle_rad",
        PoseRelation::RotationPart => "rot_part",
        PoseRelation::FullTransformation => "full",
    }
}

/// Our errors for one tool and relation, computed through the public API.
fn our_errors(case: &Case, report: &EvalReport, tool: &str, relation: PoseRelation) -> Vec<f64> {
    match (tool, relation) {
        ("ape", PoseRelation::TranslationPart) => report.ape_translation.errors.clone(),
        ("ape", PoseRelation::RotationAngleDeg) => report.ape_rotation.errors.clone(),
        ("rpe", PoseRelation::TranslationPart) => report.rpe_translation.errors.clone(),
        ("rpe", PoseRelation::RotationAngleDeg) => report.rpe_rotation.errors.clone(),
        _ => {
            // Other relations through the building blocks, as a library user would.
            let assoc =
                associate(&case.reference, &case.estimate, &case.config.association).unwrap();
            let aligned = align_estimate(
                &assoc.reference,
                &assoc.estimate,
                case.config.align,
                case.config.n_to_align,
            )
            .unwrap();
            if tool == "ape" {
                ape(&assoc.reference, &aligned.estimate, relation).unwrap()
            } else {
                let pairs = rpe_pairs(&aligned.estimate.poses, &case.config.rpe).unwrap();
                rpe(&assoc.reference, &aligned.estimate, &pairs, relation).unwrap()
            }
        }
    }
}

fn rel_diff(a: f64, b: f64) -> f64 {
    let scale = a.abs().max(b.abs());
    if scale < 1e-12 {
        0.0
    } else {
        (a - b).abs() / scale
    }
}

#[test]
fn ape_and_rpe_match_evo_on_generated_trajectories() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_string_lossy().into_owned();
    let mut cases = Vec::new();

    // 1. Same rate and frame, no alignment, RPE every frame.
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let gt = ground_truth(&mut rng, 400, 10.0, 1_700_000_000.0);
    let est = estimate_of(&mut rng, &gt, 1, &Sim3::identity(), 0.0, 0.0);
    cases.push(Case {
        name: "none",
        files: vec![],
        reference: gt,
        estimate: est,
        config: EvalConfig::default(),
    });

    // 2. Estimate in a rotated, shifted frame: SE(3) alignment (`-a`), RPE every 10 frames.
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let gt = ground_truth(&mut rng, 300, 10.0, 500.0);
    let g = Sim3::new(
        1.0,
        UnitQuaternion::from_euler_angles(0.2, -0.1, 2.4),
        Vector3::new(-30.0, 12.0, 4.0),
    );
    let est = estimate_of(&mut rng, &gt, 1, &g, 0.0, 0.0);
    cases.push(Case {
        name: "se3",
        files: vec![],
        reference: gt,
        estimate: est,
        config: EvalConfig {
            align: AlignMode::Se3,
            rpe: RpeConfig {
                delta: 10.0,
                ..Default::default()
            },
            ..Default::default()
        },
    });

    // 3. Monocular-like: unknown scale, Sim(3) alignment (`-as`), RPE every 8 m of path.
    let mut rng = ChaCha8Rng::seed_from_u64(33);
    let gt = ground_truth(&mut rng, 300, 10.0, 0.0);
    let g = Sim3::new(
        2.7,
        UnitQuaternion::from_euler_angles(-0.4, 0.3, -1.1),
        Vector3::new(5.0, -60.0, 20.0),
    );
    let est = estimate_of(&mut rng, &gt, 1, &g, 0.0, 0.0);
    cases.push(Case {
        name: "sim3_metres",
        files: vec![],
        reference: gt,
        estimate: est,
        config: EvalConfig {
            align: AlignMode::Sim3,
            rpe: RpeConfig {
                delta: 8.0,
                unit: DeltaUnit::Meters,
                ..Default::default()
            },
            ..Default::default()
        },
    });

    // 4. Association: ground truth at 20 Hz, estimate at ~6.7 Hz with a clock 0.75 s ahead,
    //    Sim(3), RPE over 3 frames with all pairs.
    let mut rng = ChaCha8Rng::seed_from_u64(44);
    let gt = ground_truth(&mut rng, 1200, 20.0, 100.0);
    let g = Sim3::new(
        0.4,
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7),
        Vector3::new(1.0, 2.0, 3.0),
    );
    let est = estimate_of(&mut rng, &gt, 3, &g, 0.75, 0.008);
    // A 3 s gap in the ground truth leaves some estimate poses without partner.
    let kept: Vec<usize> = (0..gt.len()).filter(|i| !(600..660).contains(i)).collect();
    cases.push(Case {
        name: "assoc_sim3",
        files: vec![],
        reference: gt.select(&kept),
        estimate: est,
        config: EvalConfig {
            association: AssociationConfig {
                max_diff: 0.02,
                offset: -0.75,
            },
            align: AlignMode::Sim3,
            rpe: RpeConfig {
                delta: 3.0,
                all_pairs: true,
                ..Default::default()
            },
            ..Default::default()
        },
    });

    // 5. EuRoC ground truth (ns, qw first) vs a sparser TUM estimate, SE(3) fitted on the
    //    first 100 poses only, RPE every 5 m with all pairs.
    let mut rng = ChaCha8Rng::seed_from_u64(55);
    let gt = ground_truth(&mut rng, 800, 20.0, 1_403_636_579.0);
    let est = estimate_of(&mut rng, &gt, 2, &Sim3::identity(), 0.0, 0.0);
    cases.push(Case {
        name: "euroc_se3_n",
        files: vec!["euroc".into(), path("euroc_gt.csv"), path("euroc_est.txt")],
        reference: gt,
        estimate: est,
        config: EvalConfig {
            align: AlignMode::Se3,
            n_to_align: Some(100),
            rpe: RpeConfig {
                delta: 5.0,
                unit: DeltaUnit::Meters,
                all_pairs: true,
                ..Default::default()
            },
            ..Default::default()
        },
    });

    // 6. The estimate is the denser one (40 Hz against 10 Hz ground truth; association starts
    //    from the reference then) and its clock is 0.3 s behind.
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let dense = ground_truth(&mut rng, 1600, 40.0, 2000.0);
    let est = estimate_of(&mut rng, &dense, 1, &Sim3::identity(), -0.3, 0.003);
    let sparse: Vec<usize> = (0..dense.len()).step_by(4).collect();
    cases.push(Case {
        name: "assoc_denser_estimate",
        files: vec![],
        reference: dense.select(&sparse),
        estimate: est,
        config: EvalConfig {
            association: AssociationConfig {
                max_diff: 0.01,
                offset: 0.3,
            },
            rpe: RpeConfig {
                delta: 2.0,
                unit: DeltaUnit::Meters,
                ..Default::default()
            },
            ..Default::default()
        },
    });

    // 7. Origin alignment and scale-only correction.
    let mut rng = ChaCha8Rng::seed_from_u64(66);
    let gt = ground_truth(&mut rng, 200, 10.0, 10.0);
    let est = estimate_of(&mut rng, &gt, 1, &Sim3::identity(), 0.0, 0.0);
    cases.push(Case {
        name: "origin",
        files: vec![],
        reference: gt.clone(),
        estimate: est.clone(),
        config: EvalConfig {
            align: AlignMode::Origin,
            ..Default::default()
        },
    });
    let g = Sim3::new(1.6, UnitQuaternion::identity(), Vector3::zeros());
    let est = estimate_of(&mut rng, &gt, 1, &g, 0.0, 0.0);
    cases.push(Case {
        name: "scale_only",
        files: vec![],
        reference: gt,
        estimate: est,
        config: EvalConfig {
            align: AlignMode::Scale,
            ..Default::default()
        },
    });

    // Write the files: our TUM writer feeds evo's reader; EuRoC ground truth goes through
    // the file on both sides.
    for case in &mut cases {
        if case.files.is_empty() {
            let (r, e) = (
                path(&format!("{}_gt.txt", case.name)),
                path(&format!("{}_est.txt", case.name)),
            );
            case.reference.write_tum(&r).unwrap();
            case.estimate.write_tum(&e).unwrap();
            case.files = vec!["tum".into(), r, e];
        } else {
            write_euroc(&case.reference, Path::new(&case.files[1]));
            case.estimate.write_tum(&case.files[2]).unwrap();
            case.reference = Trajectory::read_euroc(&case.files[1]).unwrap();
        }
    }

    let relations = [
        PoseRelation::TranslationPart,
        PoseRelation::RotationAngleDeg,
        PoseRelation::FullTransformation,
    ];
    let mut evo_cases = Vec::new();
    for case in &cases {
        for tool in ["ape", "rpe"] {
            for relation in relations {
                let mut argv = case.files.clone();
                argv.extend(case.evo_flags(tool));
                argv.extend(["-r".into(), relation_flag(relation).into()]);
                evo_cases.push(json!({
                    "name": format!("{}/{tool}/{}", case.name, relation_flag(relation)),
                    "tool": tool,
                    "argv": argv,
                }));
            }
        }
    }
    let evo = run_evo(dir.path(), &evo_cases);

    let mut worst = (0.0, String::new());
    for case in &cases {
        let report = evaluate(&case.reference, &case.estimate, &case.config)
            .unwrap_or_else(|e| panic!("{}: {e}", case.name));
        for tool in ["ape", "rpe"] {
            for relation in relations {
                let key = format!("{}/{tool}/{}", case.name, relation_flag(relation));
                let theirs = &evo[&key];
                let ours = our_errors(case, &report, tool, relation);
                let their_errors: Vec<f64> = theirs["errors"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                assert_eq!(ours.len(), their_errors.len(), "{key}: number of errors");
                for (i, (a, b)) in ours.iter().zip(&their_errors).enumerate() {
                    let d = rel_diff(*a, *b);
                    assert!(
                        d <= REL_TOL,
                        "{key}: error {i}: ours {a} evo {b} (rel {d:e})"
                    );
                    if d > worst.0 {
                        worst = (d, format!("{key} error[{i}]"));
                    }
                }
                let stats = jointloc_eval::Statistics::from_errors(&ours).unwrap();
                let our_stats = [
                    ("rmse", stats.rmse),
                    ("mean", stats.mean),
                    ("median", stats.median),
                    ("std", stats.std),
                    ("min", stats.min),
                    ("max", stats.max),
                    ("sse", stats.sse),
                ];
                for (name, ours) in our_stats {
                    let evo_value = theirs["stats"][name].as_f64().unwrap();
                    let d = rel_diff(ours, evo_value);
                    assert!(
                        d <= REL_TOL,
                        "{key}: {name}: ours {ours} evo {evo_value} (rel {d:e})"
                    );
                    if d > worst.0 {
                        worst = (d, format!("{key} {name}"));
                    }
                }
                if tool == "ape" && relation == PoseRelation::TranslationPart {
                    assert_eq!(report.associated_poses, their_errors.len(), "{key}");
                    if let (Some(info), Some(m)) = (&report.alignment, theirs.get("alignment")) {
                        // evo stores [sR t; 0 1]: compare the scale and translation.
                        let row = |i: usize| -> Vec<f64> {
                            m[i].as_array()
                                .unwrap()
                                .iter()
                                .map(|v| v.as_f64().unwrap())
                                .collect()
                        };
                        let r0 = row(0);
                        let (r1, r2) = (row(1), row(2));
                        let det = r0[0] * (r1[1] * r2[2] - r1[2] * r2[1])
                            - r0[1] * (r1[0] * r2[2] - r1[2] * r2[0])
                            + r0[2] * (r1[0] * r2[1] - r1[1] * r2[0]);
                        let d = rel_diff(info.scale, det.cbrt());
                        assert!(
                            d <= REL_TOL,
                            "{key}: scale ours {} evo {}",
                            info.scale,
                            det.cbrt()
                        );
                        // With scale-only correction evo still reports the full Umeyama
                        // transform, of which only the scale was applied.
                        let rows = if info.mode == AlignMode::Scale {
                            vec![]
                        } else {
                            vec![r0, r1, r2]
                        };
                        for (k, r) in rows.iter().enumerate() {
                            assert!(
                                (info.translation[k] - r[3]).abs() <= 1e-6 * (1.0 + r[3].abs()),
                                "{key}: translation"
                            );
                        }
                    }
                }
            }
        }
        eprintln!(
            "{}: {} associated poses, APE rmse {:.4} m, RPE rmse {:.4} m, scale {:?}",
            case.name,
            report.associated_poses,
            report.ape_translation.stats.rmse,
            report.rpe_translation.stats.rmse,
            report.alignment.map(|a| a.scale)
        );
    }
    eprintln!(
        "largest relative difference to evo {EVO_VERSION}: {:e} ({})",
        worst.0, worst.1
    );
}
