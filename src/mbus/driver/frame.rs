//! The link layer of wired M-Bus (EN 13757-2): the three frame formats a master reads
//! (single character, short frame, long/control frame), read from a byte buffer that may hold
//! a frame only in part, and the master's own frames built. Pure.

/// The single character a slave acknowledges with.
pub const ACK: u8 = 0xE5;
const SHORT_START: u8 = 0x10;
const LONG_START: u8 = 0x68;
const STOP: u8 = 0x16;
/// The longest frame: `68 L L 68`, L = 255 bytes from C on, checksum, stop.
pub const MAX_FRAME: usize = 255 + 6;

/// C field, master to slave: link reset.
pub const SND_NKE: u8 = 0x40;
/// C field, master to slave: send user data (FCV set, FCB clear).
pub const SND_UD: u8 = 0x53;
/// C field, master to slave: request class 2 data (FCV set, FCB clear).
pub const REQ_UD2: u8 = 0x5B;
/// The frame count bit of a master's C field.
pub const FCB: u8 = 0x20;
/// The bit saying the FCB is valid.
pub const FCV: u8 = 0x10;
/// C field, slave to master: user data (ACD and DFC bits masked off).
pub const RSP_UD: u8 = 0x08;

/// The address of the slave selected by secondary address.
pub const SELECTED: u8 = 0xFD;
/// Broadcast that every slave answers (test only: they collide).
pub const BROADCAST_ANSWERED: u8 = 0xFE;
/// Broadcast that no slave answers.
pub const BROADCAST: u8 = 0xFF;

/// CI field of a master's frame: application reset.
pub const CI_APPLICATION_RESET: u8 = 0x50;
/// CI field of a master's frame: select by secondary address.
pub const CI_SELECT: u8 = 0x52;

/// One frame of the link layer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Frame {
    /// `E5`.
    Ack,
    /// `10 C A CS 16`.
    Short { control: u8, address: u8 },
    /// `68 03 03 68 C A CI CS 16`: a long frame without data.
    Control { control: u8, address: u8, ci: u8 },
    /// `68 L L 68 C A CI data… CS 16`.
    Long {
        control: u8,
        address: u8,
        ci: u8,
        data: Vec<u8>,
    },
}

/// What reading a buffer found: a whole frame, or how many more bytes it needs at least.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Scan {
    /// A frame and the number of bytes of the buffer it took.
    Frame { frame: Frame, consumed: usize },
    /// The frame is not complete yet: read at least this many more bytes.
    Need(usize),
}

/// Why bytes are not a frame. A serial reader drops the buffer on any of these (the line is
/// garbled) and waits for the next answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("garbage on the line: byte {0:#04x} starts no M-Bus frame")]
    Garbage(u8),
    #[error("long frame with two different lengths ({0} and {1}): a garbled or overlapping answer")]
    LengthMismatch(u8, u8),
    #[error("long frame of length {0}: at least 3 (C, A, CI) are needed")]
    TooShort(u8),
    #[error("long frame without its second start byte 0x68 (found {0:#04x})")]
    BadSecondStart(u8),
    #[error("bad checksum: the frame says {found:#04x}, its bytes sum to {expected:#04x}")]
    BadChecksum { expected: u8, found: u8 },
    #[error("bad stop byte {0:#04x} (0x16 expected)")]
    BadStop(u8),
    #[error("{0} bytes after the frame: a garbled or overlapping answer")]
    Trailing(usize),
}

/// The checksum of the link layer: the sum of the bytes, modulo 256.
pub fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |s, b| s.wrapping_add(*b))
}

/// Reads the frame at the start of `buf`. Bounded: never looks past [`MAX_FRAME`] bytes.
pub fn scan(buf: &[u8]) -> Result<Scan, FrameError> {
    let Some(&first) = buf.first() else {
        return Ok(Scan::Need(1));
    };
    match first {
        ACK => Ok(Scan::Frame {
            frame: Frame::Ack,
            consumed: 1,
        }),
        SHORT_START => scan_short(buf),
        LONG_START => scan_long(buf),
        other => Err(FrameError::Garbage(other)),
    }
}

fn scan_short(buf: &[u8]) -> Result<Scan, FrameError> {
    if buf.len() < 5 {
        return Ok(Scan::Need(5 - buf.len()));
    }
    let (control, address) = (buf[1], buf[2]);
    check_sum_and_stop(&buf[1..3], buf[3], buf[4])?;
    Ok(Scan::Frame {
        frame: Frame::Short { control, address },
        consumed: 5,
    })
}

