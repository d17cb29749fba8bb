//! Device profiles: what a module model looks like on the wire, as data.
//!
//! A profile says which registers hold the work mode of each group of inputs, and for each work
//! mode which channels exist and where their count, frequency, rpm and pulses-per-revolution
//! live. The gateway reads the work modes at start and asks the profile for the channels
//! ([`Profile::channels`]); no register address of a module appears in code outside its profile.

mod builtin;
mod raw;
mod settings;

use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

/// Longest answer timeout, of a profile or of a bus or device in the config (a module that
/// needs longer is not answering).
pub const MAX_TIMEOUT: Duration = Duration::from_secs(60);

pub use raw::{ChannelKind, ValueType, WordOrder};
pub use settings::{Allowed, Applies, Place, Setting, SettingError};

/// A profile could not be loaded or is inconsistent.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    #[error("profile {origin}: {source}")]
    Parse {
        origin: String,
        source: Box<toml::de::Error>,
    },
    #[error("profile {origin}: {message}")]
    Invalid { origin: String, message: String },
    #[error("profile directory {dir}: {source}")]
    Dir { dir: String, source: std::io::Error },
}

/// The work mode a module reported is not described by its profile.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{group} {instance}: work mode {value} is not described by profile {model}")]
pub struct UnknownMode {
    pub model: String,
    pub group: String,
    pub instance: u16,
    pub value: u16,
}

/// One register (or register pair) with its type, resolved to an address.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Register {
    pub address: u16,
    pub ty: ValueType,
}

impl Register {
    /// Number of 16-bit registers the value spans.
    #[allow(clippy::len_without_is_empty)] // a register is never empty
    pub fn len(&self) -> u16 {
        self.ty.words()
    }

    /// One past the last register of the value.
    pub fn end(&self) -> u16 {
        self.address + self.len()
    }
}

/// How to clear one channel: write `code` to `register`; where `restart` is set, the register
/// also starts and stops the counter (ZH-YX1600), so the gateway reads it first and writes back
/// the running direction after the clear.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClearSpec {
    pub register: u16,
    pub code: u16,
    pub restart: Vec<u16>,
    /// The code that pauses the counter, where the register runs it.
    pub pause: Option<u16>,
}

/// A single register write of a fixed code (clear-all).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CodeWrite {
    pub register: u16,
    pub code: u16,
}

/// A channel of a module in its current work mode, with every address resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSpec {
    pub name: String,
    pub kind: ChannelKind,
    pub count: Register,
    pub freq: Option<Register>,
    pub rpm: Option<Register>,
    pub ppr: Option<Register>,
    pub clear: ClearSpec,
    /// The module keeps this count across power loss (unless autosave is off).
    pub retains_count: bool,
    /// Highest input rate the module can count on this channel: a larger jump is a reset.
    pub max_rate_hz: f64,
    /// The clear-all write that covers this channel, where the mode has one.
    pub clear_all: Option<CodeWrite>,
    /// Values a preset may write (inclusive), where the datasheet narrows the register's range.
    pub preset_range: Option<(i64, i64)>,
    /// The frequency register counts pulses over this window (ZH-YX1600), not Hz.
    pub freq_window: Option<FreqWindow>,
    /// The mode word this channel's existence depends on.
    pub mode_register: u16,
    /// Where the module keeps the counter's run state after power-up.
    pub power_on: Option<PowerOn>,
}

/// The power-on run state of a counter: `mask` bits of the word at `address`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PowerOn {
    pub address: u16,
    pub mask: u16,
    pub up: u16,
    pub down: u16,
}

impl PowerOn {
    /// `word` with its power-on bits set to count up (`down == false`) or down; other bits kept.
    pub fn apply(&self, word: u16, down: bool) -> u16 {
        (word & !self.mask) | if down { self.down } else { self.up }
    }
}

/// A frequency register that holds the pulses counted in a window set by another register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FreqWindow {
    pub register: Register,
    pub unit_ms: u32,
    pub zero_ms: u32,
}

