//! What the Modbus driver keeps of one device ([`ModbusDevice`]) and how it polls it: identity,
//! work modes and the channels they give, slow registers, then counts and frequencies read in
//! planned blocks (holes learnt from exception 02 are read around).

use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;
use tokio_modbus::ExceptionCode;

use super::identity::Identity;
use super::link::{Link, LinkError};
use super::retry::{Lost, NOISE_RETRIES, Next, Tries};
use super::run_state::RunState;
use super::sizing::{Change, Prices, Sizing};
use crate::bus::device::{DeviceRt, ProtocolError};
use crate::bus::driver::DeviceState;
use crate::bus_health::RequestSize;
use crate::config::{Bus, Device, Run};
use crate::decode::decode;
use crate::modbus::config::plan::{Block, PollPlan, Wire, plan_reads_within};
use crate::profile::{ChannelSpec, Register, WordOrder};
use crate::sample::{At, Sample, Wrap};
use crate::state::device_key;

/// What goes wrong in a Modbus poll, besides what the bus core understands.
#[derive(Debug, thiserror::Error)]
pub enum ModbusError {
    #[error("{0}")]
    Link(#[from] LinkError),
    #[error("refused a read of {len} registers at {start}: {exception:?}")]
    Refused {
        start: u16,
        len: u16,
        exception: ExceptionCode,
    },
    /// The module is not the configured model: out of service, no readings.
    #[error("wrong model: {0}")]
    WrongModel(String),
}

impl ProtocolError for ModbusError {
    fn device_answered(&self) -> bool {
        match self {
            ModbusError::Link(l) => l.device_answered(),
            ModbusError::Refused { .. } | ModbusError::WrongModel(_) => true,
        }
    }

    fn out_of_service(&self) -> Option<&str> {
        match self {
            ModbusError::WrongModel(why) => Some(why),
            _ => None,
        }
    }
}

/// A poll error of the Modbus driver.
pub type PollError = crate::bus::device::PollError<ModbusError>;

impl From<LinkError> for PollError {
    fn from(e: LinkError) -> PollError {
        PollError::Protocol(ModbusError::Link(e))
    }
}

/// Registers read in one poll, by block.
pub(super) struct Snapshot {
    blocks: Vec<(Block, Vec<u16>, At)>,
}

impl Snapshot {
    pub(super) fn get(&self, r: &Register) -> Option<(&[u16], At)> {
        self.blocks
            .iter()
            .find(|(b, ..)| b.covers(r))
            .map(|(b, words, at)| {
                let off = usize::from(r.address - b.start);
                (&words[off..off + usize::from(r.len())], *at)
            })
    }
}

/// What a Modbus driver keeps of one channel, in the order it declared them to the core (a
/// sample's `channel` is its index here).
pub(super) struct ModbusChannel {
    pub(super) name: Arc<str>,
    /// Its registers in the current work mode.
    pub(super) spec: ChannelSpec,
    /// The range its count wraps in now: a ZH-YX1600 counter's direction follows its command
    /// word.
    pub(super) wrap: Wrap,
    /// Pulses per revolution: configured, or read from the module.
    pub(super) ppr: Option<f64>,
    /// The command register, where the module starts and stops counters by register.
    pub(super) command: Option<Register>,
    /// The counting window of a frequency register that holds pulses per window, in seconds;
    /// `None` while unknown (then no frequency is published).
    pub(super) window_s: Option<f64>,
    pub(super) window_bad: bool,
    /// The power-on state was checked (and set where configured) in this run.
    pub(super) power_on_done: bool,
    /// What to do when the counter is found stopped (modules with a command register).
    pub(super) run: Run,
    /// Resume the counter when it is found paused.
    pub(super) resume_paused: bool,
}

/// What a Modbus driver keeps of one device: its unit, the register plan and what shapes it
/// (holes, wire prices, measured turnaround), the work modes, and the identity check.
pub struct ModbusDevice {
    pub unit: u8,
    /// Where the holes are saved in the state file.
    pub(super) holes_key: String,
    /// Answer timeout before line time is added.
    pub(super) answer_timeout: Duration,
    pub(super) wire: Wire,
    pub(super) modes: Option<Vec<u16>>,
    pub(super) fast: Vec<Register>,
    /// Per channel, in the order of the device's channels.
    pub(super) channels: Vec<ModbusChannel>,
    /// Register ranges the device refused (exception 02): never bridged again.
    pub holes: Vec<Range<u16>>,
    pub(super) last_slow: Option<Instant>,
    pub(super) slow_every: Duration,
    /// The plan of the last read asked for (the count poll asks for the same every time).
    pub(super) plan_memo: Option<PollPlan>,
    /// The longest read allowed now: shorter after answers lost to noise.
    pub(super) sizing: Sizing,
    /// How the count poll is cut into requests now, for the bus stats.
    pub(super) poll_shape: Option<RequestSize>,
    /// Measured turnaround (seconds, moving average), RTU only.
    pub(super) turnaround: Option<f64>,
    /// The module's identity is to be checked before the next poll (at discovery, after a
    /// reset).
    pub(super) identify_due: bool,
    /// Identification of every known model, to name what a wrong module is.
    pub(super) known: Arc<[Identity]>,
    pub(super) unidentified_warned: bool,
    /// Quadrature pairs whose two mode words disagree, described; and its last change, not
    /// yet published.
    pub(super) mode_mismatch: Option<String>,
    pub(super) mismatch_changed: Option<Option<String>>,
}

impl ModbusDevice {
    pub fn new(bus: &Bus, config: &Device, wire: Wire, holes: Vec<Range<u16>>) -> ModbusDevice {
        ModbusDevice {
            unit: config.unit,
            holes_key: device_key(config.unit, &config.model),
            answer_timeout: config.answer_timeout(bus),
            wire,
            modes: None,
            fast: Vec::new(),
            channels: Vec::new(),
            holes,
            last_slow: None,
            slow_every: bus.slow_poll,
            plan_memo: None,
            sizing: Sizing::default(),
            poll_shape: None,
            turnaround: None,
            identify_due: true,
            known: Arc::from(Vec::new()),
            unidentified_warned: false,
            mode_mismatch: None,
            mismatch_changed: None,
        }
    }

