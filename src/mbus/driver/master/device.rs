//! What the M-Bus master keeps of one meter ([`MeterDevice`]) and how it reads it: `SND_NKE`
//! when the link is new (at start, after the meter was away), then per poll a `REQ_UD2` (after
//! a select for a meter found by its secondary address) with the FCB as the standard wants,
//! and the next telegrams while the meter says more records follow (DIF 1F). What it read
//! goes to the core as samples; it counts nothing.

use std::time::Duration;

use super::link::{Heard, Link, LinkError};
use super::records::{self, Picked};
use crate::bus::device::{DeviceRt, PollError, ProtocolError};
use crate::bus::driver::DeviceState;
use crate::config::Device;
use crate::mbus::config::MeterAddress;
use crate::mbus::driver::address::{SecondaryAddress, SecondaryMask, manufacturer_from_letters};
use crate::mbus::driver::frame::{self, Fcb, Frame, SELECTED};
use crate::mbus::driver::header::Header;
use crate::mbus::driver::{DecodeError, Record, Telegram, decode_frame};
use crate::sample::{At, Sample};

/// The most telegrams one readout may take (DIF 1F after each but the last).
pub const MAX_TELEGRAMS: usize = 16;

/// How many times a request that got no (or a garbled) answer is sent: the first and one
/// repeat, with the same FCB (a meter repeats its last answer).
const TRIES: usize = 2;

/// Why a meter's poll failed. Every cause counts towards offline: a meter that answers only
/// garbage, errors or collisions gives no readings, so it is as good as away.
#[derive(Debug, thiserror::Error)]
pub enum MeterError {
    #[error("{0}")]
    Link(#[from] LinkError),
    #[error("{what}: no answer within {waited:?}")]
    Silent { what: String, waited: Duration },
    #[error("{what}: garbled answer ({bytes} bytes: {why})")]
    Garbled {
        what: String,
        bytes: usize,
        why: String,
    },
    #[error("{what}: several meters answer the select at once (a collision): {why}")]
    Collision { what: String, why: String },
    #[error("{what}: {source}")]
    Decode {
        what: String,
        #[source]
        source: DecodeError,
    },
    #[error("{what}: {why}")]
    Unexpected { what: String, why: String },
}

impl ProtocolError for MeterError {
    fn device_answered(&self) -> bool {
        false
    }
}

impl MeterError {
    /// A fault of the line (port, connection), not of one meter.
    pub fn is_line_fault(&self) -> bool {
        matches!(self, MeterError::Link(_))
    }
}

/// A poll failure of the M-Bus driver.
pub type MeterPollError = PollError<MeterError>;

/// Where a meter answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Address {
    Primary(u8),
    /// Selected by this mask, then read at address 253.
    Secondary(SecondaryMask),
}

impl Address {
    /// The address of a configured meter.
    pub fn of(meter: &MeterAddress) -> Address {
        match meter {
            MeterAddress::Primary(a) => Address::Primary(*a),
            MeterAddress::Secondary {
                id,
                manufacturer,
                version,
                medium,
            } => {
                let mut mask = SecondaryMask::from_id(id).unwrap_or(SecondaryMask::ANY);
                mask.manufacturer = manufacturer.as_deref().and_then(manufacturer_from_letters);
                mask.version = *version;
                mask.medium = *medium;
                Address::Secondary(mask)
            }
        }
    }

    /// The primary address requests go to.
    fn wire(&self) -> u8 {
        match self {
            Address::Primary(a) => *a,
            Address::Secondary(_) => SELECTED,
        }
    }

    /// The meter in words (`primary address 5`, `meter 12345678`).
    pub fn describe(&self) -> String {
        match self {
            Address::Primary(a) => format!("primary address {a}"),
            Address::Secondary(m) => format!("meter {}", m.id_text()),
        }
    }
}

/// What the master keeps of one meter.
pub struct MeterDevice {
    pub address: Address,
    what: String,
    fcb: Fcb,
    /// `SND_NKE` was answered since the start (or since the meter was away).
    linked: bool,
    /// The meter that answered last (a primary address may get another meter).
    last_id: Option<SecondaryAddress>,
    /// The channels declared to the core, from which records.
    picked: Vec<Picked>,
    /// The meter's own answer time (its `timeout`), where the config gives one.
    timeout: Option<Duration>,
}

impl MeterDevice {
    /// The meter of a device's config.
    pub fn new(config: &Device) -> MeterDevice {
        let address = config
            .address
            .of::<crate::mbus::config::MeterAddress>()
            .map_or(Address::Primary(config.unit), Address::of);
        MeterDevice {
            timeout: config.timeout,
            ..MeterDevice::at(address)
        }
    }

    /// The meter at `address`, its link not reset yet.
    pub fn at(address: Address) -> MeterDevice {
        MeterDevice {
            what: address.describe(),
            address,
            fcb: Fcb::after_reset(),
            linked: false,
            last_id: None,
            picked: Vec::new(),
            timeout: None,
        }
    }
}

impl DeviceState for MeterDevice {
    type Error = MeterError;

    fn went_offline(&mut self) {
        self.linked = false;
    }

    fn reset_found(&mut self) {
        self.linked = false;
    }
}