/// Longest window taken as real: a day. A larger value is not a window the module was set to
/// (the ZH-YX1600 datasheet puts live lower limits, 0x8000_0000 at the factory, at addresses
/// that overlap the windows).
pub const LONGEST_WINDOW_MS: u64 = 24 * 3600 * 1000;

impl FreqWindow {
    /// The window in seconds for a register value, or `None` when the value cannot be a window.
    pub fn seconds(&self, raw: u64) -> Option<f64> {
        let ms = if raw == 0 {
            u64::from(self.zero_ms)
        } else {
            raw.checked_mul(u64::from(self.unit_ms))?
        };
        (ms > 0 && ms <= LONGEST_WINDOW_MS).then(|| ms as f64 / 1000.0)
    }
}

impl ChannelSpec {
    /// The register that starts and stops the counter, where the module has one (ZH-YX1600):
    /// the clear register of a channel whose clear restarts it.
    pub fn command_register(&self) -> Option<Register> {
        (!self.clear.restart.is_empty()).then_some(Register {
            address: self.clear.register,
            ty: ValueType::U16,
        })
    }

    /// The registers every poll reads for this channel: count, frequency and run state. `check`
    /// prints the plan of these, and the bus executes it.
    pub fn polled(&self) -> impl Iterator<Item = Register> + '_ {
        std::iter::once(self.count)
            .chain(self.freq)
            .chain(self.command_register())
    }

    /// Whether a preset value fits the channel's count register.
    pub fn accepts_preset(&self, value: i64) -> bool {
        if let Some((lo, hi)) = self.preset_range
            && !(lo..=hi).contains(&value)
        {
            return false;
        }
        match self.count.ty {
            ValueType::I32 => i32::try_from(value).is_ok(),
            ValueType::U32 => u32::try_from(value).is_ok(),
            ValueType::I16 => i16::try_from(value).is_ok(),
            ValueType::U16 => u16::try_from(value).is_ok(),
            ValueType::F32 => false,
        }
    }
}

/// The mode register of one instance of a group.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModeRegister {
    pub group: usize,
    pub instance: u16,
    pub address: u16,
    pub mask: u16,
    /// A second mode word that must agree with this one under `mask`.
    pub partner: Option<u16>,
}

/// A checked module profile.
#[derive(Debug, Clone)]
pub struct Profile {
    pub model: String,
    pub aliases: Vec<String>,
    pub title: String,
    /// Maker of `model` (an alias may come from another maker).
    pub manufacturer: Option<String>,
    pub word_order: WordOrder,
    pub answer_timeout: Duration,
    pub bauds: Vec<u32>,
    /// The factory Modbus TCP port of the Ethernet model, where the datasheet gives one.
    pub tcp_port: Option<u16>,
    pub identify: Option<(u16, Vec<u16>)>,
    pub autosave: Option<u16>,
    /// A hash of the profile's text: a reload sees an edited profile file.
    pub fingerprint: u64,
    /// Settings `pulsegate setup` may write, by name (`unit`, `baud`, ...).
    pub settings: BTreeMap<String, Setting>,
    groups: Vec<raw::Group>,
}

impl Profile {
    /// What a device whose channels are found when it answers has in the place of a profile
    /// (an M-Bus meter: its channels are its answer's records): no registers and no channels,
    /// its protocol's name for it as the model, the baud rates and answer timeout its protocol
    /// gives.
    pub fn answered(model: &str, title: &str, bauds: &[u32], answer_timeout: Duration) -> Profile {
        Profile {
            model: model.into(),
            aliases: Vec::new(),
            title: title.into(),
            manufacturer: None,
            word_order: WordOrder::LowFirst,
            answer_timeout,
            bauds: bauds.to_vec(),
            tcp_port: None,
            identify: None,
            autosave: None,
            fingerprint: 0,
            settings: BTreeMap::new(),
            groups: Vec::new(),
        }
    }