fn scan_long(buf: &[u8]) -> Result<Scan, FrameError> {
    if buf.len() < 4 {
        if let (Some(&a), Some(&b)) = (buf.get(1), buf.get(2)) {
            if a != b {
                return Err(FrameError::LengthMismatch(a, b));
            }
        }
        return Ok(Scan::Need(4 - buf.len()));
    }
    let (l1, l2) = (buf[1], buf[2]);
    if l1 != l2 {
        return Err(FrameError::LengthMismatch(l1, l2));
    }
    if buf[3] != LONG_START {
        return Err(FrameError::BadSecondStart(buf[3]));
    }
    if l1 < 3 {
        return Err(FrameError::TooShort(l1));
    }
    let total = usize::from(l1) + 6;
    if buf.len() < total {
        return Ok(Scan::Need(total - buf.len()));
    }
    let body = &buf[4..4 + usize::from(l1)];
    check_sum_and_stop(body, buf[total - 2], buf[total - 1])?;
    let (control, address, ci) = (body[0], body[1], body[2]);
    let frame = if l1 == 3 {
        Frame::Control {
            control,
            address,
            ci,
        }
    } else {
        Frame::Long {
            control,
            address,
            ci,
            data: body[3..].to_vec(),
        }
    };
    Ok(Scan::Frame {
        frame,
        consumed: total,
    })
}

fn check_sum_and_stop(body: &[u8], sum: u8, stop: u8) -> Result<(), FrameError> {
    let expected = checksum(body);
    if expected != sum {
        return Err(FrameError::BadChecksum {
            expected,
            found: sum,
        });
    }
    if stop != STOP {
        return Err(FrameError::BadStop(stop));
    }
    Ok(())
}

/// Reads exactly one frame from `buf` (an answer read to its end): no bytes may follow it.
/// A frame cut short is a [`FrameError`] here too, naming what is missing.
pub fn parse(buf: &[u8]) -> Result<Frame, ParseError> {
    match scan(buf)? {
        Scan::Need(n) => Err(ParseError::Incomplete(n)),
        Scan::Frame { frame, consumed } if consumed == buf.len() => Ok(frame),
        Scan::Frame { consumed, .. } => Err(FrameError::Trailing(buf.len() - consumed).into()),
    }
}

/// Why a complete answer is not one frame.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error("the frame ends {0} byte(s) early")]
    Incomplete(usize),
}

impl Frame {
    /// The frame's bytes on the wire.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            Frame::Ack => vec![ACK],
            Frame::Short { control, address } => {
                vec![
                    SHORT_START,
                    *control,
                    *address,
                    checksum(&[*control, *address]),
                    STOP,
                ]
            }
            Frame::Control {
                control,
                address,
                ci,
            } => long(*control, *address, *ci, &[]),
            Frame::Long {
                control,
                address,
                ci,
                data,
            } => long(*control, *address, *ci, data),
        }
    }
}

/// A long frame; `data` longer than 252 bytes is cut (a master never sends one).
fn long(control: u8, address: u8, ci: u8, data: &[u8]) -> Vec<u8> {
    let data = &data[..data.len().min(252)];
    let len = (data.len() + 3) as u8;
    let mut out = Vec::with_capacity(data.len() + 9);
    out.extend_from_slice(&[LONG_START, len, len, LONG_START, control, address, ci]);
    out.extend_from_slice(data);
    out.push(checksum(&out[4..]));
    out.push(STOP);
    out
}

/// `SND_NKE` to `address`: resets the slave's link (it clears its FCB); `SND_NKE` to 253
/// deselects the selected slave.
pub fn snd_nke(address: u8) -> Vec<u8> {
    Frame::Short {
        control: SND_NKE,
        address,
    }
    .encode()
}

/// `REQ_UD2` to `address`, with the FCB valid and set as `fcb` says (0x7B set, 0x5B clear).
pub fn req_ud2(address: u8, fcb: bool) -> Vec<u8> {
    let control = if fcb { REQ_UD2 | FCB } else { REQ_UD2 };
    Frame::Short { control, address }.encode()
}

/// `SND_UD` to address 253 with CI 0x52: selects the slave whose secondary address matches
/// `mask` (wildcards allowed). C field 0x73 (FCB set), as libmbus and pymeterbus send it.
pub fn select(mask: &super::address::SecondaryMask) -> Vec<u8> {
    long(SND_UD | FCB, SELECTED, CI_SELECT, &mask.to_bytes())
}

/// `SND_UD` with CI 0x50 to `address`: application reset (all data, from the first telegram).
pub fn application_reset(address: u8) -> Vec<u8> {
    long(SND_UD, address, CI_APPLICATION_RESET, &[])
}

/// The master's frame count bit, by the standard's rule: after `SND_NKE` the slave has cleared
/// its FCB, so the first `REQ_UD2` carries FCB = 1; the bit toggles after every answer
/// received whole; a request that got no (or a garbled) answer is sent again with the same
/// bit, and the slave repeats its last answer. The next telegram of a multi-telegram answer is
/// asked with the toggled bit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fcb {
    next: bool,
}

impl Default for Fcb {
    fn default() -> Self {
        Fcb::after_reset()
    }
}

impl Fcb {
    /// The state right after `SND_NKE`.
    pub fn after_reset() -> Fcb {
        Fcb { next: true }
    }

    /// The bit of the next `REQ_UD2`.
    pub fn bit(&self) -> bool {
        self.next
    }

    /// The next `REQ_UD2` to `address`.
    pub fn request(&self, address: u8) -> Vec<u8> {
        req_ud2(address, self.next)
    }

    /// An answer arrived whole: the next request toggles.
    pub fn answered(&mut self) {
        self.next = !self.next;
    }
}

#[cfg(test)]
#[path = "frame_tests.rs"]
mod tests;
