//! The registers a Modbus server output serves, built from the gateway's events: each device's
//! words as of its last poll. A poll's readings replace a device's words whole (a new `Arc`),
//! so a request, which reads one device's words once, never sees half of one poll and half of
//! the next: a 64-bit total is never torn. Pure: events and time in, words out.

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::Arc;
use std::time::SystemTime;

use crate::modbus::config::server::map::{
    BLOCK, CHANNEL_FIELDS, DEVICE_FIELDS, DeviceMap, RegisterMap, Type, result,
};
use crate::reading::{Output, Reading};

/// One device's words and what its device block says at read time.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceWords {
    pub map: Arc<DeviceMap>,
    /// From address 0 to the end of its last block.
    pub words: Arc<[u16]>,
    pub online: bool,
    /// When its last answer arrived.
    pub last_answer: Option<SystemTime>,
    /// The addresses in its blocks, as runs of adjacent blocks: a read must lie in one.
    spans: Arc<[Range<u32>]>,
}

impl DeviceWords {
    fn new(map: DeviceMap) -> DeviceWords {
        let mut words = vec![0u16; map.end() as usize];
        for base in map.channels.values() {
            for f in CHANNEL_FIELDS
                .iter()
                .filter(|f| f.ty == Type::F64 || f.ty == Type::F32)
            {
                put(&mut words, base + f.offset, f.ty, Value::Float(f64::NAN));
            }
        }
        DeviceWords {
            spans: spans(&map).into(),
            map: Arc::new(map),
            words: words.into(),
            online: false,
            last_answer: None,
        }
    }

    /// `count` registers from `address`, with the device block as of `now`; `None` when they
    /// are not all in the map (beyond its end, or in a gap a pinned block or an unpicked
    /// record leaves: read as zeros, a wrong address in a PLC program would go unnoticed).
    pub fn read(&self, address: u16, count: u16, now: SystemTime) -> Option<Vec<u16>> {
        let (start, end) = (u32::from(address), u32::from(address) + u32::from(count));
        let inside = self.spans.iter().any(|s| s.start <= start && end <= s.end);
        if !inside || count == 0 {
            return None;
        }
        let end = end as usize;
        let mut out = self.words[usize::from(address)..end].to_vec();
        let mut head = self.words[..usize::from(BLOCK)].to_vec();
        put(
            &mut head,
            DEVICE_FIELDS[0].offset,
            Type::U16,
            Value::Int(i64::from(self.online)),
        );
        let age = self.last_answer.map_or(u64::from(u32::MAX), |t| {
            now.duration_since(t)
                .map_or(0, |d| d.as_secs())
                .min(u64::from(u32::MAX - 1))
        });
        put(
            &mut head,
            DEVICE_FIELDS[1].offset,
            Type::U32,
            Value::Int(age as i64),
        );
        for (i, w) in out.iter_mut().enumerate() {
            let a = usize::from(address) + i;
            if a < usize::from(BLOCK) {
                *w = head[a];
            }
        }
        Some(out)
    }
}

/// The device block and every channel block of `map`, adjacent blocks joined.
fn spans(map: &DeviceMap) -> Vec<Range<u32>> {
    let mut bases: Vec<u32> = map.channels.values().map(|b| u32::from(*b)).collect();
    bases.push(0);
    bases.sort_unstable();
    let mut out: Vec<Range<u32>> = Vec::new();
    for base in bases {
        let block = base..base + u32::from(BLOCK);
        match out.last_mut() {
            Some(last) if last.end >= block.start => last.end = last.end.max(block.end),
            _ => out.push(block),
        }
    }
    out
}

/// Every device's words, by unit id.
#[derive(Debug, Clone, Default)]
pub struct Image {
    pub units: BTreeMap<u8, DeviceWords>,
    by_device: BTreeMap<String, u8>,
}

impl Image {
    /// Zeros (and NaN) for every device of `map`: nothing read yet, every device offline.
    pub fn new(map: &RegisterMap) -> Image {
        let units: BTreeMap<u8, DeviceWords> = map
            .units
            .iter()
            .map(|(u, d)| (*u, DeviceWords::new(d.clone())))
            .collect();
        let by_device = units
            .iter()
            .map(|(u, d)| (d.map.device.clone(), *u))
            .collect();
        Image { units, by_device }
    }

