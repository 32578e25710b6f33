//! The contract of `fissure.v1` as a client outside this workspace sees it,
//! on the cube scene: which calls need the token, health before and after
//! loading, flow control of a client far ahead of stepped mode, the loop
//! interval reported, reflection (v1 and v1alpha), and the answers to
//! malformed claims, the watcher limit, subnormal quaternions and the stats
//! counters.

use crate::raw_h2;
use crate::reliability_common;

use crate::reliability_common::{FLAT_DOWN, HANDLE_Y, LEFT_X, TOUCH_Z};
use fissure_engine::sim::{Mode, SimOptions};
use fissure_proto::v1 as pb;
use fissure_server::ServeOptions;
use fissure_tests::{Haptic, TestServer, pose};
use std::time::Duration;
use tokio_stream::wrappers::ReceiverStream;

const TOKEN: &str = "Zq8-unit-token";

fn above() -> [f64; 3] {
    [LEFT_X, HANDLE_Y, TOUCH_Z + 0.001]
}

/// A haptic request claiming `left` with the given metadata values.
fn haptic_request(
    metadata: &[(&'static str, &str)],
) -> (
    tokio::sync::mpsc::Sender<pb::PoseSample>,
    tonic::Request<ReceiverStream<pb::PoseSample>>,
) {
    let (tx, rx) = tokio::sync::mpsc::channel(16);
    let mut req = tonic::Request::new(ReceiverStream::new(rx));
    for (k, v) in metadata {
        req.metadata_mut().append(*k, v.parse().unwrap());
    }
    (tx, req)
}

fn with_auth<T>(msg: T, values: &[&str]) -> tonic::Request<T> {
    let mut req = tonic::Request::new(msg);
    for v in values {
        req.metadata_mut()
            .append("authorization", v.parse().unwrap());
    }
    req
}

/// With a token, `Reset` and `Haptic` need it: without it, with a wrong one
/// or with two values they are UNAUTHENTICATED (naming the call) and change
/// nothing (no frame is published); the scheme is accepted in any case
/// (RFC 7235) with one or more spaces. `GetScene`, `GetSurface`, `GetStats`
/// and `Watch` are open.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reset_and_haptic_need_the_token_and_reading_calls_are_open() -> anyhow::Result<()> {
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
    let frames = |c: &mut fissure_proto::v1::fissure_client::FissureClient<_>| {
        let mut c = c.clone();
        async move {
            anyhow::Ok(
                c.get_stats(pb::GetStatsRequest {})
                    .await?
                    .into_inner()
                    .frames,
            )
        }
    };
    // The loop takes one step at the start; nothing changes after it.
    let mut before = frames(&mut client).await?;
    loop {
        tokio::time::sleep(Duration::from_millis(200)).await;
        let now = frames(&mut client).await?;
        if now == before {
            break;
        }
        before = now;
    }
    let refused = [
        (vec![], "requires `authorization: Bearer <token>` for Reset"),
        (vec!["Bearer wrong"], "the bearer token is wrong"),
        (vec![TOKEN], "is not `Bearer <token>`"),
        (vec!["Basic Zm9vOmJhcg=="], "is not `Bearer <token>`"),
        (
            vec!["Bearer wrong", "Bearer Zq8-unit-token"],
            "2 `authorization` values",
        ),
    ];
    for (values, why) in refused {
        let err = client
            .reset(with_auth(pb::ResetRequest {}, &values))
            .await
            .unwrap_err();
        assert_eq!(
            err.code(),
            tonic::Code::Unauthenticated,
            "{values:?}: {err}"
        );
        assert!(err.message().contains(why), "{values:?}: {err}");
    }
    // Nothing was reset: free-running with nothing claimed, no frame since.
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(frames(&mut client).await?, before);
    for value in [
        format!("bearer {TOKEN}"),
        format!("BEARER   {TOKEN}"),
        format!("Bearer {TOKEN}"),
    ] {
        let r = client
            .reset(with_auth(pb::ResetRequest {}, &[value.as_str()]))
            .await?
            .into_inner();
        assert!(r.frame > before, "{value}: frame {}", r.frame);
    }
    // A claim with the scheme in lower case is served.
    let (tx, req) = haptic_request(&[
        ("fissure-instrument", "left"),
        ("authorization", &format!("bearer {TOKEN}")),
    ]);
    let mut answers = client.haptic(req).await?.into_inner();
    tx.send(pose(0.0, 1, above(), FLAT_DOWN)).await?;
    let a = answers.message().await?.expect("an answer");
    assert!(a.rejection.is_none(), "{:?}", a.rejection);
    drop(tx);
    while answers.message().await?.is_some() {}
    let (_tx, req) = haptic_request(&[("fissure-instrument", "left")]);
    let err = client.haptic(req).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated);
    assert!(err.message().contains("for Haptic"), "{err}");

    // The calls that only read need no token.
    let scene = client.get_scene(pb::GetSceneRequest {}).await?.into_inner();
    assert_eq!(scene.name, "cube");
    let surface = client
        .get_surface(pb::GetSurfaceRequest {})
        .await?
        .into_inner();
    assert!(!surface.triangles.is_empty());
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: false,
        })
        .await?
        .into_inner();
    assert!(watch.message().await?.is_some());
    server.stop().await
}

