//! The seam of an output that serves clients instead of holding an MQTT connection (the Modbus
//! TCP server for PLCs): what `app/` starts without knowing its protocol.

use tokio::sync::mpsc::{Sender, UnboundedReceiver};
use tokio::task::JoinHandle;

use crate::config::Config;
use crate::dispatch::Incoming;
use crate::reading::Output;

/// An output that serves clients.
pub trait Server: Send {
    /// The output's name (`[outputs.<name>]`).
    fn name(&self) -> &str;
    /// Runs it on the events of the fan-out, sending commands to `incoming`, taking reloads.
    fn start(
        self: Box<Self>,
        events: UnboundedReceiver<Output>,
        incoming: Sender<Incoming>,
        reloads: UnboundedReceiver<Config>,
    ) -> JoinHandle<()>;
}
