//! Records the git commit the binary is built from, so that `jointloc bench` reports name it
//! wherever the binary runs (an installed `jointloc` runs outside the repository).

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
        .filter(|s| !s.is_empty())
}

/// Watches `path` if it exists (cargo reruns the script on every build for a missing one).
fn watch(path: String) {
    if std::path::Path::new(&path).exists() {
        println!("cargo:rerun-if-changed={path}");
    }
}

fn main() {
    let commit = git(&["rev-parse", "--short", "HEAD"]).unwrap_or_default();
    println!("cargo:rustc-env=JOINTLOC_BUILD_COMMIT={commit}");
    // Rebuild when HEAD moves: HEAD itself (a worktree has its own), the branch refs and the
    // packed refs (shared by worktrees).
    if let Some(dir) = git(&["rev-parse", "--absolute-git-dir"]) {
        watch(format!("{dir}/HEAD"));
    }
    if let Some(common) = git(&["rev-parse", "--path-format=absolute", "--git-common-dir"]) {
        watch(format!("{common}/packed-refs"));
        // A directory is scanned for any change: a branch ref written loose after a commit.
        watch(format!("{common}/refs/heads"));
    }
    println!("cargo:rerun-if-changed=build.rs");
}
