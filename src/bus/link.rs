//! The wire of one bus: a Modbus RTU serial port or a Modbus TCP connection, one transaction at
//! a time, each with a timeout.
//!
//! tokio-modbus has no per-call timeout and may bind a late answer to the next request (its
//! issues 324 and 60). So every call here runs under a timeout; the serial input is flushed in
//! the kernel before each request (tokio-modbus clears only its own buffer); each answer is
//! checked to be exactly the shape asked for; and after a timeout or protocol error the client
//! is rebuilt so no half-read frame survives into the next transaction.

use std::borrow::Cow;
use std::io;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context as TaskContext, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::Instant;
use tokio_modbus::client::{Client, Context};
use tokio_modbus::prelude::SlaveContext;
use tokio_modbus::{ExceptionCode, Request, Response, Slave};
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialStream};

use crate::config::{Link as LinkConfig, Parity};
use crate::plan::LineTiming;

/// Why a transaction got no usable answer. The device answering with an exception is not one of
/// these: that is `Ok(Err(ExceptionCode))`, as in tokio-modbus.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("no answer within {0:?}")]
    Timeout(Duration),
    #[error("cannot open {what}: {message}")]
    Open { what: String, message: String },
    #[error("i/o error: {0}")]
    Io(#[from] io::Error),
    #[error("answer does not match the request: {0}")]
    Mismatch(String),
    /// Another unit's answer (late, to an earlier request) arrived in this transaction.
    #[error("stale answer from another unit: {0}")]
    Stale(String),
    /// Bytes came back but never a valid frame: CRC errors, a frame cut short. The device is
    /// there; the line is noisy.
    #[error("garbled answer ({0} bytes, no valid frame) within {1:?}")]
    Garbled(u64, Duration),
}

impl LinkError {
    /// Whether the fault lies with the line or adapter rather than one device.
    pub fn is_line_fault(&self) -> bool {
        matches!(self, LinkError::Open { .. } | LinkError::Io(_))
    }

    /// Worth asking again at once (a read only): the request or the answer may have been hit
    /// by noise.
    pub fn is_noise(&self) -> bool {
        matches!(
            self,
            LinkError::Timeout(_) | LinkError::Garbled(..) | LinkError::Mismatch(_)
        )
    }

    /// Something answered: the device is alive even though this answer is unusable.
    pub fn device_answered(&self) -> bool {
        matches!(self, LinkError::Garbled(..))
    }
}

/// A transaction's outcome: the link failed, or the device answered (possibly an exception).
pub type Answer<T> = Result<Result<T, ExceptionCode>, LinkError>;

/// Counters of what happened on the wire (for health stats).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WireCounters {
    pub transactions: u64,
    pub timeouts: u64,
    pub mismatches: u64,
    pub io_errors: u64,
    pub exceptions: u64,
    pub reconnects: u64,
    /// Answers that arrived garbled (bad CRC, cut short).
    pub garbled: u64,
}

/// One bus's wire.
pub struct Link {
    config: LinkConfig,
    timing: Option<LineTiming>,
    port: Option<SharedPort>,
    ctx: Option<Context>,
    /// Bytes read from the serial port, to tell a garbled answer from silence, and when the
    /// last of them arrived (the silent interval counts from there).
    bytes_in: Arc<AtomicU64>,
    last_byte: Arc<Mutex<Option<Instant>>>,
    last_io: Option<Instant>,
    pub counters: WireCounters,
    /// Time the line was busy with our transactions (for utilisation).
    pub busy: Duration,
    /// Units that answer at another baud rate than the bus's: one RS-485 wire can carry
    /// several, so the port is switched to a unit's rate before its transaction.
    unit_bauds: std::collections::HashMap<u8, u32>,
    /// The rate the open port is set to.
    speed: Option<u32>,
    guard: Duration,
}

impl Link {
    /// A link for `config`; nothing is opened until the first transaction.
    pub fn new(config: LinkConfig, guard: Duration) -> Link {
        let timing = crate::config::line_timing(&config, guard);
        Link {
            config,
            timing,
            port: None,
            ctx: None,
            bytes_in: Arc::default(),
            last_byte: Arc::default(),
            last_io: None,
            counters: WireCounters::default(),
            busy: Duration::ZERO,
            unit_bauds: std::collections::HashMap::new(),
            speed: None,
            guard,
        }
    }

    /// Character timing of the line while talking to `unit` (its own rate where it has one).
    pub fn timing_for(&self, unit: u8) -> Option<LineTiming> {
        let mut config = self.config.clone();
        if let (LinkConfig::Rtu { baud, .. }, Some(own)) = (&mut config, self.unit_bauds.get(&unit))
        {
            *baud = *own;
        }
        crate::config::line_timing(&config, self.guard)
    }

