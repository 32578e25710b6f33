//! The runtime the gRPC server runs on: its own tokio runtime, whose threads
//! (`grpc-transport`) ask for a real-time policy.
//!
//! A force sample crosses the transport twice: its pose is read off the
//! socket and handed to the force loop, its answer is handed back and written
//! out. On a machine whose CPUs are busy with the deformation solve, a
//! normal-priority worker woken for either crossing ran, now and then, about
//! a millisecond late (measured with `fissure bench loop`), and a 1 kHz
//! sample then missed its tick. Under `SCHED_FIFO`
//! ([`priority::DEFAULT_TRANSPORT_RT_PRIORITY`], one below the force loops)
//! a woken worker runs at once. The workers sleep in `epoll` between messages
//! and the pose rate of each stream is bounded
//! ([`super::MAX_POSE_RATE_FACTOR`]); Linux's real-time throttling bounds them
//! regardless.
//!
//! The runtime serves the gRPC calls only: scene loading, signal handling and
//! the simulation's threads belong elsewhere (threads inherit the policy of
//! the thread that spawns them; the force loops set their own,
//! [`fissure_engine::sim::Claim::enter_force_thread`]).

use super::{RunningServer, ServeOptions, serve};
use fissure_engine::sim::runtime::priority;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// The gRPC transport's runtime. Dropping it stops its threads without
/// waiting (shut the server down first, [`RunningServer::shutdown`]).
#[derive(Debug)]
pub struct Transport {
    runtime: Option<tokio::runtime::Runtime>,
    priority: u8,
    refused: Arc<AtomicBool>,
}

impl Transport {
    /// Starts the runtime; its threads ask for `SCHED_FIFO` at `rt_priority`
    /// (1-99; 0 asks for none). Where that is not permitted they run at
    /// normal priority and the refusal is logged once ([`Self::realtime`]
    /// says which).
    pub fn new(rt_priority: u8) -> std::io::Result<Self> {
        let refused = Arc::new(AtomicBool::new(false));
        let flag = refused.clone();
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .thread_name("grpc-transport")
            .on_thread_start(move || {
                if let Err(why) = priority::raise_current_thread(rt_priority) {
                    if !flag.swap(true, Ordering::Relaxed) {
                        tracing::warn!(
                            priority = rt_priority,
                            %why,
                            "the gRPC transport runs at normal priority: no real-time scheduling \
                             here (grant CAP_SYS_NICE or an RLIMIT_RTPRIO allowance, or pass 0 to \
                             stop asking)"
                        );
                    }
                }
            })
            .build()?;
        Ok(Self {
            runtime: Some(runtime),
            priority: rt_priority,
            refused,
        })
    }

    /// The runtime's handle (to spawn onto it).
    pub fn handle(&self) -> &tokio::runtime::Handle {
        self.runtime
            .as_ref()
            .expect("the runtime lives as long as the transport")
            .handle()
    }

    /// Whether a real-time priority was asked for and every thread started
    /// so far got it.
    pub fn realtime(&self) -> bool {
        self.priority > 0 && !self.refused.load(Ordering::Relaxed)
    }

    /// [`serve`] on this runtime: binds `addr` and serves `fissure.v1`,
    /// health and reflection from the transport's threads. Callable from any
    /// runtime.
    pub async fn serve(
        &self,
        addr: SocketAddr,
        options: ServeOptions,
    ) -> anyhow::Result<RunningServer> {
        self.handle().spawn(serve(addr, options)).await?
    }
}

impl Drop for Transport {
    fn drop(&mut self) {
        // Never blocks, so the transport may be dropped inside another
        // runtime's task.
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;

    #[test]
    fn transport_threads_run_fifo_at_the_priority_and_threads_they_spawn_can_leave_it() {
        let transport = Transport::new(7).expect("a runtime");
        let h = transport.handle().clone();
        let (on_worker, in_blocking, spawned_default, spawned_none) = h.block_on(async {
            let on_worker = tokio::spawn(async { priority::current_thread_realtime() })
                .await
                .unwrap();
            let in_blocking = tokio::task::spawn_blocking(priority::current_thread_realtime)
                .await
                .unwrap();
            // A thread spawned from a worker inherits its policy ...
            let spawned_default = tokio::spawn(async {
                std::thread::spawn(priority::current_thread_realtime)
                    .join()
                    .unwrap()
            })
            .await
            .unwrap();
            // ... and leaves it when it asks for none.
            let spawned_none = tokio::spawn(async {
                std::thread::spawn(|| {
                    priority::raise_current_thread(0).unwrap();
                    (
                        priority::current_thread_realtime(),
                        priority::current_thread_nice(),
                    )
                })
                .join()
                .unwrap()
            })
            .await
            .unwrap();
            (on_worker, in_blocking, spawned_default, spawned_none)
        });
        if transport.realtime() {
            assert_eq!(on_worker, Some((true, 7)));
            assert_eq!(in_blocking, Some((true, 7)));
            assert_eq!(spawned_default, Some((true, 7)));
        } else {
            // Unprivileged: every thread stays at the normal policy.
            assert_eq!(on_worker.map(|s| s.0), Some(false));
            assert_eq!(spawned_default.map(|s| s.0), Some(false));
        }
        assert_eq!(spawned_none.0, Some((false, 0)));
        if transport.realtime() {
            // Back at the normal policy with nice 0.
            assert_eq!(spawned_none.1, Some(0));
        }
        // Asking for none leaves every thread as it is.
        let plain = Transport::new(0).expect("a runtime");
        assert!(!plain.realtime());
        let state = plain
            .handle()
            .block_on(async { tokio::spawn(async { priority::current_thread_realtime() }).await })
            .unwrap();
        assert_eq!(state.map(|s| s.0), Some(false));
    }
}
