//! A simulated module's place on the line: its unit id and baud rate, kept in the registers the
//! datasheets name and taken at once or at the next power-up as each datasheet says.
//!
//! The table here is the simulator's own reading of the datasheets, not the profiles' `settings`
//! section, so a wrong profile shows up as a failing test instead of agreeing with itself.
//!
//! How modules at different baud rates share one pseudo-terminal: a pty carries bytes at no
//! speed, but it keeps the speed its opener set (termios). A module answers only a request sent
//! while the line is set to its own baud rate; at any other speed it stays silent, as a real
//! UART at another speed sees framing errors and does not answer. This is one wire with modules
//! at several speeds, which RS-485 allows; what it cannot show is the garbage a wrong-speed
//! frame makes on a real line (the simulated module is simply silent).

use std::collections::BTreeMap;

use super::model::SimModule;

/// Where one model keeps its address and baud rate, per its datasheet.
#[derive(Debug, PartialEq, Eq)]
pub struct CommRegisters {
    pub unit: u16,
    pub baud: u16,
    /// Baud code → baud rate.
    pub codes: &'static [(u16, u32)],
    /// A written address is used at once (otherwise at the next power-up).
    pub unit_at_once: bool,
    /// The parity / character format register, where the model has one (factory value 0 =
    /// no parity, 1 stop bit). The simulator stores it; it does not model parity on the line.
    pub format: Option<u16>,
}

/// YL67 / IBF67 / WJ157, 40202: "0x0004 = 2400 bps, 0x0005 = 4800 bps 0x0006 = 9600 bps,
/// 0x0007 = 19200 bps 0x0008 = 38400 bps, 0x0009 = 57600 bps 0x000A = 115200bps".
const YL_CODES: &[(u16, u32)] = &[
    (4, 2400),
    (5, 4800),
    (6, 9600),
    (7, 19200),
    (8, 38400),
    (9, 57600),
    (10, 115200),
];

/// ZH-YX1600, 0x0051: "0000 … 115200bps 0001 … 9600bps 0002 … 19200bps 0003 … 38000bps 0004 …
/// 2400bps 0005 … 4800bps 0006 … 9600bps 0007 … 19200bps 0008 … 38400bps 0009 … 57600bps 000A
/// … 115200bps" (code 3 is taken as 38400, the only standard rate near it).
const ZH_CODES: &[(u16, u32)] = &[
    (1, 9600),
    (0, 115200),
    (2, 19200),
    (3, 38400),
    (4, 2400),
    (5, 4800),
    (6, 9600),
    (7, 19200),
    (8, 38400),
    (9, 57600),
    (10, 115200),
];

/// The datasheet registers of `model` (a profile's model name).
pub fn registers(model: &str) -> Option<&'static CommRegisters> {
    static YL: CommRegisters = CommRegisters {
        unit: 200,
        baud: 201,
        codes: YL_CODES,
        // "模块地址 读/写 整数，重启后生效" (takes effect after a restart).
        unit_at_once: false,
        format: None,
    };
    static WJ: CommRegisters = CommRegisters {
        unit: 200,
        baud: 201,
        codes: YL_CODES,
        unit_at_once: false,
        // WJ157 40203: "0: 无校验 1: 奇校验 2: 偶校验" (YL67 has none: "无校验", fixed).
        format: Some(202),
    };
    static ZH: CommRegisters = CommRegisters {
        unit: 0x0050,
        baud: 0x0051,
        codes: ZH_CODES,
        // "返回数据后, 后续就必须用 02 设备地址来进行通讯" (after the answer, use address 02).
        unit_at_once: true,
        // 0x0052: "0000 无校验, 1 个停止位 (出厂默认)".
        format: Some(0x0052),
    };
    match model {
        "yl67" | "ibf67" => Some(&YL),
        "wj157" => Some(&WJ),
        "zh-yx1600" => Some(&ZH),
        _ => None,
    }
}

impl CommRegisters {
    fn code_of(&self, baud: u32) -> Option<u16> {
        self.codes.iter().find(|(_, b)| *b == baud).map(|(c, _)| *c)
    }

    pub(crate) fn baud_of(&self, code: u16) -> Option<u32> {
        self.codes.iter().find(|(c, _)| *c == code).map(|(_, b)| *b)
    }
}

