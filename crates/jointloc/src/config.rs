//! Settings of the fused system.

use crate::virtual_frames::MosaicConfig;
use jointloc_absloc::AbsLocConfig;
use jointloc_slam::system::SystemConfig;
use serde::{Deserialize, Serialize};

use crate::error::{JointLocError, Result};
use crate::faults::FaultConfig;
use crate::final_ba::FinalBaConfig;
use crate::terrain_shift::TerrainConfig;

/// JointLoc settings; the SLAM and absolute-localisation settings are nested.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct JointLocConfig {
    /// Matcher of the absolute localisation, by name (`jointloc match --list`): the
    /// detector + matcher pair whose fixes the fusion uses.
    pub matcher: String,
    /// Every k-th frame goes to absolute localisation. The paper's fusion frequency is 10;
    /// 5 (a fix a second at 5 Hz; the alignment's window, then 40 s, held 40) measured
    /// 0.073 → 0.063 m online and 0.047 → 0.044 m at the end on 18 held-out flights, at one
    /// predicted-window search (60–80 ms) more per 10 frames (`docs/jointloc.md` §"A fix
    /// every 5th frame").
    pub fusion_every: usize,
    /// Fixes with a lower confidence are not used (a failed search has w = 0).
    pub min_confidence: f64,
    /// SLAM→world alignment: consistent fixes needed before poses are geo-referenced. Two
    /// always agree (a similarity fits any two), so with 2 one wrong fix at the start makes a
    /// wrong alignment; from 3 on, a wrong fix is out-voted.
    pub min_fixes: usize,
    /// Alignment RANSAC inlier threshold, metres (world frame).
    pub inlier_threshold_m: f64,
    /// The alignment's inliers are then reweighted (Cauchy) on their horizontal residuals,
    /// at a scale of 3 robust σ of the residuals but at least this many metres; 0: off. It
    /// takes four fifths of the weight from an inlier fix a metre off while the others agree
    /// to a decimetre, which matters while an alignment rests on few fixes. 0.5 m: at 0.2 m it
    /// also took weight from the newest fixes where the SLAM's drift bends the window, and
    /// the output after the first 10 s of geo-referencing was worse (`docs/jointloc.md` §"A
    /// robust alignment and a slower terrain correction").
    pub alignment_robust_floor_m: f64,
    /// Alignment RANSAC hypotheses.
    pub ransac_iterations: usize,
    /// Weight, relative to the fix's, of the nadir prior that pairs the point under each fix's
    /// camera (along its optical axis, at the altimeter range) with the map point: it fixes the
    /// roll about a straight track, which positions alone leave free.
    pub nadir_weight: f64,
    /// Local BA: each fix also pulls its camera onto the point above the fix at the altimeter
    /// reading (a nadir view), with σ this many times `global_sigma`; 0: off. The camera's true
    /// tilt makes that point wrong by altitude × tilt (9 cm at 10 m and 0.5°), but the jitter
    /// is fast and zero-mean, while the SLAM's own tilt drifts slowly (0.5° rms on
    /// crater-easy-s101): 0.25 measured best of 0 / 0.25 / 0.5 / 1 / 2 (`docs/jointloc.md`
    /// §"Tilt").
    pub nadir_sigma_scale: f64,
    /// The nadir pairs of the fixes in the alignment's window assume that the camera looks
    /// down on average over **every tracked frame** within this many seconds of each fix,
    /// not at the fix's own frame: each pair's camera is moved by the range × its frame's
    /// optical axis off the mean axis of those frames (both through the alignment; the SLAM
    /// knows these differences well over a few seconds, and the alignment's own tilt cancels
    /// in them). With a fix every 10th frame (2 s) the attitude's wobble (periods of 1.5–8 s
    /// in the simulator) sampled at the fixes alone aliases into slow errors that the window
    /// does not average out: 0.63–1.08 m online at 200 m against 0.27–0.32 m at a fix every
    /// 5th frame (`docs/jointloc.md` §"200 m at a fix every 10th frame"). Over the whole
    /// window instead, the SLAM's own slow tilt drift entered the pairs. 0: off (each pair
    /// assumes it at its own frame).
    pub nadir_mean_window_s: f64,
    /// The nadir pairs put the camera where it looks at its fix from, at the camera's mean
    /// tilt off nadir as the fused attitudes show it, instead of straight above the fix: a
    /// body-fixed camera on a UAV pitched to cruise, or mounted off nadir, no longer pulls
    /// the outputs off by altitude × tilt (`docs/jointloc.md` §"A camera that does not look
    /// straight down").
    pub estimate_camera_tilt: bool,
    /// The estimated tilt is shrunk by this many degrees before use (a non-negative garrote:
    /// smaller tilts count as none, a tilt of 3° is used as 2.96°): on a camera that looks
    /// straight down the estimate wanders by 0.1–0.2°.
    pub camera_tilt_min_deg: f64,
    /// Altitude, metres, at which the settings whose errors grow with the range hold as
    /// given (they were measured at 10 m). Above it, with `a = altitude / this`: the nadir
    /// factor's σ is `a ×` `nadir_sigma_scale` (the point above a fix is off by altitude ×
    /// tilt: 0.09 m at 10 m, 1.2 m rms at 100 m on the simulator's 0.5° jitter, while the fix
    /// of the ground point stays as good); the alignment's inlier bound of the nadir pair,
    /// and of the ground pair's height (altimeter + elevation model), is `a ×`
    /// `inlier_threshold_m`; and the altimeter aid averages over `√a ×`
    /// `altitude_window_s` (the altimeter's noise is a share of the range). Below it, as at
    /// it (`docs/jointloc.md` §"At altitude on HiRISE-class maps").
    pub reference_altitude_m: f64,
    /// The alignment is fitted to the newest fixes, as many as this many seconds of flight
    /// hold at the search rate (`fusion_every` frames at the camera's rate) when no search
    /// fails; failed searches make the window reach further back (0: all fixes). SLAM drift
    /// (scale, yaw) makes one similarity for the whole flight a compromise that is worst at
    /// the current frame, the one being reported; too few fixes leave the fixes' noise in it.
    /// 30 s (30 m at 1 m/s; 30 fixes at a fix every 5th frame of 5 Hz): better online than
    /// 40 s on four sets of 18 fresh flights, at the end on three (`docs/jointloc.md`
    /// §"The alignment's window at a fix a second"); 40 s was 20 fixes every 10th frame,
    /// the best of 10 / 20 / 30 then. In seconds, so that `fusion_every` changes how many
    /// fixes the window holds and not how far back it reaches.
    pub alignment_window_s: f64,
    /// The window always holds at least this many fixes: with a fix every 100th frame (20 s
    /// at 5 Hz) 30 s would hold one, fewer than `min_fixes`, and no pose would ever be
    /// geo-referenced.
    pub alignment_window_min_fixes: usize,
    /// Reported z: shifted by the mean of `ground + altimeter − z` over the last this-many
    /// seconds of tracked frames (see [`crate::altitude`]), where the plane below is not
    /// fitted; 0: z from the alignment alone.
    pub altitude_window_s: f64,
    /// Near the reference altitude over a fine elevation model (the aid's window scaled by at
    /// most 1.25), the aid instead fits a plane to those residuals over the last this-many
    /// seconds and takes it at the newest frame: the alignment's tilt makes them grow along
    /// the track, and the plane follows what a longer mean would lag (see
    /// [`crate::altitude::AltitudeFilter::z_offset`]); 0: the mean everywhere. 15 s: 10–20 s
    /// within 0.1 mm online (`docs/jointloc.md` §"z online: a plane through the altimeter's
    /// heights").
    pub altitude_plane_window_s: f64,
    /// Prior σ of the plane's slopes (the alignment's tilt), degrees: across a straight track
    /// the slope is not observed and the prior keeps it level. 0.2°: the online attitude's
    /// error is about that. 0: no plane.
    pub altitude_tilt_sigma_deg: f64,
    /// The same aid for the outputs written at the end (`trajectory-final.tum`): the mean
    /// over this many seconds centred on each pose, from the final poses (scaled with the
    /// altitude and the elevation model's σ as `altitude_window_s`); 0: off. Centred on final
    /// poses it does not lag as a trailing window would online: 30 s measured best of
    /// 5 / 30 / 60 / 120 on six development flights (`docs/jointloc.md` §"z at the end").
    pub final_altitude_window_s: f64,
    /// World (x, y) of the take-off, metres, if known (e.g. the lander's position): the first
    /// absolute search starts from the tiles nearest to it instead of the whole map (a
    /// whole-map search with 8 rotation hypotheses takes seconds). `None`: whole map.
    pub start_position: Option<[f64; 2]>,
    /// How far the SLAM's take-off may lie from `start_position`, metres: the take-off's own
    /// uncertainty. With `start_position`, every alignment of the flight's first map, and a
    /// one-fix similarity that steers the searches before the first, must put the SLAM's
    /// take-off (its first tracked frame carried back to the flight's first frame) within
    /// this of it, plus allowances for the carrying back, the range and `start_drift`
    /// (`crate::takeoff`; 0: no such check). Under a sun reversed from the map's, fixes with
    /// the view turned half a turn agreed with each other and put the output 33–69 m off on
    /// 10 m flights (`docs/jointloc.md` §"The take-off checks the first alignment").
    pub start_radius_m: f64,
    /// See `start_radius_m`: the SLAM's drift as a fraction of the distance from the
    /// take-off (a few per cent over the first minutes of a monocular SLAM).
    pub start_drift: f64,
    /// Before the alignment exists, every this-many-th absolute search of a failing streak
    /// goes without a heading, so the localiser sweeps rotations (0: never give it a heading).
    /// The heading then comes from one fix, which may be wrong, and with it every search would
    /// fail; a sweep costs 8× a search with a heading.
    pub sweep_after_failures: usize,
    /// Once geo-referenced, a failing streak's search goes without a heading (a sweep of the
    /// rotations) each time the streak has lasted this many more seconds (0: never give it a
    /// heading). The heading then comes from at least `min_fixes` consistent fixes and the
    /// SLAM, and a failure is the matcher's, so sweeps are rare: 20 s (a sweep over the
    /// search radius matched 392 tiles, 35 s, on a medium mountain map). In seconds, so that
    /// `fusion_every` does not change how often a failing flight sweeps.
    pub sweep_after_failing_s: f64,
    /// Sequential mode, before the first fix (no fix, no alignment, no world pose yet): after
    /// n searches failed in a row, the next is made once 2^(n−1) search intervals have passed
    /// since the last, at most this many seconds of flight (0: at every due frame). Each
    /// covers the whole map (or, with `start_position`, falls back to it), seconds of work
    /// even on a 60 m medium map, where a mountain flight failed 22 in a row and ran at
    /// 4.6 Hz. 5 s: about what one such search takes at the camera rate, where the threaded
    /// mode could not search more often either; 8 s delayed the first world pose by up to
    /// 9 s (`docs/jointloc.md` §"Searches before the first fix back off").
    pub blind_retry_max_s: f64,
    /// After this many seconds of lost tracking without a relocalisation, the SLAM map is set
    /// aside and a new one initialised, geo-referenced again by the next `min_fixes` fixes
    /// (0: wait for relocalisation for ever, as ORB-SLAM2). A UAV keeps flying over ground its
    /// old map never saw, so relocalisation rarely ends a long loss; 5 s is 5 m at 1 m/s,
    /// half the camera's footprint at 10 m.
    pub new_map_after_lost_s: f64,
    /// A map set aside after a loss is merged back into the new one once the new one's
    /// alignment rests on as many fixes of its own as this many seconds hold at the search
    /// rate (0: never; the outputs then concatenate the maps). Both maps are tied to the
    /// world, so their alignments give the similarity between them (`crate::map_merge`).
    /// 40 s, longer than the alignment's window (30 s): from then on the window holds no fix
    /// of the earlier map, whose placement rests on the new map's early alignment. Maps not
    /// merged by the end of the flight are merged then, through the last alignment.
    pub merge_maps_after_s: f64,
    /// While there is no world pose (tracking lost, a new map not yet geo-referenced), the
    /// search prior is the last world pose carried forward at the last ground velocity, for
    /// at most this many seconds (0: the last world pose as it is). A UAV keeps flying: 12 s
    /// lost at 1 m/s leaves the last pose 12 m behind, more than a tile.
    pub dead_reckoning_max_s: f64,
    /// Altimeter gate (see [`crate::altimeter_gate`]): a reading that differs from the last
    /// accepted one by more than this rate × the time since it (+ 0.5 m for the sensor's
    /// noise) is dropped. 15 m/s is above what a small UAV climbs or sinks (multirotors are
    /// typically limited to 5–8 m/s vertically) and above the fastest change
    /// of height over ground from terrain slope at flight speed (1–5 m/s over 60° slopes),
    /// while a spike or a lost echo (a far ground return, a reading near 0) exceeds it. A step
    /// of the ground (a ledge) is accepted a fraction of a second later, the limit growing
    /// with the time since the last accepted reading.
    pub max_altitude_rate_mps: f64,
    /// Without `--start`, before the first world pose, a first alignment through virtual
    /// frames that rests on a fix with a confidence below `strong_fix_confidence` needs its
    /// inlier fixes to lie at least this far apart, metres (0: no such rule). Successive
    /// virtual frames share most of their ground, so a wrong place that matches one matches
    /// the next few too: on a 2 km crater flight three whole-map searches in a row put the
    /// views 945 m off at w 0.08–0.10, 6 m apart, while the right place, under a sun 160°
    /// from the map's, scored w 0.10–0.15 (`docs/absloc.md` §"Under a reversed sun"). 20 m
    /// of new ground is 40 % of a virtual frame.
    pub first_fix_span_m: f64,
    /// See `first_fix_span_m`: fixes at or above this confidence may make the first
    /// alignment at any span, and before it the virtual frame after such a fix is searched
    /// around it rather than over the whole map. Wrong whole-map fixes have scored up to
    /// w 0.19 on the flights measured, right ones under a near sun 0.37–0.50.
    pub strong_fix_confidence: f64,
    /// An alignment whose inlier fixes are all weak (below `strong_fix_confidence`) and whose
    /// newest inlier is older than this many seconds is dropped: the world poses stop, the
    /// fixes that made it and the search prior go, and the next fixes geo-reference the map
    /// again (0: never). Right fixes keep confirming an alignment (one search in 10 frames,
    /// most of them found even under a reversed sun); on a 10 m flight over mountains under a
    /// sun 173° away three weak wrong fixes and none after them put 1321 world poses 56 m off
    /// (`docs/jointloc.md` §"A wrong place despite --start").
    pub unconfirmed_weak_alignment_s: f64,
    /// Before the alignment, two successive one-fix similarities (SLAM → world) whose
    /// rotations differ by more than this many degrees disagree on the heading: the SLAM turns
    /// the map by a fraction of a degree between two fixes, so one of the two headings is
    /// wrong, and the next search sweeps the headings instead of trusting the newer one
    /// (0: never). At 100 m over gravel a search was made with a prior heading 167° off after
    /// a right fix, and found a wrong place 138 m away (`docs/jointloc.md` §"A prior heading
    /// that turns between two fixes").
    pub provisional_turn_deg: f64,
    /// Seed of the alignment RANSAC.
    pub seed: u64,
    pub slam: SystemConfig,
    pub absloc: AbsLocConfig,
    /// Correction of the fixes' common bias by where the map points sit on the elevation
    /// model (`[terrain]`; only with an elevation model in `map.toml`).
    pub terrain: TerrainConfig,
    /// Global bundle adjustment of the whole map with every fix, for the outputs written at
    /// the end (`[final_ba]`, see [`crate::final_ba`]).
    pub final_ba: FinalBaConfig,
    /// Fault injection for robustness runs (off by default).
    pub faults: FaultConfig,
    /// Fixes through virtual frames where a frame is too small on the map.
    pub mosaic: MosaicConfig,
}

