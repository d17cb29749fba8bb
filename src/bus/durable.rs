//! The way out of a bus for readings, kept durable: readings are held until a state save that
//! covers their seqs is on disk ([`super::saver`] writes it), the first reading of each channel
//! after a start carries what the last run booked but never handed over, and interval records
//! a crash left unsent go out again.

use std::collections::BTreeMap;

use super::device::DeviceRt;
use super::driver::DeviceState;
use super::ledger::{Ledger, Resume, seqs};
use super::saver::Saver;
use crate::counter::{CounterState, Handed};
use crate::state::BusState;

/// The way out of a bus for readings: a reading whose seq is not yet covered by a durable save
/// is held (with every reading after it, so each channel keeps its order) until a save covers it;
/// the bus goes on polling meanwhile, and one save covers everything polled while it ran. The
/// first reading of each channel after a crash carries `after_seq`, and after any start the
/// pulses the last run booked but handed over in no reading (see [`Resume`]).
pub struct Durable {
    pub saver: Saver,
    ledger: Ledger,
    /// Per channel key, where the channel resumes, until its first reading.
    resume: BTreeMap<String, Resume>,
    /// Per channel key, the last reading handed to the MQTT side (from the file until then):
    /// each save writes where it stands, for the next start's [`Resume`].
    handed: BTreeMap<String, Handed>,
    /// Outputs waiting for a save, with the channel key and seq of each reading in them, in
    /// order.
    held: std::collections::VecDeque<(Vec<(String, u64)>, Output)>,
    /// Saved state no configured device claims, written back with every save.
    pub orphans: crate::state::BusState,
}

use crate::reading::{Output, Reading};

/// The readings an output carries (none for statuses and stats).
fn readings_of(o: &Output) -> &[Reading] {
    match o {
        Output::DeviceReadings { readings, .. } => readings,
        _ => &[],
    }
}

fn readings_of_mut(o: &mut Output) -> &mut [Reading] {
    match o {
        Output::DeviceReadings { readings, .. } => readings,
        _ => &mut [],
    }
}

impl Durable {
    /// `saved`: the channels of the state file, `resume` what [`super::ledger::resume`] made of
    /// them.
    pub fn new(
        saver: Saver,
        saved: &BTreeMap<String, CounterState>,
        resume: BTreeMap<String, Resume>,
    ) -> Durable {
        let handed = saved
            .iter()
            .map(|(key, st)| {
                let from_file = Handed {
                    seq: st.seq,
                    total: st.total,
                };
                let at = resume.get(key).map_or(from_file, |r| r.handed);
                (key.clone(), at)
            })
            .collect();
        Durable {
            saver,
            ledger: Ledger::default(),
            resume,
            handed,
            held: Default::default(),
            orphans: Default::default(),
        }
    }

    /// The state file of a clean shutdown is durable as it is: the first readings of this run
    /// go out at once, not after a save (so a crash right after that save cannot take their
    /// deltas with it). After a crash the moved seqs are not durable until saved.
    pub fn trust(&mut self, saved: &BusState) {
        self.ledger.durable(&seqs(&saved.channels));
    }

    /// Readings are waiting for a save (the bus should come back soon).
    pub fn holding(&self) -> bool {
        !self.held.is_empty()
    }

    /// Collects a finished save, releases what it covers, and starts the next save if readings
    /// are still held.
    pub async fn collect<P: DeviceState>(
        &mut self,
        devices: &[DeviceRt<P>],
        out: &tokio::sync::mpsc::UnboundedSender<Output>,
    ) {
        self.saver.collect(&mut self.ledger).await;
        self.release(out);
        if self.holding() {
            let state = self.snapshot(devices, false);
            self.saver.start(state, out);
        }
    }

    /// Sends `outputs` (the readings of `devices[from]`), or holds them until a save covers
    /// their seq.
    pub fn publish<P: DeviceState>(
        &mut self,
        outputs: Vec<Output>,
        from: usize,
        devices: &[DeviceRt<P>],
        out: &tokio::sync::mpsc::UnboundedSender<Output>,
    ) {
        let d = &devices[from];
        let key = |r: &Reading| d.channel_key(&r.channel);
        for o in outputs {
            let keys = match &o {
                Output::Interval(i) => vec![(
                    super::ledger::record_key(&d.channel_key(&i.channel), &i.period),
                    i.record.seq,
                )],
                // A gauge's value has no seq to make durable: it goes with the counts.
                _ => readings_of(&o)
                    .iter()
                    .filter(|r| !r.is_gauge())
                    .map(|r| (key(r), r.update.seq))
                    .collect(),
            };
            self.held.push_back((keys, o));
        }
        self.release(out);
        if self.holding() {
            let state = self.snapshot(devices, false);
            self.saver.start(state, out);
        }
    }

