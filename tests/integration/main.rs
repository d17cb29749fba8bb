//! One integration binary: the gateway against the simulator over real pseudo-terminals and a
//! real Mosquitto broker.

mod batching;
mod big_messages;
mod billing;
mod burn_in;
mod clock;
mod commands;
mod commission;
mod config_cases;
mod counters;
mod dashboards;
mod edges;
mod edges_local;
mod faults;
mod fleet;
mod format_seam;
mod hostile;
mod local_socket;
mod mbus_frames;
mod mbus_gateway;
mod mbus_pymeterbus;
mod mbus_sim;
mod metering;
mod metrics;
mod outputs;
mod pipeline;
mod plants;
mod plc;
mod protocol;
mod pushes;
mod readings_first;
mod service;
mod sparkplug;
mod spool_truth;
mod status_page;
mod support;