/// Health answers NOT_SERVING for the server as a whole ("", what probes
/// ask by default) and for `fissure.v1.Fissure` while the scene loads, and
/// SERVING for both once it is loaded and factorized.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_is_not_serving_for_the_server_or_the_service_until_loaded() -> anyhow::Result<()> {
    use tonic_health::pb::HealthCheckRequest;
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::health_client::HealthClient;
    let server = fissure_server::serve("127.0.0.1:0".parse()?, ServeOptions::default()).await?;
    let channel = tonic::transport::Channel::from_shared(format!("http://{}", server.addr))?
        .connect()
        .await?;
    let mut health = HealthClient::new(channel);
    let status = |name: &'static str| {
        let mut h = health.clone();
        async move {
            anyhow::Ok(
                h.check(HealthCheckRequest {
                    service: name.into(),
                })
                .await?
                .into_inner()
                .status,
            )
        }
    };
    for name in fissure_server::HEALTH_SERVICES {
        assert_eq!(
            status(name).await?,
            ServingStatus::NotServing as i32,
            "{name:?}"
        );
    }
    let (scene, _) = fissure_engine::scene::Scene::load("cube")?;
    let sim = tokio::task::spawn_blocking(move || {
        fissure_engine::sim::Simulation::start(scene, SimOptions::default())
    })
    .await??;
    // Still loading as far as clients know, until the service has it.
    assert_eq!(status("").await?, ServingStatus::NotServing as i32);
    server.set_simulation(sim.clone()).await;
    for name in fissure_server::HEALTH_SERVICES {
        assert_eq!(
            status(name).await?,
            ServingStatus::Serving as i32,
            "{name:?}"
        );
    }
    let _ = health.check(HealthCheckRequest::default()).await?;
    server.shutdown().await?;
    tokio::task::spawn_blocking(move || sim.shutdown()).await?;
    Ok(())
}

