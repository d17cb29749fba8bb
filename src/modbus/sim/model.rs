//! A simulated counter module, driven by its profile: counts advance with time at each channel's
//! pulse rate; frequency, rpm, clear, preset and command registers behave as the datasheets say.
//! The other documented registers (identification, settings, limits) answer with the
//! datasheets' factory values, written down in [`super::datasheet`] apart from the profiles;
//! reads of undocumented registers answer exception 02. A ZH-YX1600 starts as its datasheet
//! says: mode words 0, counters stopped until a command starts them. Pure: time comes in as
//! seconds since the plant started.

use std::collections::BTreeMap;
use std::sync::Arc;

use tokio_modbus::ExceptionCode;

use crate::decode::{decode, encode_int};
use crate::profile::{ChannelKind, ChannelSpec, Profile, ValueType};

use super::datasheet::{self as ds, ZH_DOWN, ZH_PAUSE, ZH_STOP, ZH_UP};

/// One simulated channel.
#[derive(Debug, Clone)]
pub struct SimChannel {
    pub spec: ChannelSpec,
    /// Pulses per second (negative: an encoder turning backwards).
    rate: f64,
    /// Count at `since`, unwrapped.
    base: i64,
    since: f64,
    /// Pulses that reached the input since the plant started (the meter on the wall).
    generated_base: i64,
    /// Counting (false after a stop/clear command until restarted).
    running: bool,
    /// Command register value, where the channel has one.
    command: u16,
    /// A quadrature pair whose two mode words disagree: the datasheet says it does not count.
    dead: bool,
    pub ppr: u16,
    /// The counts that clears and presets replaced, in order: what the module held at the
    /// instant of the write (a test's account of the pulses between a gateway's last read and
    /// its write, which no gateway can see).
    pub overwritten: Vec<i64>,
}

impl SimChannel {
    fn pulses(&self, now: f64) -> i64 {
        (self.rate * (now - self.since)).floor() as i64
    }

    /// The count register's value (unwrapped; the register keeps the low 32 bits).
    pub fn count(&self, now: f64) -> i64 {
        let p = if self.counting() { self.pulses(now) } else { 0 };
        let down = self.command == ZH_DOWN && self.spec.kind == ChannelKind::Counter;
        self.base + if down { -p } else { p }
    }

    /// Pulses generated at the input since the plant started.
    pub fn generated(&self, now: f64) -> i64 {
        self.generated_base + self.pulses(now)
    }

    /// Freezes the current count as the base, so rate or run state can change from `now`.
    fn rebase(&mut self, now: f64) {
        self.generated_base = self.generated(now);
        self.base = self.count(now);
        self.since = now;
    }

    fn set_count(&mut self, now: f64, value: i64) {
        self.rebase(now);
        self.overwritten.push(self.base);
        self.base = value;
    }

    fn freq(&self) -> f64 {
        if self.counting() {
            self.rate.abs()
        } else {
            0.0
        }
    }

    fn counting(&self) -> bool {
        self.running && !self.dead
    }

    /// Whether the counter runs (its command register is up or down).
    pub fn running(&self) -> bool {
        self.running
    }

    /// The ZH-YX1600 counter number (0-based) of this channel, from its count register.
    fn zh_index(&self) -> u16 {
        (self.spec.count.address - ds::ZH_COUNT) / 2
    }
}

