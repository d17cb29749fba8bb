//! The quantities and units the standard's VIF tables name. Pure.

use std::fmt;

/// What a record measures or says, as the VIF tables of EN 13757-3 name it.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Quantity {
    Energy,
    Volume,
    Mass,
    OnTime,
    OperatingTime,
    Power,
    VolumeFlow,
    MassFlow,
    FlowTemperature,
    ReturnTemperature,
    TemperatureDifference,
    ExternalTemperature,
    Pressure,
    Date,
    DateTime,
    /// Heat cost allocator units (dimensionless).
    HcaUnits,
    AveragingDuration,
    ActualityDuration,
    FabricationNumber,
    EnhancedIdentification,
    BusAddress,
    /// "Any VIF": a master's readout selection, not a value.
    AnyVif,
    /// VIF 7F/FF: manufacturer specific.
    ManufacturerSpecific,
    /// VIF 7C/FC: the unit is the text.
    PlainText(String),
    /// A quantity of the FD or FB extension table, by its snake-case name.
    Extended(&'static str),
    /// A code the tables mark reserved, or one this decoder does not know: (table, code).
    Unknown(Table, u8),
}

/// The VIF table a code is from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Table {
    Primary,
    /// FD: the main extension table.
    Fd,
    /// FB: the alternate extension table.
    Fb,
    /// The unit codes of the fixed data structure (CI 0x73).
    Fixed,
}

impl Quantity {
    /// The quantity's name, lowercase ASCII with `_` (a channel name's first part).
    pub fn name(&self) -> String {
        let s = match self {
            Quantity::Energy => "energy",
            Quantity::Volume => "volume",
            Quantity::Mass => "mass",
            Quantity::OnTime => "on_time",
            Quantity::OperatingTime => "operating_time",
            Quantity::Power => "power",
            Quantity::VolumeFlow => "volume_flow",
            Quantity::MassFlow => "mass_flow",
            Quantity::FlowTemperature => "flow_temperature",
            Quantity::ReturnTemperature => "return_temperature",
            Quantity::TemperatureDifference => "temperature_difference",
            Quantity::ExternalTemperature => "external_temperature",
            Quantity::Pressure => "pressure",
            Quantity::Date => "date",
            Quantity::DateTime => "date_time",
            Quantity::HcaUnits => "hca",
            Quantity::AveragingDuration => "averaging_duration",
            Quantity::ActualityDuration => "actuality_duration",
            Quantity::FabricationNumber => "fabrication_number",
            Quantity::EnhancedIdentification => "enhanced_identification",
            Quantity::BusAddress => "bus_address",
            Quantity::AnyVif => "any_vif",
            Quantity::ManufacturerSpecific => "manufacturer_specific",
            Quantity::PlainText(text) => return plain_name(text),
            Quantity::Extended(name) => name,
            Quantity::Unknown(table, code) => {
                let t = match table {
                    Table::Primary => "vif",
                    Table::Fd => "vif_fd",
                    Table::Fb => "vif_fb",
                    Table::Fixed => "fixed_unit",
                };
                return format!("{t}_{code:02x}");
            }
        };
        s.to_string()
    }
}

/// A plain-text unit as a name: its letters and digits, lowercase, `_` between words.
fn plain_name(text: &str) -> String {
    let mut out = String::from("text");
    let mut gap = true;
    for c in text.chars() {
        if c.is_ascii_alphanumeric() {
            if gap {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
            gap = false;
        } else {
            gap = true;
        }
    }
    out
}

impl fmt::Display for Quantity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Quantity::PlainText(t) => write!(f, "{t}"),
            other => f.write_str(&other.name().replace('_', " ")),
        }
    }
}