    /// Knows every model in `known`, to name what a wrong module is.
    pub fn with_known(mut self, known: Arc<[Identity]>) -> ModbusDevice {
        self.known = known;
        self
    }

    /// The key under which this device's holes are saved.
    pub fn holes_key(&self) -> String {
        self.holes_key.clone()
    }

    /// Whether the channels are known (the work modes were read).
    pub fn discovered(&self) -> bool {
        self.modes.is_some()
    }

    /// The module restarted (or was reset by someone else): it may be another module now, and
    /// mode words written before take effect at a restart. Both are read again next poll.
    pub(super) fn module_restarted(&mut self) {
        self.identify_due = true;
        self.last_slow = None;
    }

    /// What `snapshot` says of each channel whose registers all arrived: the samples, the
    /// samples of counters found stopped (to start, see `run_control.rs`), and the channels
    /// found paused (to resume where configured).
    fn samples(
        &mut self,
        snapshot: &Snapshot,
        order: WordOrder,
    ) -> (Vec<Sample>, Vec<Sample>, Vec<usize>) {
        let mut samples = Vec::with_capacity(self.channels.len());
        let (mut stopped, mut paused) = (Vec::new(), Vec::new());
        for (i, mb) in self.channels.iter_mut().enumerate() {
            // A channel is sampled whole or not at all: every register it polls arrived.
            if !mb.spec.polled().all(|r| snapshot.get(&r).is_some()) {
                continue;
            }
            let Some((words, at)) = snapshot.get(&mb.spec.count) else {
                continue;
            };
            let count = decode(words, mb.spec.count.ty, order).as_i64();
            let freq_hz = mb
                .spec
                .freq
                .and_then(|r| Some(decode(snapshot.get(&r)?.0, r.ty, order).as_f64()))
                .filter(|f| f.is_finite())
                .and_then(|f| match mb.spec.freq_window {
                    // Pulses in the module's counting window → Hz.
                    Some(_) => mb.window_s.map(|s| f / s),
                    None => Some(f),
                });
            let rpm = match (freq_hz, mb.ppr) {
                (Some(f), Some(ppr)) if ppr > 0.0 => Some(f * 60.0 / ppr),
                _ => None,
            };
            let state = mb
                .command
                .and_then(|r| snapshot.get(&r))
                .map(|(w, _)| super::run_state::run_state(&mb.spec, w[0]));
            if let Some(RunState::Running(d)) = state {
                mb.wrap.direction = d;
            }
            let sample = Sample::count(i, at, count, mb.wrap).with_rates(freq_hz, rpm);
            match state {
                // The module cleared it; the gateway starts it after this read.
                Some(RunState::Stopped) if mb.run != Run::Leave => stopped.push(sample),
                Some(RunState::Paused) if mb.resume_paused => {
                    paused.push(i);
                    samples.push(sample);
                }
                _ => samples.push(sample),
            }
        }
        (samples, stopped, paused)
    }

