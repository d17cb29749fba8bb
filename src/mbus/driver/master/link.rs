//! The M-Bus master's line: a serial level converter (8 data bits, even parity by default, 1
//! stop bit) or an M-Bus-to-Ethernet converter (raw frames on a TCP socket). One exchange at a
//! time: the request out, then the answer read until a frame is whole ([`frame::scan`]), until
//! the bytes can be no frame (a collision or a broken meter: what else arrives in a moment is
//! read with them), or nothing within the answer time (330 bit times + 50 ms by the standard).

use std::io;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

use crate::bus_health::WireCounters;
use crate::config::Parity;
use crate::mbus::config::Line as MbusLine;
use crate::mbus::driver::frame::{self, Frame, MAX_FRAME, Scan};

/// Bits of one character on the M-Bus line: start, 8 data, parity, stop.
pub const BITS_PER_CHAR: u32 = 11;

/// How long a converter on TCP may take to pass an answer on, when the config gives no
/// timeout (its own serial line and buffering come on top of the meter's answer time).
pub const TCP_ANSWER: Duration = Duration::from_millis(500);

/// The standard's answer time at `baud`: a meter answers within 330 bit times + 50 ms.
pub fn answer_time(baud: u32) -> Duration {
    Duration::from_secs_f64(330.0 / f64::from(baud.max(1))) + Duration::from_millis(50)
}

/// The time `bytes` characters take on the line at `baud`.
pub fn char_time(baud: u32, bytes: usize) -> Duration {
    Duration::from_secs_f64(bytes as f64 * f64::from(BITS_PER_CHAR) / f64::from(baud.max(1)))
}

/// What came back for one request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Heard {
    /// Nothing within the answer time.
    Nothing,
    /// One whole frame.
    Frame(Frame),
    /// Bytes that are no frame: several meters at once (a collision), a broken meter, noise,
    /// or an answer cut short; `why` says what the reader found.
    Garbled { bytes: Vec<u8>, why: String },
}

/// Why the line itself failed (the port or the connection, not one meter).
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("cannot open {what}: {message}")]
    Open { what: String, message: String },
    #[error("i/o error on {what}: {source}")]
    Io {
        what: String,
        #[source]
        source: io::Error,
    },
}

/// An open line.
enum Stream {
    Serial(tokio_serial::SerialStream),
    Tcp(tokio::net::TcpStream),
}

/// The master's line, opened at first use and again after a failure.
pub struct Link {
    line: MbusLine,
    stream: Option<Stream>,
    /// The answer time; the config's `timeout` where it gives one.
    answer: Duration,
    /// What the wire did: transactions, timeouts, garbled answers, i/o errors, reconnects.
    pub counters: WireCounters,
    /// Time spent in exchanges.
    pub busy: Duration,
}

impl Link {
    /// The line of `line`, answers awaited for `timeout` (default: the standard's answer time
    /// at the baud rate, or [`TCP_ANSWER`]).
    pub fn new(line: MbusLine, timeout: Option<Duration>) -> Link {
        let answer = timeout.unwrap_or(match &line {
            MbusLine::Serial { baud, .. } => answer_time(*baud),
            MbusLine::Tcp { .. } => TCP_ANSWER,
        });
        Link {
            line,
            stream: None,
            answer,
            counters: WireCounters::default(),
            busy: Duration::ZERO,
        }
    }

    /// The line's name in messages (`/dev/ttyUSB0`, `10.0.0.5:10001`).
    pub fn what(&self) -> String {
        match &self.line {
            MbusLine::Serial { port, .. } => port.display().to_string(),
            MbusLine::Tcp { host, port } => format!("{host}:{port}"),
        }
    }

    /// The line's config.
    pub fn line(&self) -> &MbusLine {
        &self.line
    }

    /// How long a meter has to answer.
    pub fn answer_time(&self) -> Duration {
        self.answer
    }

    /// The times an exchange on this line waits for an answer in `answer`.
    fn timing(&self, answer: Duration) -> Timing {
        match &self.line {
            MbusLine::Serial { baud, .. } => Timing {
                answer,
                per_char: char_time(*baud, 1),
                slack: Duration::from_millis(50),
                settle: char_time(*baud, 3).max(Duration::from_millis(30)),
            },
            MbusLine::Tcp { .. } => Timing {
                answer,
                per_char: Duration::ZERO,
                slack: Duration::from_millis(200),
                settle: Duration::from_millis(40),
            },
        }
    }

    async fn open(&mut self) -> Result<(), LinkError> {
        if self.stream.is_some() {
            return Ok(());
        }
        self.counters.reconnects += 1;
        let what = self.what();
        let open_err = |message: String| LinkError::Open {
            what: what.clone(),
            message,
        };
        let stream = match &self.line {
            MbusLine::Serial { port, baud, parity } => {
                Stream::Serial(open_serial(port, *baud, *parity).map_err(open_err)?)
            }
            MbusLine::Tcp { host, port } => {
                let connect = tokio::net::TcpStream::connect((host.as_str(), *port));
                let stream = tokio::time::timeout(Duration::from_secs(3), connect)
                    .await
                    .map_err(|_| open_err("connect timed out".into()))?
                    .map_err(|e| open_err(e.to_string()))?;
                let _ = stream.set_nodelay(true);
                Stream::Tcp(stream)
            }
        };
        self.stream = Some(stream);
        Ok(())
    }

    /// Closes the line (it opens again at the next exchange).
    pub fn close(&mut self) {
        self.stream = None;
    }

    /// Sends `request` and reads what comes back.
    pub async fn exchange(&mut self, request: &[u8]) -> Result<Heard, LinkError> {
        self.exchange_within(request, None).await
    }

