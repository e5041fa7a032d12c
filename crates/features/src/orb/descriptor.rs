//! Steered BRIEF: 256 binary tests `I(p) < I(q)` on the Gaussian-blurred level, with the test
//! points rotated by the keypoint's orientation, packed LSB-first into 32 bytes.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::error::{FeaturesError, Result};

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

/// `y as i32` (truncation = floor) for 0 ≤ y < 2^22, without the saturating float-to-int
/// cast, which does not vectorise: adding 2^23 rounds y to the nearest integer (ties to even)
/// in the mantissa bits; one less when that rounded up.
#[inline(always)]
fn floor_small(y: f32) -> i32 {
    const M: f32 = 8_388_608.0; // 2^23
    let m = y + M;
    let r = m.to_bits() as i32 - M.to_bits() as i32;
    r - ((m - M) > y) as i32
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
            return Err(FeaturesError::InvalidConfig {
                field: "brief_pattern",
                value: tests.len().to_string(),
                reason: "must hold 256 tests",
            });
        }
        let r2 = (PATTERN_RADIUS * PATTERN_RADIUS) as i32;
        for t in &tests {
            let inside = |x: i8, y: i8| (x as i32).pow(2) + (y as i32).pow(2) <= r2;
            if !inside(t[0], t[1]) || !inside(t[2], t[3]) || (t[0], t[1]) == (t[2], t[3]) {
                return Err(FeaturesError::InvalidConfig {
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

/// A pattern's test points as f32 coordinate arrays (structure of arrays), so that rotating
/// all 512 points of a keypoint is a few vectorised loops; [`describe_steered`] uses it.
#[derive(Debug, Clone, PartialEq)]
pub struct SteeredPattern {
    x1: [f32; N_TESTS],
    y1: [f32; N_TESTS],
    x2: [f32; N_TESTS],
    y2: [f32; N_TESTS],
}

impl SteeredPattern {
    pub fn new(pattern: &BriefPattern) -> Self {
        let col =
            |j: usize| -> [f32; N_TESTS] { std::array::from_fn(|i| pattern.tests[i][j] as f32) };
        Self {
            x1: col(0),
            y1: col(1),
            x2: col(2),
            y2: col(3),
        }
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
    describe_steered(blurred, w, h, x, y, angle, &SteeredPattern::new(pattern))
}

/// [`describe`] with the pattern already in [`SteeredPattern`] form (same result).
pub fn describe_steered(
    blurred: &[u8],
    w: usize,
    h: usize,
    x: usize,
    y: usize,
    angle: f64,
    pattern: &SteeredPattern,
) -> Descriptor {
    let (s, c) = (angle.sin() as f32, angle.cos() as f32);
    let r = PATTERN_RADIUS;
    let inside = x >= r && y >= r && x + r < w && y + r < h;
    // Rotated, rounded test points: the same f32 operations as `round_offset`, with the
    // truncating cast replaced by `floor_small` (equal here, and it vectorises).
    let rot_u = |fx: f32, fy: f32| floor_small(fx * c - fy * s + 64.5) - 64;
    let rot_v = |fx: f32, fy: f32| floor_small(fx * s + fy * c + 64.5) - 64;
    let (mut u1, mut v1) = ([0i32; N_TESTS], [0i32; N_TESTS]);
    let (mut u2, mut v2) = ([0i32; N_TESTS], [0i32; N_TESTS]);
    for i in 0..N_TESTS {
        u1[i] = rot_u(pattern.x1[i], pattern.y1[i]);
        v1[i] = rot_v(pattern.x1[i], pattern.y1[i]);
        u2[i] = rot_u(pattern.x2[i], pattern.y2[i]);
        v2[i] = rot_v(pattern.x2[i], pattern.y2[i]);
    }
    let mut less = [false; N_TESTS];
    if inside {
        // Offsets from the patch's centre inside the (2r + 1)-row window around the keypoint.
        let wi = w as i32;
        let (mut o1, mut o2) = ([0i32; N_TESTS], [0i32; N_TESTS]);
        for i in 0..N_TESTS {
            o1[i] = v1[i] * wi + u1[i];
            o2[i] = v2[i] * wi + u2[i];
        }
        let centre = r * w + r;
        let patch = &blurred[(y - r) * w + x - r..=(y + r) * w + x + r];
        for i in 0..N_TESTS {
            let p = patch[(centre as i32 + o1[i]) as usize];
            let q = patch[(centre as i32 + o2[i]) as usize];
            less[i] = p < q;
        }
    } else {
        let (xi, yi) = (x as i32, y as i32);
        let at = |u: i32, v: i32| {
            let px = (xi + u).clamp(0, w as i32 - 1) as usize;
            let py = (yi + v).clamp(0, h as i32 - 1) as usize;
            blurred[py * w + px]
        };
        for i in 0..N_TESTS {
            less[i] = at(u1[i], v1[i]) < at(u2[i], v2[i]);
        }
    }
    let mut d = [0u8; 32];
    for (byte, bits) in d.iter_mut().zip(less.chunks_exact(8)) {
        *byte = bits
            .iter()
            .enumerate()
            .fold(0u8, |b, (bit, &l)| b | ((l as u8) << bit));
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_small_equals_the_truncating_cast() {
        // Every f32 in [32, 128) (rotated points + 64.5 lie in [50.5, 78.5]), and samples
        // of the whole valid range.
        let mut y = 32.0f32;
        while y < 128.0 {
            assert_eq!(floor_small(y), y as i32, "{y}");
            y = f32::from_bits(y.to_bits() + 1);
        }
        for k in 0..100_000u32 {
            let y = k as f32 * 41.94304 + (k % 7) as f32 * 0.25;
            assert_eq!(floor_small(y), y as i32, "{y}");
        }
    }

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

    /// The per-test scalar form `describe` had before [`SteeredPattern`] (the definition).
    fn describe_reference(
        blurred: &[u8],
        w: usize,
        h: usize,
        x: usize,
        y: usize,
        angle: f64,
        pattern: &BriefPattern,
    ) -> Descriptor {
        let (s, c) = (angle.sin() as f32, angle.cos() as f32);
        let (xi, yi) = (x as isize, y as isize);
        let index = |dx: i8, dy: i8| -> usize {
            let (fx, fy) = (dx as f32, dy as f32);
            let u = round_offset(fx * c - fy * s);
            let v = round_offset(fx * s + fy * c);
            let px = (xi + u).clamp(0, w as isize - 1) as usize;
            let py = (yi + v).clamp(0, h as isize - 1) as usize;
            py * w + px
        };
        let mut d = [0u8; 32];
        for (byte, tests) in d.iter_mut().zip(pattern.tests.chunks_exact(8)) {
            for (bit, t) in tests.iter().enumerate() {
                let (p, q) = (blurred[index(t[0], t[1])], blurred[index(t[2], t[3])]);
                *byte |= ((p < q) as u8) << bit;
            }
        }
        d
    }

    #[test]
    fn steered_descriptors_equal_the_scalar_definition() {
        let (w, h) = (61, 47);
        let mut s = 99u64;
        let img: Vec<u8> = (0..w * h)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect();
        for pattern in [BriefPattern::learned(), BriefPattern::random_gaussian(7)] {
            let steered = SteeredPattern::new(&pattern);
            for k in 0..400 {
                // Every pixel class: inside, near and at the border; many angles, including
                // the multiples of π/2 and π/4 where rotated points land on .5 ties.
                let (x, y) = ((k * 7) % w, (k * 11) % h);
                let angle = if k % 3 == 0 {
                    (k % 8) as f64 * std::f64::consts::FRAC_PI_4
                } else {
                    k as f64 * 0.0731
                };
                assert_eq!(
                    describe_steered(&img, w, h, x, y, angle, &steered),
                    describe_reference(&img, w, h, x, y, angle, &pattern),
                    "({x}, {y}) angle {angle}"
                );
            }
        }
    }

    #[test]
    fn describing_at_the_border_does_not_panic() {
        let img: Vec<u8> = (0..40 * 30).map(|i| (i * 37 % 251) as u8).collect();
        let p = BriefPattern::random_gaussian(1);
        let _ = describe(&img, 40, 30, 0, 0, 1.0, &p);
        let _ = describe(&img, 40, 30, 39, 29, 4.0, &p);
    }
}