/// Gives a new module its address and baud rate registers; `baud` must be one its datasheet
/// lists. (Factory state is unit 1 at 9600; a plant may place a module elsewhere, as if it had
/// been set up before.)
pub fn install(m: &mut SimModule, unit: u8, baud: u32) -> Result<(), String> {
    let Some(regs) = registers(&m.profile.model) else {
        return Ok(());
    };
    let code = regs
        .code_of(baud)
        .ok_or_else(|| format!("{} has no baud rate {baud}", m.profile.model))?;
    m.store(regs.unit, u16::from(unit));
    m.store(regs.baud, code);
    if let Some(format) = regs.format {
        m.store(format, 0);
    }
    Ok(())
}

/// After a write to the module at `unit`: a module whose address applies at once moves now.
/// Returns the new unit if it moved.
pub fn after_write(modules: &mut BTreeMap<u8, SimModule>, unit: u8) -> Option<u8> {
    let m = modules.get(&unit)?;
    let regs = registers(&m.profile.model)?;
    if !regs.unit_at_once {
        return None;
    }
    move_to_stored_unit(modules, unit)
}

/// Moves the module at `unit` to the address in its register, when that is a free unit id.
pub(crate) fn move_to_stored_unit(modules: &mut BTreeMap<u8, SimModule>, unit: u8) -> Option<u8> {
    let m = modules.get(&unit)?;
    let regs = registers(&m.profile.model)?;
    let stored = u8::try_from(m.stored(regs.unit)?).ok()?;
    if stored == unit || !(1..=247).contains(&stored) || modules.contains_key(&stored) {
        return None;
    }
    let m = modules.remove(&unit)?;
    modules.insert(stored, m);
    Some(stored)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Profiles;

    fn module(model: &str) -> SimModule {
        SimModule::new(Profiles::builtin().get(model).unwrap(), &[]).unwrap()
    }

    #[test]
    fn a_factory_yl67_reads_unit_1_and_baud_code_6_at_40201() {
        // YL67.md: factory "Modbus 地址为 01", "波特率 9600 bps"; 40202 "0x0006 = 9600 bps".
        let mut m = module("yl67");
        install(&mut m, 1, 9600).unwrap();
        assert_eq!(m.read(0.0, 200, 2), Ok(vec![1, 6]));
    }

    #[test]
    fn a_factory_zh_yx1600_reads_baud_code_1() {
        // ZH-YX1600.md 0x0051: "如串口为 RS485 或 RS232 时出厂默认为 0x0001" (9600).
        let mut m = module("zh-yx1600");
        install(&mut m, 1, 9600).unwrap();
        assert_eq!(m.read(0.0, 0x0050, 2), Ok(vec![1, 1]));
    }

    #[test]
    fn a_yl67_address_write_waits_for_the_power_up() {
        let mut modules = BTreeMap::new();
        let mut m = module("wj157");
        install(&mut m, 1, 9600).unwrap();
        m.write_one(0.0, 200, 9).unwrap();
        modules.insert(1, m);
        assert_eq!(after_write(&mut modules, 1), None);
        assert!(modules.contains_key(&1));
        assert_eq!(move_to_stored_unit(&mut modules, 1), Some(9));
    }

    #[test]
    fn the_zh_yx1600_datasheet_address_write_moves_the_module_at_once() {
        // 01 06 00 50 00 02 08 1A: the module answers at 02 from then on.
        let mut modules = BTreeMap::new();
        let mut m = module("zh-yx1600");
        install(&mut m, 1, 9600).unwrap();
        m.write_one(0.0, 0x0050, 0x0002).unwrap();
        modules.insert(1, m);
        assert_eq!(after_write(&mut modules, 1), Some(2));
        assert!(modules.contains_key(&2) && !modules.contains_key(&1));
    }

    #[test]
    fn a_zh_yx1600_counter_runs_after_power_up_only_when_pauto_says_so() {
        let mut m = module("zh-yx1600");
        m.set_rate(0.0, "di1", 100.0);
        // Factory mode word 0x0000: pAuto 0, the counter is stopped after power-up.
        m.power_cycle(1.0);
        assert_eq!(m.channel("di1").unwrap().count(3.0), 0);
        // Derived frame 01 06 07 00 01 00: counter 1 counts up at power-on.
        m.write_one(3.0, 0x0700, 0x0100).unwrap();
        m.power_cycle(4.0);
        assert_eq!(m.channel("di1").unwrap().count(5.0), 100);
        assert_eq!(m.read(5.0, 0x1100, 1), Ok(vec![0x00A2]));
    }

    #[test]
    fn a_baud_the_datasheet_lacks_is_refused() {
        let mut m = module("yl67");
        assert!(install(&mut m, 1, 14400).is_err());
    }
}