    /// Parses and checks a profile from TOML text; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Profile, ProfileError> {
        let raw: raw::Profile = toml::from_str(text).map_err(|e| ProfileError::Parse {
            origin: origin.to_string(),
            source: Box::new(e),
        })?;
        let invalid = |message: String| ProfileError::Invalid {
            origin: origin.to_string(),
            message,
        };
        let settings = raw
            .settings
            .into_iter()
            .map(|(name, s)| Setting::from_raw(&name, s).map(|s| (name, s)))
            .collect::<Result<BTreeMap<_, _>, _>>()
            .map_err(invalid)?;
        settings::check(&settings, &raw.bauds).map_err(invalid)?;
        let profile = Profile {
            model: raw.model,
            aliases: raw.aliases,
            title: raw.title,
            manufacturer: raw.manufacturer,
            word_order: raw.word_order,
            answer_timeout: raw.answer_timeout,
            bauds: raw.bauds,
            tcp_port: raw.tcp_port,
            identify: raw.identify.map(|i| (i.address, i.words)),
            autosave: raw.autosave.map(|a| a.address),
            fingerprint: {
                use std::hash::{Hash, Hasher};
                let mut h = std::collections::hash_map::DefaultHasher::new();
                text.hash(&mut h);
                h.finish()
            },
            settings,
            groups: raw.groups,
        };
        profile.check().map_err(|message| ProfileError::Invalid {
            origin: origin.to_string(),
            message,
        })?;
        Ok(profile)
    }

    /// The setting `name`, or an error listing the ones the datasheet documents.
    pub fn setting(&self, name: &str) -> Result<&Setting, SettingError> {
        self.settings
            .get(name)
            .ok_or_else(|| SettingError::Unknown {
                model: self.model.clone(),
                name: name.to_string(),
                known: self.settings.keys().cloned().collect::<Vec<_>>().join(", "),
            })
    }

    /// Every mode register the gateway reads at start, in group and instance order.
    pub fn mode_registers(&self) -> Vec<ModeRegister> {
        let mut out = Vec::new();
        for (g, group) in self.groups.iter().enumerate() {
            for i in 0..group.instances {
                out.push(ModeRegister {
                    group: g,
                    instance: i,
                    address: group.mode.address + i * group.mode.stride,
                    mask: group.mode.mask,
                    partner: group
                        .mode
                        .partner
                        .map(|o| group.mode.address + i * group.mode.stride + o),
                });
            }
        }
        out
    }

    /// The channels of a module whose mode registers (in [`Profile::mode_registers`] order)
    /// read `modes`, raw: the profile applies each register's mask.
    pub fn channels(&self, modes: &[u16]) -> Result<Vec<ChannelSpec>, UnknownMode> {
        let mut out = Vec::new();
        for (reg, &raw_value) in self.mode_registers().iter().zip(modes) {
            let group = &self.groups[reg.group];
            let value = raw_value & reg.mask;
            let mode = group
                .modes
                .iter()
                .find(|m| m.value == value)
                .ok_or_else(|| UnknownMode {
                    model: self.model.clone(),
                    group: group.name.clone(),
                    instance: reg.instance,
                    value,
                })?;
            for ch in &mode.channels {
                let mut c = resolve(ch, reg.instance, mode.clear_all);
                c.mode_register = reg.address;
                out.push(c);
            }
        }
        Ok(out)
    }

    /// Every channel the module can have in any mode, for checking user config and for the
    /// simulator; a name may appear more than once (one per mode).
    pub fn all_channels(&self) -> Vec<ChannelSpec> {
        let mut out = Vec::new();
        for group in &self.groups {
            for i in 0..group.instances {
                for mode in &group.modes {
                    for ch in &mode.channels {
                        let mut c = resolve(ch, i, mode.clear_all);
                        c.mode_register = group.mode.address + i * group.mode.stride;
                        out.push(c);
                    }
                }
            }
        }
        out
    }

    /// Every address, code and number a profile can produce stays within u16, every rate is
    /// positive: checked in u32 before anything is resolved, so a user profile cannot make the
    /// gateway overflow.
    fn check_ranges(&self) -> Result<(), String> {
        let fits = |what: &str, base: u16, stride: u16, n: u16, width: u32| {
            let last = u32::from(base) + u32::from(n.saturating_sub(1)) * u32::from(stride);
            if last + width > 0x1_0000 {
                Err(format!(
                    "{what}: register or value {last} (+{width}) is beyond 65535"
                ))
            } else {
                Ok(())
            }
        };
        if self.answer_timeout.is_zero() || self.answer_timeout > MAX_TIMEOUT {
            return Err("answer_timeout must be between 1ms and 60s".into());
        }
        if let Some((address, words)) = &self.identify {
            let n = u32::try_from(words.len()).unwrap_or(u32::MAX);
            if u32::from(*address) + n > 0x1_0000 || words.len() > 125 {
                return Err("identify: registers beyond 65535 or more than 125".into());
            }
        }
        for g in &self.groups {
            if g.instances == 0 {
                return Err(format!("group {} has no instances", g.name));
            }
            let n = g.instances;
            fits(
                &format!("group {} mode", g.name),
                g.mode.address,
                g.mode.stride,
                n,
                1,
            )?;
            for mode in &g.modes {
                for ch in &mode.channels {
                    let what = format!("channel {}", ch.name);
                    if !(ch.max_rate_hz > 0.0 && ch.max_rate_hz.is_finite()) {
                        return Err(format!("{what}: max_rate_hz must be greater than zero"));
                    }
                    fits(&what, ch.number.base, ch.number.stride, n, 0)?;
                    for r in [
                        Some(&ch.count),
                        ch.freq.as_ref(),
                        ch.rpm.as_ref(),
                        ch.ppr.as_ref(),
                    ]
                    .into_iter()
                    .flatten()
                    {
                        fits(&what, r.address, r.stride, n, u32::from(r.ty.words()))?;
                    }
                    fits(&what, ch.clear.address, ch.clear.stride, n, 1)?;
                    fits(&what, ch.clear.code, ch.clear.code_stride, n, 0)?;
                }
            }
        }
        Ok(())
    }

    fn check(&self) -> Result<(), String> {
        if self.model.is_empty() {
            return Err("model name is empty".into());
        }
        self.check_ranges()?;
        if self.groups.is_empty() {
            return Err("no groups of channels".into());
        }
        for g in &self.groups {
            if g.modes.is_empty() {
                return Err(format!("group {} has no modes", g.name));
            }
        }
        // Channel names must be unique whatever the modes: check with every group in its k-th
        // mode (or its last, for groups with fewer), for each k.
        let most_modes = self.groups.iter().map(|g| g.modes.len()).max().unwrap_or(1);
        for k in 0..most_modes {
            let modes: Vec<u16> = self
                .mode_registers()
                .iter()
                .map(|r| {
                    let g = &self.groups[r.group];
                    g.modes[k.min(g.modes.len() - 1)].value
                })
                .collect();
            let channels = self.channels(&modes).map_err(|e| e.to_string())?;
            let mut seen = std::collections::BTreeSet::new();
            for ch in &channels {
                if !seen.insert(ch.name.clone()) {
                    return Err(format!("channel name {} appears twice", ch.name));
                }
                if !crate::topics::is_topic_safe(&ch.name) {
                    return Err(format!("channel name {:?} is not safe in a topic", ch.name));
                }
                if ch.count.end() as u32 > 0xFFFF {
                    return Err(format!("channel {} count register out of range", ch.name));
                }
            }
        }
        Ok(())
    }
}