    /// The same devices with a new map: what was read is kept where a device and its channels
    /// still are.
    pub fn remap(&self, map: &RegisterMap) -> Image {
        let mut next = Image::new(map);
        for (unit, d) in next.units.iter_mut() {
            let Some(old) = self.device(&d.map.device) else {
                continue;
            };
            d.online = old.online;
            d.last_answer = old.last_answer;
            let mut words = d.words.to_vec();
            for (name, base) in &d.map.channels {
                if let Some(old_base) = old.map.channels.get(name) {
                    let (from, to) = (usize::from(*old_base), usize::from(*base));
                    let n = usize::from(BLOCK);
                    words[to..to + n].copy_from_slice(&old.words[from..from + n]);
                }
            }
            d.words = words.into();
            let _ = unit;
        }
        next
    }

    fn device(&self, name: &str) -> Option<&DeviceWords> {
        self.units.get(self.by_device.get(name)?)
    }

    /// The unit id `device` answers as.
    pub fn unit_of(&self, device: &str) -> Option<u8> {
        self.by_device.get(device).copied()
    }

    /// What an event changes. `true` when it changed something.
    pub fn apply(&mut self, event: &Output) -> bool {
        match event {
            Output::DeviceReadings { device, readings } => self.readings(device, readings),
            Output::DeviceStatus { device, online } => self.status(device, *online),
            Output::DeviceProblem { device, .. } => self.status(device, false),
            _ => false,
        }
    }

    fn status(&mut self, device: &str, online: bool) -> bool {
        let Some(unit) = self.by_device.get(device) else {
            return false;
        };
        let d = self.units.get_mut(unit).expect("indexed");
        d.online = online;
        true
    }

    fn readings(&mut self, device: &str, readings: &[Reading]) -> bool {
        let Some(unit) = self.by_device.get(device) else {
            return false;
        };
        let d = self.units.get_mut(unit).expect("indexed");
        let mut words = d.words.to_vec();
        for r in readings {
            let Some(base) = d.map.channels.get(&*r.channel) else {
                continue;
            };
            write_reading(&mut words, *base, r);
            d.last_answer = Some(d.last_answer.map_or(r.ts, |t| t.max(r.ts)));
        }
        d.online = true;
        d.words = words.into();
        true
    }

    /// The device block's command fields after a write to `channel_base`.
    pub fn command(&mut self, unit: u8, channel_base: u16, outcome: u16) {
        let Some(d) = self.units.get_mut(&unit) else {
            return;
        };
        let mut words = d.words.to_vec();
        put(
            &mut words,
            DEVICE_FIELDS[2].offset,
            Type::U16,
            Value::Int(i64::from(outcome)),
        );
        put(
            &mut words,
            DEVICE_FIELDS[3].offset,
            Type::U16,
            Value::Int(i64::from(channel_base)),
        );
        d.words = words.into();
    }
}

/// A reading's fields into its block.
fn write_reading(words: &mut [u16], base: u16, r: &Reading) {
    let field = |name: &str| {
        CHANNEL_FIELDS
            .iter()
            .find(|f| f.name == name)
            .expect("a field")
    };
    let value = match &r.measured {
        Some(m) => m.to_f64().unwrap_or(f64::NAN),
        None => r
            .units
            .as_ref()
            .and_then(|u| u.scale.as_ref())
            .map_or(f64::NAN, |s| r.update.total as f64 * s.to_f64()),
    };
    let (total, rate) = match &r.measured {
        Some(_) => (0, f64::NAN),
        None => (
            r.update.total,
            r.update.rate_hz.or(r.freq_hz).unwrap_or(f64::NAN),
        ),
    };
    for (name, v) in [
        ("total", Value::Int(total)),
        ("rate", Value::Float(rate)),
        (
            "seq",
            Value::Int((r.update.seq & u64::from(u32::MAX)) as i64),
        ),
        ("value", Value::Float(value)),
    ] {
        let f = field(name);
        put(words, base + f.offset, f.ty, v);
    }
}

#[derive(Debug, Clone, Copy)]
enum Value {
    Int(i64),
    Float(f64),
}

/// `v` as `ty` at `address`, high word first.
fn put(words: &mut [u16], address: u16, ty: Type, v: Value) {
    let bytes: Vec<u8> = match (ty, v) {
        (Type::U16, Value::Int(i)) => (i as u16).to_be_bytes().to_vec(),
        (Type::U32, Value::Int(i)) => (i as u32).to_be_bytes().to_vec(),
        (Type::I64, Value::Int(i)) => i.to_be_bytes().to_vec(),
        (Type::F32, Value::Float(f)) => (f as f32).to_be_bytes().to_vec(),
        (Type::F64, Value::Float(f)) => f.to_be_bytes().to_vec(),
        (Type::F32, Value::Int(i)) => (i as f32).to_be_bytes().to_vec(),
        (Type::F64, Value::Int(i)) => (i as f64).to_be_bytes().to_vec(),
        (_, Value::Float(f)) => {
            (f as i64).to_be_bytes()[8 - 2 * ty.registers() as usize..].to_vec()
        }
    };
    for (i, pair) in bytes.chunks(2).enumerate() {
        if let Some(w) = words.get_mut(usize::from(address) + i) {
            *w = u16::from_be_bytes([pair[0], pair[1]]);
        }
    }
}

