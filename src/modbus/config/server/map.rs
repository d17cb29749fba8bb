//! The register map of a Modbus server output: a contract with the PLC programs that read it,
//! so it follows from the config alone (`pulsegate check --register-map` prints it without a
//! module on the line) and nothing that was in it moves when a device or a channel is added.
//!
//! Every device answers as its own unit id: its `server_unit`, by default its own address
//! (a Modbus module's `unit`, an M-Bus meter's primary address), as a transparent gateway maps
//! them. Its registers, readable as input registers (function 04) and, the same values, as
//! holding registers (function 03), are blocks of [`BLOCK`] registers:
//!
//! - block 0 at address 0, the device: `online` (1/0), `age` (seconds since its last answer,
//!   `0xFFFFFFFF` before the first), and the last command's `result` and the `command_channel`
//!   (the first address of the channel block it was written to);
//! - one block per channel: `total` (i64), `rate` (f32, pulses a second), `seq` (u32, the low
//!   32 bits), `value` (f64: the total in the channel's unit, a gauge's value; NaN when it has
//!   none), and the command registers `clear` (write 1) and `preset` (write the i64 with one
//!   function 16).
//!
//! A Modbus module's channel `k` of its model's channel list (every channel any work mode gives
//! it, in the profile's order) is block `k + 1`: the map is the same whatever mode the module is
//! in, and a channel never moves. An M-Bus meter's channel picking record `r` is block `r + 1`;
//! channels named without `record` follow the highest record, in name order. `register = N` on a
//! channel pins its block at address `N`. Words are big-endian and multi-register values high
//! word first, as Modbus convention has it.

use std::collections::BTreeMap;

use crate::config::model::{Bus, Config, Device};

use crate::config::walk::Errors;

/// Registers in a block.
pub const BLOCK: u16 = 20;

/// `result` of the device block: what became of the last command written to it.
pub mod result {
    /// No command yet.
    pub const NONE: u16 = 0;
    /// Written, not yet answered.
    pub const PENDING: u16 = 1;
    pub const DONE: u16 = 2;
    pub const REFUSED: u16 = 3;
    pub const FAILED: u16 = 4;
}

/// The type of a field's registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Type {
    U16,
    U32,
    I64,
    F32,
    F64,
}

impl Type {
    pub fn registers(self) -> u16 {
        match self {
            Type::U16 => 1,
            Type::U32 | Type::F32 => 2,
            Type::I64 | Type::F64 => 4,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Type::U16 => "uint16",
            Type::U32 => "uint32",
            Type::I64 => "int64",
            Type::F32 => "float32",
            Type::F64 => "float64",
        }
    }
}

/// A field of a block: its name, offset in the block and type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    pub name: &'static str,
    pub offset: u16,
    pub ty: Type,
    /// Written by a client (with `commands = true`), read back as 0.
    pub command: bool,
}

const fn field(name: &'static str, offset: u16, ty: Type) -> Field {
    Field {
        name,
        offset,
        ty,
        command: false,
    }
}

/// The device block's fields.
pub const DEVICE_FIELDS: [Field; 4] = [
    field("online", 0, Type::U16),
    field("age", 1, Type::U32),
    field("result", 3, Type::U16),
    field("command_channel", 4, Type::U16),
];

/// A channel block's fields.
pub const CHANNEL_FIELDS: [Field; 6] = [
    field("total", 0, Type::I64),
    field("rate", 4, Type::F32),
    field("seq", 6, Type::U32),
    field("value", 8, Type::F64),
    Field {
        command: true,
        ..field("clear", 12, Type::U16)
    },
    Field {
        command: true,
        ..field("preset", 13, Type::I64)
    },
];

/// Where a channel's block starts, by field.
pub fn offset_of(name: &str) -> Option<u16> {
    CHANNEL_FIELDS
        .iter()
        .find(|f| f.name == name)
        .map(|f| f.offset)
}

/// One device's registers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceMap {
    pub device: String,
    pub unit: u8,
    /// Channel name → the first address of its block.
    pub channels: BTreeMap<String, u16>,
}

impl DeviceMap {
    /// One past the last address served.
    pub fn end(&self) -> u32 {
        let last = self.channels.values().max().copied().unwrap_or(0);
        u32::from(last) + u32::from(BLOCK)
    }

    /// The channel whose block holds `address`, and the offset in it.
    pub fn channel_at(&self, address: u16) -> Option<(&str, u16)> {
        self.channels
            .iter()
            .find(|(_, base)| (**base..base.saturating_add(BLOCK)).contains(&address))
            .map(|(name, base)| (name.as_str(), address - base))
    }
}

/// Every device's registers, by unit id.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RegisterMap {
    pub units: BTreeMap<u8, DeviceMap>,
}

/// One line of the printed map.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Entry {
    pub device: String,
    pub channel: Option<String>,
    pub field: &'static str,
    pub unit_id: u8,
    pub table: &'static str,
    pub address: u16,
    pub registers: u16,
    #[serde(rename = "type")]
    pub ty: &'static str,
}

impl RegisterMap {
    /// The map of a checked config (its collisions and overlaps were refused by the check).
    pub fn of(config: &Config) -> RegisterMap {
        let mut errs = Errors::default();
        RegisterMap::build(&config.buses, &mut errs)
    }

