//! Scheduling priorities of the loops.
//!
//! On a machine with few cores the deformation loop (a solve that can use
//! every core for tens of milliseconds) and the force loops (one short query
//! per pose, due every millisecond) compete for the same CPUs, with the gRPC
//! runtime and the watchers' frames. The haptic loop is the one with a
//! deadline:
//!
//! * the deformation thread and its rayon pool run at a higher *nice* value
//!   (lower priority), so that the scheduler lets a force sample preempt them
//!   and the deformation loop takes the time left; lowering one's own priority
//!   never needs privileges;
//! * each force loop asks for a real-time policy (`SCHED_FIFO`, priority
//!   [`DEFAULT_FORCE_LOOP_RT_PRIORITY`] of 1-99), as haptic servo loops do, so
//!   that no ordinary thread (the runtime encoding frames, another process)
//!   delays a sample once its pose has arrived. This needs `CAP_SYS_NICE` (or
//!   an `RLIMIT_RTPRIO` allowance); without it the loop logs why once and runs
//!   at normal priority. A force loop sleeps between poses and a sample takes
//!   well under a millisecond, so it cannot monopolise a CPU; Linux's
//!   real-time throttling (`sched_rt_runtime_us`) bounds it regardless;
//! * the gRPC transport (the runtime whose workers read poses off the sockets
//!   and write force samples back: the service's `Transport`) asks for
//!   `SCHED_FIFO` one step below the force loops
//!   ([`DEFAULT_TRANSPORT_RT_PRIORITY`]). A pose crosses it twice per round
//!   trip; at normal priority, beside the solver, a woken worker now and then
//!   ran about a millisecond late (measured), and a 1 kHz sample was then
//!   late. Its workers sleep in `epoll` between messages.
//!
//! Linux threads inherit the policy of the thread that creates them, so a
//! thread spawned from a real-time worker is real-time too: every loop sets
//! its own policy when it starts ([`lower_current_thread`] and
//! [`raise_current_thread`] both leave a real-time thread at normal policy
//! when asked for none).

/// Sets the nice value of the calling thread to `nice` (Linux: threads are
/// scheduled individually; 0 leaves the thread as it is), or leaves it where
/// it is when it already runs nicer: a server started under `nice` is never
/// raised, even where the privilege to raise it is held. Failures are
/// logged, not fatal: the loops still work, only with less isolation.
///
/// A thread that inherited a real-time policy (spawned from a real-time
/// thread) is first put back under the normal policy.
pub fn lower_current_thread(nice: i32) {
    if let Err(why) = leave_realtime() {
        tracing::warn!(%why, "a thread that inherited a real-time policy keeps it");
    }
    if nice <= 0 {
        return;
    }
    #[cfg(target_os = "linux")]
    if let Err(e) = rustix::process::setpriority_process(
        Some(rustix::thread::gettid()),
        nice.min(19).max(current_thread_nice().unwrap_or(0)),
    ) {
        tracing::debug!(error = %e, nice, "cannot lower the deformation thread's priority");
    }
    #[cfg(not(target_os = "linux"))]
    tracing::debug!(nice, "thread priorities are only set on Linux");
}

/// Puts the calling thread back under the normal policy (`SCHED_OTHER`, nice
/// 0) if it runs under a real-time one; does nothing otherwise. Leaving a
/// real-time policy never needs privileges.
pub fn leave_realtime() -> Result<(), String> {
    #[cfg(target_os = "linux")]
    {
        use thread_priority::unix::{
            NormalThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy,
            thread_native_id, thread_schedule_policy,
        };
        let policy = thread_schedule_policy().map_err(|e| e.to_string())?;
        if !matches!(policy, ThreadSchedulePolicy::Realtime(_)) {
            return Ok(());
        }
        // The crate maps its 0-99 scale onto nice values (48 is nice 0); the
        // nice value is then set exactly, in case that mapping changes (the
        // transport's test checks SCHED_OTHER at nice 0).
        let value =
            thread_priority::ThreadPriorityValue::try_from(48u8).map_err(|e| e.to_string())?;
        set_thread_priority_and_policy(
            thread_native_id(),
            thread_priority::ThreadPriority::Crossplatform(value),
            ThreadSchedulePolicy::Normal(NormalThreadSchedulePolicy::Other),
        )
        .map_err(|e| e.to_string())?;
        rustix::process::setpriority_process(Some(rustix::thread::gettid()), 0)
            .map_err(|e| e.to_string())
    }
    #[cfg(not(target_os = "linux"))]
    Ok(())
}

/// Default real-time priority of the force loops (`SCHED_FIFO`, 1-99; 0 asks
/// for none). Low in the real-time range: above every ordinary thread, below
/// the kernel's own real-time threads.
pub const DEFAULT_FORCE_LOOP_RT_PRIORITY: u8 = 10;

/// Default real-time priority of the gRPC transport's workers (`SCHED_FIFO`;
/// 0 asks for none): one below the force loops, so that the transport never
/// preempts a force sample and preempts every ordinary thread.
pub const DEFAULT_TRANSPORT_RT_PRIORITY: u8 = 9;

