//! Streaming a trajectory to a server as one haptic client, and collecting the
//! force samples.

use crate::client::trajectory::Trajectory;
use anyhow::{Context, bail};
use fissure_proto::v1 as pb;
use fissure_proto::v1::fissure_client::FissureClient;
use fissure_proto::{AUTHORIZATION_METADATA_KEY, INSTRUMENT_METADATA_KEY};
use std::time::{Duration, Instant};
use tonic::transport::Channel;

/// How poses are paced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Pacing {
    /// Each pose is sent at its timestamp (wall clock, from the start).
    #[default]
    Realtime,
    /// Each pose is sent as soon as the previous force sample came back.
    Fast,
}

/// One row of a forces file.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ForceRow {
    /// Pose time, s.
    pub t_s: f64,
    /// Pose sequence.
    pub sequence: u64,
    /// Force on the instrument, N.
    pub force_n: [f64; 3],
    /// Torque about the handle point, N m.
    pub torque_nm: [f64; 3],
    /// Contact vertices.
    pub contact_count: u32,
    /// Deformation frame used.
    pub model_frame: u64,
    /// Safety flags.
    pub safety_flags: u32,
    /// Server compute time, us.
    pub server_us: f64,
    /// Round trip measured by the client, us.
    pub rtt_us: f64,
    /// Handle position sent, m.
    pub position_m: [f64; 3],
}

/// The CSV header of forces files.
pub const FORCES_HEADER: &str = "t_s,sequence,fx_n,fy_n,fz_n,tx_nm,ty_nm,tz_nm,contact_count,model_frame,safety_flags,server_us,rtt_us,x_m,y_m,z_m";

/// Writes force rows as CSV.
pub fn forces_csv(rows: &[ForceRow]) -> String {
    let mut s = String::from(FORCES_HEADER);
    s.push('\n');
    for r in rows {
        s.push_str(&format!(
            "{:.6},{},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{:.9e},{},{},{},{:.1},{:.1},{:.9},{:.9},{:.9}\n",
            r.t_s,
            r.sequence,
            r.force_n[0],
            r.force_n[1],
            r.force_n[2],
            r.torque_nm[0],
            r.torque_nm[1],
            r.torque_nm[2],
            r.contact_count,
            r.model_frame,
            r.safety_flags,
            r.server_us,
            r.rtt_us,
            r.position_m[0],
            r.position_m[1],
            r.position_m[2],
        ));
    }
    s
}

/// Connects to a server URL such as `http://127.0.0.1:50051`.
pub async fn connect(url: &str) -> anyhow::Result<FissureClient<Channel>> {
    let channel = Channel::from_shared(url.to_owned())
        .with_context(|| format!("invalid server URL {url:?}"))?
        .tcp_nodelay(true)
        .connect()
        .await
        .with_context(|| format!("cannot connect to {url}"))?;
    Ok(FissureClient::new(channel))
}

/// Builds a haptic request with the claim metadata.
pub fn haptic_request<S>(
    stream: S,
    instrument: &str,
    token: Option<&str>,
) -> anyhow::Result<tonic::Request<S>> {
    let mut req = tonic::Request::new(stream);
    req.metadata_mut().insert(
        INSTRUMENT_METADATA_KEY,
        instrument
            .parse()
            .context("instrument name is not valid metadata")?,
    );
    if let Some(t) = token {
        req.metadata_mut().insert(
            AUTHORIZATION_METADATA_KEY,
            format!("Bearer {t}")
                .parse()
                .context("token is not valid metadata")?,
        );
    }
    Ok(req)
}

/// A pose message from a waypoint.
pub fn pose_message(p: &crate::client::trajectory::Waypoint, sequence: u64) -> pb::PoseSample {
    pb::PoseSample {
        t_s: p.t_s,
        sequence,
        position_m: Some(pb::Vec3 {
            x: p.x_m,
            y: p.y_m,
            z: p.z_m,
        }),
        orientation: Some(pb::Quaternion {
            w: p.qw,
            x: p.qx,
            y: p.qy,
            z: p.qz,
        }),
    }
}

/// Replays `trajectory` as `instrument`, one pose at a time (the next pose goes
/// out when the previous force sample came back, and not before its timestamp in
/// real-time pacing). `progress` is called with the fraction done.
pub async fn replay(
    client: &mut FissureClient<Channel>,
    instrument: &str,
    token: Option<&str>,
    trajectory: &Trajectory,
    pacing: Pacing,
    mut progress: impl FnMut(f64),
) -> anyhow::Result<Vec<ForceRow>> {
    let (tx, rx) = tokio::sync::mpsc::channel::<pb::PoseSample>(16);
    let req = haptic_request(
        tokio_stream::wrappers::ReceiverStream::new(rx),
        instrument,
        token,
    )?;
    let mut inbound = client
        .haptic(req)
        .await
        .with_context(|| format!("claiming instrument {instrument:?}"))?
        .into_inner();
    let start = Instant::now();
    let t0 = trajectory.points.first().map_or(0.0, |p| p.t_s);
    let n = trajectory.points.len();
    let mut rows = Vec::with_capacity(n);
    for (i, p) in trajectory.points.iter().enumerate() {
        if pacing == Pacing::Realtime {
            let due = Duration::from_secs_f64((p.t_s - t0).max(0.0));
            let elapsed = start.elapsed();
            if due > elapsed {
                tokio::time::sleep(due - elapsed).await;
            }
        }
        let sent = Instant::now();
        tx.send(pose_message(p, i as u64 + 1))
            .await
            .context("the server closed the haptic stream")?;
        let Some(sample) = inbound.message().await.context("reading a force sample")? else {
            bail!("the server ended the haptic stream after {i} samples");
        };
        let rtt_us = sent.elapsed().as_secs_f64() * 1e6;
        if let Some(r) = &sample.rejection {
            bail!("pose {} (t = {} s) rejected: {}", i + 1, p.t_s, r.message);
        }
        let f = sample.force_n.unwrap_or_default();
        let tq = sample.torque_nm.unwrap_or_default();
        rows.push(ForceRow {
            t_s: sample.t_s,
            sequence: sample.sequence,
            force_n: [f.x, f.y, f.z],
            torque_nm: [tq.x, tq.y, tq.z],
            contact_count: sample.contact_count,
            model_frame: sample.model_frame,
            safety_flags: sample.safety_flags,
            server_us: sample.server_compute_us,
            rtt_us,
            position_m: [p.x_m, p.y_m, p.z_m],
        });
        if i % 50 == 0 || i + 1 == n {
            progress((i + 1) as f64 / n as f64);
        }
    }
    drop(tx);
    // Drain the end of the stream so the claim is released before returning.
    while let Ok(Some(_)) = inbound.message().await {}
    Ok(rows)
}
