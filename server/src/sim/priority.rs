//! Scheduling priority of the deformation loop.
//!
//! On a machine with few cores the deformation loop (a solve that can use
//! every core for tens of milliseconds) and the force loops (one short query
//! per pose, due every millisecond) compete for the same CPUs. The haptic
//! loop is the one with a deadline: the deformation thread and its rayon pool
//! run at a higher *nice* value (lower priority), so that the scheduler lets a
//! force sample preempt them, and the deformation loop takes the time left.
//! Raising the force loops' priority instead would need privileges; lowering
//! one's own never does.

/// Sets the nice value of the calling thread to `nice` (Linux: threads are
/// scheduled individually; 0 leaves the thread as it is). Failures are
/// logged, not fatal: the loops still work, only with less isolation.
pub fn lower_current_thread(nice: i32) {
    if nice <= 0 {
        return;
    }
    #[cfg(target_os = "linux")]
    if let Err(e) =
        rustix::process::setpriority_process(Some(rustix::thread::gettid()), nice.min(19))
    {
        tracing::debug!(error = %e, nice, "cannot lower the deformation thread's priority");
    }
    #[cfg(not(target_os = "linux"))]
    tracing::debug!(nice, "thread priorities are only set on Linux");
}

/// The nice value of the calling thread (Linux), for tests and logs.
pub fn current_thread_nice() -> Option<i32> {
    #[cfg(target_os = "linux")]
    {
        rustix::process::getpriority_process(Some(rustix::thread::gettid())).ok()
    }
    #[cfg(not(target_os = "linux"))]
    None
}

/// A rayon pool for the deformation loop whose threads run at `nice`, so that
/// the solver's parallel work yields to the force loops too. Falls back to
/// `None` (the global pool) if the pool cannot be built.
pub fn deformation_pool(nice: i32) -> Option<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .thread_name(|i| format!("deformation-{i}"))
        .start_handler(move |_| lower_current_thread(nice))
        .build()
        .map_err(|e| tracing::warn!(error = %e, "cannot build the deformation thread pool"))
        .ok()
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn a_lowered_thread_and_its_pool_run_at_the_given_nice_value() {
        let base = std::thread::spawn(current_thread_nice).join().unwrap();
        let base = base.expect("getpriority works on Linux");
        let got = std::thread::spawn(|| {
            lower_current_thread(7);
            current_thread_nice()
        })
        .join()
        .unwrap();
        assert_eq!(got, Some(base.clamp(7, 19)));
        let pool = deformation_pool(9).expect("a pool");
        let in_pool = pool.install(current_thread_nice);
        assert_eq!(in_pool, Some(base.clamp(9, 19)));
    }
}
