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
//! and a deadline per connection. Tokens are limited per client (`door.rs`, `lockout.rs`).
//!
//! A probe of `/healthz` or a scrape of `/metrics` is answered however many connections others
//! open, close or hold: what a connection asks for is known only once its request head has
//! come, so every connection is accepted at once into a pool of its own (`HEADS` slots, the
//! head within `HEADER_TIMEOUT`; when they are all taken the oldest is closed for the new
//! one), and the accept loop lets every accepted connection read what has come before it
//! accepts the next. Only `HEADS` newer connections accepted before its head has come can
//! push a connection out; a probe sends its head as soon as it is connected, so its head is read
//! when it is accepted or a few accepts later, and it moves to the probes' reserve (`PROBES`
//! slots, which only another probe or scrape can take): an idle or slow connection cannot take
//! a reserved slot at all. The page, its API and the login have their slots
//! (`MAX_CONNECTIONS`), and event streams theirs. The listen backlog (`BACKLOG`) holds a
//! burst of a flood while the gateway is busy, rather than the kernel dropping a probe's
//! connection.

mod auth;
mod door;
mod feed;
mod lockout;
mod page;
mod reply;
mod slots;

use std::convert::Infallible;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use door::Door;
use feed::Feed;
use http_body_util::{Either, Full};
use hyper::body::{Bytes, Incoming};
use hyper::header::{CONTENT_TYPE, HeaderValue};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use lockout::Client;
use reply::plain;
use slots::{Lease, Pool, Slots, lock};
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use crate::config::Secret;
use crate::health::Health;
use crate::metrics::Metrics;
use crate::status::Live;

/// Connections waiting for their request head; a new one beyond them closes the oldest.
const HEADS: usize = 64;
/// `/healthz` and `/metrics` answered at once, whatever else is open; a new one beyond them
/// closes the oldest of them.
const PROBES: usize = 4;
/// The page's files, its API and the login served at once; a new one beyond them closes the
/// oldest.
const MAX_CONNECTIONS: usize = 8;
/// A request head (request line and headers) must arrive within this: a scraper or a probe
/// sends it at once.
const HEADER_TIMEOUT: Duration = Duration::from_secs(1);
/// A short request's whole life, request head to last byte of the answer.
const CONNECTION_DEADLINE: Duration = Duration::from_secs(10);
/// Connections the kernel holds for the endpoint until it accepts them: a burst of a flood
/// waits here while the gateway polls, rather than a probe's connection being dropped (and
/// retried a second later) because 128, std's default, were full.
const BACKLOG: u32 = 1024;
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
    let listen = || {
        let socket = match addr {
            SocketAddr::V4(_) => tokio::net::TcpSocket::new_v4()?,
            SocketAddr::V6(_) => tokio::net::TcpSocket::new_v6()?,
        };
        // As std's listener does: a restarted gateway binds again at once.
        socket.set_reuseaddr(true)?;
        socket.bind(addr)?;
        socket.listen(BACKLOG)
    };
    listen().map_err(|source| ServeError { addr, source })
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

/// The connections being served, by what they are waiting for or asked, and the frames of the
/// event streams.
struct Pools {
    /// Connections whose request head has not come yet.
    heads: Pool,
    /// `/healthz` and `/metrics`.
    probes: Pool,
    /// The page's files, the API, the login, and anything else asked.
    fresh: Pool,
    /// Event streams of open pages.
    streams: Pool,
    /// The newest snapshot as an event, from [`feed::feed`].
    frames: watch::Sender<Bytes>,
}

impl Pools {
    fn new() -> Pools {
        let pool = |n| Arc::new(Mutex::new(Slots::new(n)));
        Pools {
            heads: pool(HEADS),
            probes: pool(PROBES),
            fresh: pool(MAX_CONNECTIONS),
            streams: pool(feed::STREAMS),
            frames: watch::channel(Bytes::new()).0,
        }
    }

    /// The pool a request for `path` is served in (an event stream moves on to its own once
    /// the door lets it in).
    fn for_path(&self, path: &str) -> &Pool {
        match path {
            "/healthz" | "/metrics" => &self.probes,
            _ => &self.fresh,
        }
    }

    fn close_all(&self) {
        for pool in [&self.heads, &self.probes, &self.fresh, &self.streams] {
            lock(pool).close_all();
        }
    }
}

/// What the endpoint serves, who may see the page, and the connections.
struct Server {
    endpoint: Endpoint,
    door: Door,
    pools: Pools,
}

/// One connection: who it is from, what closes it, its slot in the pool it is in now, and
/// whether it became a stream.
struct Connection {
    client: Client,
    closed: CancellationToken,
    lease: Mutex<Option<Lease>>,
    streaming: AtomicBool,
}

impl Connection {
    /// The connection leaves its pool for a slot of `pool` (unless it is being closed: it
    /// would close another for nothing).
    fn move_to(&self, pool: &Pool) {
        if self.closed.is_cancelled() {
            return;
        }
        let lease = Lease::take(pool, self.closed.clone());
        *lock(&self.lease) = Some(lease);
    }
}

