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

use super::serial::{RtuPort, expected_len};

use crate::config::Parity;
use crate::modbus::config::Line as LinkConfig;
use crate::modbus::config::plan::{LineTiming, REQUEST_BYTES, read_answer_bytes};

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

use crate::bus_health::WireCounters;

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
    /// Times the silent interval on the runtime's thread (RTU; made at the first wait).
    timer: Option<super::timer::FineTimer>,
    /// The last transaction's time from its request to its answer's last byte.
    answer_time: Option<Duration>,
}

impl Link {
    /// A link for `config`; nothing is opened until the first transaction.
    pub fn new(config: LinkConfig, guard: Duration) -> Link {
        let timing = config.timing(guard);
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
            timer: None,
            answer_time: None,
        }
    }

    /// How long to wait for the answer to a read of `len` registers from a device that takes
    /// `answer` to answer, at the line's own rate ([`crate::modbus::config::plan::read_timeout`]).
    pub fn timeout_for(&self, answer: Duration, len: u16) -> Duration {
        crate::modbus::config::plan::read_timeout(answer, self.timing().as_ref(), len)
    }

    /// Character timing of the line while talking to `unit` (its own rate where it has one).
    pub fn timing_for(&self, unit: u8) -> Option<LineTiming> {
        let mut config = self.config.clone();
        if let (LinkConfig::Rtu { baud, .. }, Some(own)) = (&mut config, self.unit_bauds.get(&unit))
        {
            *baud = *own;
        }
        config.timing(self.guard)
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

    /// The last transaction's latency: from its request to the last byte of its answer (read
    /// a little later, see `FlushingPort`).
    pub fn answer_time(&self) -> Option<Duration> {
        self.answer_time
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
            self.wait_until(last + timing.silent_interval()).await;
        }
        self.switch_speed(unit)?;
        self.ensure_timer();
        let ctx = self.ctx.as_mut().expect("opened above");
        ctx.set_slave(Slave(unit));
        self.counters.transactions += 1;
        let started = Instant::now();
        let bytes_before = self.bytes_in.load(Ordering::Relaxed);
        // The timeout on the fine timer too: a runtime timer registered per transaction wakes
        // the runtime's driver once more each time (to take the new, earlier deadline).
        // The port reads an answer's end only after the silent interval that follows it
        // (see `FlushingPort`): an answer complete on the wire just in time is not late.
        let after = self.timing.map_or(Duration::ZERO, |t| t.silent_interval());
        let result = tokio::select! {
            biased;
            answer = ctx.call(req) => Ok(answer),
            () = deadline(self.timer.as_ref(), started + timeout + after) => Err(()),
        };
        let now = Instant::now();
        let last_byte = self
            .last_byte
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take();
        let end = last_byte.unwrap_or(now).min(now);
        self.busy += end - started;
        self.answer_time = Some(end - started);
        self.last_io = Some(end);
        self.judge(result, bytes_before, timeout)
    }

    /// What a transaction's result says of the line and the client: counted, and the client
    /// rebuilt where a late or broken answer could otherwise be read as the next one.
    fn judge(
        &mut self,
        result: Result<Result<Result<Response, ExceptionCode>, tokio_modbus::Error>, ()>,
        bytes_before: u64,
        timeout: Duration,
    ) -> Answer<Response> {
        match result {
            Err(_elapsed) => {
                // A late answer may still arrive: rebuild so it cannot be read as the next one.
                self.ctx = None;
                // Bytes still in the kernel (fewer than the port waited for) came back too.
                let unread = self.port.as_ref().map_or(0, |p| p.with(|s| s.pending()));
                let got = self.bytes_in.load(Ordering::Relaxed) - bytes_before + unread as u64;
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

    /// Waits until `t` with sub-millisecond precision (see [`super::timer`]); where no timerfd
    /// can be had, on the runtime's timer, which rounds up (never early, up to a tick late).
    async fn wait_until(&mut self, t: Instant) {
        if t <= Instant::now() {
            return;
        }
        self.ensure_timer();
        deadline(self.timer.as_ref(), t).await;
    }

    fn ensure_timer(&mut self) {
        if self.timer.is_none() {
            match super::timer::FineTimer::new() {
                Ok(timer) => self.timer = Some(timer),
                Err(e) => tracing::debug!("no timerfd ({e}): timing on the runtime timer"),
            }
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
                        self.timing = self.config.timing(self.guard);
                        p
                    }
                };
                self.ctx = Some(tokio_modbus::client::rtu::attach(FlushingPort::new(
                    port,
                    self.bytes_in.clone(),
                    self.last_byte.clone(),
                    self.guard,
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

    fn open_serial(&self) -> Result<RtuPort, LinkError> {
        let LinkConfig::Rtu {
            port,
            baud,
            parity,
            stop_bits,
        } = &self.config
        else {
            unreachable!("serial open on a TCP link");
        };
        let builder = serialport::new(port_name(port), *baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(match parity {
                Parity::None => serialport::Parity::None,
                Parity::Even => serialport::Parity::Even,
                Parity::Odd => serialport::Parity::Odd,
            })
            .stop_bits(if *stop_bits == 2 {
                serialport::StopBits::Two
            } else {
                serialport::StopBits::One
            })
            .flow_control(serialport::FlowControl::None);
        RtuPort::open(&builder).map_err(|e| LinkError::Open {
            what: port.display().to_string(),
            message: e.to_string(),
        })
    }
}

/// The length of a normal answer to the RTU request `frame` (unit, function, …), where the
/// function is one the gateway uses.
fn answer_len_for(frame: &[u8]) -> Option<usize> {
    match frame {
        [_, 0x03 | 0x04, _, _, hi, lo, ..] => {
            Some(read_answer_bytes(u16::from_be_bytes([*hi, *lo])))
        }
        [_, 0x06 | 0x10, ..] => Some(REQUEST_BYTES),
        _ => None,
    }
}

/// Returns at `t`: on the fine timer where there is one and it works, else on the runtime's.
async fn deadline(timer: Option<&super::timer::FineTimer>, t: Instant) {
    if let Some(timer) = timer
        && timer.sleep_until(t).await.is_ok()
    {
        return;
    }
    tokio::time::sleep_until(t).await;
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
struct SharedPort(Arc<Mutex<RtuPort>>);

impl SharedPort {
    fn new(s: RtuPort) -> SharedPort {
        SharedPort(Arc::new(Mutex::new(s)))
    }

    fn with<R>(&self, f: impl FnOnce(&mut RtuPort) -> R) -> R {
        // A poisoned lock only means another poll panicked mid-I/O; the port itself is fine.
        let mut guard = self.0.lock().unwrap_or_else(|e| e.into_inner());
        f(&mut guard)
    }
}

/// The port as tokio-modbus sees it: before the first byte of each request, whatever the kernel
/// holds in the input buffer (a late answer, line noise) is discarded, and the port is set to
/// wake the reader when the answer's first five bytes are in, then when the rest of it is
/// (see [`super::serial`]).
struct FlushingPort {
    port: SharedPort,
    at_request_start: bool,
    /// The first bytes of the answer being read, and how many have come.
    head: [u8; 3],
    got: usize,
    /// The answer's length as the request implies it (a normal answer, not an exception).
    expected: Option<usize>,
    bytes_in: Arc<AtomicU64>,
    last_byte: Arc<Mutex<Option<Instant>>>,
    /// Extra quiet time after the silent interval (the bus's `guard`).
    guard: Duration,
    /// When the answer's last byte leaves the wire, as its first bytes tell: they come at the
    /// line's rate once started (a gap of 1.5 characters ends an RTU frame), so the end is at
    /// most the rest's line time after the first bytes were read.
    wire_end: Option<Instant>,
}

impl FlushingPort {
    fn new(
        port: SharedPort,
        bytes_in: Arc<AtomicU64>,
        last_byte: Arc<Mutex<Option<Instant>>>,
        guard: Duration,
    ) -> FlushingPort {
        FlushingPort {
            port,
            at_request_start: true,
            head: [0; 3],
            got: 0,
            expected: None,
            bytes_in,
            last_byte,
            guard,
            wire_end: None,
        }
    }

    /// The answer's length: from its header once that is in, else as the request implies.
    fn total(&self) -> Option<usize> {
        if self.got >= self.head.len() {
            expected_len(&self.head)
        } else {
            self.expected
        }
    }

    /// Whether the answer's bytes are all in (as far as its header tells).
    fn complete(&self) -> bool {
        self.total().is_some_and(|t| self.got >= t)
    }

    /// Notes `bytes` of the answer; while more are to come, the port stays quiet for the time
    /// they take on the wire.
    fn answer_bytes(&mut self, bytes: &[u8]) -> io::Result<()> {
        for (i, b) in bytes.iter().enumerate() {
            if let Some(slot) = self.head.get_mut(self.got + i) {
                *slot = *b;
            }
        }
        self.got += bytes.len();
        let Some(rest) = self
            .total()
            .map(|t| t.saturating_sub(self.got))
            .filter(|r| *r > 0)
        else {
            return Ok(()); // complete, or of a length nobody can tell: watched
        };
        let guard = self.guard;
        let (end, result) = self.port.with(|s| {
            let end = Instant::now() + s.line_time(rest);
            // Read the rest once the silent interval after it is over too: the next request
            // may then go out at once, in the same wake-up (rather than one wake-up for the
            // bytes and another for the silence). A quarter character of slack for the
            // adapter's delivery.
            let t = end + s.timing(guard).silent_interval() + s.line_time(1) / 4;
            (end, s.quiet_until(t))
        });
        self.wire_end = Some(end);
        result
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
            let now = Instant::now();
            let foretold = this.wire_end.take();
            this.answer_bytes(&buf.filled()[before..])?;
            // The silent interval counts from the last byte on the wire: when the first bytes
            // foretold it, from then (the bytes were read later, after the quiet wait).
            let last = match foretold {
                Some(end) if this.complete() => end.min(now),
                _ => now,
            };
            *this.last_byte.lock().unwrap_or_else(|e| e.into_inner()) = Some(last);
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
            this.got = 0;
            this.wire_end = None;
            this.expected = answer_len_for(data);
            this.port.with(|s| {
                s.clear_input().map_err(io::Error::other)?;
                s.await_answer()
            })?;
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

/// A 9600 baud 8N1 RTU link on `port`, as the tests below open their pseudo-terminals.
#[cfg(test)]
fn rtu_9600(port: PathBuf) -> LinkConfig {
    LinkConfig::Rtu {
        port,
        baud: 9600,
        parity: Parity::None,
        stop_bits: 1,
    }
}

#[cfg(test)]
mod speed_tests {
    use super::*;
    use serialport::SerialPort;

    #[tokio::test]
    async fn the_port_is_switched_to_a_units_own_baud_rate_and_back() {
        let (_master, slave) = serialport::TTYPort::pair().unwrap();
        let path = PathBuf::from(slave.name().unwrap());
        let config = rtu_9600(path);
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

#[cfg(test)]
mod silence_tests {
    use super::*;
    use serialport::SerialPort;
    use std::io::{Read, Write};

    fn crc16(frame: &[u8]) -> [u8; 2] {
        let mut crc: u16 = 0xFFFF;
        for b in frame {
            crc ^= u16::from(*b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xA001
                } else {
                    crc >> 1
                };
            }
        }
        crc.to_le_bytes()
    }

    /// A module on a pty: reads one 8-byte request, then sends a 21-byte answer (8 registers)
    /// one character a millisecond, as a UART hands them over at 9600 baud.
    fn trickling_module(
        mut master: serialport::TTYPort,
    ) -> std::thread::JoinHandle<serialport::TTYPort> {
        std::thread::spawn(move || {
            let mut request = [0u8; 8];
            master
                .set_timeout(std::time::Duration::from_secs(2))
                .unwrap();
            master.read_exact(&mut request).unwrap();
            let mut answer = vec![request[0], 0x03, 16];
            answer.extend((1..=16u8).map(|b| b * 3));
            let crc = crc16(&answer);
            answer.extend(crc);
            for b in answer {
                std::thread::sleep(std::time::Duration::from_millis(1));
                master.write_all(&[b]).unwrap();
            }
            master
        })
    }

    /// The answer's end is read only after the silent interval that must follow it: when the
    /// read returns, the next request may go at once (one wake-up for both, not two), and the
    /// latency recorded is the time to the answer's last byte, not to the read.
    #[tokio::test]
    async fn a_trickled_answer_is_read_after_its_silent_interval_and_the_next_request_need_not_wait()
     {
        let (master, slave) = serialport::TTYPort::pair().unwrap();
        let path = PathBuf::from(slave.name().unwrap());
        let module = trickling_module(master);
        let config = rtu_9600(path);
        let mut link = Link::new(config, Duration::ZERO);
        let started = Instant::now();
        let words = link
            .read(1, 16, 8, Duration::from_millis(500))
            .await
            .expect("answered")
            .expect("no exception");
        let read_at = Instant::now();
        let _master = module.join().unwrap();
        assert_eq!(words[0], u16::from_be_bytes([3, 6]));
        let silent = link.timing().unwrap().silent_interval();
        let last = link.last_io.expect("a transaction happened");
        assert!(
            last + silent <= read_at,
            "the silent interval after the answer is over when it is read ({:?} short)",
            (last + silent) - read_at
        );
        let latency = link.answer_time().unwrap();
        assert!(latency + silent <= read_at - started, "{latency:?}");
    }
}