/// Stepped mode: a client that sends 5,000 poses (5 s of a press, one
/// HTTP/2 frame each, as C-core clients send them) without waiting for their
/// answers, far ahead of the deformation steps that answer them, is held
/// back by HTTP/2 flow control, not disconnected: every pose is answered, in
/// order, and the connection serves a unary call after. (With hyper's
/// default 1 MiB stream window the server's HTTP/2 layer buffered the
/// unread poses until their framing overhead exceeded its budget, and closed
/// the connection with GOAWAY ENHANCE_YOUR_CALM.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stepped_client_far_ahead_of_the_steps_is_held_back_not_disconnected()
-> anyhow::Result<()> {
    let server = TestServer::start(
        "cube",
        SimOptions {
            mode: Some(Mode::Stepped { clients: 1 }),
            ..Default::default()
        },
        ServeOptions::default(),
    )
    .await?;
    const N: u64 = 5_000;
    let mut conn = raw_h2::connect(server.addr).await?;
    let (resp, mut stream) =
        raw_h2::call(&mut conn, "Haptic", &[("fissure-instrument", "left")], None).await?;
    // Queued at once: the client's HTTP/2 layer sends them as fast as the
    // server's window lets it.
    for k in 0..N {
        let depth = 0.002 * (k as f64 / N as f64);
        let p = pose(
            k as f64 * 1e-3,
            k + 1,
            [LEFT_X, HANDLE_Y, TOUCH_Z - depth],
            FLAT_DOWN,
        );
        stream.send_data(raw_h2::frame(&p), k + 1 == N)?;
    }
    let started = std::time::Instant::now();
    let mut answers = raw_h2::Reader::new(resp).await?;
    let mut next = 1;
    let end = loop {
        match tokio::time::timeout(Duration::from_secs(60), answers.next::<pb::ForceSample>())
            .await?
        {
            Ok(a) => {
                assert_eq!(a.sequence, next, "answers in order");
                assert!(a.rejection.is_none(), "{:?}", a.rejection);
                next += 1;
            }
            Err(end) => break end,
        }
    };
    eprintln!(
        "stepped, far ahead: {} answers in {:.2} s",
        next - 1,
        started.elapsed().as_secs_f64()
    );
    assert_eq!(end.0, 0, "the stream ends with OK: {end:?}");
    assert_eq!(next - 1, N);
    let (stats, _s) = raw_h2::call(
        &mut conn,
        "GetStats",
        &[],
        Some(raw_h2::frame(&pb::GetStatsRequest {})),
    )
    .await?;
    let stats: pb::Stats = raw_h2::Reader::new(stats)
        .await?
        .next()
        .await
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    assert_eq!(stats.force_samples, N);
    assert!(stats.frames > 200, "{} frames", stats.frames);
    server.stop().await
}

/// Free-running, `GetScene` reports the scene's interval (0.02 s) and
/// frames are at least that far apart in simulation (wall-clock) time while
/// a client moves at 1 kHz: the interval is the shortest time between steps.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn free_running_frames_are_at_least_the_reported_interval_apart() -> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let loops = client
        .get_scene(pb::GetSceneRequest {})
        .await?
        .into_inner()
        .loops
        .expect("loops");
    assert!(!loops.stepped);
    assert_eq!(loops.deformation_interval_s, 0.02);
    let mut watch = client
        .watch(pb::WatchRequest {
            include_positions: false,
        })
        .await?
        .into_inner();
    let frames = tokio::spawn(async move {
        let mut times = Vec::new();
        while let Ok(Some(f)) = watch.message().await {
            times.push((f.frame, f.sim_time_s));
        }
        times
    });
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    for k in 0..1_000u64 {
        let z = TOUCH_Z + 0.001 - 0.002 * (k as f64 / 1000.0);
        haptic
            .send(pose(
                k as f64 * 1e-3,
                k + 1,
                [LEFT_X, HANDLE_Y, z],
                FLAT_DOWN,
            ))
            .await?;
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    haptic.close().await;
    server.stop().await?;
    let times = frames.await?;
    let steps: Vec<(u64, f64)> = times.into_iter().filter(|(f, _)| *f > 0).collect();
    assert!(steps.len() >= 10, "{} frames", steps.len());
    for w in steps.windows(2) {
        let dt = w[1].1 - w[0].1;
        assert!(
            dt >= loops.deformation_interval_s - 1e-9,
            "frames {} and {} are {dt} s apart",
            w[0].0,
            w[1].0
        );
    }
    Ok(())
}

