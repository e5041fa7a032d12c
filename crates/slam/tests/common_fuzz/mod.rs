//! The fuzz tests' runner: cases from `JOINTLOC_FUZZ_CASES` (default 500, the bounded CI
//! run), seed from `JOINTLOC_FUZZ_SEED` (default 0), no persisted failures.

use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed, TestRunner};

pub fn runner() -> TestRunner {
    let env = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<u64>().ok());
    TestRunner::new(Config {
        cases: env("JOINTLOC_FUZZ_CASES").map_or(500, |n| n as u32),
        rng_seed: RngSeed::Fixed(env("JOINTLOC_FUZZ_SEED").unwrap_or(0)),
        failure_persistence: None,
        ..Config::default()
    })
}

/// Runs `check` on bytes from `strategy`; a failure (or panic) prints the shrunk input.
pub fn fuzz(strategy: impl Strategy<Value = Vec<u8>>, check: impl Fn(&[u8]) -> Result<(), String>) {
    runner()
        .run(&strategy, |bytes| {
            check(&bytes).map_err(TestCaseError::fail)
        })
        .unwrap_or_else(|e| panic!("{e}"));
}
