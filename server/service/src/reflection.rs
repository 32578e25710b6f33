//! gRPC server reflection, `grpc.reflection.v1` and `grpc.reflection.v1alpha`,
//! over the descriptors of the services this server serves.
//!
//! Written here rather than taken from `tonic-reflection`'s services (0.14):
//! those end the whole reflection stream with an error status at the first
//! request they cannot answer (an unknown symbol or file name), where the
//! protocol answers in-band with an `ErrorResponse` and keeps the stream open;
//! `grpc_cli` and grpcio-reflection's client look symbols up one after another
//! on one stream and lose it at the first miss. The generated message types
//! of `tonic-reflection` are used as they are.
//!
//! Both versions share one [`DescriptorIndex`]: their messages have the same
//! fields and field numbers, so a `v1alpha` request is read as a `v1` one and
//! the `v1` answer is re-encoded as `v1alpha` (the same bytes on the wire).
//!
//! A file is answered with the files it imports, transitively (as the C++ and
//! Go servers do), so that a client can build its descriptor pool from one
//! answer.

use prost::Message;
use prost_types::{DescriptorProto, EnumDescriptorProto, FileDescriptorSet};
use std::collections::{HashMap, HashSet};
use std::pin::Pin;
use std::sync::Arc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use tonic_reflection::pb::{v1, v1alpha};

use v1::server_reflection_request::MessageRequest;
use v1::server_reflection_response::MessageResponse;

/// Errors in building the index from encoded descriptor sets.
#[derive(Debug, thiserror::Error)]
pub enum ReflectionError {
    /// A descriptor set does not decode.
    #[error("a file descriptor set does not decode: {0}")]
    Decode(#[from] prost::DecodeError),
    /// A file descriptor has no name.
    #[error("a file descriptor has no name")]
    Unnamed,
}

/// The files, symbols and services of a set of file descriptors.
#[derive(Debug, Default)]
pub struct DescriptorIndex {
    /// File name -> (encoded `FileDescriptorProto`, names of its imports).
    files: HashMap<String, (Vec<u8>, Vec<String>)>,
    /// Fully qualified symbol (package, message, field, enum, enum value,
    /// service, method, oneof) -> the file declaring it.
    symbols: HashMap<String, String>,
    /// Fully qualified names of the services, in registration order.
    services: Vec<String>,
}

fn qualify(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_owned()
    } else {
        format!("{prefix}.{name}")
    }
}

impl DescriptorIndex {
    /// Indexes encoded `FileDescriptorSet`s; a file already indexed is kept
    /// from its first set.
    pub fn new(encoded_sets: &[&[u8]]) -> Result<Self, ReflectionError> {
        let mut index = Self::default();
        for bytes in encoded_sets {
            let set = FileDescriptorSet::decode(*bytes)?;
            for file in set.file {
                let name = file.name.clone().ok_or(ReflectionError::Unnamed)?;
                if index.files.contains_key(&name) {
                    continue;
                }
                let package = file.package.clone().unwrap_or_default();
                for m in &file.message_type {
                    index.message(&name, &package, m);
                }
                for e in &file.enum_type {
                    index.enumeration(&name, &package, e);
                }
                for s in &file.service {
                    let service = qualify(&package, s.name());
                    for m in &s.method {
                        index
                            .symbols
                            .insert(qualify(&service, m.name()), name.clone());
                    }
                    index.symbols.insert(service.clone(), name.clone());
                    index.services.push(service);
                }
                index
                    .files
                    .insert(name, (file.encode_to_vec(), file.dependency.clone()));
            }
        }
        Ok(index)
    }

    fn message(&mut self, file: &str, prefix: &str, m: &DescriptorProto) {
        let name = qualify(prefix, m.name());
        for f in &m.field {
            self.symbols
                .insert(qualify(&name, f.name()), file.to_owned());
        }
        for o in &m.oneof_decl {
            self.symbols
                .insert(qualify(&name, o.name()), file.to_owned());
        }
        for n in &m.nested_type {
            self.message(file, &name, n);
        }
        for e in &m.enum_type {
            self.enumeration(file, &name, e);
        }
        self.symbols.insert(name, file.to_owned());
    }

    fn enumeration(&mut self, file: &str, prefix: &str, e: &EnumDescriptorProto) {
        let name = qualify(prefix, e.name());
        for v in &e.value {
            self.symbols
                .insert(qualify(&name, v.name()), file.to_owned());
        }
        self.symbols.insert(name, file.to_owned());
    }

