//! The standard's three VIF tables (EN 13757-3: the primary VIF table, the FD main extension
//! table, the FB alternate extension table): a code to a quantity, a unit and a decimal
//! exponent. Written from the standard's tables, not from another decoder. Pure.

use super::quantity::{Quantity, Table, Unit};

/// What a VIF (or a table VIFE) says before any combinable VIFE: quantity, unit, exponent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Base {
    pub quantity: Quantity,
    pub unit: Option<Unit>,
    pub exp: i32,
}

fn base(quantity: Quantity, unit: Unit, exp: i32) -> Base {
    Base {
        quantity,
        unit: Some(unit),
        exp,
    }
}

fn bare(quantity: Quantity) -> Base {
    Base {
        quantity,
        unit: None,
        exp: 0,
    }
}

fn unknown(table: Table, code: u8) -> Base {
    bare(Quantity::Unknown(table, code))
}

/// The primary table, by the VIF without its extension bit (0x00–0x7A, 0x7E, 0x7F; the
/// markers 7B/7C/7D are read by the caller).
pub fn primary(code: u8) -> Base {
    let n = i32::from(code & 0x07);
    let nn = i32::from(code & 0x03);
    use Quantity as Q;
    match code & 0x7F {
        0x00..=0x07 => base(Q::Energy, Unit::Wh, n - 3),
        0x08..=0x0F => base(Q::Energy, Unit::J, n),
        0x10..=0x17 => base(Q::Volume, Unit::M3, n - 6),
        0x18..=0x1F => base(Q::Mass, Unit::Kg, n - 3),
        0x20..=0x23 => base(Q::OnTime, Unit::time_nn(code), 0),
        0x24..=0x27 => base(Q::OperatingTime, Unit::time_nn(code), 0),
        0x28..=0x2F => base(Q::Power, Unit::W, n - 3),
        0x30..=0x37 => base(Q::Power, Unit::JPerH, n),
        0x38..=0x3F => base(Q::VolumeFlow, Unit::M3PerH, n - 6),
        0x40..=0x47 => base(Q::VolumeFlow, Unit::M3PerMin, n - 7),
        0x48..=0x4F => base(Q::VolumeFlow, Unit::M3PerS, n - 9),
        0x50..=0x57 => base(Q::MassFlow, Unit::KgPerH, n - 3),
        0x58..=0x5B => base(Q::FlowTemperature, Unit::Celsius, nn - 3),
        0x5C..=0x5F => base(Q::ReturnTemperature, Unit::Celsius, nn - 3),
        0x60..=0x63 => base(Q::TemperatureDifference, Unit::Kelvin, nn - 3),
        0x64..=0x67 => base(Q::ExternalTemperature, Unit::Celsius, nn - 3),
        0x68..=0x6B => base(Q::Pressure, Unit::Bar, nn - 3),
        0x6C => bare(Q::Date),
        0x6D => bare(Q::DateTime),
        0x6E => bare(Q::HcaUnits),
        0x70..=0x73 => base(Q::AveragingDuration, Unit::time_nn(code), 0),
        0x74..=0x77 => base(Q::ActualityDuration, Unit::time_nn(code), 0),
        0x78 => bare(Q::FabricationNumber),
        0x79 => bare(Q::EnhancedIdentification),
        0x7A => bare(Q::BusAddress),
        0x7E => bare(Q::AnyVif),
        0x7F => bare(Q::ManufacturerSpecific),
        other => unknown(Table::Primary, other),
    }
}

/// The FD (main extension) table, by the first VIFE without its extension bit.
pub fn fd(code: u8) -> Base {
    let code = code & 0x7F;
    let e = |name| bare(Quantity::Extended(name));
    let u = |name, unit, exp| base(Quantity::Extended(name), unit, exp);
    let nn = i32::from(code & 0x03);
    match code {
        0x00..=0x03 => u("credit", Unit::CurrencyUnits, nn - 3),
        0x04..=0x07 => u("debit", Unit::CurrencyUnits, nn - 3),
        0x08 => e("access_number"),
        0x09 => e("medium"),
        0x0A => e("manufacturer"),
        0x0B => e("parameter_set_identification"),
        0x0C => e("model_version"),
        0x0D => e("hardware_version"),
        0x0E => e("firmware_version"),
        0x0F => e("software_version"),
        0x10 => e("customer_location"),
        0x11 => e("customer"),
        0x12 => e("access_code_user"),
        0x13 => e("access_code_operator"),
        0x14 => e("access_code_system_operator"),
        0x15 => e("access_code_developer"),
        0x16 => e("password"),
        0x17 => e("error_flags"),
        0x18 => e("error_mask"),
        0x1A => e("digital_output"),
        0x1B => e("digital_input"),
        0x1C => u("baud_rate", Unit::Baud, 0),
        0x1D => u("response_delay", Unit::BitTimes, 0),
        0x1E => e("retry"),
        0x20 => e("first_storage_number"),
        0x21 => e("last_storage_number"),
        0x22 => e("storage_block_size"),
        0x24..=0x27 => u("storage_interval", Unit::time_nn(code), 0),
        0x28 => u("storage_interval", Unit::Month, 0),
        0x29 => u("storage_interval", Unit::Year, 0),
        0x2C..=0x2F => u("duration_since_readout", Unit::time_nn(code), 0),
        0x31..=0x33 => u("tariff_duration", Unit::time_nn(code), 0),
        0x34..=0x37 => u("tariff_period", Unit::time_nn(code), 0),
        0x38 => u("tariff_period", Unit::Month, 0),
        0x39 => u("tariff_period", Unit::Year, 0),
        0x3A => e("dimensionless"),
        0x40..=0x4F => u("voltage", Unit::Volt, i32::from(code & 0x0F) - 9),
        0x50..=0x5F => u("current", Unit::Ampere, i32::from(code & 0x0F) - 12),
        _ => fd_high(code),
    }
}

