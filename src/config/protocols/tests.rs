use super::mbus::MeterAddress;
use super::modbus::Unit;
use super::*;

fn secondary(id: &str) -> Address {
    Address::Mbus(MeterAddress::Secondary {
        id: id.into(),
        manufacturer: None,
        version: None,
        medium: None,
    })
}

#[test]
fn every_protocol_parses_back_from_the_name_a_config_writes() {
    for p in Protocol::ALL {
        assert_eq!(p.name().parse::<Protocol>(), Ok(p));
        assert_eq!(p.to_string(), p.name());
    }
    let err = "dlms".parse::<Protocol>().unwrap_err();
    assert_eq!(err, "unknown protocol \"dlms\": use \"modbus\" or \"mbus\"");
}

#[test]
fn an_error_on_a_modbus_bus_points_to_the_other_protocols() {
    assert_eq!(
        Protocol::Modbus.others(),
        "`protocol = \"mbus\"` for M-Bus meters"
    );
}

#[test]
fn a_modbus_unit_is_keyed_tagged_and_said_as_before() {
    let a = Address::Modbus(Unit(3));
    assert_eq!(
        (a.key(), a.tag(), a.to_string()),
        ("3".into(), "u3".into(), "unit 3".into())
    );
    assert_eq!(a.short(), "unit 3");
    assert_eq!(a.unit_id(), Some(3));
    assert!(a.writable_counts() && !a.channels_from_device());
}

#[test]
fn a_meter_at_a_primary_address_is_keyed_tagged_and_said_as_before() {
    let a = Address::Mbus(MeterAddress::Primary(5));
    assert_eq!(a.key(), "5");
    assert_eq!(a.tag(), "a5");
    assert_eq!(a.to_string(), "primary address 5");
    assert_eq!(a.short(), "address 5");
    assert_eq!(a.unit_id(), Some(5));
    assert_eq!(Address::Mbus(MeterAddress::Primary(0)).unit_id(), None);
    assert!(!a.writable_counts() && a.channels_from_device());
}

#[test]
fn a_meter_by_its_id_is_keyed_and_tagged_by_its_id_and_has_no_unit_id() {
    let a = secondary("12345678");
    assert_eq!(a.key(), "12345678");
    assert_eq!(a.tag(), "id12345678");
    assert_eq!(a.to_string(), "id 12345678");
    assert_eq!(a.short(), "id 12345678");
    assert_eq!(a.unit_id(), None);
    assert_eq!(a.as_mbus().map(MeterAddress::wire), Some(0xFD));
}