    /// Talks to `unit` at `baud` instead of the bus's rate (RTU).
    pub fn set_unit_baud(&mut self, unit: u8, baud: u32) {
        self.unit_bauds.insert(unit, baud);
    }

    /// Switches the open port to the rate `unit` answers at, after the silent interval at the
    /// old rate has passed.
    fn switch_speed(&mut self, unit: u8) -> Result<(), LinkError> {
        let LinkConfig::Rtu { baud, .. } = &self.config else {
            return Ok(());
        };
        let want = self.unit_bauds.get(&unit).copied().unwrap_or(*baud);
        if self.speed == Some(want) {
            return Ok(());
        }
        if let Some(port) = &self.port {
            port.with(|s| s.set_baud_rate(want))
                .map_err(|e| LinkError::Io(io::Error::other(e)))?;
        }
        self.speed = Some(want);
        self.timing = self.timing_for(unit);
        Ok(())
    }

    /// Character timing of an RTU line.
    pub fn timing(&self) -> Option<LineTiming> {
        self.timing
    }

    /// Drops the client and the port: the next transaction reopens both.
    pub fn close(&mut self) {
        self.ctx = None;
        self.port = None;
        self.speed = None;
    }

    /// Reads `len` holding registers from `start`.
    pub async fn read(
        &mut self,
        unit: u8,
        start: u16,
        len: u16,
        timeout: Duration,
    ) -> Answer<Vec<u16>> {
        let answer = self
            .call(unit, Request::ReadHoldingRegisters(start, len), timeout)
            .await?;
        Ok(match answer {
            Ok(Response::ReadHoldingRegisters(words)) if words.len() == usize::from(len) => {
                Ok(words)
            }
            Ok(other) => {
                return Err(
                    self.mismatch(format!("asked {len} registers at {start}, got {other:?}"))
                );
            }
            Err(e) => Err(e),
        })
    }

    /// Writes one register (FC06); the echo must match.
    pub async fn write_register(
        &mut self,
        unit: u8,
        address: u16,
        value: u16,
        timeout: Duration,
    ) -> Answer<()> {
        let answer = self
            .call(unit, Request::WriteSingleRegister(address, value), timeout)
            .await?;
        Ok(match answer {
            Ok(Response::WriteSingleRegister(a, v)) if a == address && v == value => Ok(()),
            Ok(other) => {
                return Err(self.mismatch(format!("wrote {value} at {address}, echo {other:?}")));
            }
            Err(e) => Err(e),
        })
    }

    /// Writes consecutive registers (FC16); the answer must confirm the range.
    pub async fn write_registers(
        &mut self,
        unit: u8,
        address: u16,
        values: &[u16],
        timeout: Duration,
    ) -> Answer<()> {
        let req = Request::WriteMultipleRegisters(address, Cow::Owned(values.to_vec()));
        let answer = self.call(unit, req, timeout).await?;
        Ok(match answer {
            Ok(Response::WriteMultipleRegisters(a, n))
                if a == address && usize::from(n) == values.len() =>
            {
                Ok(())
            }
            Ok(other) => {
                return Err(self.mismatch(format!(
                    "wrote {} at {address}, answer {other:?}",
                    values.len()
                )));
            }
            Err(e) => Err(e),
        })
    }

    fn mismatch(&mut self, message: String) -> LinkError {
        self.counters.mismatches += 1;
        self.ctx = None;
        LinkError::Mismatch(message)
    }

    /// One transaction. An answer from another unit (a late answer to an earlier request that
    /// arrived during this one) is dropped and the request sent once more: the unit asked is not
    /// at fault, and its own answer may be right behind.
    async fn call(
        &mut self,
        unit: u8,
        req: Request<'static>,
        timeout: Duration,
    ) -> Answer<Response> {
        match self.call_once(unit, req.clone(), timeout).await {
            Err(LinkError::Stale(m)) => {
                tracing::debug!(unit, "stale answer dropped ({m}); asking again");
                self.call_once(unit, req, timeout).await
            }
            other => other,
        }
    }