    /// The services, fully qualified.
    pub fn services(&self) -> &[String] {
        &self.services
    }

    /// The encoded file `name` followed by the files it imports, transitively
    /// (those indexed), each once.
    fn with_imports(&self, name: &str) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        let mut seen = HashSet::new();
        let mut todo = vec![name.to_owned()];
        while let Some(f) = todo.pop() {
            if !seen.insert(f.clone()) {
                continue;
            }
            if let Some((bytes, deps)) = self.files.get(&f) {
                out.push(bytes.clone());
                todo.extend(deps.iter().rev().cloned());
            }
        }
        out
    }

    /// The answer to one request: a file, a service list, or an in-band error
    /// (`NOT_FOUND` for an unknown file, symbol or type, `INVALID_ARGUMENT` for
    /// an empty request).
    pub fn answer(&self, request: &v1::ServerReflectionRequest) -> MessageResponse {
        let not_found = |what: String| {
            MessageResponse::ErrorResponse(v1::ErrorResponse {
                error_code: tonic::Code::NotFound as i32,
                error_message: what,
            })
        };
        let files = |name: &str| {
            MessageResponse::FileDescriptorResponse(v1::FileDescriptorResponse {
                file_descriptor_proto: self.with_imports(name),
            })
        };
        match &request.message_request {
            None => MessageResponse::ErrorResponse(v1::ErrorResponse {
                error_code: tonic::Code::InvalidArgument as i32,
                error_message: "the request names no query".into(),
            }),
            Some(MessageRequest::FileByFilename(name)) => {
                if self.files.contains_key(name) {
                    files(name)
                } else {
                    not_found(format!("no file {name:?} on this server"))
                }
            }
            Some(MessageRequest::FileContainingSymbol(symbol)) => match self.symbols.get(symbol) {
                Some(file) => files(file),
                None => not_found(format!("no symbol {symbol:?} on this server")),
            },
            Some(MessageRequest::FileContainingExtension(e)) => not_found(format!(
                "no extension {} of {:?} on this server (it declares no extensions)",
                e.extension_number, e.containing_type
            )),
            Some(MessageRequest::AllExtensionNumbersOfType(ty)) => {
                if self.symbols.contains_key(ty) {
                    MessageResponse::AllExtensionNumbersResponse(v1::ExtensionNumberResponse {
                        base_type_name: ty.clone(),
                        extension_number: Vec::new(),
                    })
                } else {
                    not_found(format!("no type {ty:?} on this server"))
                }
            }
            Some(MessageRequest::ListServices(_)) => {
                MessageResponse::ListServicesResponse(v1::ListServiceResponse {
                    service: self
                        .services
                        .iter()
                        .map(|name| v1::ServiceResponse { name: name.clone() })
                        .collect(),
                })
            }
        }
    }
}

/// The reflection services (both versions) over one index.
#[derive(Debug, Clone)]
pub struct Reflection {
    index: Arc<DescriptorIndex>,
}

impl Reflection {
    /// Reflection over the encoded descriptor sets of the served services
    /// (the reflection services' own are added).
    pub fn new(encoded_sets: &[&[u8]]) -> Result<Self, ReflectionError> {
        let mut sets = encoded_sets.to_vec();
        sets.push(v1::FILE_DESCRIPTOR_SET);
        sets.push(v1alpha::FILE_DESCRIPTOR_SET);
        Ok(Self {
            index: Arc::new(DescriptorIndex::new(&sets)?),
        })
    }

    /// The `grpc.reflection.v1` service.
    pub fn v1(&self) -> v1::server_reflection_server::ServerReflectionServer<Self> {
        v1::server_reflection_server::ServerReflectionServer::new(self.clone())
    }

    /// The `grpc.reflection.v1alpha` service.
    pub fn v1alpha(&self) -> v1alpha::server_reflection_server::ServerReflectionServer<Self> {
        v1alpha::server_reflection_server::ServerReflectionServer::new(self.clone())
    }

