//! A gRPC client written on the bare HTTP/2 layer (`h2`), as clients in
//! other languages are: one DATA frame a message, 64 KiB stream windows, a
//! 1 MiB connection window, and no limit of its own on small frames (the
//! Rust HTTP/2 client behind tonic coalesces the messages it sends into large
//! frames, and closes its own connection after about 150 unread 100-byte
//! frames; C-core and Java clients do neither).

#![allow(dead_code)]

use bytes::{Buf, Bytes, BytesMut};
use prost::Message;

pub struct Connection {
    pub send: h2::client::SendRequest<Bytes>,
    pub addr: std::net::SocketAddr,
}

pub async fn connect(addr: std::net::SocketAddr) -> anyhow::Result<Connection> {
    let tcp = tokio::net::TcpStream::connect(addr).await?;
    let (send, conn) = h2::client::Builder::new()
        .initial_window_size(65_535)
        .initial_connection_window_size(1 << 20)
        .data_frame_budget(1 << 30)
        .handshake::<_, Bytes>(tcp)
        .await?;
    tokio::spawn(conn);
    Ok(Connection { send, addr })
}

/// One gRPC message, length-prefixed.
pub fn frame(m: &impl Message) -> Bytes {
    let body = m.encode_to_vec();
    let mut b = BytesMut::with_capacity(5 + body.len());
    b.extend_from_slice(&[0]);
    b.extend_from_slice(&(body.len() as u32).to_be_bytes());
    b.extend_from_slice(&body);
    b.freeze()
}

/// Opens a call of `method` with metadata `meta`.
pub async fn call(
    c: &mut Connection,
    method: &str,
    meta: &[(&str, &str)],
    end: Option<Bytes>,
) -> anyhow::Result<(h2::client::ResponseFuture, h2::SendStream<Bytes>)> {
    let mut req = http::Request::builder()
        .method("POST")
        .uri(format!("http://{}/fissure.v1.Fissure/{method}", c.addr))
        .header("content-type", "application/grpc")
        .header("te", "trailers");
    for (k, v) in meta {
        req = req.header(*k, *v);
    }
    c.send = c.send.clone().ready().await?;
    let (resp, mut stream) = c.send.send_request(req.body(())?, false)?;
    if let Some(body) = end {
        stream.send_data(body, true)?;
    }
    Ok((resp, stream))
}

/// `grpc-message` is percent-encoded (gRPC over HTTP/2).
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        match (
            b[i],
            b.get(i + 1).and_then(|&c| hex(c)),
            b.get(i + 2).and_then(|&c| hex(c)),
        ) {
            (b'%', Some(h), Some(l)) => {
                out.push((h * 16 + l) as u8);
                i += 3;
            }
            (c, _, _) => {
                out.push(c);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Reads the gRPC messages of a response as they come (releasing their
/// flow-control capacity), then its status.
pub struct Reader {
    body: h2::RecvStream,
    buf: BytesMut,
}

impl Reader {
    pub async fn new(resp: h2::client::ResponseFuture) -> anyhow::Result<Self> {
        Ok(Self {
            body: resp.await?.into_body(),
            buf: BytesMut::new(),
        })
    }

    /// The next message, or `Err((grpc-status, grpc-message))` at the end.
    pub async fn next<M: Message + Default>(&mut self) -> Result<M, (i32, String)> {
        loop {
            if self.buf.len() >= 5 {
                let len = u32::from_be_bytes([self.buf[1], self.buf[2], self.buf[3], self.buf[4]])
                    as usize;
                if self.buf.len() >= 5 + len {
                    self.buf.advance(5);
                    let msg = self.buf.split_to(len);
                    return M::decode(msg.freeze()).map_err(|e| (-1, e.to_string()));
                }
            }
            match self.body.data().await {
                Some(Ok(chunk)) => {
                    let _ = self.body.flow_control().release_capacity(chunk.len());
                    self.buf.extend_from_slice(&chunk);
                }
                Some(Err(e)) => return Err((-1, e.to_string())),
                None => {
                    let trailers = self.body.trailers().await.ok().flatten();
                    let get = |k: &str| {
                        trailers
                            .as_ref()
                            .and_then(|t| t.get(k))
                            .and_then(|v| v.to_str().ok())
                            .unwrap_or("")
                            .to_owned()
                    };
                    return Err((
                        get("grpc-status").parse().unwrap_or(-1),
                        percent_decode(&get("grpc-message")),
                    ));
                }
            }
        }
    }
}
