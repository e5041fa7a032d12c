//! One line naming the machine and build, printed on every table and figure.

/// `"<CPU model>, N cores, <profile> build, jointloc <version>"`.
pub fn describe() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let profile = if cfg!(debug_assertions) {
        "debug"
    } else {
        "release"
    };
    format!(
        "{model}, {cores} cores, {profile} build, jointloc {}",
        env!("CARGO_PKG_VERSION")
    )
}
