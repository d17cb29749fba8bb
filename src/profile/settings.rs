//! Module settings `pulsegate setup` may write, as profile data: which register, which values
//! the datasheet allows, and whether the module takes the new value at once or after its next
//! power-up. Only settings a datasheet documents are described; there is no factory reset.

use std::collections::BTreeMap;

use serde::Deserialize;

/// When a module takes a written setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Applies {
    /// At once: the next request already sees it (a new unit id answers at once).
    Now,
    /// At the module's next power-up; until then it keeps working with the old value.
    Restart,
    /// The datasheet does not say: at once or after the next power-up.
    Unstated,
}

/// The setting as written in a profile file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSetting {
    /// Register address; absent for a per-channel setting (`channel`).
    pub address: Option<u16>,
    /// The setting lives in each channel's register of this kind (only `ppr` so far).
    pub channel: Option<String>,
    #[serde(default = "one")]
    pub instances: u16,
    #[serde(default)]
    pub stride: u16,
    /// The bits of the register this setting occupies (the rest are kept).
    #[serde(default = "all_bits")]
    pub mask: u16,
    /// Inclusive numeric range of the value.
    pub range: Option<[u16; 2]>,
    /// Named values and their codes.
    #[serde(default)]
    pub values: BTreeMap<String, u16>,
    /// Further codes the module may report for a named value (never written).
    #[serde(default)]
    pub reads: BTreeMap<String, u16>,
    pub applies: Applies,
    /// What the setting is, for people.
    #[serde(default)]
    pub about: String,
}

fn one() -> u16 {
    1
}

fn all_bits() -> u16 {
    0xFFFF
}

/// Which values a setting takes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Allowed {
    /// A number in this inclusive range.
    Range(u16, u16),
    /// One of these names, written as its code; `reads` are further codes for the same names.
    Values {
        codes: BTreeMap<String, u16>,
        reads: BTreeMap<String, u16>,
    },
}

/// Where a setting lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Place {
    /// Fixed registers: `address + i * stride` for each instance `i`.
    Registers {
        address: u16,
        instances: u16,
        stride: u16,
    },
    /// Each channel's register of this kind (`ppr`).
    Channel(String),
}

/// A checked setting.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Setting {
    pub name: String,
    pub place: Place,
    pub mask: u16,
    pub allowed: Allowed,
    pub applies: Applies,
    pub about: String,
}

/// A value refused before anything is written.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SettingError {
    #[error("model {model} has no setting {name:?} in its datasheet (it has: {known})")]
    Unknown {
        model: String,
        name: String,
        known: String,
    },
    #[error("{name} {value:?} is out of the documented range {lo}..={hi}")]
    OutOfRange {
        name: String,
        value: String,
        lo: u16,
        hi: u16,
    },
    #[error("{name} {value:?} is not one of the documented values: {allowed}")]
    NotAllowed {
        name: String,
        value: String,
        allowed: String,
    },
}

impl Setting {
    pub(super) fn from_raw(name: &str, raw: RawSetting) -> Result<Setting, String> {
        let place = match (raw.address, raw.channel) {
            (Some(address), None) => Place::Registers {
                address,
                instances: raw.instances,
                stride: raw.stride,
            },
            (None, Some(kind)) if kind == "ppr" => Place::Channel(kind),
            (None, Some(kind)) => {
                return Err(format!("setting {name}: unknown channel register {kind:?}"));
            }
            _ => {
                return Err(format!(
                    "setting {name}: give either `address` or `channel`"
                ));
            }
        };
        let allowed = match (raw.range, raw.values.is_empty()) {
            (Some([lo, hi]), true) if lo <= hi => Allowed::Range(lo, hi),
            (None, false) => Allowed::Values {
                codes: raw.values,
                reads: raw.reads,
            },
            _ => return Err(format!("setting {name}: give either `range` or `values`")),
        };
        if raw.mask == 0 || raw.instances == 0 {
            return Err(format!("setting {name}: empty mask or no instances"));
        }
        let setting = Setting {
            name: name.to_string(),
            place,
            mask: raw.mask,
            allowed,
            applies: raw.applies,
            about: raw.about,
        };
        let widest = setting.mask >> setting.mask.trailing_zeros();
        let fits = |v: u16| v <= widest;
        let ok = match &setting.allowed {
            Allowed::Range(_, hi) => fits(*hi),
            Allowed::Values { codes, reads } => {
                codes.values().chain(reads.values()).all(|v| fits(*v))
            }
        };
        if !ok {
            return Err(format!("setting {name}: a value does not fit its mask"));
        }
        Ok(setting)
    }

