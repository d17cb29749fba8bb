//! One simulated M-Bus meter: who it is (id, manufacturer, version, medium, primary address),
//! registers that count at a set rate and roll over at their width, a few gauges, and the
//! link state a real meter keeps (FCB, last answer, next telegram, selected). Pure.

use super::wire::{self, dif, vif};

/// What a register counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Energy in Wh steps.
    EnergyWh,
    /// Energy in kWh steps.
    EnergyKwh,
    /// Volume in litre (10^-3 m³) steps.
    VolumeLitre,
}

/// How wide a register is on the wire, and so where it rolls over.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Width {
    /// 8-digit BCD: rolls over at 10^8.
    Bcd8,
    /// 32-bit binary integer: rolls over at 2^32.
    Int32,
}

impl Width {
    /// The number of steps after which the register starts again at 0.
    pub fn modulus(&self) -> u64 {
        match self {
            Width::Bcd8 => 100_000_000,
            Width::Int32 => 1 << 32,
        }
    }
}

/// A register counting `rate` steps a second from `base` at time `since`.
#[derive(Debug, Clone, PartialEq)]
pub struct Register {
    pub quantity: Quantity,
    pub width: Width,
    base: u64,
    rate: f64,
    since: f64,
}

impl Register {
    /// A register at `start` steps at time 0, counting `rate` steps a second.
    pub fn new(quantity: Quantity, width: Width, start: u64, rate: f64) -> Register {
        Register {
            quantity,
            width,
            base: start % width.modulus(),
            rate,
            since: 0.0,
        }
    }

    /// Steps counted since time 0 (no roll-over): what a gateway's total should sum to.
    pub fn counted(&self, now: f64) -> u64 {
        self.base + (self.rate * (now - self.since).max(0.0)).floor() as u64
    }

    /// The register as the meter shows it at `now`: rolled over at its width.
    pub fn count(&self, now: f64) -> u64 {
        self.counted(now) % self.width.modulus()
    }

    /// Sets the count at `now` (and keeps the rate).
    pub fn set(&mut self, now: f64, count: u64) {
        self.base = count % self.width.modulus();
        self.since = now;
    }

    /// Changes the rate from `now` on, keeping the count.
    pub fn set_rate(&mut self, now: f64, rate: f64) {
        self.base = self.counted(now);
        self.since = now;
        self.rate = rate;
    }

    fn record(&self, now: f64) -> Vec<u8> {
        let v = match self.quantity {
            Quantity::EnergyWh => vif::WH,
            Quantity::EnergyKwh => vif::KWH,
            Quantity::VolumeLitre => vif::LITRE,
        };
        let count = self.count(now);
        match self.width {
            Width::Bcd8 => [vec![dif::BCD8, v], wire::bcd(count, 4)].concat(),
            Width::Int32 => [vec![dif::INT32, v], (count as u32).to_le_bytes().to_vec()].concat(),
        }
    }
}

/// A value that does not count: power, flow, temperatures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gauge {
    /// Power in W (32-bit integer).
    PowerW(i32),
    /// Volume flow in l/h (16-bit integer).
    FlowLitrePerHour(i16),
    /// Flow temperature in 0.01 °C (16-bit integer).
    FlowTemperatureCenti(i16),
    /// Return temperature in 0.01 °C (16-bit integer).
    ReturnTemperatureCenti(i16),
}

impl Gauge {
    fn record(&self) -> Vec<u8> {
        match *self {
            Gauge::PowerW(w) => [vec![dif::INT32, vif::WATT], w.to_le_bytes().to_vec()].concat(),
            Gauge::FlowLitrePerHour(v) => int16(vif::LITRE_PER_HOUR, v),
            Gauge::FlowTemperatureCenti(v) => int16(vif::FLOW_CENTI_C, v),
            Gauge::ReturnTemperatureCenti(v) => int16(vif::RETURN_CENTI_C, v),
        }
    }
}

fn int16(v: u8, value: i16) -> Vec<u8> {
    [vec![dif::INT16, v], value.to_le_bytes().to_vec()].concat()
}

/// How a meter behaves on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Behaviour {
    #[default]
    Normal,
    /// Answers nothing.
    Silent,
    /// Answers bytes that are no frame (a broken transceiver).
    Garbage,
}

/// One simulated meter.
#[derive(Debug, Clone, PartialEq)]
pub struct SimMeter {
    /// The identification number, 8 decimal digits (0–99999999).
    pub id: u32,
    /// Three letters A–Z.
    pub manufacturer: [u8; 3],
    pub version: u8,
    pub medium: u8,
    /// Primary address (0 = unconfigured, as many meters ship).
    pub address: u8,
    pub registers: Vec<Register>,
    pub gauges: Vec<Gauge>,
    pub behaviour: Behaviour,
    /// The most records in one telegram; more are sent in further telegrams (DIF 1F). 0: all
    /// in one.
    pub records_per_telegram: usize,
    /// A recorded answer (a corpus frame) served instead of built ones, with its address byte
    /// and checksum made this meter's.
    pub recorded: Option<Vec<u8>>,
    access: u8,
    pub(super) selected: bool,
    last_fcb: Option<bool>,
    last: Option<Vec<u8>>,
    next_telegram: usize,
}

impl SimMeter {
    /// A meter with no registers yet.
    pub fn new(id: u32, manufacturer: &str, version: u8, medium: u8, address: u8) -> SimMeter {
        let m = manufacturer.as_bytes();
        SimMeter {
            id: id % 100_000_000,
            manufacturer: [m[0], m[1], m[2]],
            version,
            medium,
            address,
            registers: Vec::new(),
            gauges: Vec::new(),
            behaviour: Behaviour::Normal,
            records_per_telegram: 0,
            recorded: None,
            access: 0,
            selected: false,
            last_fcb: None,
            last: None,
            next_telegram: 0,
        }
    }