/// A simulated module.
#[derive(Debug, Clone)]
pub struct SimModule {
    pub profile: Arc<Profile>,
    modes: Vec<u16>,
    pub channels: Vec<SimChannel>,
    /// Registers with no behaviour of their own (mode words, identification, autosave).
    plain: BTreeMap<u16, u16>,
    /// Silent modules do not answer at all.
    pub silent: bool,
    /// Answers come this late (a slow module, or one whose answer outlives the gateway's
    /// timeout and arrives while the gateway already talks to the next module).
    pub answer_delay: std::time::Duration,
    /// A module answering nonsense in well-formed frames (valid CRC): wrong register counts,
    /// answers to another function, unknown exception codes.
    pub nonsense: bool,
    /// Channels whose next read returns a count of 0 once (a glitch on the line or in the
    /// module), then the true count again.
    pub glitch_zero: Vec<String>,
    /// Write requests (FC06/FC16) this module has received, accepted or not, and when the last
    /// one arrived (plant seconds).
    pub writes: u64,
    pub last_write: Option<f64>,
    /// A ZH-YX1600: counters run by command register, frequency over a window.
    zh: bool,
    /// The baud rate the module's serial port runs at (see `comm`); `None`: it answers at any
    /// line speed (plants that do not say, so older tests can run their line at 115200).
    pub baud: Option<u32>,
    /// Stay silent, instead of answering exception 02, when asked for a register the module
    /// lacks (no datasheet says which a module does).
    pub silent_on_unknown: bool,
    /// Read requests (FC03) this module has answered: a count of transactions that does not
    /// depend on the client (the benchmark compares the gateway with another Modbus master).
    pub reads: u64,
    /// The last [`ANSWER_LOG`] reads this module answered (a test's own count between two
    /// reads, e.g. an interval record's boundary reads).
    pub answered: std::collections::VecDeque<Answered>,
}

/// One read a module answered.
#[derive(Debug, Clone, PartialEq)]
pub struct Answered {
    /// Plant seconds.
    pub at: f64,
    /// The registers read.
    pub start: u16,
    pub len: u16,
    /// Pulses each channel had generated then, in channel order.
    pub generated: Vec<i64>,
}

/// How many answered reads a module remembers.
pub const ANSWER_LOG: usize = 4096;

/// Words of `value` as a register of type `ty`, keeping the low bits like the module does.
fn words_of(value: i64, ty: ValueType, order: crate::profile::WordOrder) -> Vec<u16> {
    let wrapped = match ty {
        ValueType::I32 => i64::from(value as i32),
        ValueType::U32 => i64::from(value as u32),
        ValueType::I16 => i64::from(value as i16),
        ValueType::U16 => i64::from(value as u16),
        ValueType::F32 => return f32_words(value as f32, order),
    };
    encode_int(wrapped, ty, order).expect("wrapped into range")
}

fn f32_words(v: f32, order: crate::profile::WordOrder) -> Vec<u16> {
    crate::decode::encode_f32(v, order)
}

impl SimModule {
    /// A module of `profile` whose mode registers read `modes` (raw values, in
    /// [`Profile::mode_registers`] order; missing entries take each group's first mode).
    pub fn new(profile: Arc<Profile>, modes: &[u16]) -> Result<SimModule, String> {
        let regs = profile.mode_registers();
        let mut plain = BTreeMap::new();
        for (start, values) in ds::factory_registers(&profile.model) {
            for (i, v) in values.into_iter().enumerate() {
                plain.insert(start + i as u16, v);
            }
        }
        let zh = profile.model == "zh-yx1600";
        if zh {
            // Frequency windows: 0 (1 s) at the factory.
            for a in ds::ZH_WINDOW..ds::ZH_WINDOW + 32 {
                plain.insert(a, 0);
            }
        }
        for (i, r) in regs.iter().enumerate() {
            let v = modes.get(i).copied().unwrap_or(0);
            plain.insert(r.address, v);
            // A quadrature pair's even counter carries the same mode word (ZH-YX1600).
            if r.mask != 0xFFFF {
                plain.insert(r.address + 1, v);
            }
        }
        let mut m = SimModule {
            profile,
            modes: Vec::new(),
            channels: Vec::new(),
            plain,
            silent: false,
            nonsense: false,
            answer_delay: std::time::Duration::ZERO,
            glitch_zero: Vec::new(),
            writes: 0,
            last_write: None,
            zh,
            baud: None,
            silent_on_unknown: false,
            reads: 0,
            answered: std::collections::VecDeque::new(),
        };
        m.power_up(0.0)?;
        Ok(m)
    }

