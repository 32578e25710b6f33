//! The gRPC side of a device bridge, shared by every device protocol: one
//! haptic stream (a lane) per claimed instrument, and the answers still owed.
//!
//! A lane forwards each pose to its stream and remembers, in order, where
//! the answer goes (a `T` of the protocol: a UDP sender and its format, say).
//! The server answers a stream's poses in order, one force sample each, so
//! the answer read from the stream goes to the oldest place remembered. A
//! lane holds at most [`QUEUE`] poses in flight: a pose beyond that is not
//! forwarded ([`Lanes::forward`] says so at once) rather than queued, so a
//! stalled server never delays the device's loop. The places are allocated
//! once, so a sample costs no allocation here.

use crate::client::replay::haptic_request;
use anyhow::Context;
use fissure_proto::v1 as pb;
use fissure_proto::v1::fissure_client::FissureClient;
use std::collections::VecDeque;
use std::future::Future;
use std::sync::{Arc, Mutex};
use tonic::transport::Channel;

/// Poses in flight per instrument before new ones are answered
/// `not forwarded`.
pub const QUEUE: usize = 64;

/// Where a protocol sends the server's answers.
pub trait Answers<T>: Send + 'static {
    /// Sends `sample`, the server's answer to the pose of instrument `index`
    /// (`name`) that was forwarded with the place `to`.
    fn answer(
        &mut self,
        index: usize,
        name: &str,
        to: T,
        sample: pb::ForceSample,
    ) -> impl Future<Output = ()> + Send;
}

/// One instrument's haptic stream.
struct Lane<T> {
    name: String,
    tx: tokio::sync::mpsc::Sender<pb::PoseSample>,
    pending: Arc<Mutex<VecDeque<T>>>,
}

/// The haptic streams of the bridged instruments, in index order.
pub struct Lanes<T> {
    lanes: Vec<Lane<T>>,
    readers: Vec<tokio::task::JoinHandle<()>>,
}

impl<T: Send + 'static> Lanes<T> {
    /// Claims `names` (in index order) on `client`, each answer read from a
    /// stream handed to an `Answers` made by `answers` for that lane.
    pub async fn open<A: Answers<T>>(
        client: &mut FissureClient<Channel>,
        names: &[String],
        token: Option<&str>,
        mut answers: impl FnMut() -> A,
    ) -> anyhow::Result<Self> {
        let mut lanes = Vec::with_capacity(names.len());
        let mut readers = Vec::with_capacity(names.len());
        for (index, name) in names.iter().enumerate() {
            let (tx, rx) = tokio::sync::mpsc::channel::<pb::PoseSample>(QUEUE);
            let req = haptic_request(tokio_stream::wrappers::ReceiverStream::new(rx), name, token)?;
            let mut inbound = client
                .haptic(req)
                .await
                .with_context(|| format!("claiming instrument {name:?}"))?
                .into_inner();
            let pending = Arc::new(Mutex::new(VecDeque::with_capacity(QUEUE + 1)));
            lanes.push(Lane {
                name: name.clone(),
                tx,
                pending: pending.clone(),
            });
            let (mut answers, name) = (answers(), name.clone());
            readers.push(tokio::spawn(async move {
                loop {
                    let sample = match inbound.message().await {
                        Ok(Some(s)) => s,
                        Ok(None) => break,
                        Err(e) => {
                            tracing::warn!("instrument {name}: haptic stream: {e}");
                            break;
                        }
                    };
                    let Some(to) = pending.lock().expect("pending lock").pop_front() else {
                        tracing::warn!("instrument {name}: a force sample without a pose");
                        continue;
                    };
                    answers.answer(index, &name, to, sample).await;
                }
            }));
        }
        Ok(Self { lanes, readers })
    }

    /// Number of lanes.
    pub fn len(&self) -> usize {
        self.lanes.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.lanes.is_empty()
    }

    /// The instrument of lane `index`.
    pub fn name(&self, index: usize) -> &str {
        &self.lanes[index].name
    }

    /// The lane of instrument `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.lanes.iter().position(|l| l.name == name)
    }

    /// Forwards `pose` on lane `index`, its answer owed to `to`; false (and
    /// nothing owed) when the lane has [`QUEUE`] poses in flight or its
    /// stream is closed.
    pub fn forward(&self, index: usize, pose: pb::PoseSample, to: T) -> bool {
        let lane = &self.lanes[index];
        let mut pending = lane.pending.lock().expect("pending lock");
        // Push first: the answer may come back before `try_send` returns.
        pending.push_back(to);
        match lane.tx.try_send(pose) {
            Ok(()) => true,
            Err(_) => {
                pending.pop_back();
                false
            }
        }
    }

    /// Closes the streams (releasing the claims) and waits until the
    /// answers still in flight are handed on.
    pub async fn close(self) {
        drop(self.lanes);
        for r in self.readers {
            let _ = r.await;
        }
    }
}