    /// The same, the answer awaited for `answer` where given (a meter's own `timeout`).
    pub async fn exchange_within(
        &mut self,
        request: &[u8],
        answer: Option<Duration>,
    ) -> Result<Heard, LinkError> {
        self.open().await?;
        let started = Instant::now();
        let what = self.what();
        let timing = self.timing(answer.unwrap_or(self.answer));
        let result = match self.stream.as_mut() {
            Some(Stream::Serial(s)) => transact(s, request, &timing).await,
            Some(Stream::Tcp(s)) => transact(s, request, &timing).await,
            None => Ok(Heard::Nothing),
        };
        self.busy += started.elapsed();
        self.counters.transactions += 1;
        match &result {
            Ok(Heard::Nothing) => self.counters.timeouts += 1,
            Ok(Heard::Garbled { .. }) => self.counters.garbled += 1,
            Ok(Heard::Frame(_)) => {}
            Err(_) => {
                self.counters.io_errors += 1;
                self.stream = None;
            }
        }
        result.map_err(|source| LinkError::Io { what, source })
    }
}

/// The times one exchange waits.
struct Timing {
    /// For the first byte of the answer.
    answer: Duration,
    /// One character on the line (zero on TCP), and the slack on top of the characters an
    /// answer under way still needs.
    per_char: Duration,
    slack: Duration,
    /// The quiet that ends a garbled answer.
    settle: Duration,
}

impl Timing {
    /// How long to wait for `n` more bytes of an answer under way.
    fn rest(&self, n: usize) -> Duration {
        self.per_char * n as u32 + self.slack
    }
}

/// One exchange on an open stream: stale bytes dropped, the request written, the answer read.
async fn transact<S: AsyncRead + AsyncWrite + Unpin>(
    s: &mut S,
    request: &[u8],
    timing: &Timing,
) -> io::Result<Heard> {
    let mut chunk = [0u8; 512];
    // A late answer to an earlier request must not be read as this one's.
    while let Some(read) = read_now(s, &mut chunk).await {
        if read? == 0 {
            return Err(io::ErrorKind::UnexpectedEof.into());
        }
    }
    s.write_all(request).await?;
    s.flush().await?;
    let mut buf = Vec::new();
    let mut wait = timing.answer;
    loop {
        match tokio::time::timeout(wait, s.read(&mut chunk)).await {
            Err(_) if buf.is_empty() => return Ok(Heard::Nothing),
            Err(_) => {
                let why = format!("the answer stopped after {} bytes", buf.len());
                return Ok(Heard::Garbled { bytes: buf, why });
            }
            Ok(Ok(0)) => return Err(io::ErrorKind::UnexpectedEof.into()),
            Ok(Ok(n)) => buf.extend_from_slice(&chunk[..n]),
            Ok(Err(e)) => return Err(e),
        }
        match frame::scan(&buf) {
            Ok(Scan::Need(n)) => wait = timing.rest(n),
            Ok(Scan::Frame { frame, consumed }) if consumed == buf.len() => {
                return Ok(Heard::Frame(frame));
            }
            Ok(Scan::Frame { consumed, .. }) => {
                let why = format!("{} bytes after a frame", buf.len() - consumed);
                return settle(s, buf, why, timing.settle).await;
            }
            Err(e) => return settle(s, buf, e.to_string(), timing.settle).await,
        }
    }
}

/// What the stream holds now, without waiting (`None`: nothing). Not a zero timeout: a timer
/// of zero still waits for the runtime's next millisecond tick, once per exchange.
async fn read_now<S: AsyncRead + Unpin>(s: &mut S, buf: &mut [u8]) -> Option<io::Result<usize>> {
    std::future::poll_fn(|cx| {
        let mut b = tokio::io::ReadBuf::new(buf);
        match std::pin::Pin::new(&mut *s).poll_read(cx, &mut b) {
            std::task::Poll::Ready(r) => std::task::Poll::Ready(Some(r.map(|()| b.filled().len()))),
            std::task::Poll::Pending => std::task::Poll::Ready(None),
        }
    })
    .await
}

/// Reads what else arrives until the line is quiet: the rest of a garbled answer.
async fn settle<S: AsyncRead + Unpin>(
    s: &mut S,
    mut bytes: Vec<u8>,
    why: String,
    quiet: Duration,
) -> io::Result<Heard> {
    let mut chunk = [0u8; 512];
    while bytes.len() < 4 * MAX_FRAME {
        match tokio::time::timeout(quiet, s.read(&mut chunk)).await {
            Ok(Ok(n)) if n > 0 => bytes.extend_from_slice(&chunk[..n]),
            Ok(Err(e)) => return Err(e),
            _ => break,
        }
    }
    Ok(Heard::Garbled { bytes, why })
}

/// Opens a serial port for M-Bus: 8 data bits, `parity`, 1 stop bit, exclusively.
fn open_serial(
    port: &std::path::Path,
    baud: u32,
    parity: Parity,
) -> Result<tokio_serial::SerialStream, String> {
    use serialport::SerialPort as _;
    let parity = match parity {
        Parity::None => serialport::Parity::None,
        Parity::Even => serialport::Parity::Even,
        Parity::Odd => serialport::Parity::Odd,
    };
    let mut tty = serialport::new(port.display().to_string(), baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(parity)
        .stop_bits(serialport::StopBits::One)
        .timeout(Duration::ZERO)
        .open_native()
        .map_err(|e| e.to_string())?;
    // Another process on the same converter would garble every frame.
    let _ = tty.set_exclusive(true);
    let _ = tty.clear(serialport::ClearBuffer::All);
    tokio_serial::SerialStream::try_from(tty).map_err(|e| e.to_string())
}
