//! The simulated plant: modules and meters of every supported protocol, served over the real
//! wire (pseudo-terminals and TCP ports), each protocol's part in its own folder
//! (`modbus/sim/`: modules behind real Modbus servers; `mbus/sim/`: M-Bus segments and
//! meters). This file knows none of them: a [`SimConfig`] holds each protocol's tables of
//! sim.toml and a [`Plant`] each protocol's running part, and `crate::protocols` is where
//! sim.toml is read into them (`SimConfig::from_toml`) and each part started
//! (`Plant::start`). A protocol's folder adds what a test asks of its part (a bus, a segment).
//!
//! Tests and the demo hold a [`Plant`] and steer it (rates, counts, power cycles, silence) while
//! the gateway talks to it over the wire like to real devices.

pub(crate) mod endpoint;
mod error;
pub mod gateway;

use std::any::Any;
use std::time::Instant;

use tokio_util::sync::CancellationToken;

pub use endpoint::Endpoint;
pub(crate) use endpoint::relink;
pub use error::SimError;

/// The whole plant's config (sim.toml): each protocol's tables, as its folder reads them.
#[derive(Default)]
pub struct SimConfig {
    parts: Vec<Box<dyn Any + Send + Sync>>,
}

impl SimConfig {
    /// A config of these protocols' tables (each a type of its protocol's folder).
    pub(crate) fn of(parts: Vec<Box<dyn Any + Send + Sync>>) -> SimConfig {
        SimConfig { parts }
    }

    /// A protocol's tables, by their type.
    pub fn part<T: Any>(&self) -> Option<&T> {
        self.parts.iter().find_map(|p| p.downcast_ref())
    }

    /// A protocol's tables, by their type, to change before the plant starts.
    pub fn part_mut<T: Any>(&mut self) -> Option<&mut T> {
        self.parts.iter_mut().find_map(|p| p.downcast_mut())
    }
}

/// One protocol's running part of a plant.
pub trait Part: Any + Send + Sync {
    /// Where each of its buses is reached, one line each (`pulsegate simulate` prints them).
    fn endpoints(&self) -> Vec<String>;
}

/// A running simulated plant.
pub struct Plant {
    parts: Vec<Box<dyn Part>>,
    start: Instant,
    cancel: CancellationToken,
}

impl Plant {
    /// A plant of these running parts, their clock started at `start`, all stopped by `cancel`.
    pub(crate) fn of(
        parts: Vec<Box<dyn Part>>,
        start: Instant,
        cancel: CancellationToken,
    ) -> Plant {
        Plant {
            parts,
            start,
            cancel,
        }
    }

    /// A protocol's running part, by its type.
    pub fn part<T: Part>(&self) -> Option<&T> {
        self.parts
            .iter()
            .find_map(|p| (p.as_ref() as &dyn Any).downcast_ref())
    }

    /// Where each bus of the plant is reached, one line each.
    pub fn endpoints(&self) -> Vec<String> {
        self.parts.iter().flat_map(|p| p.endpoints()).collect()
    }

    /// Seconds since the plant started (the devices' clock).
    pub fn now(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// The token that stops the whole plant (a part's tasks run on its children).
    pub(crate) fn cancel(&self) -> &CancellationToken {
        &self.cancel
    }

    /// Stops serving.
    pub fn stop(&self) {
        self.cancel.cancel();
    }
}

impl Drop for Plant {
    fn drop(&mut self) {
        self.cancel.cancel();
    }
}
