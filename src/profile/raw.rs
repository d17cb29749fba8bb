//! The profile file format, as written (serde).

use serde::Deserialize;
use std::time::Duration;

/// Order of the two words of a 32-bit value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WordOrder {
    /// Low word at the lower address (YL67, IBF67, WJ157).
    LowFirst,
    /// High word at the lower address (ZH-YX1600, the Modbus convention).
    HighFirst,
}

/// Type of a register value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ValueType {
    U16,
    I16,
    U32,
    I32,
    F32,
}

impl ValueType {
    /// Number of 16-bit registers the value spans.
    pub fn words(self) -> u16 {
        match self {
            ValueType::U16 | ValueType::I16 => 1,
            ValueType::U32 | ValueType::I32 | ValueType::F32 => 2,
        }
    }
}

/// What a channel counts: a position (signed, may go back) or pulses on one input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ChannelKind {
    /// A/B quadrature encoder: signed count, the total is a position.
    Encoder,
    /// An input counting on its own.
    Counter,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Profile {
    pub model: String,
    #[serde(default)]
    pub aliases: Vec<String>,
    #[serde(default)]
    pub title: String,
    /// Maker of the model itself (not of its aliases), from the datasheet's imprint.
    #[serde(default)]
    pub manufacturer: Option<String>,
    pub word_order: WordOrder,
    #[serde(with = "humantime_serde")]
    pub answer_timeout: Duration,
    pub bauds: Vec<u32>,
    /// The port the Ethernet model listens on at the factory (Modbus TCP).
    #[serde(default)]
    pub tcp_port: Option<u16>,
    pub identify: Option<Identify>,
    pub autosave: Option<Autosave>,
    #[serde(default)]
    pub settings: std::collections::BTreeMap<String, super::settings::RawSetting>,
    pub groups: Vec<Group>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Identify {
    pub address: u16,
    pub words: Vec<u16>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Autosave {
    pub address: u16,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Group {
    pub name: String,
    pub instances: u16,
    pub mode: ModeTemplate,
    pub modes: Vec<Mode>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ModeTemplate {
    pub address: u16,
    #[serde(default)]
    pub stride: u16,
    #[serde(default = "all_bits")]
    pub mask: u16,
    /// Offset of a second mode word that must agree under `mask` (a ZH-YX1600 quadrature
    /// pair counts only when both of its mode words select quadrature).
    #[serde(default)]
    pub partner: Option<u16>,
}

fn all_bits() -> u16 {
    0xFFFF
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Mode {
    pub value: u16,
    pub clear_all: Option<CodeTemplate>,
    pub channels: Vec<ChannelTemplate>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct CodeTemplate {
    pub address: u16,
    pub code: u16,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ChannelTemplate {
    pub name: String,
    pub number: Number,
    pub kind: ChannelKind,
    pub count: RegisterTemplate,
    pub freq: Option<RegisterTemplate>,
    pub rpm: Option<RegisterTemplate>,
    pub ppr: Option<RegisterTemplate>,
    pub clear: ClearTemplate,
    pub retains_count: bool,
    pub max_rate_hz: f64,
    /// Values a preset may write, where the datasheet narrows the register's range.
    #[serde(default)]
    pub preset_range: Option<[i64; 2]>,
    /// Where the frequency register holds pulses per window rather than Hz: the window.
    #[serde(default)]
    pub freq_window: Option<WindowTemplate>,
    /// The bits of a settings word that say how the counter runs after power-up.
    #[serde(default)]
    pub power_on: Option<PowerOnTemplate>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct PowerOnTemplate {
    pub address: u16,
    #[serde(default)]
    pub stride: u16,
    pub mask: u16,
    pub up: u16,
    pub down: u16,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct WindowTemplate {
    pub address: u16,
    #[serde(default)]
    pub stride: u16,
    #[serde(rename = "type")]
    pub ty: ValueType,
    /// Milliseconds per unit of the register.
    pub unit_ms: u32,
    /// The window when the register reads 0.
    pub zero_ms: u32,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct Number {
    pub base: u16,
    pub stride: u16,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RegisterTemplate {
    pub address: u16,
    #[serde(default)]
    pub stride: u16,
    #[serde(rename = "type")]
    pub ty: ValueType,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct ClearTemplate {
    pub address: u16,
    #[serde(default)]
    pub stride: u16,
    pub code: u16,
    #[serde(default)]
    pub code_stride: u16,
    #[serde(default)]
    pub restart: Vec<u16>,
    /// The code that pauses the counter (kept, not counting), where the register runs it.
    #[serde(default)]
    pub pause: Option<u16>,
}
