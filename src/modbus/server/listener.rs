//! The listener of a Modbus server output, on tokio-modbus's TCP server (its MBAP framing and
//! PDU codec), with what a server facing a plant network needs around it: clients outside
//! `allow` are closed at accept; at most `max_connections` are held, the oldest idle one closed
//! for a new one; a connection silent for [`IDLE`] (a half frame that stalls, a client that went
//! away) is closed. A slow or hostile client holds one connection and costs the rest nothing.

use std::collections::BTreeMap;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;
use tokio::time::{Instant, Sleep};
use tokio_util::sync::{CancellationToken, WaitForCancellationFutureOwned};

use crate::metrics::OutputMetrics;
use crate::modbus::config::server::ModbusServer;

/// A connection that sends nothing for this long is closed: PLCs poll every few hundred
/// milliseconds, and a frame arrives whole within one TCP segment or two.
pub const IDLE: Duration = Duration::from_secs(60);

/// The connections held, each with when it last received a byte and how to close it.
#[derive(Default)]
pub struct Slots {
    next: u64,
    open: BTreeMap<u64, (Instant, CancellationToken)>,
}

fn lock(slots: &Mutex<Slots>) -> std::sync::MutexGuard<'_, Slots> {
    slots.lock().unwrap_or_else(|e| e.into_inner())
}

impl Slots {
    /// A slot for a new connection; when all `max` are taken, the one idle longest is closed.
    fn take(&mut self, max: usize) -> (u64, CancellationToken, bool) {
        let mut evicted = false;
        while self.open.len() >= max {
            let Some((&oldest, _)) = self.open.iter().min_by_key(|(_, (seen, _))| *seen) else {
                break;
            };
            if let Some((_, token)) = self.open.remove(&oldest) {
                token.cancel();
                evicted = true;
            }
        }
        self.next += 1;
        let token = CancellationToken::new();
        self.open.insert(self.next, (Instant::now(), token.clone()));
        (self.next, token, evicted)
    }
}

/// A client's stream in its slot: it records activity, ends when evicted or idle, and gives
/// its slot back when dropped.
pub struct Leased {
    stream: TcpStream,
    id: u64,
    slots: Arc<Mutex<Slots>>,
    evicted: Pin<Box<WaitForCancellationFutureOwned>>,
    idle: Pin<Box<Sleep>>,
    metrics: OutputMetrics,
}

impl Drop for Leased {
    fn drop(&mut self) {
        let mut slots = lock(&self.slots);
        slots.open.remove(&self.id);
        self.metrics.server_connections(slots.open.len());
    }
}

impl AsyncRead for Leased {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if self.evicted.as_mut().poll(cx).is_ready() {
            self.metrics.server_closed("evicted");
            return Poll::Ready(Err(io::ErrorKind::ConnectionAborted.into()));
        }
        if self.idle.as_mut().poll(cx).is_ready() {
            self.metrics.server_closed("idle");
            return Poll::Ready(Err(io::ErrorKind::TimedOut.into()));
        }
        let before = buf.filled().len();
        let polled = Pin::new(&mut self.stream).poll_read(cx, buf);
        if matches!(polled, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            let now = Instant::now();
            self.idle.as_mut().reset(now + IDLE);
            if let Some(slot) = lock(&self.slots).open.get_mut(&self.id) {
                slot.0 = now;
            }
        }
        polled
    }
}

impl AsyncWrite for Leased {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }
}

use std::future::Future as _;

/// A connection accepted from `peer`: leased a slot, or refused (`None`: closed at once).
pub fn admit(
    server: &ModbusServer,
    slots: &Arc<Mutex<Slots>>,
    metrics: &OutputMetrics,
    stream: TcpStream,
    peer: SocketAddr,
) -> Option<Leased> {
    if !server.allows(peer.ip()) {
        metrics.server_closed("not_allowed");
        tracing::debug!(%peer, output = %server.name, "a Modbus client outside allow: closed");
        return None;
    }
    let _ = stream.set_nodelay(true);
    let mut held = lock(slots);
    let (id, token, evicted) = held.take(server.max_connections);
    metrics.server_connections(held.open.len());
    drop(held);
    if evicted {
        tracing::debug!(output = %server.name, "the oldest idle Modbus connection closed for a new one");
    }
    Some(Leased {
        stream,
        id,
        slots: slots.clone(),
        evicted: Box::pin(token.cancelled_owned()),
        idle: Box::pin(tokio::time::sleep(IDLE)),
        metrics: metrics.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_full_server_closes_the_connection_idle_longest_for_a_new_one() {
        let mut slots = Slots::default();
        let (a, ta, _) = slots.take(2);
        tokio::time::advance(Duration::from_secs(1)).await;
        let (b, tb, _) = slots.take(2);
        // `a` spoke last.
        tokio::time::advance(Duration::from_secs(1)).await;
        slots.open.get_mut(&a).unwrap().0 = Instant::now();
        let (_, _, evicted) = slots.take(2);
        assert!(evicted);
        assert!(tb.is_cancelled(), "b was idle longest");
        assert!(!ta.is_cancelled());
        assert!(!slots.open.contains_key(&b));
        assert_eq!(slots.open.len(), 2);
    }
}
