//! Where a device answers on its bus ([`Address`]): its protocol's own address type (a
//! Modbus unit, an M-Bus meter's address, a toy's pin), held behind one type every part of the
//! gateway can store, compare, key and print, and taken back as the protocol's own type by that
//! protocol's code ([`Address::of`]). A new protocol implements [`AddressOf`] for its type.

use std::any::Any;
use std::fmt;
use std::sync::Arc;

/// A protocol's address of one device on its bus: written, keyed and told apart by the
/// protocol's own type.
pub trait AddressOf: fmt::Debug + fmt::Display + Eq + Send + Sync + 'static {
    /// The address as the state file keys it (`3`, `5`, `12345678`): unique on its bus.
    fn key(&self) -> String;
    /// The address as a name part, stable across renames (`u3`, `a5`, `id12345678`).
    fn tag(&self) -> String;
    /// The address in a few words after the bus's name (`unit 3`, `address 5`): a device's
    /// serial number in Home Assistant.
    fn short(&self) -> String {
        self.to_string()
    }
    /// A number from 1 to 247 the device answers by on its bus, if it has one (a Modbus server
    /// output gives the device that unit id unless told otherwise).
    fn unit_id(&self) -> Option<u8> {
        None
    }
    /// Whether the device's channels are what it answers (found when it answers) rather than
    /// its profile's list.
    fn channels_from_device(&self) -> bool;
    /// Whether the device's counts can be cleared or preset.
    fn writable_counts(&self) -> bool;
}

/// [`AddressOf`] as the object an [`Address`] holds.
trait AnyAddress: fmt::Debug + fmt::Display + Send + Sync {
    fn key(&self) -> String;
    fn tag(&self) -> String;
    fn short(&self) -> String;
    fn unit_id(&self) -> Option<u8>;
    fn channels_from_device(&self) -> bool;
    fn writable_counts(&self) -> bool;
    fn as_any(&self) -> &dyn Any;
    fn same(&self, other: &dyn AnyAddress) -> bool;
}

impl<T: AddressOf> AnyAddress for T {
    fn key(&self) -> String {
        AddressOf::key(self)
    }
    fn tag(&self) -> String {
        AddressOf::tag(self)
    }
    fn short(&self) -> String {
        AddressOf::short(self)
    }
    fn unit_id(&self) -> Option<u8> {
        AddressOf::unit_id(self)
    }
    fn channels_from_device(&self) -> bool {
        AddressOf::channels_from_device(self)
    }
    fn writable_counts(&self) -> bool {
        AddressOf::writable_counts(self)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn same(&self, other: &dyn AnyAddress) -> bool {
        other.as_any().downcast_ref::<T>() == Some(self)
    }
}

/// Where a device answers on its bus, in its protocol's terms: written, keyed and told apart
/// by the protocol's address type once.
#[derive(Clone)]
pub struct Address(Arc<dyn AnyAddress>);

impl Address {
    /// A device's address `a`.
    pub fn new(a: impl AddressOf) -> Address {
        Address(Arc::new(a))
    }

    /// The address as its protocol's type, if it is one of `T`.
    pub fn of<T: AddressOf>(&self) -> Option<&T> {
        self.0.as_any().downcast_ref()
    }

    /// See [`AddressOf::key`].
    pub fn key(&self) -> String {
        self.0.key()
    }

    /// See [`AddressOf::tag`].
    pub fn tag(&self) -> String {
        self.0.tag()
    }

    /// See [`AddressOf::short`].
    pub fn short(&self) -> String {
        self.0.short()
    }

    /// See [`AddressOf::unit_id`].
    pub fn unit_id(&self) -> Option<u8> {
        self.0.unit_id()
    }

    /// See [`AddressOf::channels_from_device`].
    pub fn channels_from_device(&self) -> bool {
        self.0.channels_from_device()
    }

    /// See [`AddressOf::writable_counts`].
    pub fn writable_counts(&self) -> bool {
        self.0.writable_counts()
    }
}

impl PartialEq for Address {
    fn eq(&self, other: &Address) -> bool {
        self.0.same(&*other.0)
    }
}

impl Eq for Address {}

impl fmt::Debug for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

impl fmt::Display for Address {
    /// The address as a person says it (`unit 3`, `primary address 5`, `id 12345678`).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}