    async fn call_once(
        &mut self,
        unit: u8,
        req: Request<'static>,
        timeout: Duration,
    ) -> Answer<Response> {
        self.ensure_open(timeout).await?;
        if let (Some(timing), Some(last)) = (self.timing, self.last_io) {
            // RTU frames must be separated by the silent interval.
            wait_until(last + timing.silent_interval()).await;
        }
        self.switch_speed(unit)?;
        let ctx = self.ctx.as_mut().expect("opened above");
        ctx.set_slave(Slave(unit));
        self.counters.transactions += 1;
        let started = Instant::now();
        let bytes_before = self.bytes_in.load(Ordering::Relaxed);
        let result = tokio::time::timeout(timeout, ctx.call(req)).await;
        let now = Instant::now();
        self.busy += now - started;
        let last_byte = self
            .last_byte
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        self.last_io = Some(last_byte.unwrap_or(now).min(now));
        match result {
            Err(_elapsed) => {
                // A late answer may still arrive: rebuild so it cannot be read as the next one.
                self.ctx = None;
                let got = self.bytes_in.load(Ordering::Relaxed) - bytes_before;
                if got > 0 {
                    self.counters.garbled += 1;
                    Err(LinkError::Garbled(got, timeout))
                } else {
                    self.counters.timeouts += 1;
                    Err(LinkError::Timeout(timeout))
                }
            }
            // tokio-modbus reports a frame it could not decode (bad CRC, an impossible function
            // code or length) as an I/O error of kind InvalidData: that is a garbled answer on
            // a noisy line, not a line fault. Rebuild the client so decoding starts afresh.
            Ok(Err(tokio_modbus::Error::Transport(e)))
                if e.kind() == io::ErrorKind::InvalidData =>
            {
                self.counters.garbled += 1;
                self.ctx = None;
                let got = self.bytes_in.load(Ordering::Relaxed) - bytes_before;
                Err(LinkError::Garbled(got.max(1), timeout))
            }
            Ok(Err(tokio_modbus::Error::Transport(e))) => {
                self.counters.io_errors += 1;
                self.close();
                Err(LinkError::Io(e))
            }
            Ok(Err(tokio_modbus::Error::Protocol(
                e @ tokio_modbus::ProtocolError::HeaderMismatch { .. },
            ))) => {
                self.counters.mismatches += 1;
                self.ctx = None;
                Err(LinkError::Stale(e.to_string()))
            }
            Ok(Err(tokio_modbus::Error::Protocol(e))) => Err(self.mismatch(e.to_string())),
            Ok(Ok(Err(exception))) => {
                self.counters.exceptions += 1;
                Ok(Err(exception))
            }
            Ok(Ok(Ok(response))) => Ok(Ok(response)),
        }
    }

    async fn ensure_open(&mut self, timeout: Duration) -> Result<(), LinkError> {
        if self.ctx.is_some() {
            return Ok(());
        }
        self.counters.reconnects += 1;
        match &self.config {
            LinkConfig::Rtu { .. } => {
                let port = match &self.port {
                    Some(p) => p.clone(),
                    None => {
                        let p = SharedPort::new(self.open_serial()?);
                        self.port = Some(p.clone());
                        self.speed = match &self.config {
                            LinkConfig::Rtu { baud, .. } => Some(*baud),
                            LinkConfig::Tcp { .. } => None,
                        };
                        self.timing = crate::config::line_timing(&self.config, self.guard);
                        p
                    }
                };
                self.ctx = Some(tokio_modbus::client::rtu::attach(FlushingPort::new(
                    port,
                    self.bytes_in.clone(),
                    self.last_byte.clone(),
                )));
            }
            LinkConfig::Tcp { host, port } => {
                let what = format!("{host}:{port}");
                let open_err = |message: String| LinkError::Open {
                    what: what.clone(),
                    message,
                };
                let connect = tokio::net::TcpStream::connect((host.as_str(), *port));
                let stream = tokio::time::timeout(timeout.max(Duration::from_secs(1)), connect)
                    .await
                    .map_err(|_| open_err("connect timed out".into()))?
                    .map_err(|e| open_err(e.to_string()))?;
                let _ = stream.set_nodelay(true);
                self.ctx = Some(tokio_modbus::client::tcp::attach(stream));
            }
        }
        Ok(())
    }

    fn open_serial(&self) -> Result<SerialStream, LinkError> {
        let LinkConfig::Rtu {
            port,
            baud,
            parity,
            stop_bits,
        } = &self.config
        else {
            unreachable!("serial open on a TCP link");
        };
        let open_err = |e: tokio_serial::Error| LinkError::Open {
            what: port.display().to_string(),
            message: e.to_string(),
        };
        let mut stream = tokio_serial::new(port_name(port), *baud)
            .data_bits(tokio_serial::DataBits::Eight)
            .parity(match parity {
                Parity::None => tokio_serial::Parity::None,
                Parity::Even => tokio_serial::Parity::Even,
                Parity::Odd => tokio_serial::Parity::Odd,
            })
            .stop_bits(if *stop_bits == 2 {
                tokio_serial::StopBits::Two
            } else {
                tokio_serial::StopBits::One
            })
            .flow_control(tokio_serial::FlowControl::None)
            .open_native_async()
            .map_err(open_err)?;
        // Another process on the same adapter would garble every frame.
        let _ = stream.set_exclusive(true);
        Ok(stream)
    }
}