/// The FD table from 0x60 on.
fn fd_high(code: u8) -> Base {
    let e = |name| bare(Quantity::Extended(name));
    let u = |name, unit, exp| base(Quantity::Extended(name), unit, exp);
    match code {
        0x60 => e("reset_counter"),
        0x61 => e("cumulation_counter"),
        0x62 => e("control_signal"),
        0x63 => e("day_of_week"),
        0x64 => e("week_number"),
        0x65 => e("day_change_time_point"),
        0x66 => e("parameter_activation_state"),
        0x67 => e("special_supplier_information"),
        0x68..=0x6B => u("duration_since_cumulation", Unit::time_pp(code), 0),
        0x6C..=0x6F => u("battery_operating_time", Unit::time_pp(code), 0),
        0x70 => e("battery_change_date_time"),
        0x71 => u("rf_level", Unit::Dbm, 0),
        0x72 => e("daylight_saving"),
        0x73 => e("listening_window"),
        0x74 => u("remaining_battery_life", Unit::Day, 0),
        0x75 => e("meter_stop_count"),
        other => unknown(Table::Fd, other),
    }
}

/// The FB (alternate extension) table, by the first VIFE without its extension bit.
pub fn fb(code: u8) -> Base {
    let code = code & 0x7F;
    let n = i32::from(code & 0x01);
    let nn = i32::from(code & 0x03);
    use Quantity as Q;
    let x = |name, unit, exp| base(Q::Extended(name), unit, exp);
    match code {
        // 10^(n-1) MWh = 10^(n+5) Wh; 10^(n-1) GJ = 10^(n+8) J.
        0x00..=0x01 => base(Q::Energy, Unit::Wh, n + 5),
        0x02..=0x03 => x("reactive_energy", Unit::Varh, n + 3),
        0x08..=0x09 => base(Q::Energy, Unit::J, n + 8),
        0x10..=0x11 => base(Q::Volume, Unit::M3, n + 2),
        0x14..=0x17 => x("reactive_power", Unit::Var, nn),
        // 10^(n+2) t = 10^(n+5) kg.
        0x18..=0x19 => base(Q::Mass, Unit::Kg, n + 5),
        0x1A..=0x1B => x("relative_humidity", Unit::Percent, n - 1),
        0x20 => base(Q::Volume, Unit::Feet3, 0),
        0x21 => base(Q::Volume, Unit::Feet3, -1),
        0x28..=0x29 => base(Q::Power, Unit::W, n + 5),
        0x2A => x("phase_voltage_voltage", Unit::Degree, -1),
        0x2B => x("phase_voltage_current", Unit::Degree, -1),
        0x2C..=0x2F => x("frequency", Unit::Hertz, nn - 3),
        0x30..=0x31 => base(Q::Power, Unit::JPerH, n + 8),
        0x58..=0x5B => base(Q::FlowTemperature, Unit::Fahrenheit, nn - 3),
        0x5C..=0x5F => base(Q::ReturnTemperature, Unit::Fahrenheit, nn - 3),
        0x60..=0x63 => base(Q::TemperatureDifference, Unit::Fahrenheit, nn - 3),
        0x64..=0x67 => base(Q::ExternalTemperature, Unit::Fahrenheit, nn - 3),
        0x70..=0x73 => x("temperature_limit", Unit::Fahrenheit, nn - 3),
        0x74..=0x77 => x("temperature_limit", Unit::Celsius, nn - 3),
        0x78..=0x7F => x("max_power_count", Unit::W, i32::from(code & 0x07) - 3),
        other => unknown(Table::Fb, other),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_primary_table_gives_quantity_unit_and_exponent() {
        assert_eq!(primary(0x13), base(Quantity::Volume, Unit::M3, -3));
        assert_eq!(primary(0x06), base(Quantity::Energy, Unit::Wh, 3));
        assert_eq!(primary(0x3B), base(Quantity::VolumeFlow, Unit::M3PerH, -3));
        assert_eq!(
            primary(0x5B),
            base(Quantity::FlowTemperature, Unit::Celsius, 0)
        );
        assert_eq!(primary(0x22), base(Quantity::OnTime, Unit::Hour, 0));
        assert_eq!(
            primary(0x6F).quantity,
            Quantity::Unknown(Table::Primary, 0x6F)
        );
    }

    #[test]
    fn the_extension_tables_give_volts_amperes_and_megawatt_hours() {
        assert_eq!(fd(0x48).unit, Some(Unit::Volt));
        assert_eq!(fd(0x48).exp, -1);
        assert_eq!(fd(0x59).exp, -3);
        assert_eq!(fd(0x17).quantity, Quantity::Extended("error_flags"));
        assert_eq!(fb(0x01), base(Quantity::Energy, Unit::Wh, 6));
        assert_eq!(fb(0x7F).quantity, Quantity::Extended("max_power_count"));
    }
}
