//! Security limits not covered by the claim, token and TLS tests of
//! `server_*.rs`: message-size limits on the wire and the loopback default of
//! the binary.

use crate::reliability_common::*;
use fissure_engine::sim::SimOptions;
use fissure_proto::v1 as pb;
use fissure_server::{MAX_DECODING_MESSAGE_BYTES, ServeOptions};
use fissure_tests::{Haptic, TestServer};
use prost::Message;
use std::marker::PhantomData;
use std::process::Command;
use tonic::Status;
use tonic::codec::{Codec, DecodeBuf, Decoder, EncodeBuf, Encoder};
use tonic::codegen::http::uri::PathAndQuery;

/// A codec that sends raw bytes (any message, of any size, including ones
/// no generated client would build) and decodes answers as `T`.
struct RawCodec<T>(PhantomData<T>);

struct RawEncoder;

struct RawDecoder<T>(PhantomData<T>);

impl Encoder for RawEncoder {
    type Item = Vec<u8>;
    type Error = Status;
    fn encode(&mut self, item: Vec<u8>, dst: &mut EncodeBuf<'_>) -> Result<(), Status> {
        use prost::bytes::BufMut;
        dst.put_slice(&item);
        Ok(())
    }
}

impl<T: Message + Default + Send + 'static> Decoder for RawDecoder<T> {
    type Item = T;
    type Error = Status;
    fn decode(&mut self, src: &mut DecodeBuf<'_>) -> Result<Option<T>, Status> {
        T::decode(src)
            .map(Some)
            .map_err(|e| Status::internal(e.to_string()))
    }
}

impl<T: Message + Default + Send + 'static> Codec for RawCodec<T> {
    type Encode = Vec<u8>;
    type Decode = T;
    type Encoder = RawEncoder;
    type Decoder = RawDecoder<T>;
    fn encoder(&mut self) -> RawEncoder {
        RawEncoder
    }
    fn decoder(&mut self) -> RawDecoder<T> {
        RawDecoder(PhantomData)
    }
}

/// A pose message padded with an unknown length-delimited field (number 15)
/// to `total` bytes. Decoders skip unknown fields, so only the size matters.
fn padded_pose(sequence: u64, total: usize) -> Vec<u8> {
    let mut buf =
        flat_pose(sequence as f64 * 1e-3, sequence, LEFT_X, TOUCH_Z + 0.001).encode_to_vec();
    // Key (1 byte) + length varint (3 bytes for 16 KiB..2 MiB) + padding.
    let pad = total - buf.len() - 1 - 3;
    prost::encoding::encode_key(15, prost::encoding::WireType::LengthDelimited, &mut buf);
    prost::encoding::encode_varint(pad as u64, &mut buf);
    buf.resize(buf.len() + pad, 0);
    assert_eq!(buf.len(), total);
    buf
}

async fn raw_grpc(url: &str) -> anyhow::Result<tonic::client::Grpc<tonic::transport::Channel>> {
    let channel = tonic::transport::Channel::from_shared(url.to_owned())?
        .connect()
        .await?;
    Ok(tonic::client::Grpc::new(channel))
}

fn assert_size_refusal(status: &Status) {
    assert!(
        matches!(
            status.code(),
            tonic::Code::ResourceExhausted | tonic::Code::OutOfRange
        ),
        "an oversized message got {status:?}"
    );
}

/// A pose of 60 KiB (under the 64 KiB limit) is served; one of 65 KiB ends
/// the stream with RESOURCE_EXHAUSTED or OUT_OF_RANGE and releases the claim;
/// an oversized unary request is refused the same way; the server keeps
/// serving: stats answer, the instrument is claimed again and its poses
/// answered.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn messages_over_64_kib_are_refused_and_the_server_keeps_serving() -> anyhow::Result<()> {
    assert_eq!(MAX_DECODING_MESSAGE_BYTES, 64 * 1024);
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut grpc = raw_grpc(&server.url).await?;
    grpc.ready().await?;
    let (tx, rx) = tokio::sync::mpsc::channel::<Vec<u8>>(4);
    let mut req = tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx));
    req.metadata_mut()
        .insert(fissure_proto::INSTRUMENT_METADATA_KEY, "left".parse()?);
    let mut answers = grpc
        .streaming(
            req,
            PathAndQuery::from_static("/fissure.v1.Fissure/Haptic"),
            RawCodec::<pb::ForceSample>(PhantomData),
        )
        .await?
        .into_inner();
    tx.send(padded_pose(1, 60 * 1024)).await?;
    let a = answers.message().await?.expect("answer to the 60 KiB pose");
    assert!(a.rejection.is_none() && a.sequence == 1, "{a:?}");
    tx.send(padded_pose(2, 65 * 1024)).await?;
    let status = match answers.message().await {
        Ok(Some(a)) => panic!("the 65 KiB pose was answered: {a:?}"),
        Ok(None) => panic!("the stream ended without a status"),
        Err(s) => s,
    };
    assert_size_refusal(&status);
    drop(tx);
    // Unary: an oversized GetStats request.
    grpc.ready().await?;
    let mut big = Vec::new();
    prost::encoding::encode_key(15, prost::encoding::WireType::LengthDelimited, &mut big);
    prost::encoding::encode_varint(1 << 20, &mut big);
    big.resize(big.len() + (1 << 20), 0);
    let err = grpc
        .unary(
            tonic::Request::new(big),
            PathAndQuery::from_static("/fissure.v1.Fissure/GetStats"),
            RawCodec::<pb::Stats>(PhantomData),
        )
        .await
        .expect_err("a 1 MiB request was accepted");
    assert_size_refusal(&err);
    // Still serving.
    let mut client = server.client().await?;
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert_eq!(stats.force_samples, 1);
    let sim = server.sim.clone();
    assert!(
        eventually(std::time::Duration::from_secs(2), || sim
            .stats()
            .claimed
            .is_empty())
        .await,
        "the claim was not released"
    );
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let a = haptic
        .send(flat_pose(0.0, 1, LEFT_X, TOUCH_Z - 0.001))
        .await?;
    assert!(a.rejection.is_none() && a.contact_count > 0, "{a:?}");
    haptic.close().await;
    server.stop().await
}

/// The binary refuses a non-loopback --listen without --allow-remote (before
/// loading anything), and its default listen address is loopback.
#[test]
fn binary_refuses_a_non_loopback_listen_without_allow_remote() {
    for addr in ["0.0.0.0:0", "[::]:0", "192.0.2.1:50051"] {
        let out = Command::new(server_binary())
            .args(["--scene", "cube", "--listen", addr])
            .env_remove("FISSURE_TOKEN")
            .output()
            .expect("running fissure-server");
        assert!(!out.status.success(), "--listen {addr} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("not a loopback address") && err.contains("--allow-remote"),
            "{err}"
        );
    }
    let help = Command::new(server_binary())
        .arg("--help")
        .output()
        .expect("fissure-server --help");
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.contains("[default: 127.0.0.1:50051]"),
        "default listen address is not loopback:\n{help}"
    );
}