/// Reflection answers on `grpc.reflection.v1` and `v1alpha` alike: the
/// services, an unknown symbol as an in-band NOT_FOUND error response that
/// leaves the stream open, then the file of a known symbol on the same
/// stream, with the language options (Go, Java, C#) set.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reflection_v1_and_v1alpha_answer_unknown_symbols_in_band() -> anyhow::Result<()> {
    use prost::Message;
    use tonic_reflection::pb::{v1, v1alpha};
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let channel = tonic::transport::Channel::from_shared(server.url.clone())?
        .connect()
        .await?;
    let queries = [
        v1::server_reflection_request::MessageRequest::ListServices(String::new()),
        v1::server_reflection_request::MessageRequest::FileContainingSymbol(
            "fissure.v1.NoSuchMessage".into(),
        ),
        v1::server_reflection_request::MessageRequest::FileContainingSymbol(
            "fissure.v1.Fissure.Haptic".into(),
        ),
        v1::server_reflection_request::MessageRequest::FileByFilename("nope.proto".into()),
        v1::server_reflection_request::MessageRequest::FileByFilename(
            "fissure/v1/fissure.proto".into(),
        ),
    ];
    let check = |answers: Vec<v1::server_reflection_response::MessageResponse>| {
        use v1::server_reflection_response::MessageResponse as R;
        assert_eq!(answers.len(), 5, "{answers:?}");
        match &answers[0] {
            R::ListServicesResponse(l) => {
                let names: Vec<_> = l.service.iter().map(|s| s.name.as_str()).collect();
                assert!(
                    names.contains(&"fissure.v1.Fissure")
                        && names.contains(&"grpc.health.v1.Health")
                        && names.contains(&"grpc.reflection.v1alpha.ServerReflection"),
                    "{names:?}"
                );
            }
            other => panic!("{other:?}"),
        }
        for k in [1, 3] {
            match &answers[k] {
                R::ErrorResponse(e) => assert_eq!(e.error_code, tonic::Code::NotFound as i32),
                other => panic!("{other:?}"),
            }
        }
        for k in [2, 4] {
            match &answers[k] {
                R::FileDescriptorResponse(f) => {
                    let file =
                        prost_types::FileDescriptorProto::decode(&*f.file_descriptor_proto[0])
                            .unwrap();
                    assert_eq!(file.name(), "fissure/v1/fissure.proto");
                    // The options code generators of other languages read;
                    // Java's outer class is not `Fissure`, the service.
                    let o = file.options.unwrap();
                    assert_eq!(o.java_outer_classname(), "FissureProto");
                    assert_eq!(o.java_package(), "invalid.example.fissure.v1");
                    assert!(o.java_multiple_files());
                    assert_eq!(o.csharp_namespace(), "Fissure.V1");
                    assert!(o.go_package().ends_with("fissure/v1;fissurev1"), "{o:?}");
                }
                other => panic!("{other:?}"),
            }
        }
    };

    // v1
    let mut c = v1::server_reflection_client::ServerReflectionClient::new(channel.clone());
    let (tx, rx) = tokio::sync::mpsc::channel(8);
    let mut answers = c
        .server_reflection_info(ReceiverStream::new(rx))
        .await?
        .into_inner();
    let mut got = Vec::new();
    for q in &queries {
        tx.send(v1::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(q.clone()),
        })
        .await?;
        let a = answers
            .message()
            .await?
            .expect("an answer, the stream open");
        got.push(a.message_response.expect("a response"));
    }
    check(got);

    // v1alpha: the same answers, re-encoded.
    let mut c = v1alpha::server_reflection_client::ServerReflectionClient::new(channel);
    let (tx, rx) = tokio::sync::mpsc::channel(8);
    let mut answers = c
        .server_reflection_info(ReceiverStream::new(rx))
        .await?
        .into_inner();
    let mut got = Vec::new();
    for q in &queries {
        let req = v1::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(q.clone()),
        };
        tx.send(v1alpha::ServerReflectionRequest::decode(
            req.encode_to_vec().as_slice(),
        )?)
        .await?;
        let a = answers
            .message()
            .await?
            .expect("an answer, the stream open");
        let a = v1::ServerReflectionResponse::decode(a.encode_to_vec().as_slice())?;
        got.push(a.message_response.expect("a response"));
    }
    check(got);
    drop(tx);
    assert!(
        answers.message().await?.is_none(),
        "ends when the client ends"
    );
    server.stop().await
}

/// A claim with two `fissure-instrument` values is INVALID_ARGUMENT naming
/// both, and claims nothing; a watcher beyond the limit is told the limit
/// and the flag that sets it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ambiguous_claims_and_the_watcher_limit_are_named() -> anyhow::Result<()> {
    let server = TestServer::start(
        "cube",
        SimOptions {
            max_watchers: 1,
            ..Default::default()
        },
        ServeOptions::default(),
    )
    .await?;
    let mut client = server.client().await?;
    let (_tx, req) = haptic_request(&[
        ("fissure-instrument", "left"),
        ("fissure-instrument", "right"),
    ]);
    let err = client.haptic(req).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument, "{err}");
    assert!(
        err.message()
            .contains("2 `fissure-instrument` values given (\"left\", \"right\")"),
        "{err}"
    );
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert!(stats.claimed.is_empty(), "{:?}", stats.claimed);

    let request = || pb::WatchRequest {
        include_positions: false,
    };
    let mut first = client.watch(request()).await?.into_inner();
    assert!(first.message().await?.is_some());
    let err = client.watch(request()).await.unwrap_err();
    assert_eq!(err.code(), tonic::Code::ResourceExhausted, "{err}");
    assert!(
        err.message().contains("at most 1") && err.message().contains("--max-watchers"),
        "{err}"
    );
    drop(first);
    server.stop().await
}

