//! What the datasheets say, written down for the simulator on its own (literal values, not taken
//! from the gateway's profiles), so that a mistake in a profile is not repeated by the simulator
//! and a test against the simulator can catch it.

/// Documented registers with no behaviour of their own, and their factory values:
/// `(first address, values)`.
pub fn factory_registers(model: &str) -> Vec<(u16, Vec<u16>)> {
    match model {
        // YL67 / IBF67 register tables.
        "yl67" | "ibf67" => vec![
            (88, vec![0]),       // factory reset (write 0xFF00)
            (200, vec![1, 6]),   // address 01, baud code 6 = 9600
            (210, vec![0x0067]), // module name
        ],
        // WJ157 register table.
        "wj157" => vec![
            (40, vec![60, 60]), // pulses per revolution of A0, B0: default 60
            (80, vec![1]),      // keep counts across power loss: 1 (default)
            (88, vec![0]),
            (180, vec![0, 0]),    // input filter of A0, B0, ms: default 0
            (200, vec![1, 6, 0]), // address, baud code, parity none
            (210, vec![0x0150]),  // module name
        ],
        "zh-yx1600" => {
            let mut v = vec![
                // Address 01; baud code 0x0001 (9600, RS-485 model); 8N1.
                (0x0050, vec![0x0001, 0x0001, 0x0000]),
                // Module name "YX" "16" "00", software version "05" ".01".
                (0x0055, vec![0x5958, 0x3136, 0x3030, 0x3035, 0x3031]),
                (0x005A, vec![0x0001, 0x0000]),
                // Counter mode words: factory 0x0000 (single phase, stopped at power-up).
                (ZH_MODE, vec![0; 16]),
                (0x1000, vec![0]), // upper limit flags
                (0x1002, vec![0]), // lower limit flags
            ];
            // Power-on and live limits: 0x7FFF_FFFF and 0x8000_0000, high word first.
            for base in [0x0750, ZH_LIVE_UPPER] {
                v.push((base, [0x7FFF, 0xFFFF].repeat(16)));
            }
            v.push((0x0770, [0x8000, 0x0000].repeat(16)));
            // Live lower limits at 0x1130: the datasheet's range runs into the frequency
            // windows at 0x1140 (see docs/datasheet-notes.md); the windows win, so only the
            // lower limits of counters 1..8 answer here.
            v.push((ZH_LIVE_LOWER, [0x8000, 0x0000].repeat(8)));
            v
        }
        _ => Vec::new(),
    }
}

/// ZH-YX1600 counter mode words, one per counter (section 8.5).
pub const ZH_MODE: u16 = 0x0700;
// 0x1100: the ZH-YX1600 counter command registers, one per counter; the simulator takes them
// from the profile (`profiles/zh-yx1600.toml`), like the gateway.
pub const ZH_LIVE_UPPER: u16 = 0x1110;
pub const ZH_LIVE_LOWER: u16 = 0x1130;
/// ZH-YX1600 frequency windows (u32, units of 10 ms, 0 = 1 s), two registers per counter.
pub const ZH_WINDOW: u16 = 0x1140;
/// ZH-YX1600 counter values (i32), two registers per counter.
pub const ZH_COUNT: u16 = 0x1160;

/// ZH-YX1600 command codes.
pub const ZH_STOP: u16 = 0x0000;
pub const ZH_PAUSE: u16 = 0x0001;
pub const ZH_UP: u16 = 0x00A2;
pub const ZH_DOWN: u16 = 0x00A3;

/// The command a ZH-YX1600 counter takes at power-up from its mode word's pAuto bits (9:8):
/// 0 stop, 1 up, 2 down.
pub fn zh_power_on_command(mode_word: u16) -> u16 {
    match (mode_word >> 8) & 0b11 {
        1 => ZH_UP,
        2 => ZH_DOWN,
        _ => ZH_STOP,
    }
}

/// Whether a ZH-YX1600 mode word selects A/B quadrature (bit 1).
pub fn zh_quadrature(mode_word: u16) -> bool {
    mode_word & 0x0002 != 0
}