/// The i64 in four registers, high word first (a preset written with function 16).
pub fn i64_of(words: &[u16]) -> Option<i64> {
    let w: [u16; 4] = words.try_into().ok()?;
    let mut b = [0u8; 8];
    for (i, x) in w.iter().enumerate() {
        b[2 * i..2 * i + 2].copy_from_slice(&x.to_be_bytes());
    }
    Some(i64::from_be_bytes(b))
}

/// The device block's `result` for a command's outcome, read from its type: `FAILED` when the
/// command reached the device and the write or its read-back failed (or it never answered),
/// `REFUSED` when it was turned down before anything was written (a value out of range, busy,
/// commands off, a device that cannot be written).
pub fn result_code(outcome: &crate::outcome::Outcome) -> u16 {
    use crate::command::CommandError;
    let crate::outcome::Outcome::Command(c) = outcome else {
        return result::FAILED;
    };
    match &c.result {
        Ok(_) => result::DONE,
        Err(
            CommandError::Offline(_) | CommandError::WriteFailed(_) | CommandError::ReadBack { .. },
        ) => result::FAILED,
        Err(_) => result::REFUSED,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::CommandError;
    use crate::outcome::{CommandOutcome, Outcome};

    fn outcome(result: Result<Option<i64>, CommandError>) -> Outcome {
        Outcome::Command(CommandOutcome {
            id: Some("modbus-plc-1-0".into()),
            op: Some("preset".into()),
            result,
        })
    }

    #[test]
    fn a_read_in_the_gap_a_pinned_block_leaves_is_outside_the_map() {
        let map = DeviceMap {
            device: "pack".into(),
            unit: 40,
            channels: [("di1".to_string(), 20), ("di2".to_string(), 1000)].into(),
        };
        let d = DeviceWords::new(map);
        let now = SystemTime::now();
        let reads = |a: u16, n: u16| d.read(a, n, now).map(|w| w.len());
        assert_eq!(
            reads(0, 40),
            Some(40),
            "the device's block and di1's, adjacent"
        );
        assert_eq!(reads(20, 20), Some(20));
        assert_eq!(reads(1000, 20), Some(20), "the pinned block");
        assert_eq!(reads(40, 1), None, "di2's place before the pin: a gap");
        assert_eq!(reads(30, 20), None, "from di1 into the gap");
        assert_eq!(reads(500, 4), None);
        assert_eq!(reads(999, 2), None, "into the pinned block from the gap");
        assert_eq!(reads(1019, 2), None, "past the end");
        assert_eq!(reads(0, 0), None);
    }

    #[test]
    fn a_preset_out_of_range_or_a_busy_device_is_refused_not_failed() {
        let out_of_range = CommandError::OutOfRange {
            channel: "a0".into(),
            value: -5,
        };
        assert_eq!(result_code(&outcome(Err(out_of_range))), result::REFUSED);
        let busy = CommandError::Busy {
            device: "m".into(),
            why: "too many commands",
        };
        assert_eq!(result_code(&outcome(Err(busy))), result::REFUSED);
        let meter = CommandError::NotWritable {
            device: "heat".into(),
            why: "an M-Bus meter",
        };
        assert_eq!(result_code(&outcome(Err(meter))), result::REFUSED);
        let off = CommandError::Disabled("m".into());
        assert_eq!(result_code(&outcome(Err(off))), result::REFUSED);
    }

    #[test]
    fn a_write_that_failed_or_was_never_answered_is_failed_and_one_read_back_is_done() {
        let failed = [
            CommandError::Offline("m".into()),
            CommandError::WriteFailed("exception 02".into()),
            CommandError::ReadBack {
                expected: 0,
                got: 12,
            },
        ];
        for e in failed {
            assert_eq!(result_code(&outcome(Err(e))), result::FAILED);
        }
        assert_eq!(result_code(&outcome(Ok(Some(0)))), result::DONE);
    }
}