    /// Power-up: the channels of the saved mode words; a ZH-YX1600 counter takes its run state
    /// from its mode word's power-on bits (factory: stopped), and a quadrature pair counts only
    /// when both mode words select quadrature.
    fn power_up(&mut self, now: f64) -> Result<(), String> {
        let modes: Vec<u16> = self
            .profile
            .mode_registers()
            .iter()
            .map(|r| self.plain.get(&r.address).copied().unwrap_or(0))
            .collect();
        let specs = self.profile.channels(&modes).map_err(|e| e.to_string())?;
        let old = std::mem::take(&mut self.channels);
        for spec in specs {
            let kept = old.iter().find(|c| c.spec == spec);
            let mut c = SimChannel {
                rate: kept.map_or(0.0, |c| c.rate),
                base: kept.map_or(0, |c| c.count(now)),
                since: now,
                generated_base: kept.map_or(0, |c| c.generated(now)),
                running: true,
                command: 0,
                dead: false,
                ppr: kept.map_or(1000, |c| c.ppr),
                overwritten: kept.map_or_else(Vec::new, |c| c.overwritten.clone()),
                spec,
            };
            if self.zh {
                let i = c.zh_index();
                let word = self.plain.get(&(ds::ZH_MODE + i)).copied().unwrap_or(0);
                c.command = ds::zh_power_on_command(word);
                c.running = c.command != ZH_STOP;
                if c.spec.kind == ChannelKind::Encoder {
                    let partner = self.plain.get(&(ds::ZH_MODE + i + 1)).copied();
                    c.dead = !partner.is_some_and(ds::zh_quadrature);
                }
            }
            self.channels.push(c);
        }
        self.modes = modes;
        Ok(())
    }

    /// Stores a register the module keeps (address, baud rate: see `comm`).
    pub fn store(&mut self, address: u16, value: u16) {
        self.plain.insert(address, value);
    }

    /// A register the module keeps, as last written.
    pub fn stored(&self, address: u16) -> Option<u16> {
        self.plain.get(&address).copied()
    }

    /// The raw mode values the module was built with.
    pub fn modes(&self) -> &[u16] {
        &self.modes
    }

    pub fn channel(&self, name: &str) -> Option<&SimChannel> {
        self.channels.iter().find(|c| c.spec.name == name)
    }

    fn channel_mut(&mut self, name: &str) -> Option<&mut SimChannel> {
        self.channels.iter_mut().find(|c| c.spec.name == name)
    }

    /// Sets a channel's pulse rate from `now` on.
    pub fn set_rate(&mut self, now: f64, name: &str, rate: f64) -> bool {
        self.channel_mut(name)
            .map(|c| {
                c.rebase(now);
                c.rate = rate;
            })
            .is_some()
    }

    /// Sets a channel's count (as if preset) without generating pulses.
    pub fn set_count(&mut self, now: f64, name: &str, value: i64) -> bool {
        self.channel_mut(name)
            .map(|c| c.set_count(now, value))
            .is_some()
    }

    pub fn set_ppr(&mut self, name: &str, ppr: u16) -> bool {
        self.channel_mut(name).map(|c| c.ppr = ppr).is_some()
    }

    /// Power loss and return: counts the module does not keep go back to 0; mode words written
    /// since the last power-up take effect now.
    pub fn power_cycle(&mut self, now: f64) {
        let autosave = self
            .profile
            .autosave
            .is_none_or(|a| self.plain.get(&a) == Some(&1));
        for c in &mut self.channels {
            if !(c.spec.retains_count && autosave) {
                c.set_count(now, 0);
            }
        }
        if let Err(e) = self.power_up(now) {
            tracing::warn!("simulated module: {e}");
        }
    }

    /// A ZH-YX1600 frequency window in seconds for counter `index` (0 = 1 s; units of 10 ms).
    fn zh_window_s(&self, index: u16) -> f64 {
        let a = ds::ZH_WINDOW + 2 * index;
        let hi = u32::from(self.plain.get(&a).copied().unwrap_or(0));
        let lo = u32::from(self.plain.get(&(a + 1)).copied().unwrap_or(0));
        match (hi << 16) | lo {
            0 => 1.0,
            n => f64::from(n) * 0.01,
        }
    }