/// Waits until `t` with sub-millisecond precision. The runtime's timer ticks in milliseconds,
/// which at 115200 baud (1.75 ms silent interval) would cost a third of the line's capacity;
/// the last stretch is slept on a blocking thread instead, which the OS wakes on time.
async fn wait_until(t: Instant) {
    const COARSE: Duration = Duration::from_millis(2);
    let now = Instant::now();
    if t <= now {
        return;
    }
    if t - now > COARSE {
        tokio::time::sleep_until(t - COARSE).await;
    }
    // Even with a fine timer slack the OS wakes a little late: sleep short of the mark, then
    // yield until it.
    const SPIN: Duration = Duration::from_micros(30);
    let rest = t.saturating_duration_since(Instant::now());
    if rest > SPIN {
        let _ = tokio::task::spawn_blocking(move || {
            fine_timer_slack();
            std::thread::sleep(rest - SPIN)
        })
        .await;
    }
    while Instant::now() < t {
        tokio::task::yield_now().await;
    }
}

/// Asks Linux to wake this thread's sleeps on time: the default timer slack (50 us) would
/// stretch every silent interval.
pub fn fine_timer_slack() {
    // SAFETY: PR_SET_TIMERSLACK takes one integer argument and only affects this thread.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
    }
}

fn port_name(p: &std::path::Path) -> String {
    // Follow udev-style symlinks so errors and locks name the real device.
    std::fs::canonicalize(p)
        .unwrap_or_else(|_| PathBuf::from(p))
        .display()
        .to_string()
}

/// The serial port, shared so the client can be rebuilt without reopening the device.
#[derive(Clone)]
struct SharedPort(Arc<Mutex<SerialStream>>);

impl SharedPort {
    fn new(s: SerialStream) -> SharedPort {
        SharedPort(Arc::new(Mutex::new(s)))
    }

    fn with<R>(&self, f: impl FnOnce(&mut SerialStream) -> R) -> R {
        // A poisoned lock only means another poll panicked mid-I/O; the port itself is fine.
        let mut guard = self.0.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut guard)
    }
}

/// The port as tokio-modbus sees it: before the first byte of each request, whatever the kernel
/// holds in the input buffer (a late answer, line noise) is discarded.
struct FlushingPort {
    port: SharedPort,
    at_request_start: bool,
    bytes_in: Arc<AtomicU64>,
    last_byte: Arc<Mutex<Option<Instant>>>,
}

impl FlushingPort {
    fn new(
        port: SharedPort,
        bytes_in: Arc<AtomicU64>,
        last_byte: Arc<Mutex<Option<Instant>>>,
    ) -> FlushingPort {
        FlushingPort {
            port,
            at_request_start: true,
            bytes_in,
            last_byte,
        }
    }
}

impl AsyncRead for FlushingPort {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        this.at_request_start = true;
        let before = buf.filled().len();
        let poll = this.port.with(|s| Pin::new(s).poll_read(cx, buf));
        let n = buf.filled().len() - before;
        if n > 0 {
            this.bytes_in.fetch_add(n as u64, Ordering::Relaxed);
            *this.last_byte.lock().unwrap_or_else(|e| e.into_inner()) = Some(Instant::now());
        }
        poll
    }
}

impl AsyncWrite for FlushingPort {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut TaskContext<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        if std::mem::take(&mut this.at_request_start) {
            this.port
                .with(|s| s.clear(tokio_serial::ClearBuffer::Input))
                .map_err(io::Error::other)?;
        }
        this.port.with(|s| Pin::new(s).poll_write(cx, data))
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<io::Result<()>> {
        self.get_mut().port.with(|s| Pin::new(s).poll_flush(cx))
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut TaskContext<'_>) -> Poll<io::Result<()>> {
        self.get_mut().port.with(|s| Pin::new(s).poll_shutdown(cx))
    }
}

#[cfg(test)]
mod speed_tests {
    use super::*;

    #[tokio::test]
    async fn the_port_is_switched_to_a_units_own_baud_rate_and_back() {
        let (_master, slave) = serialport::TTYPort::pair().unwrap();
        let path = PathBuf::from(slave.name().unwrap());
        let config = LinkConfig::Rtu {
            port: path,
            baud: 9600,
            parity: Parity::None,
            stop_bits: 1,
        };
        let mut link = Link::new(config, Duration::ZERO);
        link.set_unit_baud(5, 19200);
        let short = Duration::from_millis(20);
        // Nobody answers on this pty; the speed the port was set to is what counts.
        assert!(link.read(5, 210, 1, short).await.is_err());
        assert_eq!(slave.baud_rate().unwrap(), 19200);
        assert_eq!(link.timing().unwrap().baud, 19200);
        assert!(link.read(1, 210, 1, short).await.is_err());
        assert_eq!(slave.baud_rate().unwrap(), 9600);
        assert_eq!(link.timing_for(5).unwrap().baud, 19200);
    }
}
