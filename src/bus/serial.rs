//! The RTU serial port as the runtime sees it: few wake-ups per transaction.
//!
//! - The port is watched for input only. tokio-serial registers it for output too, so every
//!   request written woke the runtime once more for nothing (the port is writable again).
//! - Writing never waits for the bytes to leave (no `tcdrain`): on a real UART that call blocks
//!   the runtime's thread for the request's line time (8 ms for 8 bytes at 9600 baud). Nothing
//!   needs it: the silent interval counts from the end of the answer.
//! - An answer is read in one or two wake-ups instead of one per byte or two: the line
//!   discipline reports the port readable only once `VMIN` bytes are waiting (Linux n_tty, raw
//!   mode, `VTIME` 0), so the port asks for the five bytes every answer has (an exception is
//!   exactly five), then, from the answer's own header, for the rest of it ([`expected_len`]).
//!   A read never blocks (`O_NONBLOCK`): what is there is returned whatever `VMIN` says.

use std::io;
use std::os::fd::AsRawFd;
use std::pin::Pin;
use std::task::{Context, Poll, ready};

use serialport::{ClearBuffer, SerialPort, SerialPortBuilder, TTYPort};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};

/// The shortest Modbus RTU answer: an exception (unit, function | 0x80, code, CRC).
pub const SHORTEST_ANSWER: usize = 5;

/// A serial port opened for RTU, registered with the runtime for input only.
pub struct RtuPort {
    fd: AsyncFd<TTYPort>,
    /// The port's settings as last read, so a `VMIN` change is one system call.
    termios: Option<libc::termios>,
}

impl RtuPort {
    /// Opens and configures the port (raw mode; see `serialport`) and hands it to the runtime.
    pub fn open(builder: &SerialPortBuilder) -> Result<RtuPort, serialport::Error> {
        let mut port = TTYPort::open(builder)?;
        // Another process on the same adapter would garble every frame.
        let _ = port.set_exclusive(true);
        set_nonblocking(port.as_raw_fd())?;
        // SAFETY: the AsyncFd owns the port; nothing closes or replaces its descriptor meanwhile.
        let fd = unsafe { AsyncFd::register_with_interest(port, Interest::READABLE) }
            .map_err(|e| serialport::Error::from(io::Error::from(e)))?;
        Ok(RtuPort { fd, termios: None })
    }

    pub fn set_baud_rate(&mut self, baud: u32) -> serialport::Result<()> {
        self.termios = None;
        self.fd.get_mut().set_baud_rate(baud)
    }

    /// Discards whatever the kernel holds in the input buffer (a late answer, line noise).
    pub fn clear_input(&self) -> serialport::Result<()> {
        self.fd.get_ref().clear(ClearBuffer::Input)
    }

    /// Bytes received and not read yet.
    pub fn pending(&self) -> usize {
        self.fd.get_ref().bytes_to_read().map_or(0, |n| n as usize)
    }

    /// Lets the runtime see the port readable only once `n` bytes (1..=255) are waiting.
    pub fn wake_at(&mut self, n: usize) -> io::Result<()> {
        let n = n.clamp(1, 255) as u8;
        let fd = self.fd.get_ref().as_raw_fd();
        let termios = match &mut self.termios {
            Some(t) => t,
            None => {
                let mut t = std::mem::MaybeUninit::<libc::termios>::uninit();
                // SAFETY: tcgetattr fills the termios struct of a valid descriptor.
                if unsafe { libc::tcgetattr(fd, t.as_mut_ptr()) } < 0 {
                    return Err(io::Error::last_os_error());
                }
                // SAFETY: initialised by the successful tcgetattr above.
                self.termios.insert(unsafe { t.assume_init() })
            }
        };
        if termios.c_cc[libc::VMIN] == n && termios.c_cc[libc::VTIME] == 0 {
            return Ok(());
        }
        termios.c_cc[libc::VMIN] = n;
        termios.c_cc[libc::VTIME] = 0;
        // TCSETS directly (glibc's tcsetattr reads the settings back around it): the kernel
        // takes the leading fields of the struct, speeds stay as they are.
        // SAFETY: a valid descriptor and a termios read from it, one byte changed.
        if unsafe { libc::ioctl(fd, libc::TCSETS, termios as *const libc::termios) } < 0 {
            self.termios = None;
            return Err(io::Error::last_os_error());
        }
        Ok(())
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
        f if f & 0x80 != 0 => Some(SHORTEST_ANSWER),
        0x03 | 0x04 => Some(5 + usize::from(count)),
        0x06 | 0x10 => Some(8),
        _ => None,
    }
}

impl AsyncRead for RtuPort {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut ready = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            let unfilled_len = unfilled.len();
            let read = ready.try_io(|fd| {
                // SAFETY: reads at most `unfilled.len()` bytes into initialised memory.
                let n = unsafe {
                    libc::read(
                        fd.as_raw_fd(),
                        unfilled.as_mut_ptr().cast(),
                        unfilled.len(),
                    )
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
        let n = unsafe {
            libc::write(
                self.fd.get_ref().as_raw_fd(),
                data.as_ptr().cast(),
                data.len(),
            )
        };
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

    /// A 21-byte answer trickling in one byte at a time is read in two wake-ups: five bytes,
    /// then the sixteen announced by its header.
    #[tokio::test]
    async fn a_trickling_answer_is_read_in_two_wake_ups() {
        let (mut master, slave) = TTYPort::pair().unwrap();
        let path = slave.name().unwrap();
        let builder = serialport::new(path, 9600);
        let mut port = RtuPort::open(&builder).unwrap();
        drop(slave);
        let answer: Vec<u8> = [0x01, 0x03, 0x10]
            .into_iter()
            .chain(0..18u8)
            .collect::<Vec<u8>>();
        let feeder = std::thread::spawn(move || {
            for b in answer {
                std::thread::sleep(std::time::Duration::from_millis(1));
                master.write_all(&[b]).unwrap();
            }
            master
        });
        port.wake_at(SHORTEST_ANSWER).unwrap();
        let mut got = Vec::new();
        let mut reads = 0;
        while got.len() < 21 {
            let mut chunk = [0u8; 64];
            let n = port.read(&mut chunk).await.unwrap();
            reads += 1;
            got.extend_from_slice(&chunk[..n]);
            if let Some(total) = expected_len(&got) {
                port.wake_at(total.saturating_sub(got.len())).unwrap();
            }
        }
        let _master = feeder.join().unwrap();
        assert_eq!(got.len(), 21);
        // Without VMIN every byte (or two) wakes the reader: 10 or more reads.
        assert!(reads <= 3, "{reads} reads for one answer");
    }
}