    /// The value of one register at `now`, or `None` where the module has none.
    pub fn register(&self, now: f64, address: u16) -> Option<u16> {
        if let Some(v) = self.plain.get(&address) {
            return Some(*v);
        }
        let order = self.profile.word_order;
        for c in &self.channels {
            let s = &c.spec;
            let pick = |r: crate::profile::Register, value: Value| -> Option<u16> {
                if address < r.address || address >= r.end() {
                    return None;
                }
                let words = match value {
                    Value::Int(v) => words_of(v, r.ty, order),
                    Value::Float(f) => match r.ty {
                        ValueType::F32 => f32_words(f as f32, order),
                        ty => words_of(f.round() as i64, ty, order),
                    },
                };
                Some(words[usize::from(address - r.address)])
            };
            // A ZH-YX1600 frequency register holds the pulses counted in the counter's window.
            let freq = if self.zh {
                (c.freq() * self.zh_window_s(c.zh_index())).floor()
            } else {
                c.freq()
            };
            let rpm = if c.ppr > 0 {
                freq * 60.0 / f64::from(c.ppr)
            } else {
                0.0
            };
            let signed_rpm = if s.kind == ChannelKind::Encoder && c.rate < 0.0 {
                -rpm
            } else {
                rpm
            };
            let found = pick(s.count, Value::Int(c.count(now)))
                .or_else(|| s.freq.and_then(|r| pick(r, Value::Float(freq))))
                .or_else(|| s.rpm.and_then(|r| pick(r, Value::Float(signed_rpm))))
                .or_else(|| s.ppr.and_then(|r| pick(r, Value::Int(i64::from(c.ppr)))));
            if found.is_some() {
                return found;
            }
            if address == s.clear.register {
                return Some(if s.clear.restart.is_empty() {
                    0
                } else {
                    c.command
                });
            }
        }
        None
    }

    /// Notes a read of `len` registers from `start` answered at `now`.
    pub fn note_answer(&mut self, now: f64, start: u16, len: u16) {
        if self.answered.len() == ANSWER_LOG {
            self.answered.pop_front();
        }
        let generated = self.channels.iter().map(|c| c.generated(now)).collect();
        self.answered.push_back(Answered {
            at: now,
            start,
            len,
            generated,
        });
    }

