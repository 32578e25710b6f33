//! Integration tests that measure the process they run in, so that no other
//! test may run beside them: each test here holds [`alone`] for its whole
//! run, and the binary runs one test at a time whatever `--test-threads`
//! says. (Tests that do not measure the process are in the `integration`
//! binary, where they run in parallel.)
//!
//! * `reliability_load`, `reliability_watchers`, `reliability_recording`,
//!   and the flood test of `reliability_poses`: the process's resident memory
//!   (`VmRSS`) must stay flat; another test's servers, clients and solver
//!   caches would add theirs. `reliability_load` and `reliability_poses` also
//!   bound round-trip percentiles.
//! * `server_loops`: round-trip percentiles of a 1 kHz client against the
//!   time of slow deformation steps, and the pace of the samples; other
//!   tests' solvers would take the cores.
//! * `server_bench_loop`: `fissure bench loop` (two 1 kHz clients, watchers
//!   and a stall probe on every CPU) loads the machine and measures it.
//! * `server_priority`: finds the force loop's thread by its name
//!   (`force-loop-left`) among the process's threads; another test's force
//!   loop would have the same name.
//! * `service_logs`: installs the process's global tracing subscriber and
//!   counts the warnings it captures; other tests' servers would log into it.
//!
//! Run one file's tests with a filter: `cargo test -p fissure-tests --test
//! isolated reliability_load::`.

#[path = "../raw_h2/mod.rs"]
mod raw_h2;
#[path = "../reliability_common/mod.rs"]
mod reliability_common;

mod reliability_load;
mod reliability_poses;
mod reliability_recording;
mod reliability_watchers;
mod server_bench_loop;
mod server_loops;
mod server_priority;
mod service_logs;

/// Held by every test of this binary for its whole run.
static ALONE: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// Waits until no other test of this binary runs; the caller runs alone while
/// it holds the guard (not poisoned by a test that failed holding it).
pub async fn alone() -> tokio::sync::MutexGuard<'static, ()> {
    ALONE.lock().await
}

/// [`alone`] for tests that are not async (not within a runtime).
pub fn alone_blocking() -> tokio::sync::MutexGuard<'static, ()> {
    ALONE.blocking_lock()
}