/// Serves until `shutdown`.
pub async fn serve(listener: TcpListener, endpoint: Endpoint, shutdown: CancellationToken) {
    let door = Door::new(endpoint.token.clone(), endpoint.metrics.clone());
    let server = Arc::new(Server {
        endpoint,
        door,
        pools: Pools::new(),
    });
    if let Some(live) = &server.endpoint.status {
        let frames = server.pools.frames.clone();
        tokio::spawn(feed::feed(live.clone(), frames, shutdown.clone()));
    }
    loop {
        let (stream, peer) = tokio::select! {
            () = shutdown.cancelled() => break,
            s = listener.accept() => match s {
                Ok(s) => s,
                Err(e) => {
                    tracing::debug!("HTTP endpoint: accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    continue;
                }
            },
        };
        let closed = CancellationToken::new();
        let connection = Arc::new(Connection {
            client: Client::of(peer.ip()),
            lease: Mutex::new(Some(Lease::take(&server.pools.heads, closed.clone()))),
            closed,
            streaming: AtomicBool::new(false),
        });
        tokio::spawn(serve_connection(stream, server.clone(), connection));
        // Every connection accepted reads what has come before the next is accepted: a flood
        // of connections is then no burst of accepts that closes a probe before it was read.
        tokio::task::yield_now().await;
    }
    server.pools.close_all();
}

/// One connection, until it is answered, its deadline passes or a newer one takes its slot.
async fn serve_connection(
    stream: tokio::net::TcpStream,
    server: Arc<Server>,
    connection: Arc<Connection>,
) {
    let on = connection.clone();
    let service = hyper::service::service_fn(move |req| {
        let (server, on) = (server.clone(), on.clone());
        async move { Ok::<_, Infallible>(answer(req, &server, &on).await) }
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
fn stream(req: &Request<Incoming>, live: &Live, server: &Server, on: &Connection) -> Answer {
    let pass = server.door.request(on.client, req.headers());
    if let Some(shut) = page::shut(page::EVENTS, pass) {
        return shut.map(Either::Left);
    }
    if req.method() == Method::HEAD {
        let empty = Bytes::new();
        return reply::page(StatusCode::OK, feed::KIND, empty).map(Either::Left);
    }
    on.streaming.store(true, Ordering::Relaxed);
    // The stream's body holds its slot from now on.
    let lease = Lease::take(&server.pools.streams, on.closed.clone());
    drop(lock(&on.lease).take());
    let body = Feed::new(&live.json(), server.pools.frames.subscribe(), lease);
    reply::dress(Response::new(Either::Right(body)), feed::KIND)
}

async fn answer(req: Request<Incoming>, server: &Server, on: &Connection) -> Answer {
    let path = req.uri().path().to_string();
    // The head has come: the connection leaves the pool of those still waiting for theirs.
    on.move_to(server.pools.for_path(&path));
    let endpoint = &server.endpoint;
    if req.method() == Method::POST && path == "/login" && endpoint.status.is_some() {
        return page::login(req, &server.door, on.client)
            .await
            .map(Either::Left);
    }
    if req.method() != Method::GET && req.method() != Method::HEAD {
        return plain(StatusCode::METHOD_NOT_ALLOWED, "only GET\n".into()).map(Either::Left);
    }
    if let (page::EVENTS, Some(live)) = (path.as_str(), &endpoint.status) {
        return stream(&req, live, server, on);
    }
    whole(&path, &req, server, on.client)
        .await
        .map(Either::Left)
}

/// Every answer but the event stream.
async fn whole(
    path: &str,
    req: &Request<Incoming>,
    server: &Server,
    client: Client,
) -> Response<Full<Bytes>> {
    let endpoint = &server.endpoint;
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
            Some(live) => page::answer(path, req, live, &server.door, client).await,
            None => plain(StatusCode::NOT_FOUND, "/metrics or /healthz\n".into()),
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn connection(pools: &Pools) -> Connection {
        let closed = CancellationToken::new();
        Connection {
            client: Client::of([127, 0, 0, 1].into()),
            lease: Mutex::new(Some(Lease::take(&pools.heads, closed.clone()))),
            closed,
            streaming: AtomicBool::new(false),
        }
    }

    #[test]
    fn a_probe_whose_head_came_is_never_closed_by_connections_still_waiting_for_theirs() {
        let pools = Pools::new();
        let probe = connection(&pools);
        probe.move_to(pools.for_path("/healthz"));
        let page = connection(&pools);
        page.move_to(pools.for_path("/api/v1/status"));
        let flood: Vec<Connection> = (0..1000).map(|_| connection(&pools)).collect();
        assert!(!probe.closed.is_cancelled() && !page.closed.is_cancelled());
        let waiting = flood.iter().filter(|c| !c.closed.is_cancelled()).count();
        assert_eq!(waiting, HEADS, "the newest wait, the oldest were closed");
        assert_eq!(lock(&pools.heads).occupied(), HEADS);
        assert_eq!(lock(&pools.probes).occupied(), 1);
    }

    #[test]
    fn probes_take_the_oldest_probes_slot_and_no_other() {
        let pools = Pools::new();
        let page = connection(&pools);
        page.move_to(pools.for_path("/"));
        let probes: Vec<Connection> = (0..PROBES + 1).map(|_| connection(&pools)).collect();
        for (i, p) in probes.iter().enumerate() {
            p.move_to(pools.for_path(if i % 2 == 0 { "/healthz" } else { "/metrics" }));
        }
        assert!(
            probes[0].closed.is_cancelled(),
            "the oldest probe made room"
        );
        assert!(probes[1..].iter().all(|p| !p.closed.is_cancelled()));
        assert!(!page.closed.is_cancelled());
        assert_eq!(
            lock(&pools.heads).occupied(),
            0,
            "each left the waiting pool"
        );
    }
}
