//! The evaluation plot renders to SVG (labelled) and PNG (no text: plotters has no font
//! rasteriser in this build) without panicking, and refuses unknown formats.

use jointloc_eval::{AlignMode, EvalConfig, EvalError, evaluate, plot_report};
use jointloc_geometry::CameraToWorld;
use jointloc_geometry::trajectory::Trajectory;
use nalgebra::{UnitQuaternion, Vector3};

fn circle(n: usize, radius: f64, wobble: f64) -> Trajectory {
    let poses = (0..n)
        .map(|i| {
            let a = i as f64 * 0.05;
            CameraToWorld::from_rotation_translation(
                UnitQuaternion::from_euler_angles(0.0, 0.0, a + wobble * (3.0 * a).sin()),
                Vector3::new(radius * a.cos(), radius * a.sin(), wobble * (5.0 * a).sin()),
            )
        })
        .collect();
    Trajectory::new((0..n).map(|i| i as f64 * 0.1).collect(), poses).unwrap()
}

#[test]
fn writes_svg_and_png() {
    let reference = circle(120, 20.0, 0.0);
    let estimate = circle(120, 21.0, 0.3);
    let config = EvalConfig {
        align: AlignMode::Se3,
        ..Default::default()
    };
    let report = evaluate(&reference, &estimate, &config).unwrap();
    let dir = tempfile::tempdir().unwrap();

    let svg = dir.path().join("eval.svg");
    plot_report(&report, &svg).unwrap();
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.contains("<svg"));
    assert!(text.contains("APE [m]"));
    assert!(text.contains("rmse = "));

    let png = dir.path().join("eval.PNG");
    plot_report(&report, &png).unwrap();
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");

    let bad = dir.path().join("eval.pdf");
    assert!(matches!(
        plot_report(&report, &bad),
        Err(EvalError::Plot { .. })
    ));
}