/// A unit as the standard names it. Scale is not part of the unit: a record's exponent says
/// it (0.001 m³ steps are `M3` with exponent -3).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Unit {
    Wh,
    J,
    M3,
    Kg,
    W,
    JPerH,
    M3PerH,
    M3PerMin,
    M3PerS,
    KgPerH,
    Celsius,
    Kelvin,
    Fahrenheit,
    Bar,
    Second,
    Minute,
    Hour,
    Day,
    Month,
    Year,
    Volt,
    Ampere,
    Hertz,
    Percent,
    /// Tenths of a degree of phase angle are `Degree` with exponent -1.
    Degree,
    Varh,
    Var,
    Feet3,
    UsGallon,
    UsGallonPerMin,
    UsGallonPerH,
    Dbm,
    Baud,
    BitTimes,
    CurrencyUnits,
    /// A plain-text unit, as sent.
    Text(String),
    /// A unit per something (a VIFE's "per hour", "per input pulse"…): (unit, per what).
    Per(Box<Unit>, &'static str),
    /// A unit multiplied by something (a VIFE's "multiplied by s"): (unit, by what).
    Times(Box<Unit>, &'static str),
}

impl Unit {
    /// The unit's symbol (`m³`, `°C`, `Wh`, `m³/pulse`).
    pub fn symbol(&self) -> String {
        let s = match self {
            Unit::Wh => "Wh",
            Unit::J => "J",
            Unit::M3 => "m³",
            Unit::Kg => "kg",
            Unit::W => "W",
            Unit::JPerH => "J/h",
            Unit::M3PerH => "m³/h",
            Unit::M3PerMin => "m³/min",
            Unit::M3PerS => "m³/s",
            Unit::KgPerH => "kg/h",
            Unit::Celsius => "°C",
            Unit::Kelvin => "K",
            Unit::Fahrenheit => "°F",
            Unit::Bar => "bar",
            Unit::Second => "s",
            Unit::Minute => "min",
            Unit::Hour => "h",
            Unit::Day => "d",
            Unit::Month => "month",
            Unit::Year => "year",
            Unit::Volt => "V",
            Unit::Ampere => "A",
            Unit::Hertz => "Hz",
            Unit::Percent => "%",
            Unit::Degree => "°",
            Unit::Varh => "varh",
            Unit::Var => "var",
            Unit::Feet3 => "ft³",
            Unit::UsGallon => "US gal",
            Unit::UsGallonPerMin => "US gal/min",
            Unit::UsGallonPerH => "US gal/h",
            Unit::Dbm => "dBm",
            Unit::Baud => "Bd",
            Unit::BitTimes => "bit times",
            Unit::CurrencyUnits => "currency units",
            Unit::Text(t) => return t.clone(),
            Unit::Per(u, per) => return format!("{}/{per}", u.symbol()),
            Unit::Times(u, by) => return format!("{}·{by}", u.symbol()),
        };
        s.to_string()
    }

    /// A time unit by the standard's two bits `nn`: seconds, minutes, hours, days.
    pub fn time_nn(nn: u8) -> Unit {
        match nn & 3 {
            0 => Unit::Second,
            1 => Unit::Minute,
            2 => Unit::Hour,
            _ => Unit::Day,
        }
    }

    /// A time unit by the standard's two bits `pp`: hours, days, months, years.
    pub fn time_pp(pp: u8) -> Unit {
        match pp & 3 {
            0 => Unit::Hour,
            1 => Unit::Day,
            2 => Unit::Month,
            _ => Unit::Year,
        }
    }
}

impl fmt::Display for Unit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.symbol())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_lowercase_ascii_digits_and_underscores() {
        assert_eq!(Quantity::PlainText("%RH".into()).name(), "text_rh");
        assert_eq!(Quantity::PlainText("".into()).name(), "text");
        assert_eq!(Quantity::Unknown(Table::Fd, 0x7A).name(), "vif_fd_7a");
        assert_eq!(Quantity::VolumeFlow.name(), "volume_flow");
    }

    #[test]
    fn composed_units_print_their_parts() {
        assert_eq!(Unit::Per(Box::new(Unit::M3), "pulse").symbol(), "m³/pulse");
        assert_eq!(Unit::Times(Box::new(Unit::M3PerH), "s").symbol(), "m³/h·s");
    }
}
