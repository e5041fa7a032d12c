//! What `jointloc run` prints at the end, and the evaluation against the dataset's ground
//! truth (world frame, no alignment) that it adds to `summary.json`.

use std::path::Path;

use jointloc_eval::{AlignMode, EvalConfig, evaluate};
use jointloc_geometry::trajectory::{Trajectory, TumOptions};
use jointloc_system::Outputs;

/// The run's figures, one line per subject.
pub(super) fn print(outputs: &Outputs) {
    let s = &outputs.summary;
    let t = &outputs.timing;
    println!(
        "{} frames ({:.1} Hz, {}); {} lost; {} new maps after losses, {} merged back ({} at the end); {} loops closed; geo-referenced from frame {}; {} world poses written",
        s.frames,
        s.hz,
        s.mode,
        s.lost,
        s.new_maps,
        s.maps_merged,
        s.maps_at_end,
        s.loops_closed,
        s.geo_referenced_from
            .map_or("-".into(), |i: usize| i.to_string()),
        s.world_poses
    );
    if let Some(r) = &s.realtime {
        println!(
            "real-time replay at {}× the camera rate: capacity {:.1} Hz; lag behind the \
             camera median {:.1} ms, max {:.1} ms; {} of {} frames due before the previous one was done",
            r.speed, s.capacity_hz, r.lag_median_ms, r.lag_max_ms, r.frames_late, s.frames
        );
    }
    println!(
        "fixes: {} attempts, {} found, {} used, {} inliers of the final alignment; \
         {} skipped (thread busy), {} skipped (not tracked yet), {} skipped (outage), \
         {} skipped (backing off before the first fix), \
         {} made wrong on purpose; {} through virtual frames, {} without one",
        s.absolute_attempts,
        s.fixes_found,
        s.fixes_used,
        s.fixes_inliers,
        s.skipped_busy,
        s.skipped_untracked,
        s.skipped_outage,
        s.skipped_backoff,
        s.fixes_injected_wrong,
        s.virtual_frames,
        s.skipped_no_view
    );
    let terrain = &s.terrain_correction;
    if terrain.updates > 0 {
        println!(
            "terrain correction of the fixes: ({:+.3}, {:+.3}) m after {} estimates",
            terrain.x, terrain.y, terrain.updates
        );
    }
    if let Some(t) = &s.camera_tilt {
        println!(
            "camera tilt off nadir: ({:+.2}, {:+.2})° about image (x, y), ({:+.2}, {:+.2})° used",
            t.estimated_deg[0], t.estimated_deg[1], t.used_deg[0], t.used_deg[1]
        );
    }
    if let Some(b) = &s.final_ba {
        println!(
            "final global BA: {} keyframes, {} points, {} fix factors ({} left out: wrong, or \
             their keyframe retired), {} ground factors; {} iterations, {:.0} ms",
            b.keyframes,
            b.points,
            b.global_factors,
            b.factors_left_out,
            b.ground_factors,
            b.iterations,
            b.ms
        );
    }
    println!(
        "median ms: absolute localisation {:.1}, ORB {:.1}, tracking {:.1}, local mapping {:.1}, local BA {:.1}",
        t.absolute_localisation_ms,
        t.orb_extraction_ms,
        t.tracking_ms,
        t.local_mapping_ms,
        t.local_ba_ms
    );
}

/// APE of the written trajectories against `dataset/uav/gt.txt`, when it exists, printed and
/// added to the summary (read back from the files, as evo would read them).
pub(super) fn evaluate_against_ground_truth(
    dataset: &Path,
    out: &Path,
    outputs: &mut Outputs,
) -> anyhow::Result<()> {
    let gt_path = dataset.join("uav/gt.txt");
    if !gt_path.exists() || outputs.summary.world_poses < 3 {
        return Ok(());
    }
    let mut gt = Trajectory::read_tum(&gt_path, &TumOptions::default())?;
    // Local ground truth against outputs in the map's CRS: shifted the same way.
    if let Some(crs) = &outputs.summary.output_crs {
        let shift = nalgebra::Vector3::new(crs.easting_m, crs.northing_m, 0.0);
        gt.poses.iter_mut().for_each(|p| *p = p.translated(shift));
    }
    let no_alignment = EvalConfig {
        align: AlignMode::None,
        ..Default::default()
    };
    let files = [
        (
            "trajectory.tum",
            "ape_translation",
            "APE (world frame, no alignment",
        ),
        (
            "trajectory-final.tum",
            "ape_translation_final",
            "APE of trajectory-final.tum (as known at the end",
        ),
    ];
    for (file, key, label) in files {
        let path = out.join(file);
        if !path.exists() {
            continue;
        }
        let est = Trajectory::read_tum(&path, &TumOptions::default())?;
        if est.len() < 3 {
            continue;
        }
        let report = evaluate(&gt, &est, &no_alignment)?;
        let st = report.ape_translation.stats;
        println!(
            "{label}, {} poses): rmse {:.3} m, mean {:.3}, median {:.3}, std {:.3}, max {:.3}",
            report.associated_poses, st.rmse, st.mean, st.median, st.std, st.max
        );
        outputs
            .summary
            .evaluation
            .insert(key.to_string(), serde_json::to_value(st)?);
    }
    outputs.write_summary(out)?;
    Ok(())
}
