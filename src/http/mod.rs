//! The HTTP endpoint (`[metrics] listen`): `GET /metrics` (Prometheus text format), `GET
//! /healthz` (200 only while every loop makes progress, every bus polls and no output has been
//! held or disconnected for more than 30 s; 503 naming what is not well, see
//! `Health::verdict`), and the status page: `/` and its files (`page.rs`), its data at `GET
//! /api/v1/status` (`crate::status`). With `token` set, the page, its files and the API ask
//! for it (`auth.rs`); `/metrics` and `/healthz` never do (a scraper and a probe carry no
//! secret, and they show nothing a person could act on the plant with).
//!
//! hyper's HTTP/1 server on the gateway's own single-threaded runtime: no extra threads. It is
//! meant for a local scraper and a technician's laptop (loopback by default), not the open
//! network, and a client can cost it little: a few connections at a time, small request heads,
//! and a deadline per connection. A client that holds connections open without finishing its
//! request cannot keep a probe of `/healthz` out: every connection is accepted at once, the head
//! must arrive within a second, and when all slots are taken the oldest connection is closed for
//! the new one (a watchdog or a load balancer must not restart a healthy gateway because someone
//! is slow on purpose).

mod auth;
mod page;
mod reply;

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use http_body_util::Full;
use hyper::body::{Bytes, Incoming};
use hyper::header::{CONTENT_TYPE, HeaderValue};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use reply::plain;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

use crate::config::Secret;
use crate::health::Health;
use crate::metrics::Metrics;
use crate::status::Live;

/// Connections served at once; a new one beyond them closes the oldest.
const MAX_CONNECTIONS: usize = 8;
/// A request head (request line and headers) must arrive within this: a scraper or a probe
/// sends it at once.
const HEADER_TIMEOUT: Duration = Duration::from_secs(1);
/// A connection's whole life, request head to last byte of the answer.
const CONNECTION_DEADLINE: Duration = Duration::from_secs(10);
/// Read buffer cap: a request head larger than this is refused.
const MAX_HEAD: usize = 8 * 1024;
/// A loop that has not beaten for this long makes `/healthz` fail (the watchdog's default).
const STALE_AFTER: Duration = Duration::from_secs(10);

const TEXT_FORMAT: &str = "text/plain; version=0.0.4; charset=utf-8";

/// The endpoint could not start.
#[derive(Debug, thiserror::Error)]
#[error("HTTP endpoint {addr}: {source}")]
pub struct ServeError {
    addr: SocketAddr,
    source: std::io::Error,
}

/// Binds `addr` (so a port in use is an error at start, not later).
pub async fn bind(addr: SocketAddr) -> Result<TcpListener, ServeError> {
    TcpListener::bind(addr)
        .await
        .map_err(|source| ServeError { addr, source })
}

/// What the endpoint serves.
#[derive(Clone)]
pub struct Endpoint {
    pub metrics: Metrics,
    pub health: Arc<Health>,
    /// The status board; `None` serves no page.
    pub status: Option<Arc<Live>>,
    /// `metrics.token`: the page and the API ask for it.
    pub token: Option<Secret>,
}

/// Serves until `shutdown`.
pub async fn serve(listener: TcpListener, endpoint: Endpoint, shutdown: CancellationToken) {
    let slots = Arc::new(std::sync::Mutex::new(Slots::default()));
    let endpoint = Arc::new(endpoint);
    loop {
        let stream = tokio::select! {
            () = shutdown.cancelled() => return,
            s = listener.accept() => match s {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::debug!("HTTP endpoint: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
        };
        let endpoint = endpoint.clone();
        let (id, closed) = lock(&slots).admit();
        let slots = slots.clone();
        tokio::spawn(async move {
            let service = hyper::service::service_fn(move |req| {
                let endpoint = endpoint.clone();
                async move { Ok::<_, Infallible>(answer(req, &endpoint).await) }
            });
            let conn = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT)
                .max_buf_size(MAX_HEAD)
                .keep_alive(false)
                .serve_connection(TokioIo::new(stream), service);
            tokio::select! {
                _ = tokio::time::timeout(CONNECTION_DEADLINE, conn) => {}
                () = closed.cancelled() => {}
            }
            lock(&slots).done(id);
        });
    }
}

fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The connections being served, oldest first, each with the token that closes it.
#[derive(Default)]
struct Slots {
    next: u64,
    open: BTreeMap<u64, CancellationToken>,
}

impl Slots {
    /// A new connection: its id and token; when every slot is taken, the oldest connection's
    /// token is cancelled (it closes) and its slot is the new one's.
    fn admit(&mut self) -> (u64, CancellationToken) {
        while self.open.len() >= MAX_CONNECTIONS {
            if let Some((_, oldest)) = self.open.pop_first() {
                oldest.cancel();
            }
        }
        let id = self.next;
        self.next += 1;
        let token = CancellationToken::new();
        self.open.insert(id, token.clone());
        (id, token)
    }

    /// A connection ended (answered, timed out or closed).
    fn done(&mut self, id: u64) {
        self.open.remove(&id);
    }
}

async fn answer(req: Request<Incoming>, endpoint: &Endpoint) -> Response<Full<Bytes>> {
    let path = req.uri().path().to_string();
    if req.method() == Method::POST && path == "/login" && endpoint.status.is_some() {
        return auth::login(req, endpoint.token.as_ref()).await;
    }
    if req.method() != Method::GET && req.method() != Method::HEAD {
        return plain(StatusCode::METHOD_NOT_ALLOWED, "only GET\n".into());
    }
    match path.as_str() {
        "/metrics" => {
            // Thousands of series take tens of milliseconds to encode: off the runtime thread,
            // so polling does not wait for a scrape.
            let metrics = endpoint.metrics.clone();
            let text = tokio::task::spawn_blocking(move || metrics.encode())
                .await
                .unwrap_or_default();
            let mut r = Response::new(Full::new(Bytes::from(text)));
            r.headers_mut()
                .insert(CONTENT_TYPE, HeaderValue::from_static(TEXT_FORMAT));
            r
        }
        "/healthz" => match endpoint.health.verdict(STALE_AFTER) {
            Ok(line) => plain(StatusCode::OK, format!("ok: {line}\n")),
            Err(why) => plain(StatusCode::SERVICE_UNAVAILABLE, format!("{why}\n")),
        },
        _ => match &endpoint.status {
            Some(live) => page::answer(&path, &req, live, endpoint.token.as_ref()),
            None => plain(StatusCode::NOT_FOUND, "/metrics or /healthz\n".into()),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_connection_beyond_the_slots_closes_the_oldest_and_only_it() {
        let mut slots = Slots::default();
        let first: Vec<(u64, CancellationToken)> =
            (0..MAX_CONNECTIONS).map(|_| slots.admit()).collect();
        assert!(first.iter().all(|(_, t)| !t.is_cancelled()));
        let (_, newest) = slots.admit();
        assert!(first[0].1.is_cancelled(), "the oldest is closed");
        assert!(first[1..].iter().all(|(_, t)| !t.is_cancelled()));
        assert!(!newest.is_cancelled());
        slots.done(first[0].0);
        slots.done(first[1].0);
        let (_, another) = slots.admit();
        assert!(
            !first[2].1.is_cancelled() && !another.is_cancelled(),
            "a slot freed by a finished connection is taken without closing anyone"
        );
    }
}