/// A quaternion of subnormal components is rejected with its own norm
/// (5e-324), not "norm 0"; `Stats.force_samples` counts the accepted poses
/// only and `rejected_poses` every rejection (invalid values and missing
/// fields alike).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subnormal_quaternions_report_their_norm_and_stats_count_accepted_poses()
-> anyhow::Result<()> {
    let server = TestServer::start("cube", SimOptions::default(), ServeOptions::default()).await?;
    let mut client = server.client().await?;
    let mut haptic = Haptic::open(&mut client, "left", None).await?;
    let p = above();
    let tiny = f64::from_bits(1);
    let answers = [
        haptic.send(pose(0.000, 1, p, FLAT_DOWN)).await?,
        haptic
            .send(pose(0.001, 2, p, [tiny, 0.0, 0.0, 0.0]))
            .await?,
        haptic.send(pose(0.002, 3, p, FLAT_DOWN)).await?,
        haptic.send(pose(0.003, 4, p, [2.0, 0.0, 0.0, 0.0])).await?,
        haptic
            .send(pb::PoseSample {
                orientation: None,
                ..pose(0.004, 5, p, FLAT_DOWN)
            })
            .await?,
        haptic.send(pose(0.005, 6, p, FLAT_DOWN)).await?,
    ];
    let rejected: Vec<_> = answers
        .iter()
        .filter_map(|a| {
            a.rejection
                .as_ref()
                .map(|r| (a.sequence, r.message.clone()))
        })
        .collect();
    assert_eq!(rejected.len(), 3, "{rejected:?}");
    assert!(rejected[0].1.contains("(norm 5e-324)"), "{rejected:?}");
    assert!(rejected[1].1.contains("(norm 2)"), "{rejected:?}");
    assert!(rejected[2].1.contains("orientation"), "{rejected:?}");
    let stats = client.get_stats(pb::GetStatsRequest {}).await?.into_inner();
    assert_eq!((stats.force_samples, stats.rejected_poses), (3, 3));
    haptic.close().await;
    server.stop().await
}

/// README.md gives every flag of `fissure-server --help` with its default:
/// a row of its flag table names the flag and, where `--help` shows a
/// default, that value.
#[test]
fn the_readme_gives_every_server_flag_with_its_default() {
    let help = std::process::Command::new(reliability_common::server_binary())
        .arg("--help")
        .output()
        .expect("fissure-server --help");
    let help = String::from_utf8_lossy(&help.stdout).into_owned();
    let readme = include_str!("../../../README.md");
    let rows: Vec<&str> = readme.lines().filter(|l| l.starts_with("| `--")).collect();
    // Flag blocks of the help: a line `      --name <VALUE>` (clap indents
    // flags by 6, their text by 10), then its text.
    let mut flags: Vec<(String, Option<String>)> = Vec::new();
    for line in help.lines() {
        let t = line.trim_start();
        if let Some(rest) = line.strip_prefix("      --") {
            let name = rest.split([' ', '=']).next().unwrap_or("").to_owned();
            flags.push((name, None));
        }
        if let (Some(last), Some(d)) = (flags.last_mut(), t.split("[default: ").nth(1)) {
            last.1 = Some(d.trim_end_matches(']').to_owned());
        }
    }
    let flags: Vec<_> = flags
        .into_iter()
        .filter(|(n, _)| n != "help" && n != "version")
        .collect();
    assert!(flags.len() >= 13, "{flags:?}");
    for (name, default) in flags {
        let flag = format!("`--{name}");
        let row = rows
            .iter()
            .find(|r| r.contains(&flag))
            .unwrap_or_else(|| panic!("README has no row for --{name}"));
        if let Some(d) = default {
            assert!(
                row.contains(&format!("`{d}`")),
                "--{name}: default {d} not in {row}"
            );
        }
    }
}
