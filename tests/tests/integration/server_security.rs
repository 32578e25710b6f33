//! TLS (rustls) and the bearer token of instrument claims, on the `cube` scene.

use fissure_engine::sim::SimOptions;
use fissure_proto::v1 as pb;
use fissure_proto::v1::fissure_client::FissureClient;
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};
use tonic::transport::{Certificate, Channel, ClientTlsConfig};

const FLAT_DOWN: [f64; 4] = [0.5, -0.5, 0.5, 0.5];
const LEFT_HOME: [f64; 3] = [0.011, 0.005, 0.04275];
const TOKEN: &str = "b7Jq2-correct-horse";

/// A self-signed certificate for `localhost` and `127.0.0.1`: (cert PEM, key PEM).
fn self_signed() -> anyhow::Result<(String, String)> {
    let ck = rcgen::generate_simple_self_signed(vec!["localhost".into(), "127.0.0.1".into()])?;
    Ok((ck.cert.pem(), ck.signing_key.serialize_pem()))
}

/// A client over TLS that trusts `ca_pem` only.
async fn tls_client(url: &str, ca_pem: &str) -> anyhow::Result<FissureClient<Channel>> {
    let channel = Channel::from_shared(url.to_owned())?
        .tls_config(
            ClientTlsConfig::new()
                .ca_certificate(Certificate::from_pem(ca_pem))
                .domain_name("localhost"),
        )?
        .connect()
        .await?;
    Ok(FissureClient::new(channel))
}

async fn one_sample(haptic: &mut Haptic) -> anyhow::Result<pb::ForceSample> {
    let s = haptic.send(pose(0.0, 1, LEFT_HOME, FLAT_DOWN)).await?;
    assert!(s.rejection.is_none(), "{:?}", s.rejection);
    Ok(s)
}

/// With a token configured, a claim without it or with a wrong one (also one
/// that merely starts with the right token, or lacks the `Bearer ` scheme) is
/// UNAUTHENTICATED and claims nothing; the right token claims and is served.
/// Calls that claim nothing (scene, stats) need no token.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_token_guards_claims() -> anyhow::Result<()> {
    let server = TestServer::start(
        "cube",
        SimOptions::default(),
        ServeOptions {
            token: Some(TOKEN.into()),
            tls: None,
        },
    )
    .await?;
    let mut client = server.client().await?;
    let err = Haptic::open(&mut client, "left", None).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated, "{err}");
    assert!(err.message().contains("Bearer"), "{err}");
    for wrong in ["wrong", "b7Jq2-correct-horse-battery", "b7Jq2-correct-hors"] {
        let err = Haptic::open(&mut client, "left", Some(wrong))
            .await
            .unwrap_err();
        assert_eq!(err.code(), tonic::Code::Unauthenticated, "{wrong:?}: {err}");
    }
    // The token without the scheme.
    let (_tx, rx) = tokio::sync::mpsc::channel::<pb::PoseSample>(1);
    let mut req = tonic::Request::new(tokio_stream::wrappers::ReceiverStream::new(rx));
    req.metadata_mut()
        .insert("fissure-instrument", "left".parse()?);
    req.metadata_mut().insert("authorization", TOKEN.parse()?);
    let err = client.haptic(req).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated, "{err}");
    // An unknown instrument with a wrong token: the token is checked first,
    // so the scene's instruments are not revealed.
    let err = Haptic::open(&mut client, "centre", Some("wrong"))
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated, "{err}");

    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert!(stats.claimed.is_empty(), "{:?}", stats.claimed);
    assert_eq!(stats.force_samples, 0);
    let scene = client.get_scene(pb::GetSceneRequest {}).await?.into_inner();
    assert_eq!(scene.name, "cube");

    let mut haptic = Haptic::open(&mut client, "left", Some(TOKEN)).await?;
    let s = one_sample(&mut haptic).await?;
    assert_eq!(s.sequence, 1);
    haptic.close().await;
    server.stop().await
}

/// TLS with a self-signed certificate for localhost: a client that trusts it
/// connects, claims with the token and is served; a plaintext client and a
/// TLS client that does not trust the certificate cannot call at all.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_with_self_signed_certificate() -> anyhow::Result<()> {
    let (cert, key) = self_signed()?;
    let server = TestServer::start(
        "cube",
        SimOptions::default(),
        ServeOptions {
            token: Some(TOKEN.into()),
            tls: Some((cert.clone().into_bytes(), key.into_bytes())),
        },
    )
    .await?;
    assert!(
        server.url.starts_with("https://localhost:"),
        "{}",
        server.url
    );
    let mut client = tls_client(&server.url, &cert).await?;
    let scene = client.get_scene(pb::GetSceneRequest {}).await?.into_inner();
    assert_eq!(scene.name, "cube");
    let err = Haptic::open(&mut client, "left", None).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated, "{err}");
    let mut haptic = Haptic::open(&mut client, "left", Some(TOKEN)).await?;
    one_sample(&mut haptic).await?;
    // A watcher over TLS gets full frames.
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await?
        .into_inner();
    let frame = watch.message().await?.expect("a frame");
    assert_eq!(
        frame.positions_m.len(),
        3 * server.sim.model().rest_surface.len()
    );
    drop(watch);
    haptic.close().await;

    // Plaintext HTTP/2 to a TLS port: no call succeeds.
    let plain = format!("http://{}", server.addr);
    let plain_result = async {
        let mut c = fissure_cli::client::replay::connect(&plain).await?;
        c.get_scene(pb::GetSceneRequest {}).await?;
        anyhow::Ok(())
    }
    .await;
    assert!(plain_result.is_err(), "a plaintext call succeeded over TLS");
    // A client trusting another certificate: the handshake fails.
    let (other, _) = self_signed()?;
    let untrusted = async {
        let mut c = tls_client(&server.url, &other).await?;
        c.get_scene(pb::GetSceneRequest {}).await?;
        anyhow::Ok(())
    }
    .await;
    let err = untrusted.expect_err("a client trusting another certificate connected");
    assert!(
        format!("{err:?}").to_lowercase().contains("certificate")
            || format!("{err:?}").to_lowercase().contains("invalid"),
        "{err:?}"
    );
    server.stop().await
}