    /// Records the mode-word mismatch of device `name` found now (logged once per change).
    pub(super) fn set_mismatch(&mut self, name: &str, now: Option<String>) {
        if self.mode_mismatch == now {
            return;
        }
        match &now {
            Some(why) => {
                tracing::error!(device = %name, "{why}: the module does not count that quadrature pair; its channel is not published until both words agree (after a module restart)")
            }
            None => tracing::info!(device = %name, "mode words agree again"),
        }
        self.mode_mismatch = now.clone();
        self.mismatch_changed = Some(now);
    }
}

impl DeviceState for ModbusDevice {
    type Error = ModbusError;

    fn poll_failed(&mut self, e: &PollError) {
        // A module that starts refusing registers it answered before may be another module, or
        // have restarted in another work mode: identity and modes are read again (once per new
        // refusal, so a device that keeps refusing costs no extra reads).
        if matches!(e, PollError::Protocol(ModbusError::Refused { .. })) && self.discovered() {
            self.module_restarted();
        }
    }

    fn status_change(&mut self) -> Option<Option<&'static str>> {
        let now = self.mismatch_changed.take()?;
        Some(now.map(|_| "mode_mismatch"))
    }

    fn went_offline(&mut self) {
        // Whatever answers at this address next may be another module.
        self.identify_due = true;
    }

    fn reset_found(&mut self) {
        self.module_restarted();
    }

    fn turnaround(&self) -> Option<f64> {
        self.turnaround
    }

    fn request_size(&self) -> Option<RequestSize> {
        self.poll_shape
    }

    fn save(&self, state: &mut crate::state::BusState) {
        if !self.holes.is_empty() {
            state.holes.insert(
                self.holes_key(),
                self.holes.iter().map(|h| (h.start, h.end)).collect(),
            );
        }
    }

    fn saved_key(&self) -> Option<String> {
        Some(self.holes_key())
    }
}

impl DeviceRt<ModbusDevice> {
    /// Whether a read that failed with `e` after `tries` retries is asked again at once: lost
    /// to noise, fewer than [`NOISE_RETRIES`], and the device's availability finds it worth it.
    pub(super) fn asks_again(&self, e: &LinkError, tries: u32) -> bool {
        e.is_noise()
            && tries < NOISE_RETRIES
            && self.availability.worth_retrying(e.device_answered())
    }

