//! CPU time of the calling thread, for timing summaries that stay meaningful on a shared
//! machine: wall time includes waiting for a core, CPU time does not (cache effects of other
//! processes remain).

/// Nanoseconds the calling thread has run on a CPU (Linux `/proc/thread-self/schedstat`);
/// `None` where that file is unavailable.
pub fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Milliseconds of thread CPU time between two readings (`None` if either is missing).
pub fn cpu_ms(start: Option<u64>, end: Option<u64>) -> Option<f64> {
    Some(end?.saturating_sub(start?) as f64 * 1e-6)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn busy_work_costs_cpu_time_and_sleeping_does_not() {
        let Some(a) = thread_cpu_ns() else {
            return; // Not Linux: nothing to check.
        };
        // 30 ms of spinning, whatever the optimiser makes of the loop body.
        let start = std::time::Instant::now();
        let (mut x, mut i) = (0u64, 0u64);
        while start.elapsed() < std::time::Duration::from_millis(30) {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(i));
            i += 1;
        }
        // A running thread's schedstat is brought up to date at scheduling events; a tickless
        // core may not have had one during the loop.
        std::thread::yield_now();
        let b = thread_cpu_ns();
        std::thread::sleep(std::time::Duration::from_millis(50));
        let c = thread_cpu_ns();
        assert!(cpu_ms(Some(a), b).unwrap() > 0.5);
        assert!(cpu_ms(b, c).unwrap() < 25.0);
    }
}