    /// The code to write for `value` (a number or a documented name), checked against the
    /// datasheet's range or values.
    pub fn encode(&self, value: &str) -> Result<u16, SettingError> {
        match &self.allowed {
            Allowed::Range(lo, hi) => {
                let out = || SettingError::OutOfRange {
                    name: self.name.clone(),
                    value: value.to_string(),
                    lo: *lo,
                    hi: *hi,
                };
                let v: u16 = value.trim().parse().map_err(|_| out())?;
                if v < *lo || v > *hi {
                    return Err(out());
                }
                Ok(v)
            }
            Allowed::Values { codes, .. } => {
                codes
                    .get(value.trim())
                    .copied()
                    .ok_or_else(|| SettingError::NotAllowed {
                        name: self.name.clone(),
                        value: value.to_string(),
                        allowed: codes.keys().cloned().collect::<Vec<_>>().join(", "),
                    })
            }
        }
    }

    /// The value a field holds, for people: the number, or the documented name of the code.
    pub fn describe(&self, field: u16) -> String {
        match &self.allowed {
            Allowed::Range(..) => field.to_string(),
            Allowed::Values { codes, reads } => codes
                .iter()
                .chain(reads)
                .find(|(_, c)| **c == field)
                .map(|(n, _)| n.clone())
                .unwrap_or_else(|| format!("code {field} (undocumented)")),
        }
    }

    /// The field of this setting in a register word.
    pub fn field(&self, word: u16) -> u16 {
        (word & self.mask) >> self.mask.trailing_zeros()
    }

    /// `word` with this setting's field replaced by `field` (the other bits kept).
    pub fn with_field(&self, word: u16, field: u16) -> u16 {
        (word & !self.mask) | ((field << self.mask.trailing_zeros()) & self.mask)
    }

    /// The registers of a register setting, one per instance.
    pub fn registers(&self) -> Vec<u16> {
        match self.place {
            Place::Registers {
                address,
                instances,
                stride,
            } => (0..instances).map(|i| address + i * stride).collect(),
            Place::Channel(_) => Vec::new(),
        }
    }
}

