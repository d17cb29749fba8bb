//! The I/O shells around a simulated M-Bus segment: a TCP server (an M-Bus-to-Ethernet
//! converter passes raw frames on a socket) and a serial segment on a pseudo-terminal set to
//! 2400 8E1. Both read requests off the stream and write what the segment answers.

use std::io;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

use super::segment::Segment;
use super::wire;
use crate::sim::endpoint::private;

/// A segment shared by its shell and the test or demo that steers it.
pub type SharedSegment = Arc<Mutex<Segment>>;

/// A request cut off for this long is dropped (a master's next request starts clean).
const GAP: Duration = Duration::from_millis(100);

/// Serves `segment` on TCP at `addr` (port 0 picks a free one), one connection at a time as a
/// converter does; returns the bound address. `start` is the segment's time 0.
pub async fn serve_tcp(
    addr: SocketAddr,
    segment: SharedSegment,
    start: Instant,
    cancel: CancellationToken,
) -> io::Result<SocketAddr> {
    let listener = tokio::net::TcpListener::bind(addr).await?;
    let bound = listener.local_addr()?;
    tokio::spawn(async move {
        loop {
            let stream = tokio::select! {
                accepted = listener.accept() => match accepted {
                    Ok((stream, _)) => stream,
                    Err(e) => {
                        tracing::warn!("simulated M-Bus TCP segment stopped: {e}");
                        return;
                    }
                },
                () = cancel.cancelled() => return,
            };
            serve_stream(stream, segment.clone(), start, cancel.clone()).await;
        }
    });
    Ok(bound)
}

/// Serves `segment` on a new pseudo-terminal set to `baud` 8E1 (2400 is M-Bus's usual
/// speed); returns the path of its serial end and that end (keep it open so the line
/// survives the gateway closing and reopening it). Linux keeps a pty at 8 bits without
/// parity whatever is set, so the even parity is accepted but carries no bit.
pub fn serve_pty(
    segment: SharedSegment,
    baud: u32,
    start: Instant,
    cancel: CancellationToken,
) -> io::Result<(PathBuf, TTYPort)> {
    let (master, slave) = TTYPort::pair().map_err(io::Error::other)?;
    let (master, mut slave) = (private(master), private(slave));
    slave.set_baud_rate(baud).map_err(io::Error::other)?;
    slave
        .set_parity(serialport::Parity::Even)
        .map_err(io::Error::other)?;
    slave
        .set_data_bits(serialport::DataBits::Eight)
        .map_err(io::Error::other)?;
    slave
        .set_stop_bits(serialport::StopBits::One)
        .map_err(io::Error::other)?;
    let path = slave
        .name()
        .map(PathBuf::from)
        .ok_or_else(|| io::Error::other("pseudo-terminal has no name"))?;
    let stream = tokio_serial::SerialStream::try_from(master).map_err(io::Error::other)?;
    tokio::spawn(serve_stream(stream, segment, start, cancel));
    Ok((path, slave))
}

/// Reads requests off `stream` and writes the segment's answers until the stream ends or
/// `cancel`.
async fn serve_stream<S: AsyncRead + AsyncWrite + Unpin>(
    mut stream: S,
    segment: SharedSegment,
    start: Instant,
    cancel: CancellationToken,
) {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 512];
    loop {
        let wait = if buf.is_empty() { Duration::MAX } else { GAP };
        let read = tokio::select! {
            r = tokio::time::timeout(wait, stream.read(&mut chunk)) => r,
            () = cancel.cancelled() => return,
        };
        match read {
            Err(_) => buf.clear(),
            Ok(Ok(0)) | Ok(Err(_)) => return,
            Ok(Ok(n)) => buf.extend_from_slice(&chunk[..n]),
        }
        while let Some(len) = wire::request_len(&buf) {
            if buf.len() < len {
                break;
            }
            let request: Vec<u8> = buf.drain(..len).collect();
            let now = start.elapsed().as_secs_f64();
            let answer = segment
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .answer(now, &request);
            if !answer.is_empty() && stream.write_all(&answer).await.is_err() {
                return;
            }
        }
    }
}