impl Default for JointLocConfig {
    fn default() -> Self {
        Self {
            matcher: "xfeat-lighterglue".to_string(),
            fusion_every: 5,
            min_confidence: 0.05,
            min_fixes: 3,
            inlier_threshold_m: 2.0,
            alignment_robust_floor_m: 0.5,
            ransac_iterations: 200,
            nadir_weight: 0.3,
            nadir_sigma_scale: 0.25,
            nadir_mean_window_s: 4.0,
            estimate_camera_tilt: true,
            camera_tilt_min_deg: 0.5,
            reference_altitude_m: 10.0,
            alignment_window_s: 30.0,
            alignment_window_min_fixes: 10,
            altitude_window_s: 5.0,
            altitude_plane_window_s: 15.0,
            altitude_tilt_sigma_deg: 0.2,
            final_altitude_window_s: 30.0,
            start_position: None,
            start_radius_m: 5.0,
            start_drift: 0.05,
            sweep_after_failures: 2,
            sweep_after_failing_s: 20.0,
            blind_retry_max_s: 5.0,
            new_map_after_lost_s: 5.0,
            merge_maps_after_s: 40.0,
            dead_reckoning_max_s: 20.0,
            max_altitude_rate_mps: 15.0,
            first_fix_span_m: 20.0,
            strong_fix_confidence: 0.25,
            unconfirmed_weak_alignment_s: 30.0,
            provisional_turn_deg: 30.0,
            seed: 0,
            slam: SystemConfig::default(),
            absloc: AbsLocConfig::default(),
            terrain: TerrainConfig::default(),
            final_ba: FinalBaConfig::default(),
            faults: FaultConfig::default(),
            mosaic: MosaicConfig::default(),
        }
    }
}