/// Checks a profile's settings against its other data.
pub(super) fn check(settings: &BTreeMap<String, Setting>, bauds: &[u32]) -> Result<(), String> {
    if let Some(baud) = settings.get("baud") {
        let Allowed::Values { codes, reads } = &baud.allowed else {
            return Err("setting baud: must list `values`".into());
        };
        for name in codes.keys().chain(reads.keys()) {
            let b: u32 = name
                .parse()
                .map_err(|_| format!("setting baud: {name:?} is not a baud rate"))?;
            if !bauds.contains(&b) {
                return Err(format!("setting baud: {b} is not in the profile's bauds"));
            }
        }
    }
    if let Some(unit) = settings.get("unit") {
        match unit.allowed {
            Allowed::Range(lo, hi) if lo >= 1 && hi <= 247 => {}
            _ => return Err("setting unit: must be a range within 1..=247".into()),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Profiles;

    fn setting(model: &str, name: &str) -> Setting {
        Profiles::builtin()
            .get(model)
            .unwrap()
            .setting(name)
            .unwrap()
            .clone()
    }

    #[test]
    fn yl67_unit_id_is_register_40201_and_applies_after_a_restart() {
        // YL67.md: "40201 0200 模块地址 读/写 整数，重启后生效，范围 0x0000-0x00FF".
        let s = setting("yl67", "unit");
        assert_eq!(s.registers(), [200]);
        assert_eq!(s.applies, Applies::Restart);
        assert_eq!(s.encode("7"), Ok(7));
    }

    #[test]
    fn ibf67_has_the_same_settings_as_yl67() {
        // IBF67.txt repeats the YL67 register table: 40201 address, 40202 baud.
        assert_eq!(setting("ibf67", "baud").registers(), [201]);
    }

    #[test]
    fn yl67_baud_codes_are_the_datasheet_table() {
        // "0x0004 = 2400 bps, 0x0005 = 4800 bps 0x0006 = 9600 bps, 0x0007 = 19200 bps
        //  0x0008 = 38400 bps, 0x0009 = 57600 bps 0x000A = 115200bps"
        let s = setting("yl67", "baud");
        assert_eq!(s.registers(), [201]);
        for (baud, code) in [
            ("2400", 4),
            ("4800", 5),
            ("9600", 6),
            ("19200", 7),
            ("38400", 8),
            ("57600", 9),
            ("115200", 0x0A),
        ] {
            assert_eq!(s.encode(baud), Ok(code), "{baud}");
        }
        assert_eq!(s.applies, Applies::Restart);
    }

    #[test]
    fn wj157_parity_and_autosave_are_40203_and_40081() {
        // WJ157.md: "40203 202 奇偶校验 ... 重启后生效 0: 无校验 1: 奇校验 2: 偶校验";
        // "40081 ... 0: 不自动保存, 断电清零; 1: 断电自动保存计数值".
        let parity = setting("wj157", "parity");
        assert_eq!(parity.registers(), [202]);
        assert_eq!(parity.encode("even"), Ok(2));
        assert_eq!(parity.applies, Applies::Restart);
        let autosave = setting("wj157", "autosave");
        assert_eq!(autosave.registers(), [80]);
        assert_eq!(autosave.encode("off"), Ok(0));
    }

    #[test]
    fn zh_yx1600_address_0x0050_is_used_at_once() {
        // ZH-YX1600.md 10.6: "01H 06H 00H 50H 00H 02H 08H 1AH" then
        // "返回数据后, 后续就必须用 02 设备地址来进行通讯".
        let s = setting("zh-yx1600", "unit");
        assert_eq!(s.registers(), [0x0050]);
        assert_eq!(s.encode("2"), Ok(0x0002));
        assert_eq!(s.applies, Applies::Now);
    }

    #[test]
    fn zh_yx1600_baud_register_0x0051_reads_factory_code_1_as_9600() {
        // "0001 设置波特率-9600bps ... 0008 设置波特率-38400bps ... 出厂默认为 0x0001".
        let s = setting("zh-yx1600", "baud");
        assert_eq!(s.registers(), [0x0051]);
        assert_eq!(s.describe(0x0001), "9600");
        assert_eq!(s.describe(0x0000), "115200");
        assert_eq!(s.encode("38400"), Ok(8));
        assert_eq!(s.encode("9600"), Ok(6));
        assert!(
            s.encode("38000").is_err(),
            "code 3 (38000, sic) is never written"
        );
        assert_eq!(s.applies, Applies::Unstated);
    }

    #[test]
    fn zh_yx1600_power_on_state_is_pauto_bits_9_8_of_each_mode_word() {
        // "Bit9:Bit8 -- 模块上电后，计数器初始运行状态 ... pAuto=0:计数器停止 pAuto=1:计数器向上计数
        //  pAuto=2:计数器向下计数"; mode registers 0x0700~0x070F.
        let s = setting("zh-yx1600", "power_on");
        let regs = s.registers();
        assert_eq!((regs[0], regs[15], regs.len()), (0x0700, 0x070F, 16));
        // Derived frame `01 06 07 00 01 00`: counter 1 counts up at power-on.
        assert_eq!(s.with_field(0x0000, s.encode("up").unwrap()), 0x0100);
        // A quadrature counter (bit 1 AB) keeps its other bits.
        assert_eq!(s.with_field(0x0002, s.encode("down").unwrap()), 0x0202);
        assert_eq!(s.field(0x0302), 3);
        assert_eq!(s.describe(s.field(0x0102)), "up");
        assert_eq!(s.applies, Applies::Restart);
    }

    #[test]
    fn values_outside_the_datasheet_are_refused_with_their_cause() {
        let unit = setting("yl67", "unit");
        let e = unit.encode("248").unwrap_err();
        assert!(e.to_string().contains("1..=247"), "{e}");
        assert!(unit.encode("0").is_err());
        assert!(unit.encode("seven").is_err());
        let baud = setting("yl67", "baud");
        let e = baud.encode("14400").unwrap_err();
        assert!(e.to_string().contains("115200"), "{e}");
        let ppr = setting("wj157", "ppr");
        assert!(ppr.encode("0").is_err() && ppr.encode("65536").is_err());
        assert_eq!(ppr.encode("360"), Ok(360));
    }

    #[test]
    fn an_undocumented_setting_names_the_documented_ones() {
        let p = Profiles::builtin().get("yl67").unwrap();
        let e = p.setting("power_on").unwrap_err().to_string();
        assert!(e.contains("yl67") && e.contains("baud, ppr, unit"), "{e}");
    }

    #[test]
    fn a_baud_setting_outside_the_profile_bauds_is_a_broken_profile() {
        let text = include_str!("../../profiles/wj157.toml").replace("2400 = 4", "1200 = 3");
        let e = crate::profile::Profile::from_toml(&text, "t").unwrap_err();
        assert!(e.to_string().contains("1200"), "{e}");
    }
}