    /// Index of channel `name` in [`SimModule::answered`]'s lists.
    pub fn channel_index(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.spec.name == name)
    }

    /// FC03: reads `len` registers from `start`; any undescribed register refuses the read.
    pub fn read(&mut self, now: f64, start: u16, len: u16) -> Result<Vec<u16>, ExceptionCode> {
        if len == 0 || len > 125 || u32::from(start) + u32::from(len) > 0x1_0000 {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let mut words: Vec<u16> = (start..start + len)
            .map(|a| {
                self.register(now, a)
                    .ok_or(ExceptionCode::IllegalDataAddress)
            })
            .collect::<Result<_, _>>()?;
        let mut hit = Vec::new();
        for c in &self.channels {
            let r = c.spec.count;
            if self.glitch_zero.contains(&c.spec.name)
                && r.address >= start
                && r.end() <= start + len
            {
                for a in r.address..r.end() {
                    words[usize::from(a - start)] = 0;
                }
                hit.push(c.spec.name.clone());
            }
        }
        self.glitch_zero.retain(|n| !hit.contains(n));
        Ok(words)
    }

    /// FC06.
    pub fn write_one(&mut self, now: f64, address: u16, value: u16) -> Result<(), ExceptionCode> {
        // Clear codes and counter commands.
        let mut handled = false;
        let all: Vec<usize> = (0..self.channels.len()).collect();
        for i in all {
            let c = &mut self.channels[i];
            let s = c.spec.clone();
            if s.clear.register != address {
                continue;
            }
            if self.zh {
                // A command register (ZH-YX1600 section 8.5): stop-and-clear, pause, up, down.
                c.rebase(now);
                match value {
                    ZH_STOP => {
                        c.base = 0;
                        c.running = false;
                    }
                    ZH_PAUSE => c.running = false,
                    // Quadrature: the phase decides the direction; 0xA3 has no effect.
                    ZH_DOWN if s.kind == ChannelKind::Encoder => {}
                    ZH_UP | ZH_DOWN => c.running = true,
                    _ => return Err(ExceptionCode::IllegalDataValue),
                }
                if !(value == ZH_DOWN && s.kind == ChannelKind::Encoder) {
                    c.command = value;
                }
                handled = true;
            } else if value == s.clear.code
                || s.clear_all
                    .is_some_and(|a| a.register == address && a.code == value)
            {
                c.set_count(now, 0);
                handled = true;
            }
        }
        if handled {
            return Ok(());
        }
        if self
            .channels
            .iter()
            .any(|c| c.spec.clear.register == address)
        {
            return Err(ExceptionCode::IllegalDataValue);
        }
        if let Some(v) = self.plain.get_mut(&address) {
            // Mode words, autosave: stored; modes take effect after a restart, as documented.
            *v = value;
            return Ok(());
        }
        for c in &mut self.channels {
            if c.spec.ppr.is_some_and(|r| r.address == address) {
                c.ppr = value;
                return Ok(());
            }
        }
        Err(ExceptionCode::IllegalDataAddress)
    }

    /// FC16: presets a count (both words at once), or writes single registers in turn.
    pub fn write_many(
        &mut self,
        now: f64,
        address: u16,
        values: &[u16],
    ) -> Result<(), ExceptionCode> {
        if values.is_empty() || values.len() > 123 {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let order = self.profile.word_order;
        if let Some(c) = self.channels.iter_mut().find(|c| {
            c.spec.count.address == address && usize::from(c.spec.count.len()) == values.len()
        }) {
            let v = decode(values, c.spec.count.ty, order).as_i64();
            c.set_count(now, v);
            return Ok(());
        }
        for (i, v) in values.iter().enumerate() {
            self.write_one(now, address + i as u16, *v)?;
        }
        Ok(())
    }
}

enum Value {
    Int(i64),
    Float(f64),
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Profiles;

    fn module(model: &str, modes: &[u16]) -> SimModule {
        SimModule::new(Profiles::builtin().get(model).unwrap(), modes).unwrap()
    }

    #[test]
    fn a_yl67_answers_the_datasheet_request_with_the_datasheet_words() {
        let mut m = module("yl67", &[0, 0, 0, 0]);
        m.set_count(0.0, "enc0", -13680);
        // 01 03 00 10 00 02 → 01 03 04 CA 90 FF FF
        assert_eq!(m.read(0.0, 0x10, 2), Ok(vec![0xCA90, 0xFFFF]));
    }

    #[test]
    fn counts_advance_with_time_at_the_channel_rate() {
        let mut m = module("wj157", &[1]);
        m.set_rate(0.0, "a0", 1000.0);
        assert_eq!(m.channel("a0").unwrap().count(2.5), 2500);
        assert_eq!(m.channel("a0").unwrap().generated(2.5), 2500);
    }

    #[test]
    fn undescribed_registers_answer_exception_02() {
        let mut m = module("yl67", &[0, 0, 0, 0]);
        assert_eq!(m.read(0.0, 24, 2), Err(ExceptionCode::IllegalDataAddress));
        assert_eq!(m.read(0.0, 16, 10), Err(ExceptionCode::IllegalDataAddress));
    }

    #[test]
    fn the_yl67_clear_register_clears_one_encoder() {
        let mut m = module("yl67", &[0, 0, 0, 0]);
        m.set_count(0.0, "enc0", 500);
        m.set_count(0.0, "enc1", 700);
        m.write_one(0.0, 67, 10).unwrap();
        assert_eq!(m.channel("enc0").unwrap().count(0.0), 0);
        assert_eq!(m.channel("enc1").unwrap().count(0.0), 700);
        assert_eq!(
            m.write_one(0.0, 67, 99),
            Err(ExceptionCode::IllegalDataValue)
        );
    }

    #[test]
    fn zh_yx1600_clear_is_stop_then_restart() {
        let mut m = module("zh-yx1600", &[]);
        m.write_one(0.0, 0x1100, 0xA2).unwrap();
        m.set_rate(0.0, "di1", 100.0);
        m.write_one(1.0, 0x1100, 0).unwrap();
        assert_eq!(
            m.channel("di1").unwrap().count(2.0),
            0,
            "stopped and cleared"
        );
        m.write_one(2.0, 0x1100, 0xA2).unwrap();
        assert_eq!(m.channel("di1").unwrap().count(3.0), 100);
        assert_eq!(m.read(3.0, 0x1160, 2), Ok(vec![0, 100]));
    }

    #[test]
    fn zh_yx1600_in_quadrature_has_no_even_channel() {
        let m = module("zh-yx1600", &[2]);
        assert!(m.channel("di1").is_some());
        assert!(m.channel("di2").is_none());
        assert!(m.channel("di3").is_some());
    }

    #[test]
    fn a_preset_writes_both_words_at_once() {
        let mut m = module("zh-yx1600", &[]);
        m.write_many(0.0, 0x1160, &[0x0001, 0x86A0]).unwrap();
        assert_eq!(m.channel("di1").unwrap().count(0.0), 100_000);
    }

    #[test]
    fn power_loss_clears_di_counts_but_keeps_encoders() {
        let mut m = module("yl67", &[0, 1, 0, 0]);
        m.set_count(0.0, "enc0", 5);
        m.set_count(0.0, "a1", 5);
        m.power_cycle(1.0);
        assert_eq!(m.channel("enc0").unwrap().count(1.0), 5);
        assert_eq!(m.channel("a1").unwrap().count(1.0), 0);
    }
}

/// The ZH-YX1600 as its datasheet (V5.0, sections 8.2 to 8.5 and 9) says, against literal
/// addresses and codes.
#[cfg(test)]
mod zh_yx1600_datasheet_tests {
    use super::*;
    use crate::profile::Profiles;

    fn zh(modes: &[u16]) -> SimModule {
        SimModule::new(Profiles::builtin().get("zh-yx1600").unwrap(), modes).unwrap()
    }

    #[test]
    fn at_factory_defaults_mode_words_are_0_and_counters_stay_stopped_until_0xa2() {
        let mut m = zh(&[]);
        assert_eq!(m.read(0.0, 0x0700, 16), Ok(vec![0; 16]));
        assert_eq!(m.read(0.0, 0x1100, 1), Ok(vec![0x0000]), "command: stopped");
        m.set_rate(0.0, "di1", 100.0);
        assert_eq!(
            m.read(2.0, 0x1160, 2),
            Ok(vec![0, 0]),
            "a stopped counter does not count"
        );
        m.write_one(2.0, 0x1100, 0x00A2).unwrap();
        assert_eq!(m.read(3.0, 0x1160, 2), Ok(vec![0, 100]));
    }

    #[test]
    fn command_0xa3_counts_down_into_negative_values() {
        let mut m = zh(&[]);
        m.set_rate(0.0, "di1", 100.0);
        m.write_one(0.0, 0x1100, 0x00A3).unwrap();
        assert_eq!(m.read(1.0, 0x1160, 2), Ok(vec![0xFFFF, 0xFF9C]), "-100");
    }

    #[test]
    fn the_power_on_state_in_the_mode_word_applies_only_after_a_restart() {
        let mut m = zh(&[]);
        m.set_rate(0.0, "di1", 100.0);
        // pAuto (bits 9:8) = 1: count up after power-up.
        m.write_one(0.0, 0x0700, 0x0100).unwrap();
        assert_eq!(
            m.read(1.0, 0x1160, 2),
            Ok(vec![0, 0]),
            "not before a restart"
        );
        m.power_cycle(1.0);
        assert_eq!(m.read(1.0, 0x1100, 1), Ok(vec![0x00A2]));
        assert_eq!(m.read(2.0, 0x1160, 2), Ok(vec![0, 100]));
    }

    #[test]
    fn command_0x0001_pauses_without_clearing_and_0x0000_stops_and_clears() {
        let mut m = zh(&[]);
        m.set_rate(0.0, "di1", 100.0);
        m.write_one(0.0, 0x1100, 0x00A2).unwrap();
        m.write_one(1.0, 0x1100, 0x0001).unwrap();
        assert_eq!(m.read(3.0, 0x1160, 2), Ok(vec![0, 100]), "paused, kept");
        m.write_one(3.0, 0x1100, 0x0000).unwrap();
        assert_eq!(
            m.read(4.0, 0x1160, 2),
            Ok(vec![0, 0]),
            "stopped and cleared"
        );
    }

    #[test]
    fn a_quadrature_pair_counts_only_with_bit_1_on_both_mode_words_and_ignores_0xa3() {
        let mut m = zh(&[2]);
        m.set_rate(0.0, "di1", 100.0);
        m.write_one(0.0, 0x1100, 0x00A2).unwrap();
        m.write_one(0.0, 0x1100, 0x00A3).unwrap();
        assert_eq!(
            m.read(0.0, 0x1100, 1),
            Ok(vec![0x00A2]),
            "0xA3 has no effect"
        );
        assert_eq!(m.read(1.0, 0x1160, 2), Ok(vec![0, 100]));
        // Bit 1 only on counter 1: the pair does not count after the next power-up.
        m.write_one(1.0, 0x0701, 0x0000).unwrap();
        m.power_cycle(1.0);
        m.write_one(1.0, 0x1100, 0x00A2).unwrap();
        assert_eq!(m.read(3.0, 0x1160, 2), Ok(vec![0, 0]));
    }

    #[test]
    fn identification_and_settings_answer_their_documented_values() {
        let mut m = zh(&[]);
        assert_eq!(m.read(0.0, 0x0055, 3), Ok(vec![0x5958, 0x3136, 0x3030]));
        assert_eq!(m.read(0.0, 0x0050, 3), Ok(vec![0x0001, 0x0001, 0x0000]));
        assert_eq!(m.read(0.0, 0x0750, 2), Ok(vec![0x7FFF, 0xFFFF]));
        assert_eq!(m.read(0.0, 0x0770, 2), Ok(vec![0x8000, 0x0000]));
        assert_eq!(m.read(0.0, 0x1000, 1), Ok(vec![0]));
        assert_eq!(m.read(0.0, 0x1110, 2), Ok(vec![0x7FFF, 0xFFFF]));
        let mut yl = SimModule::new(Profiles::builtin().get("yl67").unwrap(), &[]).unwrap();
        assert_eq!(yl.read(0.0, 210, 1), Ok(vec![0x0067]));
        let mut wj = SimModule::new(Profiles::builtin().get("wj157").unwrap(), &[]).unwrap();
        assert_eq!(wj.read(0.0, 210, 1), Ok(vec![0x0150]));
    }

    #[test]
    fn the_frequency_register_holds_the_pulses_of_the_counting_window() {
        let mut m = zh(&[]);
        m.set_rate(0.0, "di1", 50.0);
        m.write_one(0.0, 0x1100, 0x00A2).unwrap();
        // Window 0: one second.
        assert_eq!(m.read(1.0, 0x1180, 2), Ok(vec![0, 50]));
        // 0x1140:0x1141 = 6000: one minute (the datasheet's example).
        m.write_many(1.0, 0x1140, &[0, 6000]).unwrap();
        assert_eq!(m.read(1.0, 0x1180, 2), Ok(vec![0, 3000]));
    }
}

#[cfg(test)]
mod glitch_tests {
    use super::*;
    use crate::profile::Profiles;

    #[test]
    fn a_glitch_reads_zero_once() {
        let mut m =
            SimModule::new(Profiles::builtin().get("yl67").unwrap(), &[1, 1, 1, 1]).unwrap();
        m.set_count(0.0, "a0", 1_000_000);
        m.glitch_zero.push("a0".into());
        assert_eq!(m.read(0.0, 32, 16).unwrap()[..2], [0, 0]);
        assert_ne!(m.read(0.0, 32, 16).unwrap()[..2], [0, 0]);
    }
}
