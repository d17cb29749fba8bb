//! The RTU serial port as the runtime sees it: few wake-ups per transaction.
//!
//! - The port is watched for input only. tokio-serial registers it for output too, so every
//!   request written woke the runtime once more for nothing (the port is writable again).
//! - Writing never waits for the bytes to leave (no `tcdrain`): on a real UART that call blocks
//!   the runtime's thread for the request's line time (8 ms for 8 bytes at 9600 baud). Nothing
//!   needs it: the silent interval counts from the end of the answer.
//! - An answer is read in one or two wake-ups, not one per byte or two: the port is watched
//!   until the answer's first bytes arrive, then taken out of the runtime's epoll set
//!   ([`RtuPort::quiet_until`]) while the rest of the answer is on the wire, the time its
//!   length takes at the baud rate, and read at once on a timer. (`VMIN` alone is not enough:
//!   the kernel still wakes an epoll waiter at every byte to ask the line discipline again.)
//!   If the bytes are not all there by then, the port is watched again: nothing is lost, the
//!   answer costs a wake-up more. The quiet wait also covers the silent interval that must
//!   follow the answer (see `link::FlushingPort`), so the next request goes out in the same
//!   wake-up that reads the answer's end.
//! - An answer the line cut short (a byte lost on a noisy line) is known as such once the line
//!   stays quiet for [`CUT_GRACE`] after its end should have come: it is read as garbled then,
//!   rather than after the whole answer timeout. On a line that loses a byte in a few dozen,
//!   most lost reads are of this kind, and the timeout they cost was most of the line's time.

use std::io;
use std::os::fd::AsRawFd;
use std::pin::Pin;
use std::task::{Context, Poll, ready};
use std::time::Duration;

use serialport::{ClearBuffer, SerialPort, SerialPortBuilder, TTYPort};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};
use tokio::time::Instant;

use super::timer::FineTimer;
use crate::modbus::config::plan::{
    ANSWER_OVERHEAD_BYTES, EXCEPTION_BYTES, LineTiming, REQUEST_BYTES, bits_per_char,
};

/// How long the line may stay quiet past an answer's end before the answer counts as cut short:
/// enough for an adapter that holds bytes for its latency timer (16 ms for an FTDI chip left at
/// its default), far less than an answer timeout.
pub const CUT_GRACE: Duration = Duration::from_millis(30);

/// Whether the runtime watches the port.
enum Watch {
    /// In the runtime's epoll set: woken by the first byte that arrives.
    Watched(AsyncFd<TTYPort>),
    /// Out of it, until the timer says the answer should be complete.
    Quiet(TTYPort),
    /// Only while switching between the two.
    Switching,
}

/// A serial port opened for RTU.
pub struct RtuPort {
    watch: Watch,
    /// Times the quiet wait.
    timer: FineTimer,
    /// The quiet wait is armed.
    quiet: bool,
    /// The answer is short of its length and the line went quiet at its end: the timer ends
    /// the grace after which it is cut short.
    cut: bool,
    /// How long past the quiet wait the line may stay silent: `CUT_GRACE` (longer only in
    /// tests whose byte-feeding thread may run late on a loaded machine).
    grace: Duration,
    /// The rate and bits per character the port is set to (the guard is the link's).
    timing: LineTiming,
}

impl RtuPort {
    /// Opens and configures the port (raw mode; see `serialport`) and hands it to the runtime.
    pub fn open(builder: &SerialPortBuilder) -> Result<RtuPort, serialport::Error> {
        let mut port = TTYPort::open(builder)?;
        // Another process on the same adapter would garble every frame.
        let _ = port.set_exclusive(true);
        set_nonblocking(port.as_raw_fd())?;
        let parity = port.parity()? != serialport::Parity::None;
        let stop = if port.stop_bits()? == serialport::StopBits::Two {
            2
        } else {
            1
        };
        let baud = port.baud_rate()?;
        let mut rtu = RtuPort {
            watch: Watch::Quiet(port),
            timer: FineTimer::new()?,
            quiet: false,
            cut: false,
            grace: CUT_GRACE,
            timing: LineTiming {
                baud,
                bits_per_char: bits_per_char(parity, stop),
                guard: Duration::ZERO,
            },
        };
        rtu.watch()?;
        Ok(rtu)
    }