    /// The same meter with one more register.
    pub fn with_register(mut self, register: Register) -> SimMeter {
        self.registers.push(register);
        self
    }

    /// The same meter with one more gauge.
    pub fn with_gauge(mut self, gauge: Gauge) -> SimMeter {
        self.gauges.push(gauge);
        self
    }

    /// The meter is swapped for a new one: a new id, its registers starting again from 0.
    pub fn replace(&mut self, now: f64, new_id: u32) {
        self.id = new_id % 100_000_000;
        for r in &mut self.registers {
            r.set(now, 0);
        }
        self.reset_link();
    }

    /// The secondary address's 8 bytes.
    pub fn secondary(&self) -> [u8; 8] {
        wire::secondary(self.id, self.manufacturer, self.version, self.medium)
    }

    /// SND_NKE: the link is reset, the FCB cleared, the next answer starts at telegram 0.
    pub(super) fn reset_link(&mut self) {
        self.last_fcb = Some(false);
        self.last = None;
        self.next_telegram = 0;
    }

    /// Application reset (CI 0x50): the readout starts again from the first telegram.
    pub(super) fn reset_application(&mut self) {
        self.next_telegram = 0;
        self.last = None;
    }

    /// The answer to a REQ_UD2 with C field `c`: the last answer again when the FCB did not
    /// toggle, else the next telegram (or the first, fresh, after the last one).
    pub(super) fn req_ud2(&mut self, now: f64, c: u8) -> Vec<u8> {
        let (fcv, fcb) = (c & 0x10 != 0, c & 0x20 != 0);
        if fcv && self.last_fcb == Some(fcb) {
            if let Some(last) = &self.last {
                return last.clone();
            }
        }
        if !fcv {
            self.next_telegram = 0;
        }
        self.last_fcb = fcv.then_some(fcb);
        let answer = self.telegram(now);
        self.last = Some(answer.clone());
        answer
    }

    /// The next telegram of the readout.
    fn telegram(&mut self, now: f64) -> Vec<u8> {
        self.access = self.access.wrapping_add(1);
        if let Some(recorded) = &self.recorded {
            let mut frame = recorded.clone();
            if frame.len() > 7 {
                frame[5] = self.address;
                let end = frame.len() - 2;
                frame[end] = wire::sum(&frame[4..end]);
            }
            return frame;
        }
        let records = self.records(now);
        let per = match self.records_per_telegram {
            0 => records.len().max(1),
            n => n,
        };
        let chunks: Vec<&[Vec<u8>]> = records.chunks(per).collect();
        let k = self.next_telegram.min(chunks.len().saturating_sub(1));
        let more = k + 1 < chunks.len();
        self.next_telegram = if more { k + 1 } else { 0 };
        let mut data = self.secondary().to_vec();
        data.extend_from_slice(&[self.access, 0x00, 0x00, 0x00]);
        for r in chunks.get(k).copied().unwrap_or_default() {
            data.extend_from_slice(r);
        }
        if more {
            data.push(dif::MORE);
        }
        wire::rsp_ud(self.address, 0x72, &data)
    }

    /// Every record's bytes: registers, gauges, then the fabrication number.
    fn records(&self, now: f64) -> Vec<Vec<u8>> {
        let mut out: Vec<Vec<u8>> = self.registers.iter().map(|r| r.record(now)).collect();
        out.extend(self.gauges.iter().map(Gauge::record));
        out.push(
            [
                vec![dif::BCD8, vif::FABRICATION],
                wire::bcd(u64::from(self.id), 4),
            ]
            .concat(),
        );
        out
    }

    /// What a broken transceiver sends: frames with a bad checksum, lengths that differ, or
    /// noise, in turn.
    pub(super) fn garbage(&mut self) -> Vec<u8> {
        self.access = self.access.wrapping_add(1);
        match self.access % 3 {
            0 => vec![
                0x68,
                0x05,
                0x05,
                0x68,
                0x08,
                self.address,
                0x72,
                0x00,
                0x00,
                0x00,
                0x16,
            ],
            1 => vec![0x68, 0x09, 0x04, 0x68, 0x08],
            _ => vec![0x3C, 0xA5, 0x00, self.access],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_8_digit_bcd_register_rolls_over_at_10_to_the_8() {
        let r = Register::new(Quantity::EnergyWh, Width::Bcd8, 99_999_990, 10.0);
        assert_eq!(r.count(0.0), 99_999_990);
        assert_eq!(r.count(2.0), 10);
        assert_eq!(r.counted(2.0), 100_000_010);
        assert_eq!(r.record(2.0), [dif::BCD8, vif::WH, 0x10, 0x00, 0x00, 0x00]);
    }

    #[test]
    fn a_32_bit_register_rolls_over_at_2_to_the_32() {
        let r = Register::new(Quantity::VolumeLitre, Width::Int32, (1 << 32) - 1, 1.0);
        assert_eq!(r.count(1.0), 0);
    }

    #[test]
    fn a_replaced_meter_has_a_new_id_and_starts_low() {
        let mut m = SimMeter::new(12345678, "KAM", 1, 4, 0).with_register(Register::new(
            Quantity::EnergyKwh,
            Width::Bcd8,
            5000,
            1.0,
        ));
        m.replace(10.0, 87654321);
        assert_eq!(m.id, 87654321);
        assert_eq!(m.registers[0].count(12.0), 2);
    }
}
