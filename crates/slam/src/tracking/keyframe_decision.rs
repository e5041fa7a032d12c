//! When the current frame becomes a keyframe: ORB-SLAM2's rules with the paper's additions
//! (§III-C): optionally at least `min_frames` frames since the last keyframe (the paper: 10;
//! default 0, ORB-SLAM2's behaviour when its local mapping is idle, which it always is in the
//! sequential mode: docs/vo.md "Map quality against ORB-SLAM2"), and an image entropy above a
//! threshold.

use serde::{Deserialize, Serialize};

/// Settings of [`need_keyframe`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeDecisionConfig {
    /// Frames since the last keyframe before a new one may be inserted. Default 0: ORB-SLAM2's
    /// `mMinFrames` with an idle local mapper (condition `c1b`), which the sequential mode always
    /// has. With the paper's 10 a keyframe is inserted every ≈ 2.1 m instead of ≈ 0.9 m
    /// (≈ 1.4 m after keyframe culling), and the per-frame RPE is ≈ 30 % larger on every flight
    /// measured; Sim(3) APE mean 0.104 → 0.073 m on six development flights, 0.108 → 0.102 m
    /// on eleven fresh ones (docs/vo.md §5).
    pub min_frames: usize,
    /// Insert as soon as the tracked points fall below this fraction of the reference
    /// keyframe's (ORB-SLAM2's monocular `thRefRatio`: 0.9; the paper's "90 %" rule).
    pub ref_ratio: f64,
    /// Below this fraction tracking is weakening fast: insert even before `min_frames`, so the
    /// map grows before the overlap is gone (not in the paper; ORB-SLAM2 has a similar urgency
    /// rule, `c1c`, for stereo only).
    pub urgent_ratio: f64,
    /// A keyframe needs more tracked inliers than this (ORB-SLAM2: 15).
    pub min_inliers: usize,
    /// Grey-level entropy a keyframe image must exceed, bits (0..8). The paper's threshold 0.5
    /// read as a fraction of the 8-bit maximum: 4 bits. Simulated Mars frames have 5.5–7 bits;
    /// a frame below 4 (over-exposed, lens cap, haze) makes a poor keyframe for both ORB
    /// triangulation and absolute matching.
    pub min_entropy_bits: f64,
}

impl Default for KeyframeDecisionConfig {
    fn default() -> Self {
        Self {
            min_frames: 0,
            ref_ratio: 0.9,
            urgent_ratio: 0.5,
            min_inliers: 15,
            min_entropy_bits: 4.0,
        }
    }
}

/// What the decision looks at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeyframeContext {
    /// Frames since the last keyframe was inserted.
    pub frames_since_keyframe: usize,
    /// Inlier matches of the current frame.
    pub inliers: usize,
    /// Points of the reference keyframe observed by at least 3 keyframes (2 while the map has
    /// at most two keyframes), ORB-SLAM2's `nRefMatches`.
    pub reference_points: usize,
    /// Grey-level entropy of the current image, bits.
    pub entropy_bits: f64,
}

/// ORB-SLAM2's rule `c2` (fewer tracked points than `ref_ratio` × the reference's, but more
/// than `min_inliers`) gated by the paper's `≥ min_frames` since the last keyframe (waived when
/// tracking falls below `urgent_ratio`) and by the entropy threshold.
pub fn need_keyframe(ctx: &KeyframeContext, cfg: &KeyframeDecisionConfig) -> bool {
    if ctx.inliers <= cfg.min_inliers || ctx.entropy_bits <= cfg.min_entropy_bits {
        return false;
    }
    let reference = ctx.reference_points as f64;
    let fewer = (ctx.inliers as f64) < cfg.ref_ratio * reference;
    let urgent = (ctx.inliers as f64) < cfg.urgent_ratio * reference;
    fewer && (ctx.frames_since_keyframe >= cfg.min_frames || urgent)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rules_combine_as_documented() {
        // The paper's frame gap, to exercise the urgency rule.
        let cfg = KeyframeDecisionConfig {
            min_frames: 10,
            ..KeyframeDecisionConfig::default()
        };
        let ctx = KeyframeContext {
            frames_since_keyframe: 10,
            inliers: 200,
            reference_points: 300,
            entropy_bits: 6.0,
        };
        assert!(need_keyframe(&ctx, &cfg));
        // Too soon, not urgent.
        assert!(!need_keyframe(
            &KeyframeContext {
                frames_since_keyframe: 9,
                ..ctx
            },
            &cfg
        ));
        // Too soon but urgent.
        let urgent = KeyframeContext {
            frames_since_keyframe: 3,
            inliers: 140,
            ..ctx
        };
        assert!(need_keyframe(&urgent, &cfg));
        // Still tracking most of the reference.
        assert!(!need_keyframe(
            &KeyframeContext {
                inliers: 280,
                ..ctx
            },
            &cfg
        ));
        // Low-information image.
        assert!(!need_keyframe(
            &KeyframeContext {
                entropy_bits: 3.9,
                ..ctx
            },
            &cfg
        ));
        // Too few inliers.
        assert!(!need_keyframe(
            &KeyframeContext { inliers: 15, ..ctx },
            &cfg
        ));
    }

    #[test]
    fn by_default_only_orb_slam2_s_tracking_rule_decides() {
        // ORB-SLAM2 with an idle local mapper: a keyframe as soon as fewer than 90 % of the
        // reference keyframe's points are tracked, however few frames ago the last one was.
        let cfg = KeyframeDecisionConfig::default();
        assert_eq!(cfg.min_frames, 0);
        let ctx = KeyframeContext {
            frames_since_keyframe: 1,
            inliers: 260,
            reference_points: 300,
            entropy_bits: 6.0,
        };
        assert!(need_keyframe(&ctx, &cfg));
        assert!(!need_keyframe(
            &KeyframeContext {
                inliers: 271,
                ..ctx
            },
            &cfg
        ));
        assert!(!need_keyframe(
            &KeyframeContext {
                entropy_bits: 3.5,
                ..ctx
            },
            &cfg
        ));
    }
}