    fn tty(&self) -> &TTYPort {
        match &self.watch {
            Watch::Watched(fd) => fd.get_ref(),
            Watch::Quiet(port) => port,
            Watch::Switching => unreachable!("port switching between watched and quiet"),
        }
    }

    pub fn set_baud_rate(&mut self, baud: u32) -> serialport::Result<()> {
        match &mut self.watch {
            Watch::Watched(fd) => fd.get_mut().set_baud_rate(baud)?,
            Watch::Quiet(port) => port.set_baud_rate(baud)?,
            Watch::Switching => unreachable!("port switching between watched and quiet"),
        }
        self.timing.baud = baud;
        Ok(())
    }

    /// Discards whatever the kernel holds in the input buffer (a late answer, line noise).
    pub fn clear_input(&self) -> serialport::Result<()> {
        self.tty().clear(ClearBuffer::Input)
    }

    /// Bytes received and not read yet.
    pub fn pending(&self) -> usize {
        self.tty().bytes_to_read().map_or(0, |n| n as usize)
    }

    /// The line's timing at the rate the port is set to now (a unit may have its own).
    pub fn timing(&self, guard: Duration) -> LineTiming {
        LineTiming {
            guard,
            ..self.timing
        }
    }

    /// Time on the wire of `chars` characters.
    pub fn line_time(&self, chars: usize) -> Duration {
        self.timing.frame_time(chars)
    }

    /// A new answer is awaited: watched, and nothing of the last one's grace is left.
    pub fn await_answer(&mut self) -> io::Result<()> {
        self.cut = false;
        self.watch()
    }

    /// Puts the port in the runtime's epoll set: the next byte wakes the reader.
    pub fn watch(&mut self) -> io::Result<()> {
        self.quiet = false;
        if let Watch::Quiet(_) = self.watch {
            let Watch::Quiet(port) = std::mem::replace(&mut self.watch, Watch::Switching) else {
                unreachable!()
            };
            // SAFETY: the AsyncFd owns the port; nothing closes or replaces its descriptor
            // meanwhile.
            match unsafe { AsyncFd::register_with_interest(port, Interest::READABLE) } {
                Ok(fd) => self.watch = Watch::Watched(fd),
                Err(e) => {
                    let (port, error) = e.into_parts();
                    self.watch = Watch::Quiet(port);
                    return Err(error);
                }
            }
        }
        Ok(())
    }

    /// Takes the port out of the runtime's epoll set until `t`, when the reader is woken to
    /// read what has come (a watched port wakes the runtime at every byte).
    pub fn quiet_until(&mut self, t: Instant) -> io::Result<()> {
        if let Watch::Watched(_) = self.watch {
            let Watch::Watched(fd) = std::mem::replace(&mut self.watch, Watch::Switching) else {
                unreachable!()
            };
            self.watch = Watch::Quiet(fd.into_inner());
        }
        self.timer.arm_at(t)?;
        self.quiet = true;
        self.cut = false;
        Ok(())
    }

    fn read_now(&self, buf: &mut [u8]) -> io::Result<usize> {
        // SAFETY: reads at most `buf.len()` bytes into initialised memory.
        let n = unsafe { libc::read(self.tty().as_raw_fd(), buf.as_mut_ptr().cast(), buf.len()) };
        if n < 0 {
            Err(io::Error::last_os_error())
        } else {
            Ok(n as usize)
        }
    }
}

