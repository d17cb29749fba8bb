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
mod feed;
mod page;
mod reply;
mod slots;

use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use feed::Feed;
use http_body_util::{Either, Full};
use hyper::body::{Bytes, Incoming};
use hyper::header::{CONTENT_TYPE, HeaderValue};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use reply::plain;
use slots::{Lease, Pool, Slots, lock};
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use crate::config::Secret;
use crate::health::Health;
use crate::metrics::Metrics;
use crate::status::Live;

/// Short requests served at once; a new one beyond them closes the oldest.
const MAX_CONNECTIONS: usize = 8;
/// A request head (request line and headers) must arrive within this: a scraper or a probe
/// sends it at once.
const HEADER_TIMEOUT: Duration = Duration::from_secs(1);
/// A short request's whole life, request head to last byte of the answer.
const CONNECTION_DEADLINE: Duration = Duration::from_secs(10);
/// Read buffer cap: a request head larger than this is refused.
const MAX_HEAD: usize = 8 * 1024;
/// A loop that has not beaten for this long makes `/healthz` fail (the watchdog's default).
const STALE_AFTER: Duration = Duration::from_secs(10);

const TEXT_FORMAT: &str = "text/plain; version=0.0.4; charset=utf-8";

/// An answer: whole, or the page's event stream.
type Answer = Response<Either<Full<Bytes>, Feed>>;

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

/// The connections being served and the frames of the event streams.
struct Pools {
    /// Short requests (`/healthz`, `/metrics`, the page's files, the API).
    fresh: Pool,
    /// Event streams of open pages.
    streams: Pool,
    /// The newest snapshot as an event, from [`feed::feed`].
    frames: watch::Sender<Bytes>,
}

/// One connection: what closes it, its slot among the short requests until it becomes a
/// stream, and whether it has.
struct Connection {
    closed: CancellationToken,
    fresh: Mutex<Option<Lease>>,
    streaming: AtomicBool,
}

/// Serves until `shutdown`.
pub async fn serve(listener: TcpListener, endpoint: Endpoint, shutdown: CancellationToken) {
    let pools = Arc::new(Pools {
        fresh: Arc::new(Mutex::new(Slots::new(MAX_CONNECTIONS))),
        streams: Arc::new(Mutex::new(Slots::new(feed::STREAMS))),
        frames: watch::channel(Bytes::new()).0,
    });
    if let Some(live) = &endpoint.status {
        let frames = pools.frames.clone();
        tokio::spawn(feed::feed(live.clone(), frames, shutdown.clone()));
    }
    let endpoint = Arc::new(endpoint);
    loop {
        let stream = tokio::select! {
            () = shutdown.cancelled() => break,
            s = listener.accept() => match s {
                Ok((s, _)) => s,
                Err(e) => {
                    tracing::debug!("HTTP endpoint: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
        };
        let closed = CancellationToken::new();
        let connection = Arc::new(Connection {
            fresh: Mutex::new(Some(Lease::take(&pools.fresh, closed.clone()))),
            closed,
            streaming: AtomicBool::new(false),
        });
        tokio::spawn(serve_connection(
            stream,
            endpoint.clone(),
            pools.clone(),
            connection,
        ));
    }
    lock(&pools.streams).close_all();
    lock(&pools.fresh).close_all();
}

/// One connection, until it is answered, its deadline passes or a newer one takes its slot.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    endpoint: Arc<Endpoint>,
    pools: Arc<Pools>,
    connection: Arc<Connection>,
) {
    let on = connection.clone();
    let service = hyper::service::service_fn(move |req| {
        let (endpoint, pools, on) = (endpoint.clone(), pools.clone(), on.clone());
        async move { Ok::<_, Infallible>(answer(req, &endpoint, &pools, &on).await) }
    });
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(HEADER_TIMEOUT)
        .max_buf_size(MAX_HEAD)
        .keep_alive(false)
        .serve_connection(TokioIo::new(stream), service);
    // A stream ends itself after its life; this cuts one whose client stopped reading.
    let deadline = async {
        tokio::time::sleep(CONNECTION_DEADLINE).await;
        if connection.streaming.load(Ordering::Relaxed) {
            tokio::time::sleep(feed::STREAM_LIFE).await;
        }
    };
    tokio::select! {
        _ = conn => {}
        () = deadline => {}
        () = connection.closed.cancelled() => {}
    }
}

/// `GET /api/v1/events`: the connection leaves the short requests' slots for a stream's.
fn stream(
    req: &Request<Incoming>,
    live: &Live,
    token: Option<&Secret>,
    pools: &Pools,
    on: &Connection,
) -> Answer {
    if !auth::allowed(req.headers(), token) {
        return page::refused(page::EVENTS).map(Either::Left);
    }
    if req.method() == Method::HEAD {
        let empty = Bytes::new();
        return reply::page(StatusCode::OK, feed::KIND, empty).map(Either::Left);
    }
    on.streaming.store(true, Ordering::Relaxed);
    let lease = Lease::take(&pools.streams, on.closed.clone());
    drop(lock(&on.fresh).take());
    let body = Feed::new(&live.json(), pools.frames.subscribe(), lease);
    reply::dress(Response::new(Either::Right(body)), feed::KIND)
}

async fn answer(
    req: Request<Incoming>,
    endpoint: &Endpoint,
    pools: &Pools,
    on: &Connection,
) -> Answer {
    let path = req.uri().path().to_string();
    if req.method() == Method::POST && path == "/login" && endpoint.status.is_some() {
        return auth::login(req, endpoint.token.as_ref())
            .await
            .map(Either::Left);
    }
    if req.method() != Method::GET && req.method() != Method::HEAD {
        return plain(StatusCode::METHOD_NOT_ALLOWED, "only GET\n".into()).map(Either::Left);
    }
    if let (page::EVENTS, Some(live)) = (path.as_str(), &endpoint.status) {
        return stream(&req, live, endpoint.token.as_ref(), pools, on);
    }
    whole(&path, &req, endpoint).await.map(Either::Left)
}

/// Every answer but the event stream.
async fn whole(path: &str, req: &Request<Incoming>, endpoint: &Endpoint) -> Response<Full<Bytes>> {
    match path {
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
            Some(live) => page::answer(path, req, live, endpoint.token.as_ref()),
            None => plain(StatusCode::NOT_FOUND, "/metrics or /healthz\n".into()),
        },
    }
}