    /// Sends the held readings a durable save covers, in order. While saves fail, everything
    /// goes: readings matter more than seq after a crash (the failure is logged).
    fn release(&mut self, out: &tokio::sync::mpsc::UnboundedSender<Output>) {
        while let Some((keys, _)) = self.held.front() {
            let covered = keys.iter().all(|(k, seq)| self.ledger.allows(k, *seq));
            if !covered && !self.saver.failing() {
                break;
            }
            let (keys, mut o) = self.held.pop_front().expect("front exists");
            let counts = readings_of_mut(&mut o).iter_mut().filter(|r| !r.is_gauge());
            for (r, (k, _)) in counts.zip(&keys) {
                if let Some(resume) = self.resume.remove(k) {
                    r.after_seq = resume.after_seq;
                    r.update.delta += resume.carry;
                }
                let at = Handed {
                    seq: r.update.seq,
                    total: r.update.total,
                };
                // Every reading passes here: the key is copied once per channel, not each time.
                match self.handed.get_mut(k) {
                    Some(h) => *h = at,
                    None => {
                        self.handed.insert(k.clone(), at);
                    }
                }
            }
            let _ = out.send(o);
        }
    }

    /// The last save, at shutdown (seq may go on from here), then whatever was held.
    pub async fn finish<P: DeviceState>(
        &mut self,
        devices: &[DeviceRt<P>],
        out: &tokio::sync::mpsc::UnboundedSender<Output>,
    ) -> bool {
        let state = self.snapshot(devices, true);
        let mut saved = self.saver.save_now(state, &mut self.ledger, out).await;
        let held = self.holding();
        self.release(out);
        if held && saved {
            // The file just written has the readings and records it held as not handed over;
            // now that they went out, one more save (after they are durable) keeps the next
            // start from sending or carrying them again.
            let state = self.snapshot(devices, true);
            saved = self.saver.save_now(state, &mut self.ledger, out).await;
        }
        saved
    }

    /// The bus's state now: every device's, the interval records still held as unsent, and
    /// the saved state no configured device claims (kept, never attached to another meter);
    /// `clean` only for the saves after the last reading at shutdown.
    pub(super) fn snapshot<P: DeviceState>(
        &self,
        devices: &[DeviceRt<P>],
        clean: bool,
    ) -> BusState {
        let mut s = BusState {
            clean,
            ..self.orphans.clone()
        };
        for d in devices {
            for (key, mut state) in d.counter_states() {
                let handed = self.handed.get(&key).copied().unwrap_or_default();
                let now = Handed {
                    seq: state.seq,
                    total: state.total,
                };
                state.handed = (handed != now).then_some(handed);
                s.channels.insert(key, state);
            }
            d.proto.save(&mut s);
        }
        for (_, o) in &self.held {
            let Output::Interval(i) = o else { continue };
            let Some(d) = devices.iter().find(|d| d.name == i.device) else {
                continue;
            };
            if let Some(ch) = s.channels.get_mut(&d.channel_key(&i.channel)) {
                let st = ch.intervals.entry(i.period.to_string()).or_default();
                st.unsent.push(i.record.clone());
            }
        }
        s
    }
}

/// Interval records a state file held as unsent: by channel key, each with its period.
pub(super) type Unsent = BTreeMap<String, Vec<(String, crate::metering::Record)>>;

/// Takes the interval records a state file holds as unsent out of it, by channel key: they
/// are sent again at start (see [`crate::metering::IntervalState::unsent`]).
pub(super) fn take_unsent(channels: &mut BTreeMap<String, crate::counter::CounterState>) -> Unsent {
    let mut out: BTreeMap<String, Vec<_>> = BTreeMap::new();
    for (key, state) in channels.iter_mut() {
        for (period, st) in state.intervals.iter_mut() {
            for r in std::mem::take(&mut st.unsent) {
                out.entry(key.clone())
                    .or_default()
                    .push((period.clone(), r));
            }
        }
    }
    out
}