    /// One poll: discovery and slow registers when due, then counts and frequencies, one
    /// sample per channel whose registers all arrived. `preempt` is asked between transactions:
    /// when it says yes, the poll gives way.
    pub async fn poll(
        &mut self,
        link: &mut Link,
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<Vec<Sample>, PollError> {
        self.discover(link, preempt).await?;
        let fast = std::mem::take(&mut self.proto.fast);
        let snapshot = self.read_blocks(link, &fast, Lost::LeftOut, preempt).await;
        self.note_poll_shape(&fast);
        self.proto.fast = fast;
        let snapshot = snapshot?;
        let (mut samples, stopped, paused) = self.proto.samples(&snapshot, self.profile.word_order);
        for s in stopped {
            if let Some(started) = self.start_stopped(link, s).await {
                samples.push(started);
            }
        }
        for i in paused {
            self.resume_paused(link, i).await;
        }
        Ok(samples)
    }

    /// Reads `regs` in planned blocks, all of them or none. A bridged block refused with
    /// exception 02 teaches a hole and is split at once.
    pub(super) async fn read_registers(
        &mut self,
        link: &mut Link,
        regs: &[Register],
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<Snapshot, PollError> {
        self.read_blocks(link, regs, Lost::FailsAll, preempt).await
    }

    /// Reads `regs` in planned blocks; a block lost to the line is asked again, shortened when
    /// the device's [`Sizing`] shortens reads, and then failed or left out as `lost` says.
    async fn read_blocks(
        &mut self,
        link: &mut Link,
        regs: &[Register],
        lost: Lost,
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<Snapshot, PollError> {
        let mut blocks = self.plan(regs);
        let mut out = Vec::with_capacity(blocks.len());
        let mut left_out: Vec<Block> = Vec::new();
        let mut last_loss = None;
        let mut tries = Tries::new(lost);
        let mut i = 0;
        while i < blocks.len() {
            if preempt() {
                return Err(PollError::Preempted);
            }
            let b = blocks[i];
            let timeout = self.timeout_for(link, b.len);
            let started = Instant::now();
            let answer = match link.read(self.proto.unit, b.start, b.len, timeout).await {
                // Asked again (see `retry`), in shorter reads when the line shortened them.
                Err(e) if e.is_noise() => {
                    let shortened = self.resize(link, |s, p| s.lost(b.len, p))
                        && b.len > self.proto.sizing.limit();
                    let heard = e.device_answered();
                    match tries.lost(heard, self.availability.worth_retrying(heard)) {
                        Next::Again if shortened => {
                            blocks.truncate(i);
                            blocks.extend(self.plan_rest(regs, &out, &left_out));
                        }
                        Next::Again => {}
                        Next::LeaveOut => {
                            left_out.push(b);
                            last_loss = Some(e);
                            i += 1;
                        }
                        Next::Stop if lost == Lost::FailsAll || out.is_empty() => {
                            return Err(e.into());
                        }
                        Next::Stop => break,
                    }
                    continue;
                }
                other => other?,
            };
            tries.answered();
            match answer {
                Ok(words) => {
                    self.took(link, b.len, started);
                    out.push((b, words, At::now()));
                    i += 1;
                }
                Err(exception) => {
                    self.refused(b, regs, exception)?;
                    blocks.truncate(i);
                    blocks.extend(self.plan_rest(regs, &out, &left_out));
                }
            }
        }
        match last_loss {
            // Nothing arrived: the poll failed as a whole.
            Some(e) if out.is_empty() => Err(e.into()),
            _ => Ok(Snapshot { blocks: out }),
        }
    }

    /// A block answered: the read may grow again, and its latency is recorded.
    fn took(&mut self, link: &Link, len: u16, started: Instant) {
        self.resize(link, |s, p| s.answered(len, p));
        let latency = link.answer_time().unwrap_or_else(|| started.elapsed());
        self.record_latency(latency, link, len);
    }

    /// A block refused with `exception`: a bridged read refused with exception 02 leaves its
    /// gaps out from now on (`Ok`: plan the rest again); any other refusal fails the poll.
    fn refused(
        &mut self,
        b: Block,
        regs: &[Register],
        exception: ExceptionCode,
    ) -> Result<(), PollError> {
        let gaps = b.gaps(regs);
        if exception == ExceptionCode::IllegalDataAddress && !gaps.is_empty() {
            tracing::info!(device = %self.name, ?gaps, "device refused bridged registers; reading around them from now on");
            self.proto.holes.extend(gaps);
            return Ok(());
        }
        Err(PollError::Protocol(ModbusError::Refused {
            start: b.start,
            len: b.len,
            exception,
        }))
    }

    /// The reads of the registers in `regs` neither read (`done`) nor given up (`left_out`)
    /// yet in this poll, at the current holes and length limit.
    fn plan_rest(
        &self,
        regs: &[Register],
        done: &[(Block, Vec<u16>, At)],
        left_out: &[Block],
    ) -> Vec<Block> {
        let rest: Vec<Register> = regs
            .iter()
            .filter(|r| !done.iter().any(|(b, ..)| b.covers(r)))
            .filter(|r| !left_out.iter().any(|b| b.covers(r)))
            .copied()
            .collect();
        plan_reads_within(
            &rest,
            &self.proto.holes,
            &self.proto.wire,
            self.proto.sizing.limit(),
        )
    }

    /// Tells the device's [`Sizing`] what a read did, on an RTU line (TCP carries no broken
    /// characters); `true` when it shortened reads. A change from or back to full length is
    /// logged; the steps between are debug (a noisy line moves them often).
    fn resize(
        &mut self,
        link: &Link,
        event: impl FnOnce(&mut Sizing, &Prices) -> Option<Change>,
    ) -> bool {
        let Some(timing) = link.timing_for(self.proto.unit) else {
            return false;
        };
        let prices = Prices {
            overhead: self.proto.wire.request_overhead,
            loss: self.proto.answer_timeout.as_secs_f64() / timing.char_time().as_secs_f64(),
        };
        let was_full = self.proto.sizing.is_full();
        let change = event(&mut self.proto.sizing, &prices);
        let limit = self.proto.sizing.limit();
        match change {
            Some(Change::Shortened(_)) if was_full => {
                tracing::info!(device = %self.name, limit, "answers lost on the line: reads shortened to at most {limit} registers");
            }
            Some(Change::Grown(_)) if self.proto.sizing.is_full() => {
                tracing::info!(device = %self.name, "the line is clean again: reads back to full length");
            }
            Some(change) => tracing::debug!(device = %self.name, ?change, "read length"),
            None => {}
        }
        matches!(change, Some(Change::Shortened(_)))
    }

    /// The reads for `regs`: planned once and reused while the registers, the holes, the
    /// wire's prices and the length limit stay the same (the count poll asks for the same
    /// registers every time).
    fn plan(&mut self, regs: &[Register]) -> Vec<Block> {
        let limit = self.proto.sizing.limit();
        if let Some(p) = &self.proto.plan_memo
            && p.fits_within(regs, self.proto.holes.len(), &self.proto.wire, limit)
        {
            return p.blocks.clone();
        }
        let p = PollPlan::within(regs, &self.proto.holes, &self.proto.wire, limit);
        tracing::debug!(device = %self.name, plan = %p.describe(), "poll plan");
        let blocks = p.blocks.clone();
        self.proto.plan_memo = Some(p);
        blocks
    }

    /// Records how the count poll (`fast`) is cut into requests now, for the stats and the
    /// metrics: the plan the next poll uses.
    fn note_poll_shape(&mut self, fast: &[Register]) {
        let blocks = self.plan(fast);
        let shape = RequestSize {
            limit: self.proto.sizing.limit(),
            requests: blocks.len(),
            longest: blocks.iter().map(|b| b.len).max().unwrap_or(0),
        };
        self.metrics.request_size(shape.limit, shape.requests);
        self.proto.poll_shape = Some(shape);
    }

    /// The answer timeout plus the time the request and answer take on the line.
    pub(super) fn timeout_for(&self, link: &Link, len: u16) -> Duration {
        let timing = link.timing_for(self.proto.unit);
        crate::modbus::config::plan::read_timeout(self.proto.answer_timeout, timing.as_ref(), len)
    }

    /// Records a transaction's latency, and on RTU the device's turnaround: the latency less
    /// the time the request and answer of `len` registers take on the line.
    fn record_latency(&mut self, d: Duration, link: &Link, len: u16) {
        self.answered_in(d);
        if let Some(t) = link.timing_for(self.proto.unit) {
            let line = t.read_time(len);
            let turnaround = d.saturating_sub(line).as_secs_f64();
            self.proto.turnaround = Some(match self.proto.turnaround {
                Some(old) => old * 0.9 + turnaround * 0.1,
                None => turnaround,
            });
        }
    }

    /// Re-prices the planner with the measured turnaround, so bridging follows what a separate
    /// request really costs this device.
    pub(super) fn replan_with_turnaround(&mut self, link: &Link) {
        if let (Some(t), Some(ta)) = (link.timing_for(self.proto.unit), self.proto.turnaround) {
            self.proto.wire = Wire::rtu(&t, Duration::from_secs_f64(ta));
        }
    }
}