    /// The map of every enabled device of `buses`; collisions and overlaps are errors.
    pub(crate) fn build(buses: &[Bus], errs: &mut Errors) -> RegisterMap {
        let mut map = RegisterMap::default();
        for bus in buses {
            for d in bus.devices.iter().filter(|d| d.enabled) {
                let path = format!("buses.{}.devices.{}", bus.name, d.name);
                let Some(unit) = unit_of(d, &path, errs) else {
                    continue;
                };
                if let Some(other) = map.units.get(&unit) {
                    let why = format!(
                        "answers as unit {unit} on the Modbus server output, as device {} does: give one server_unit = N (1..247)",
                        other.device
                    );
                    errs.push(&format!("{path}.server_unit"), None, why);
                    continue;
                }
                let channels = blocks(d, &path, errs);
                let device = d.name.clone();
                map.units.insert(
                    unit,
                    DeviceMap {
                        device,
                        unit,
                        channels,
                    },
                );
            }
        }
        map
    }

    /// Every field, in unit and address order, as input registers and then, the same, as
    /// holding registers (with the command fields only there).
    pub fn entries(&self, commands: bool) -> Vec<Entry> {
        let mut out = Vec::new();
        for table in ["input", "holding"] {
            for d in self.units.values() {
                let mut lines: Vec<(u16, Option<&str>, Field)> =
                    DEVICE_FIELDS.iter().map(|f| (f.offset, None, *f)).collect();
                for (name, base) in &d.channels {
                    for f in CHANNEL_FIELDS.iter() {
                        if f.command && (table == "input" || !commands) {
                            continue;
                        }
                        lines.push((base + f.offset, Some(name.as_str()), *f));
                    }
                }
                lines.sort_by_key(|l| l.0);
                out.extend(lines.into_iter().map(|(address, channel, f)| Entry {
                    device: d.device.clone(),
                    channel: channel.map(str::to_string),
                    field: f.name,
                    unit_id: d.unit,
                    table,
                    address,
                    registers: f.ty.registers(),
                    ty: f.ty.name(),
                }));
            }
        }
        out
    }
}

/// The unit id a device answers as.
fn unit_of(d: &Device, path: &str, errs: &mut Errors) -> Option<u8> {
    if let Some(u) = d.server_unit {
        return Some(u);
    }
    match d.address.unit_id() {
        Some(u) => Some(u),
        None => {
            let why = "a meter at primary address 0, above 247 or by secondary address has no unit id of its own on the Modbus server output: set server_unit = N (1..247)";
            errs.push(&format!("{path}.server_unit"), None, why);
            None
        }
    }
}

/// Each channel's block: pinned, or placed as the module's documentation says.
fn blocks(d: &Device, path: &str, errs: &mut Errors) -> BTreeMap<String, u16> {
    let placed = placed(d);
    let mut out = BTreeMap::new();
    for (name, index) in placed {
        let pinned = d.channels.get(&name).and_then(|c| c.register);
        let base = match pinned {
            Some(n) => n,
            None => match u16::try_from((index + 1) * usize::from(BLOCK)) {
                Ok(b) if b <= u16::MAX - BLOCK => b,
                _ => {
                    let why = "its block would be beyond address 65535: pin it with register = N";
                    errs.push(&format!("{path}.channels.{name}"), None, why);
                    continue;
                }
            },
        };
        out.insert(name, base);
    }
    overlaps(&out, path, errs);
    out
}

/// The channels of a device with the index of their block before any pin.
fn placed(d: &Device) -> Vec<(String, usize)> {
    if !d.channels_from_device() {
        let mut names: Vec<String> = Vec::new();
        for c in d.profile.all_channels() {
            if !names.contains(&c.name) {
                names.push(c.name);
            }
        }
        return names.into_iter().enumerate().map(|(i, n)| (n, i)).collect();
    }
    let by_record: Vec<(String, usize)> = d
        .channels
        .iter()
        .filter_map(|(n, c)| c.record.map(|r| (n.clone(), r)))
        .collect();
    let next = by_record.iter().map(|(_, r)| r + 1).max().unwrap_or(0);
    let unnumbered = d.channels.iter().filter(|(_, c)| c.record.is_none());
    let rest = unnumbered
        .enumerate()
        .map(|(i, (n, _))| (n.clone(), next + i));
    by_record.into_iter().chain(rest).collect()
}

fn overlaps(blocks: &BTreeMap<String, u16>, path: &str, errs: &mut Errors) {
    let mut sorted: Vec<(&String, u16)> = blocks.iter().map(|(n, b)| (n, *b)).collect();
    sorted.sort_by_key(|(_, b)| *b);
    if let Some((name, base)) = sorted.first()
        && *base < BLOCK
    {
        let why = format!("register {base}: addresses 0..{BLOCK} are the device's own block");
        errs.push(&format!("{path}.channels.{name}.register"), None, why);
    }
    for pair in sorted.windows(2) {
        let ((a, a_base), (b, b_base)) = (pair[0], pair[1]);
        if u32::from(b_base) < u32::from(a_base) + u32::from(BLOCK) {
            let why = format!(
                "its block at {b_base} overlaps channel {a}'s at {a_base} (a block is {BLOCK} registers)"
            );
            errs.push(&format!("{path}.channels.{b}.register"), None, why);
        }
    }
}
