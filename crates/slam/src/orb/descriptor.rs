//! Steered BRIEF: 256 binary tests `I(p) < I(q)` on the Gaussian-blurred level, with the test
//! points rotated by the keypoint's orientation, packed LSB-first into 32 bytes.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::error::{Result, SlamError};

/// A 256-bit binary descriptor.
pub type Descriptor = [u8; 32];

/// Number of tests (bits).
pub const N_TESTS: usize = 256;

/// Every test point lies within this distance of the keypoint (so that the rotated, rounded
/// point stays within it too, and a border of `PATTERN_RADIUS + 1` px is always enough).
pub const PATTERN_RADIUS: usize = 13;

/// Nearest integer of a rotated test coordinate (|v| < 64), halves rounded up; a cast
/// instead of `f32::round`, which is a libm call on baseline x86-64.
#[inline]
pub(crate) fn round_offset(v: f32) -> isize {
    (v + 64.5) as isize - 64
}

/// Hamming distance of two descriptors.
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    let mut d = 0;
    for k in 0..4 {
        let x = u64::from_le_bytes(a[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        let y = u64::from_le_bytes(b[8 * k..8 * k + 8].try_into().expect("8 bytes"));
        d += (x ^ y).count_ones();
    }
    d
}

/// The 256 tests as `[x1, y1, x2, y2]` offsets from the keypoint (level pixels, y down).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BriefPattern {
    tests: Vec<[i8; 4]>,
}

impl BriefPattern {
    /// Checks the count (256), that every point is within [`PATTERN_RADIUS`] and that no test
    /// compares a point with itself.
    pub fn new(tests: Vec<[i8; 4]>) -> Result<Self> {
        if tests.len() != N_TESTS {
            return Err(SlamError::InvalidConfig {
                field: "brief_pattern",
                value: tests.len().to_string(),
                reason: "must hold 256 tests",
            });
        }
        let r2 = (PATTERN_RADIUS * PATTERN_RADIUS) as i32;
        for t in &tests {
            let inside = |x: i8, y: i8| (x as i32).pow(2) + (y as i32).pow(2) <= r2;
            if !inside(t[0], t[1]) || !inside(t[2], t[3]) || (t[0], t[1]) == (t[2], t[3]) {
                return Err(SlamError::InvalidConfig {
                    field: "brief_pattern",
                    value: format!("{t:?}"),
                    reason: "test points must be distinct and within the pattern radius",
                });
            }
        }
        Ok(Self { tests })
    }

    /// The pattern learned on simulated Mars frames (`pattern.rs`).
    pub fn learned() -> Self {
        Self {
            tests: super::pattern::LEARNED_PATTERN.to_vec(),
        }
    }

    /// BRIEF's random pattern "G II" (Calonder et al. 2010): both points drawn i.i.d. from an
    /// isotropic Gaussian of σ = 31/5 px, redrawn until inside the pattern disc. The baseline
    /// the learned pattern is compared with.
    pub fn random_gaussian(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let normal = Normal::<f64>::new(0.0, 31.0 / 5.0).expect("valid σ");
        let r2 = (PATTERN_RADIUS * PATTERN_RADIUS) as i32;
        let point = |rng: &mut ChaCha8Rng| loop {
            let x = normal.sample(rng).round() as i32;
            let y = normal.sample(rng).round() as i32;
            if x * x + y * y <= r2 {
                return [x as i8, y as i8];
            }
        };
        let mut tests = Vec::with_capacity(N_TESTS);
        while tests.len() < N_TESTS {
            let (p, q) = (point(&mut rng), point(&mut rng));
            if p != q {
                tests.push([p[0], p[1], q[0], q[1]]);
            }
        }
        Self { tests }
    }

    pub fn tests(&self) -> &[[i8; 4]] {
        &self.tests
    }
}

/// Descriptor of the keypoint at level pixel (x, y) with orientation `angle` (radians) on the
/// blurred level `blurred` (w × h). Points falling outside the level (only possible within
/// `PATTERN_RADIUS` of the border, which detection avoids) are clamped to it.
pub fn describe(
    blurred: &[u8],
    w: usize,
    h: usize,
    x: usize,
    y: usize,
    angle: f64,
    pattern: &BriefPattern,
) -> Descriptor {
    let (s, c) = (angle.sin() as f32, angle.cos() as f32);
    let r = PATTERN_RADIUS;
    let inside = x >= r && y >= r && x + r < w && y + r < h;
    let (xi, yi) = (x as isize, y as isize);
    // Rotated test points as offsets into the level, then the comparisons.
    let index = |dx: i8, dy: i8| -> usize {
        let (fx, fy) = (dx as f32, dy as f32);
        let u = round_offset(fx * c - fy * s);
        let v = round_offset(fx * s + fy * c);
        if inside {
            ((yi + v) * w as isize + xi + u) as usize
        } else {
            let px = (xi + u).clamp(0, w as isize - 1) as usize;
            let py = (yi + v).clamp(0, h as isize - 1) as usize;
            py * w + px
        }
    };
    let mut d = [0u8; 32];
    for (byte, tests) in d.iter_mut().zip(pattern.tests.chunks_exact(8)) {
        let mut b = 0u8;
        for (bit, t) in tests.iter().enumerate() {
            let (p, q) = (blurred[index(t[0], t[1])], blurred[index(t[2], t[3])]);
            b |= ((p < q) as u8) << bit;
        }
        *byte = b;
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hamming_counts_differing_bits() {
        let a = [0u8; 32];
        let mut b = [0u8; 32];
        assert_eq!(hamming(&a, &b), 0);
        b[0] = 0b1011;
        b[31] = 0xFF;
        b[17] = 0x10;
        assert_eq!(hamming(&a, &b), 3 + 8 + 1);
        assert_eq!(hamming(&b, &b), 0);
        assert_eq!(hamming(&[0xFF; 32], &a), 256);
    }

    #[test]
    fn patterns_are_valid() {
        let learned = BriefPattern::learned();
        assert!(BriefPattern::new(learned.tests().to_vec()).is_ok());
        let g = BriefPattern::random_gaussian(3);
        assert!(BriefPattern::new(g.tests().to_vec()).is_ok());
        assert_eq!(g, BriefPattern::random_gaussian(3));
        assert_ne!(g, BriefPattern::random_gaussian(4));
        assert!(BriefPattern::new(vec![[0, 0, 1, 1]; 255]).is_err());
        assert!(BriefPattern::new(vec![[0, 0, 14, 0]; 256]).is_err());
        assert!(BriefPattern::new(vec![[2, 2, 2, 2]; 256]).is_err());
    }

    #[test]
    fn describing_at_the_border_does_not_panic() {
        let img: Vec<u8> = (0..40 * 30).map(|i| (i * 37 % 251) as u8).collect();
        let p = BriefPattern::random_gaussian(1);
        let _ = describe(&img, 40, 30, 0, 0, 1.0, &p);
        let _ = describe(&img, 40, 30, 39, 29, 4.0, &p);
    }
}