impl JointLocConfig {
    /// How much larger an error proportional to the range is at `altitude` metres than at
    /// the reference altitude: `max(1, altitude / reference_altitude_m)` (1 for a reading
    /// that is not finite).
    pub fn range_looseness(&self, altitude: f64) -> f64 {
        if altitude.is_finite() {
            (altitude / self.reference_altitude_m).max(1.0)
        } else {
            1.0
        }
    }

    pub fn validate(&self) -> Result<()> {
        let bad = |field, value: String, reason| {
            Err(JointLocError::InvalidConfig {
                field,
                value,
                reason,
            })
        };
        if self.fusion_every == 0 {
            return bad("fusion_every", "0".into(), "at least 1");
        }
        if !(0.0..=1.0).contains(&self.min_confidence) {
            return bad(
                "min_confidence",
                self.min_confidence.to_string(),
                "must be in [0, 1]",
            );
        }
        if !(0.0..=1.0).contains(&self.terrain.gain) {
            return bad(
                "terrain.gain",
                self.terrain.gain.to_string(),
                "must be in [0, 1] (0: off)",
            );
        }
        if self.min_fixes < 2 {
            return bad("min_fixes", self.min_fixes.to_string(), "at least 2");
        }
        if self.alignment_window_min_fixes < self.min_fixes {
            return bad(
                "alignment_window_min_fixes",
                self.alignment_window_min_fixes.to_string(),
                "at least min_fixes",
            );
        }
        let ba = &self.slam.local_mapping.ba;
        // Finite and > 0 (`zero_ok` false) or ≥ 0 (true), checked in this order.
        for (field, value, zero_ok, reason) in [
            (
                "inlier_threshold_m",
                self.inlier_threshold_m,
                false,
                "must be finite and > 0",
            ),
            (
                "alignment_robust_floor_m",
                self.alignment_robust_floor_m,
                true,
                "must be finite and ≥ 0 (0: off)",
            ),
            (
                "nadir_weight",
                self.nadir_weight,
                true,
                "must be finite and >= 0",
            ),
            (
                "nadir_sigma_scale",
                self.nadir_sigma_scale,
                true,
                "must be finite and >= 0",
            ),
            (
                "camera_tilt_min_deg",
                self.camera_tilt_min_deg,
                true,
                "must be finite and >= 0",
            ),
            (
                "reference_altitude_m",
                self.reference_altitude_m,
                false,
                "must be finite and > 0",
            ),
            (
                "altitude_window_s",
                self.altitude_window_s,
                true,
                "must be finite and >= 0",
            ),
            (
                "nadir_mean_window_s",
                self.nadir_mean_window_s,
                true,
                "must be finite and >= 0 (0: off)",
            ),
            (
                "altitude_plane_window_s",
                self.altitude_plane_window_s,
                true,
                "must be finite and >= 0",
            ),
            (
                "altitude_tilt_sigma_deg",
                self.altitude_tilt_sigma_deg,
                true,
                "must be finite and >= 0",
            ),
            (
                "final_altitude_window_s",
                self.final_altitude_window_s,
                true,
                "must be finite and >= 0",
            ),
            (
                "alignment_window_s",
                self.alignment_window_s,
                true,
                "must be finite and >= 0 (0: all fixes)",
            ),
            (
                "sweep_after_failing_s",
                self.sweep_after_failing_s,
                true,
                "must be finite and >= 0 (0: never a heading)",
            ),
            (
                "blind_retry_max_s",
                self.blind_retry_max_s,
                true,
                "must be finite and >= 0 (0: no backoff)",
            ),
            (
                "terrain.window_s",
                self.terrain.window_s,
                true,
                "must be finite and >= 0 (0: the alignment's window)",
            ),
            (
                "merge_maps_after_s",
                self.merge_maps_after_s,
                true,
                "must be finite and >= 0 (0: never)",
            ),
            (
                "new_map_after_lost_s",
                self.new_map_after_lost_s,
                true,
                "must be finite and >= 0 (0: never)",
            ),
            (
                "dead_reckoning_max_s",
                self.dead_reckoning_max_s,
                true,
                "must be finite and >= 0 (0: off)",
            ),
            (
                "first_fix_span_m",
                self.first_fix_span_m,
                true,
                "must be finite and >= 0 (0: off)",
            ),
            (
                "strong_fix_confidence",
                self.strong_fix_confidence,
                true,
                "must be finite and >= 0",
            ),
            (
                "provisional_turn_deg",
                self.provisional_turn_deg,
                true,
                "must be finite and >= 0 (0: never)",
            ),
            (
                "unconfirmed_weak_alignment_s",
                self.unconfirmed_weak_alignment_s,
                true,
                "must be finite and >= 0 (0: never)",
            ),
            (
                "start_radius_m",
                self.start_radius_m,
                true,
                "must be finite and >= 0 (0: no check)",
            ),
            (
                "start_drift",
                self.start_drift,
                true,
                "must be finite and >= 0",
            ),
            (
                "max_altitude_rate_mps",
                self.max_altitude_rate_mps,
                false,
                "must be finite and > 0",
            ),
            (
                "slam.local_mapping.ba.global_sigma",
                ba.global_sigma,
                false,
                "must be finite and > 0",
            ),
            (
                "slam.local_mapping.ba.ground_sigma",
                ba.ground_sigma,
                true,
                "must be finite and >= 0 (0: no ground factors)",
            ),
            (
                "terrain.sigma_m",
                self.terrain.sigma_m,
                false,
                "must be finite and > 0",
            ),
            (
                "terrain.huber",
                self.terrain.huber,
                false,
                "must be finite and > 0",
            ),
            (
                "terrain.max_fov_deg",
                self.terrain.max_fov_deg,
                false,
                "must be finite and > 0 (degrees)",
            ),
            (
                "terrain.tau_m",
                self.terrain.tau_m,
                false,
                "must be finite and > 0",
            ),
            (
                "terrain.max_offset_m",
                self.terrain.max_offset_m,
                true,
                "must be finite and >= 0",
            ),
        ] {
            let in_range = if zero_ok { value >= 0.0 } else { value > 0.0 };
            if !(value.is_finite() && in_range) {
                return bad(field, value.to_string(), reason);
            }
        }
        if let Some(p) = self.start_position
            && !p.iter().all(|v| v.is_finite())
        {
            return bad("start_position", format!("{p:?}"), "must be finite");
        }
        self.faults.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_sigmas_are_rejected_with_their_field() {
        assert!(JointLocConfig::default().validate().is_ok());
        for (ground, global, field) in [
            (f64::NAN, 0.15, "slam.local_mapping.ba.ground_sigma"),
            (-0.1, 0.15, "slam.local_mapping.ba.ground_sigma"),
            (0.1, 0.0, "slam.local_mapping.ba.global_sigma"),
            (0.1, f64::INFINITY, "slam.local_mapping.ba.global_sigma"),
        ] {
            let mut c = JointLocConfig::default();
            c.slam.local_mapping.ba.ground_sigma = ground;
            c.slam.local_mapping.ba.global_sigma = global;
            match c.validate() {
                Err(JointLocError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{ground} {global}: {other:?}"),
            }
        }
        let mut off = JointLocConfig::default();
        off.slam.local_mapping.ba.ground_sigma = 0.0;
        assert!(off.validate().is_ok());
    }

    #[test]
    fn range_looseness_is_one_up_to_the_reference_altitude_then_grows_with_it() {
        let c = JointLocConfig::default();
        assert_eq!(c.range_looseness(5.0), 1.0);
        assert_eq!(c.range_looseness(10.0), 1.0);
        assert!((c.range_looseness(100.0) - 10.0).abs() < 1e-12);
        assert_eq!(c.range_looseness(f64::NAN), 1.0);
        let bad = JointLocConfig {
            reference_altitude_m: 0.0,
            ..JointLocConfig::default()
        };
        assert!(matches!(
            bad.validate(),
            Err(JointLocError::InvalidConfig {
                field: "reference_altitude_m",
                ..
            })
        ));
    }

    #[test]
    fn invalid_terrain_and_recovery_settings_are_rejected_with_their_field() {
        type Set = fn(&mut JointLocConfig);
        let cases: [(Set, &str); 16] = [
            (|c| c.max_altitude_rate_mps = 0.0, "max_altitude_rate_mps"),
            (
                |c| c.max_altitude_rate_mps = f64::NAN,
                "max_altitude_rate_mps",
            ),
            (|c| c.terrain.gain = 1.5, "terrain.gain"),
            (|c| c.terrain.gain = f64::NAN, "terrain.gain"),
            (|c| c.terrain.tau_m = 0.0, "terrain.tau_m"),
            (|c| c.terrain.max_fov_deg = f64::NAN, "terrain.max_fov_deg"),
            (|c| c.terrain.max_offset_m = -1.0, "terrain.max_offset_m"),
            (|c| c.new_map_after_lost_s = -1.0, "new_map_after_lost_s"),
            (
                |c| c.dead_reckoning_max_s = f64::NAN,
                "dead_reckoning_max_s",
            ),
            (|c| c.camera_tilt_min_deg = -0.5, "camera_tilt_min_deg"),
            (|c| c.alignment_window_s = f64::NAN, "alignment_window_s"),
            (
                |c| c.alignment_window_min_fixes = 2,
                "alignment_window_min_fixes",
            ),
            (|c| c.sweep_after_failing_s = -1.0, "sweep_after_failing_s"),
            (|c| c.blind_retry_max_s = f64::NAN, "blind_retry_max_s"),
            (
                |c| c.merge_maps_after_s = f64::INFINITY,
                "merge_maps_after_s",
            ),
            (|c| c.terrain.window_s = -10.0, "terrain.window_s"),
        ];
        for (set, field) in cases {
            let mut c = JointLocConfig::default();
            set(&mut c);
            match c.validate() {
                Err(JointLocError::InvalidConfig { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: {other:?}"),
            }
        }
        let mut off = JointLocConfig::default();
        off.terrain.gain = 0.0;
        assert!(off.validate().is_ok());
    }
}