    /// Answers each request of `requests` in order, converted by `into` and
    /// `from` (the identity for v1), until the client ends its stream.
    fn serve<Req, Resp>(
        &self,
        mut requests: Streaming<Req>,
        into: fn(&Req) -> Result<v1::ServerReflectionRequest, Status>,
        from: fn(v1::ServerReflectionResponse) -> Result<Resp, Status>,
    ) -> ReceiverStream<Result<Resp, Status>>
    where
        Req: Send + 'static,
        Resp: Send + 'static,
    {
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let index = self.index.clone();
        tokio::spawn(async move {
            loop {
                let req = match requests.message().await {
                    Ok(Some(r)) => r,
                    Ok(None) => break,
                    Err(status) => {
                        let _ = tx.send(Err(status)).await;
                        break;
                    }
                };
                let answer = into(&req).and_then(|req| {
                    from(v1::ServerReflectionResponse {
                        valid_host: req.host.clone(),
                        message_response: Some(index.answer(&req)),
                        original_request: Some(req),
                    })
                });
                if tx.send(answer).await.is_err() {
                    break;
                }
            }
        });
        ReceiverStream::new(rx)
    }
}

/// Re-encodes a message as another with the same fields (v1 and v1alpha).
fn recode<A: Message, B: Message + Default>(a: &A) -> Result<B, Status> {
    B::decode(a.encode_to_vec().as_slice())
        .map_err(|e| Status::internal(format!("re-encoding a reflection message: {e}")))
}

type Answers<T> = Pin<Box<ReceiverStream<Result<T, Status>>>>;

#[tonic::async_trait]
impl v1::server_reflection_server::ServerReflection for Reflection {
    type ServerReflectionInfoStream = Answers<v1::ServerReflectionResponse>;

    async fn server_reflection_info(
        &self,
        req: Request<Streaming<v1::ServerReflectionRequest>>,
    ) -> Result<Response<Self::ServerReflectionInfoStream>, Status> {
        Ok(Response::new(Box::pin(self.serve(
            req.into_inner(),
            |r| Ok(r.clone()),
            Ok,
        ))))
    }
}

#[tonic::async_trait]
impl v1alpha::server_reflection_server::ServerReflection for Reflection {
    type ServerReflectionInfoStream = Answers<v1alpha::ServerReflectionResponse>;

    async fn server_reflection_info(
        &self,
        req: Request<Streaming<v1alpha::ServerReflectionRequest>>,
    ) -> Result<Response<Self::ServerReflectionInfoStream>, Status> {
        Ok(Response::new(Box::pin(self.serve(
            req.into_inner(),
            recode,
            |r| recode(&r),
        ))))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn index() -> DescriptorIndex {
        DescriptorIndex::new(&[
            fissure_proto::FILE_DESCRIPTOR_SET,
            tonic_health::pb::FILE_DESCRIPTOR_SET,
        ])
        .unwrap()
    }

    fn ask(index: &DescriptorIndex, q: MessageRequest) -> MessageResponse {
        index.answer(&v1::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(q),
        })
    }

    /// Every kind of symbol of `fissure.v1` resolves to its file; an unknown
    /// one is a NOT_FOUND error response naming it.
    #[test]
    fn symbols_resolve_to_their_file_and_unknown_ones_are_named() {
        let index = index();
        for symbol in [
            "fissure.v1.Fissure",
            "fissure.v1.Fissure.Haptic",
            "fissure.v1.PoseSample",
            "fissure.v1.PoseSample.t_s",
            "fissure.v1.SafetyFlag",
            "fissure.v1.SafetyFlag.SAFETY_FLAG_POSE_JUMP",
            "fissure.v1.RecordingEntry.entry",
        ] {
            match ask(&index, MessageRequest::FileContainingSymbol(symbol.into())) {
                MessageResponse::FileDescriptorResponse(f) => {
                    let file =
                        prost_types::FileDescriptorProto::decode(&*f.file_descriptor_proto[0])
                            .unwrap();
                    assert_eq!(file.name(), "fissure/v1/fissure.proto", "{symbol}");
                }
                other => panic!("{symbol}: {other:?}"),
            }
        }
        match ask(
            &index,
            MessageRequest::FileContainingSymbol("fissure.v1.Nope".into()),
        ) {
            MessageResponse::ErrorResponse(e) => {
                assert_eq!(e.error_code, tonic::Code::NotFound as i32);
                assert!(e.error_message.contains("fissure.v1.Nope"), "{e:?}");
            }
            other => panic!("{other:?}"),
        }
        match ask(&index, MessageRequest::ListServices(String::new())) {
            MessageResponse::ListServicesResponse(l) => {
                let names: Vec<_> = l.service.iter().map(|s| s.name.as_str()).collect();
                assert_eq!(names, ["fissure.v1.Fissure", "grpc.health.v1.Health"]);
            }
            other => panic!("{other:?}"),
        }
    }
}