fn resolve(ch: &raw::ChannelTemplate, i: u16, clear_all: Option<raw::CodeTemplate>) -> ChannelSpec {
    let at = |t: &raw::RegisterTemplate| Register {
        address: t.address + i * t.stride,
        ty: t.ty,
    };
    let number = ch.number.base + i * ch.number.stride;
    ChannelSpec {
        name: ch.name.replace("{}", &number.to_string()),
        kind: ch.kind,
        count: at(&ch.count),
        freq: ch.freq.as_ref().map(at),
        rpm: ch.rpm.as_ref().map(at),
        ppr: ch.ppr.as_ref().map(at),
        clear: ClearSpec {
            register: ch.clear.address + i * ch.clear.stride,
            code: ch.clear.code + i * ch.clear.code_stride,
            restart: ch.clear.restart.clone(),
            pause: ch.clear.pause,
        },
        retains_count: ch.retains_count,
        max_rate_hz: ch.max_rate_hz,
        clear_all: clear_all.map(|c| CodeWrite {
            register: c.address,
            code: c.code,
        }),
        preset_range: ch.preset_range.map(|[lo, hi]| (lo, hi)),
        freq_window: ch.freq_window.map(|w| FreqWindow {
            register: Register {
                address: w.address + i * w.stride,
                ty: w.ty,
            },
            unit_ms: w.unit_ms,
            zero_ms: w.zero_ms,
        }),
        mode_register: 0,
        power_on: ch.power_on.map(|p| PowerOn {
            address: p.address + i * p.stride,
            mask: p.mask,
            up: p.up,
            down: p.down,
        }),
    }
}