impl DeviceRt<MeterDevice> {
    /// One poll: the meter's records as samples (declared to the core as channels first when
    /// they are new or changed).
    pub(super) async fn poll_meter(
        &mut self,
        link: &mut Link,
    ) -> Result<Vec<Sample>, MeterPollError> {
        let started = tokio::time::Instant::now();
        let readout = self.proto.read_out(link).await;
        let (header, records) = match readout {
            Ok(r) => r,
            Err(e) => {
                // Start the next readout afresh: the meter may be mid-way through its telegrams.
                self.proto.linked = false;
                if matches!(e, MeterError::Decode { .. }) {
                    link.counters.exceptions += 1;
                }
                return Err(PollError::Protocol(e));
            }
        };
        // A readout's latency: from its first request to its last telegram.
        self.answered_in(started.elapsed());
        let at = At::now();
        let replaced = self.proto.check_identity(&header, &self.name);
        let medium = match header {
            Header::Long { address, .. } => Some(address.medium),
            Header::Fixed { medium, .. } => Some(medium),
            _ => None,
        };
        let picked = records::channels(&records, &self.config.channels, medium);
        if picked != self.proto.picked {
            self.declare(picked.iter().map(|p| p.channel.clone()).collect());
            self.proto.picked = picked;
        }
        Ok(records::samples(&records, &self.proto.picked, at, replaced))
    }
}

impl MeterDevice {
    /// `SND_NKE` when the link is new (after selecting a meter found by its secondary
    /// address, which the `SND_NKE` to 253 deselects again), then every telegram of one
    /// readout: the header of the answer and its records, numbered across the telegrams.
    pub async fn read_out(&mut self, link: &mut Link) -> Result<(Header, Vec<Record>), MeterError> {
        if !self.linked {
            self.select(link).await?;
            self.reset_link(link).await?;
            self.linked = true;
        }
        self.select(link).await?;
        let mut header = Header::None;
        let mut records = Vec::new();
        for _ in 0..MAX_TELEGRAMS {
            let t = self.telegram(link).await?;
            if let Header::Long { .. } | Header::Fixed { .. } = t.header {
                header = t.header;
            }
            let base = records.len();
            records.extend(t.records.into_iter().map(|mut r| {
                r.index += base;
                r
            }));
            if !t.more_records_follow {
                return Ok((header, records));
            }
        }
        Err(self.unexpected(format!(
            "more than {MAX_TELEGRAMS} telegrams in one readout"
        )))
    }

    /// `SND_NKE`: the meter's link starts again (its FCB cleared).
    async fn reset_link(&mut self, link: &mut Link) -> Result<(), MeterError> {
        self.expect_ack(link, &frame::snd_nke(self.address.wire()), false)
            .await?;
        self.fcb = Fcb::after_reset();
        Ok(())
    }

    /// Selects a meter found by its secondary address (nothing for a primary one).
    async fn select(&mut self, link: &mut Link) -> Result<(), MeterError> {
        if let Address::Secondary(mask) = self.address {
            self.expect_ack(link, &frame::select(&mask), true).await?;
        }
        Ok(())
    }

    /// Sends `request` (tried again once) and wants `E5` back.
    async fn expect_ack(
        &mut self,
        link: &mut Link,
        request: &[u8],
        select: bool,
    ) -> Result<(), MeterError> {
        match self.ask(link, request, select).await? {
            Frame::Ack => Ok(()),
            other => {
                Err(self.unexpected(format!("{other:?} where an acknowledgement (E5) was due")))
            }
        }
    }

    /// One `REQ_UD2` and its telegram, decoded; the FCB toggles once it arrived whole.
    async fn telegram(&mut self, link: &mut Link) -> Result<Telegram, MeterError> {
        let request = self.fcb.request(self.address.wire());
        let frame = self.ask(link, &request, false).await?;
        self.fcb.answered();
        let telegram = decode_frame(&frame).map_err(|source| MeterError::Decode {
            what: self.what.clone(),
            source,
        })?;
        if let (Address::Secondary(mask), Some(id)) = (self.address, telegram.header.address())
            && !mask.matches(id)
        {
            return Err(self.unexpected(format!("meter {} answered at 253", id.id_text())));
        }
        Ok(telegram)
    }

    /// Sends `request` until a frame comes back ([`TRIES`] times at most).
    async fn ask(
        &mut self,
        link: &mut Link,
        request: &[u8],
        select: bool,
    ) -> Result<Frame, MeterError> {
        let mut last = Heard::Nothing;
        for _ in 0..TRIES {
            match link.exchange_within(request, self.timeout).await? {
                Heard::Frame(f) => return Ok(f),
                heard => last = heard,
            }
        }
        let what = self.what.clone();
        Err(match last {
            Heard::Garbled { why, .. } if select => MeterError::Collision { what, why },
            Heard::Garbled { bytes, why } => MeterError::Garbled {
                what,
                bytes: bytes.len(),
                why,
            },
            _ => MeterError::Silent {
                what,
                waited: self.timeout.unwrap_or(link.answer_time()),
            },
        })
    }

    fn unexpected(&self, why: String) -> MeterError {
        MeterError::Unexpected {
            what: self.what.clone(),
            why,
        }
    }

    /// Whether the answer is from another meter than the last (a meter replaced at its primary
    /// address): its registers start over.
    fn check_identity(&mut self, header: &Header, device: &str) -> bool {
        let Some(id) = header.address().copied() else {
            return false;
        };
        let before = self.last_id.replace(id);
        let replaced = before.is_some_and(|b| b.id != id.id || b.manufacturer != id.manufacturer);
        if replaced {
            let was = before.map(|b| b.to_string()).unwrap_or_default();
            tracing::warn!(device, was = %was, now = %id, "another meter answers: counted as replaced");
        }
        replaced
    }
}
