//! Bad input given to `JointLoc::process` on a rendered flight with fixes from its ground
//! truth: implausible altimeter readings are dropped and counted while the simulator's noise
//! passes; a rejected frame (wrong size, timestamp not after the last) is an error that leaves
//! the system as it was. One scenario a test.

mod common;

use std::collections::BTreeMap;

use common::{TruthFixes, builder, flight, frames, ground_truth, online, rmse};
use jointloc_system::{JointLocConfig, Outputs};

type Frames = Vec<(image::GrayImage, f64, Option<f64>)>;

/// Runs `frames` sequentially with fixes from the ground truth (seed 1).
fn run(frames: &Frames) -> Outputs {
    let config = JointLocConfig::default();
    let mut system = builder(flight(), config, TruthFixes::new(flight(), 0.1, 1))
        .build()
        .unwrap();
    for (image, t, alt) in frames {
        system.process(image, *t, *alt).unwrap();
    }
    system.finish().unwrap()
}

#[test]
fn implausible_altimeter_readings_are_dropped_and_counted_noise_is_kept() {
    let clean = frames(flight());
    let mut faulty = clean.clone();
    // NaN, inf, negative, zero; spikes of +25 m and −8 m (a lost echo), some on the frames
    // that go to absolute localisation (every 5th), some between.
    let invalid = [(30, f64::NAN), (47, f64::INFINITY), (50, -4.0), (113, 0.0)];
    let jumps = [(70, 25.0), (91, -8.0), (140, 25.0)];
    for (i, a) in invalid {
        faulty[i].2 = Some(a);
    }
    for (i, d) in jumps {
        faulty[i].2 = faulty[i].2.map(|a| a + d);
    }
    let (clean_out, faulty_out) = (run(&clean), run(&faulty));
    // The simulator's altimeter (σ 0.1 m at 5 Hz over a crater) never trips the gate.
    assert!(
        clean_out.summary.input_faults.is_empty(),
        "{:?}",
        clean_out.summary.input_faults
    );
    let expected: BTreeMap<String, usize> = [
        ("altimeter_invalid".to_string(), invalid.len()),
        ("altimeter_jump".to_string(), jumps.len()),
    ]
    .into();
    assert_eq!(faulty_out.summary.input_faults, expected);
    assert_eq!(faulty_out.summary.frames, clean.len());
    // Seven readings fewer change little.
    let gt = ground_truth(flight());
    let (a, b) = (
        rmse(&gt, &online(&clean_out)),
        rmse(&gt, &online(&faulty_out)),
    );
    assert!(b <= 1.1 * a + 0.02, "online rmse {b} m vs clean {a} m");
    // The written summary carries the counts; a clean one has no such key.
    let dir = tempfile::tempdir().unwrap();
    faulty_out.write(&dir.path().join("faulty"), false).unwrap();
    clean_out.write(&dir.path().join("clean"), false).unwrap();
    let text = std::fs::read_to_string(dir.path().join("faulty/summary.json")).unwrap();
    assert!(text.contains("\"altimeter_jump\": 3"), "{text}");
    let text = std::fs::read_to_string(dir.path().join("clean/summary.json")).unwrap();
    assert!(!text.contains("input_faults"), "{text}");
}

#[test]
fn a_rejected_frame_is_an_error_and_leaves_the_system_as_it_was() {
    let all = frames(flight());
    let clean: Frames = all[..40].to_vec();
    let reference = run(&clean);
    let config = JointLocConfig::default();
    let mut system = builder(flight(), config, TruthFixes::new(flight(), 0.1, 1))
        .build()
        .unwrap();
    let small = image::GrayImage::new(100, 100);
    for (i, (image, t, alt)) in clean.iter().enumerate() {
        if i == 20 {
            // Wrong size, later than the next frame, with a good reading; then the frame
            // before again, with a reading far off that the gate would otherwise take as its
            // reference.
            let e = system.process(&small, t + 0.05, *alt).unwrap_err();
            assert!(e.to_string().contains("100x100"), "{e}");
            let (prev_image, prev_t, _) = &clean[i - 1];
            let e = system
                .process(prev_image, *prev_t, Some(alt.unwrap() + 0.2))
                .unwrap_err();
            assert!(e.to_string().contains("not increasing"), "{e}");
            assert_eq!(system.frames(), 20);
        }
        system.process(image, *t, *alt).unwrap();
    }
    let outputs = system.finish().unwrap();
    assert_eq!(outputs.online, reference.online);
    assert_eq!(outputs.frames, reference.frames);
    assert_eq!(outputs.summary.frames, 40);
    assert!(outputs.summary.input_faults.is_empty());
}