/// All known profiles by model name and alias: the built-in ones plus `*.toml` files in `dir`.
#[derive(Debug, Clone, Default)]
pub struct Profiles {
    by_name: BTreeMap<String, std::sync::Arc<Profile>>,
}

impl Profiles {
    /// The built-in profiles only.
    pub fn builtin() -> Profiles {
        let mut p = Profiles::default();
        for profile in builtin_profiles() {
            p.insert(profile);
        }
        p
    }

    /// Built-in profiles plus every `*.toml` in `dir` (a user profile may replace a built-in).
    pub fn with_dir(dir: &Path) -> Result<Profiles, Vec<ProfileError>> {
        let mut p = Profiles::builtin();
        let mut errors = Vec::new();
        let entries = match std::fs::read_dir(dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(p),
            Err(source) => {
                return Err(vec![ProfileError::Dir {
                    dir: dir.display().to_string(),
                    source,
                }]);
            }
        };
        let mut paths: Vec<_> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "toml"))
            .collect();
        paths.sort();
        for path in paths {
            let origin = path.display().to_string();
            match std::fs::read_to_string(&path) {
                Ok(text) => match Profile::from_toml(&text, &origin) {
                    Ok(profile) => p.insert(profile),
                    Err(e) => errors.push(e),
                },
                Err(source) => errors.push(ProfileError::Dir {
                    dir: origin,
                    source,
                }),
            }
        }
        if errors.is_empty() {
            Ok(p)
        } else {
            Err(errors)
        }
    }

    fn insert(&mut self, profile: Profile) {
        let profile = std::sync::Arc::new(profile);
        self.by_name.insert(profile.model.clone(), profile.clone());
        for alias in &profile.aliases {
            self.by_name.insert(alias.clone(), profile.clone());
        }
    }

    /// The profile for a model name or alias.
    pub fn get(&self, model: &str) -> Option<std::sync::Arc<Profile>> {
        self.by_name.get(model).cloned()
    }

    /// Known model names and aliases, for error messages.
    pub fn names(&self) -> Vec<&str> {
        self.by_name.keys().map(String::as_str).collect()
    }
}

/// The built-in profiles; they are checked by the test suite, so a failure here is a build bug.
pub fn builtin_profiles() -> Vec<Profile> {
    builtin::BUILTIN
        .iter()
        .map(|(name, text)| {
            Profile::from_toml(text, &format!("(built-in) {name}"))
                .unwrap_or_else(|e| panic!("built-in profile is broken: {e}"))
        })
        .collect()
}

#[cfg(test)]
mod tests;