/// Puts the calling thread under `SCHED_FIFO` at `priority` (1-99). With 0
/// it asks for none: a thread that inherited a real-time policy is put back
/// under the normal one ([`leave_realtime`]). `Ok(false)` when nothing was
/// asked; an error (not permitted, or not Linux) says why, and the thread
/// keeps its policy.
pub fn raise_current_thread(priority: u8) -> Result<bool, String> {
    if priority == 0 {
        return leave_realtime().map(|()| false);
    }
    #[cfg(target_os = "linux")]
    {
        use thread_priority::unix::{
            RealtimeThreadSchedulePolicy, ThreadSchedulePolicy, set_thread_priority_and_policy,
            thread_native_id,
        };
        let value = thread_priority::ThreadPriorityValue::try_from(priority.min(99))
            .map_err(|e| e.to_string())?;
        set_thread_priority_and_policy(
            thread_native_id(),
            thread_priority::ThreadPriority::Crossplatform(value),
            ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
        )
        .map(|()| true)
        .map_err(|e| e.to_string())
    }
    #[cfg(not(target_os = "linux"))]
    Err("real-time priorities are only set on Linux".into())
}

/// The CPUs the calling thread may run on (Linux; `None` elsewhere or on
/// error), in increasing order.
pub fn allowed_cpus() -> Option<Vec<usize>> {
    #[cfg(target_os = "linux")]
    {
        let set = rustix::thread::sched_getaffinity(None).ok()?;
        Some(
            (0..rustix::thread::CpuSet::MAX_CPU)
                .filter(|&c| set.is_set(c))
                .collect(),
        )
    }
    #[cfg(not(target_os = "linux"))]
    None
}

/// Restricts the calling thread to CPU `cpu` (Linux); an error says why.
pub fn pin_current_thread(cpu: usize) -> Result<(), String> {
    #[cfg(target_os = "linux")]
    {
        let mut set = rustix::thread::CpuSet::new();
        set.set(cpu);
        rustix::thread::sched_setaffinity(None, &set).map_err(|e| e.to_string())
    }
    #[cfg(not(target_os = "linux"))]
    Err(format!("threads are only pinned on Linux (CPU {cpu})"))
}

/// Whether the calling thread runs under a real-time policy, and at which
/// priority (Linux; `None` elsewhere or on error), for tests and logs.
pub fn current_thread_realtime() -> Option<(bool, u8)> {
    #[cfg(target_os = "linux")]
    {
        use thread_priority::unix::{ThreadSchedulePolicy, thread_schedule_policy};
        let policy = thread_schedule_policy().ok()?;
        let rt = matches!(policy, ThreadSchedulePolicy::Realtime(_));
        let prio = match thread_priority::get_current_thread_priority().ok()? {
            thread_priority::ThreadPriority::Crossplatform(v) => v.into(),
            _ => 0,
        };
        Some((rt, if rt { prio } else { 0 }))
    }
    #[cfg(not(target_os = "linux"))]
    None
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

    #[test]
    fn a_raised_thread_runs_fifo_at_the_priority_or_says_why_not() {
        let (asked, state) = std::thread::spawn(|| {
            let asked = raise_current_thread(12);
            (asked, current_thread_realtime())
        })
        .join()
        .unwrap();
        match asked {
            // Privileged (CAP_SYS_NICE or RLIMIT_RTPRIO): the policy took.
            Ok(true) => assert_eq!(state, Some((true, 12))),
            Ok(false) => panic!("a non-zero priority was asked"),
            // Unprivileged: the thread keeps its ordinary policy.
            Err(why) => {
                assert!(!why.is_empty());
                assert_eq!(state.map(|s| s.0), Some(false));
            }
        }
        // 0 asks for nothing.
        let untouched = std::thread::spawn(|| (raise_current_thread(0), current_thread_realtime()))
            .join()
            .unwrap();
        assert_eq!(untouched.0, Ok(false));
        assert_eq!(untouched.1.map(|s| s.0), Some(false));
    }

    #[test]
    fn a_pinned_thread_runs_on_its_cpu_only() {
        let cpus = allowed_cpus().expect("sched_getaffinity works on Linux");
        assert!(!cpus.is_empty());
        assert!(cpus.windows(2).all(|w| w[0] < w[1]));
        let last = *cpus.last().unwrap();
        let (pinned, now_allowed, ran_on) = std::thread::spawn(move || {
            let pinned = pin_current_thread(last);
            std::thread::yield_now();
            (pinned, allowed_cpus(), rustix::thread::sched_getcpu())
        })
        .join()
        .unwrap();
        assert_eq!(pinned, Ok(()));
        assert_eq!(now_allowed, Some(vec![last]));
        assert_eq!(ran_on, last);
        // A CPU the thread may not use is refused with a reason.
        let absent = rustix::thread::CpuSet::MAX_CPU - 1;
        if !cpus.contains(&absent) {
            let refused = std::thread::spawn(move || pin_current_thread(absent))
                .join()
                .unwrap();
            assert!(refused.is_err_and(|why| !why.is_empty()));
        }
    }
}