fn set_nonblocking(fd: i32) -> io::Result<()> {
    // SAFETY: F_GETFL/F_SETFL on a descriptor we own.
    let flags = unsafe { libc::fcntl(fd, libc::F_GETFL) };
    if flags < 0 || unsafe { libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

/// The length of the answer whose first bytes are `head` (at least 3), if the function is one
/// the gateway uses: read holding registers (byte count in the third byte), write one or
/// several registers (8 bytes), any exception (5 bytes).
pub fn expected_len(head: &[u8]) -> Option<usize> {
    let (&function, &count) = (head.get(1)?, head.get(2)?);
    match function {
        f if f & 0x80 != 0 => Some(EXCEPTION_BYTES),
        0x03 | 0x04 => Some(ANSWER_OVERHEAD_BYTES + usize::from(count)),
        0x06 | 0x10 => Some(REQUEST_BYTES),
        _ => None,
    }
}

impl AsyncRead for RtuPort {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        if this.quiet {
            ready!(this.timer.poll_expired(cx))?;
            this.quiet = false;
            match this.read_now(buf.initialize_unfilled()) {
                Ok(n) if n > 0 => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(_) => {}
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
                Err(e) => return Poll::Ready(Err(e)),
            }
            // Nothing more although the answer is not complete: the line may have cut it short.
            // Watch the port again, for a grace.
            this.timer.arm_at(Instant::now() + this.grace)?;
            this.cut = true;
        }
        this.watch()?;
        let Watch::Watched(fd) = &this.watch else {
            unreachable!("watched above")
        };
        loop {
            let mut ready = match fd.poll_read_ready(cx) {
                Poll::Ready(ready) => ready?,
                Poll::Pending if this.cut => {
                    ready!(this.timer.poll_expired(cx))?;
                    this.cut = false;
                    return Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::InvalidData,
                        "answer cut short: the line went quiet before its last byte",
                    )));
                }
                Poll::Pending => return Poll::Pending,
            };
            let unfilled = buf.initialize_unfilled();
            let unfilled_len = unfilled.len();
            let read = ready.try_io(|fd| {
                // SAFETY: reads at most `unfilled.len()` bytes into initialised memory.
                let n = unsafe {
                    libc::read(fd.as_raw_fd(), unfilled.as_mut_ptr().cast(), unfilled.len())
                };
                if n < 0 {
                    Err(io::Error::last_os_error())
                } else {
                    Ok(n as usize)
                }
            });
            match read {
                Ok(Ok(n)) => {
                    // Fewer bytes than asked for: the kernel has no more. Waiting for the next
                    // readiness now saves a read that would only say "would block" (a newer
                    // readiness event is kept: tokio clears only the one this read consumed).
                    if n < unfilled_len {
                        ready.clear_ready();
                    }
                    this.cut = false;
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for RtuPort {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        // SAFETY: writes at most `data.len()` bytes from `data` to a descriptor we own.
        let n = unsafe { libc::write(self.tty().as_raw_fd(), data.as_ptr().cast(), data.len()) };
        if n >= 0 {
            return Poll::Ready(Ok(n as usize));
        }
        let e = io::Error::last_os_error();
        if e.kind() == io::ErrorKind::WouldBlock {
            // The output buffer is full (kilobytes: a requests is a few bytes, so only a
            // stuck adapter does this). Try again on the next turn; the transaction's timeout
            // bounds it.
            cx.waker().wake_by_ref();
            return Poll::Pending;
        }
        Poll::Ready(Err(e))
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;
    use tokio::io::AsyncReadExt;

    #[test]
    fn an_answers_length_comes_from_its_header() {
        // Read holding registers, 8 registers: 01 03 10 … (16 data bytes) + CRC = 21 bytes.
        assert_eq!(expected_len(&[0x01, 0x03, 0x10]), Some(21));
        // Exception 02 to function 03: 01 83 02 + CRC = 5 bytes.
        assert_eq!(expected_len(&[0x01, 0x83, 0x02]), Some(5));
        // Write single register echo: 01 06 00 43 00 0A + CRC = 8 bytes.
        assert_eq!(expected_len(&[0x01, 0x06, 0x00]), Some(8));
        assert_eq!(expected_len(&[0x01, 0x10, 0x00]), Some(8));
        assert_eq!(expected_len(&[0x01, 0x2B, 0x0E]), None);
        assert_eq!(expected_len(&[0x01, 0x03]), None);
    }

    /// A 21-byte answer trickling in one byte at a time is read in two wake-ups: the first
    /// byte, then the rest after the time it takes on the wire. The port is timed at 1200 baud
    /// (9 ms a character) while the feeder writes a byte every millisecond, so a feeder running
    /// several times late on a loaded machine still fits the wait.
    #[tokio::test]
    async fn a_trickling_answer_is_read_in_two_wake_ups() {
        let (mut master, slave) = TTYPort::pair().unwrap();
        let path = slave.name().unwrap();
        let builder = serialport::new(path, 1200);
        let mut port = RtuPort::open(&builder).unwrap();
        drop(slave);
        let answer: Vec<u8> = [0x01, 0x03, 0x10].into_iter().chain(0..18u8).collect();
        let feeder = std::thread::spawn(move || {
            for b in answer {
                std::thread::sleep(std::time::Duration::from_millis(1));
                master.write_all(&[b]).unwrap();
            }
            master
        });
        let mut got = Vec::new();
        let mut reads = 0;
        while got.len() < 21 {
            let mut chunk = [0u8; 64];
            let n = port.read(&mut chunk).await.unwrap();
            reads += 1;
            got.extend_from_slice(&chunk[..n]);
            let rest = 21 - got.len();
            if rest > 0 {
                let t = Instant::now() + port.line_time(rest);
                port.quiet_until(t).unwrap();
            }
        }
        let _master = feeder.join().unwrap();
        assert_eq!(got[..3], [0x01, 0x03, 0x10]);
        // Watched throughout, every byte (or two) wakes the reader: 10 or more reads. The
        // sleeps of the feeder run late on a loaded machine, so allow a few more than two.
        assert!(reads <= 4, "{reads} reads for one answer");
    }

    #[tokio::test]
    async fn a_quiet_wait_with_nothing_come_watches_the_port_again() {
        let (mut master, slave) = TTYPort::pair().unwrap();
        let mut port = RtuPort::open(&serialport::new(slave.name().unwrap(), 9600)).unwrap();
        drop(slave);
        // The feeder's sleep may run long on a loaded machine: a grace it cannot miss.
        port.grace = Duration::from_secs(2);
        port.quiet_until(Instant::now() + Duration::from_millis(1))
            .unwrap();
        let feeder = std::thread::spawn(move || {
            // Late, as from an adapter holding bytes for its latency timer; within the grace.
            std::thread::sleep(std::time::Duration::from_millis(8));
            master.write_all(&[0x07]).unwrap();
            master
        });
        let mut chunk = [0u8; 8];
        let n = tokio::time::timeout(Duration::from_secs(2), port.read(&mut chunk))
            .await
            .expect("the byte after the quiet wait is read")
            .unwrap();
        assert_eq!(&chunk[..n], &[0x07]);
        let _ = feeder.join();
    }

    /// The rest of an answer that never comes (a byte lost on the line): once the line stays
    /// quiet for the grace after the quiet wait, the read fails as garbled data, long before
    /// an answer timeout would.
    #[tokio::test]
    async fn an_answer_the_line_cut_short_fails_after_the_grace_not_the_timeout() {
        let (_master, slave) = TTYPort::pair().unwrap();
        let mut port = RtuPort::open(&serialport::new(slave.name().unwrap(), 9600)).unwrap();
        drop(slave);
        let start = Instant::now();
        port.quiet_until(start + Duration::from_millis(1)).unwrap();
        let mut chunk = [0u8; 8];
        let read = tokio::time::timeout(Duration::from_secs(2), port.read(&mut chunk))
            .await
            .expect("the cut answer is given up");
        let e = read.unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::InvalidData, "{e}");
        assert!(start.elapsed() >= CUT_GRACE, "{:?}", start.elapsed());
        // A new answer is awaited afresh: no grace is left over from the cut one.
        port.await_answer().unwrap();
        let waited = tokio::time::timeout(Duration::from_millis(60), port.read(&mut chunk)).await;
        assert!(
            waited.is_err(),
            "a new answer waits for its bytes: {waited:?}"
        );
    }
}
