use super::*;
use crate::mbus::config::{self as mbus, MeterAddress};
use crate::modbus::config::{self as modbus, Unit};

fn secondary(id: &str) -> Address {
    Address::new(MeterAddress::Secondary {
        id: id.into(),
        manufacturer: None,
        version: None,
        medium: None,
    })
}

fn both() -> Protocols {
    Protocols::new(vec![modbus::protocol::PROTOCOL, mbus::protocol::PROTOCOL])
}

#[test]
fn every_protocol_is_found_by_the_name_a_config_writes() {
    let protocols = both();
    for p in protocols.all() {
        assert_eq!(protocols.find(p.name()), Ok(*p));
        assert_eq!(p.to_string(), p.name());
    }
    let err = protocols.find("dlms").unwrap_err();
    assert_eq!(err, "unknown protocol \"dlms\": use \"modbus\" or \"mbus\"");
}

#[test]
#[should_panic(expected = "two protocols named modbus")]
fn a_list_with_two_protocols_of_one_name_is_refused() {
    Protocols::new(vec![
        modbus::protocol::PROTOCOL,
        mbus::protocol::PROTOCOL,
        modbus::protocol::PROTOCOL,
    ]);
}

#[test]
fn an_error_on_a_modbus_bus_points_to_the_other_protocols() {
    assert_eq!(
        both().others(modbus::protocol::PROTOCOL),
        "`protocol = \"mbus\"` for M-Bus meters"
    );
}

#[test]
fn a_link_and_an_address_are_their_protocols_own_types() {
    let line = modbus::Line::Tcp {
        host: "127.0.0.1".into(),
        port: 502,
    };
    let link = Link::new(line.clone());
    assert_eq!(link.protocol(), modbus::protocol::PROTOCOL);
    assert_eq!(link.line::<modbus::Line>(), Some(&line));
    assert_eq!(link.line::<mbus::Line>(), None);
    assert_eq!(link.to_string(), "TCP 127.0.0.1:502");
    let other = Link::new(mbus::Line::Tcp {
        host: "127.0.0.1".into(),
        port: 502,
    });
    assert_ne!(link, other, "the same host and port in two protocols");
    assert_ne!(
        format!("{link:?}"),
        format!("{other:?}"),
        "the config hash reads a link's Debug"
    );
    assert_eq!(link, Link::new(line));
    assert_ne!(
        Address::new(Unit(5)),
        Address::new(MeterAddress::Primary(5))
    );
    assert_eq!(Address::new(Unit(5)).of::<Unit>(), Some(&Unit(5)));
}

#[test]
fn a_modbus_unit_is_keyed_tagged_and_said_as_before() {
    let a = Address::new(Unit(3));
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
    let a = Address::new(MeterAddress::Primary(5));
    assert_eq!(a.key(), "5");
    assert_eq!(a.tag(), "a5");
    assert_eq!(a.to_string(), "primary address 5");
    assert_eq!(a.short(), "address 5");
    assert_eq!(a.unit_id(), Some(5));
    assert_eq!(Address::new(MeterAddress::Primary(0)).unit_id(), None);
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
    assert_eq!(a.of::<MeterAddress>().map(MeterAddress::wire), Some(0xFD));
}
