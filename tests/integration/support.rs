//! Real parts for the tests: a Mosquitto broker on a free loopback port, an MQTT subscriber,
#![allow(dead_code)] // shared helpers: not every test module uses each one
//! the simulated plant on real pseudo-terminals, and the gateway binary as a child process.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use pulsegate::sim::{Plant, SimConfig};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::mqttbytes::v5::Packet;
use rumqttc::v5::{AsyncClient, Event, MqttOptions};

/// A free TCP port on 127.0.0.1.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A fresh directory under the system temp dir.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "pulsegate-test-{name}-{}-{}",
        std::process::id(),
        free_port()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A Mosquitto broker on a free loopback port, stopped on drop.
pub struct Broker {
    pub port: u16,
    child: Child,
    conf: PathBuf,
}

impl Broker {
    pub fn start() -> Broker {
        let port = free_port();
        Self::start_on(port)
    }

    pub fn start_on(port: u16) -> Broker {
        // No per-client queue limit: a flood test must not lose messages in the broker on
        // their way to a slower test subscriber (Mosquitto's default drops beyond 1000).
        Self::start_with(port, "persistence false\nmax_queued_messages 0\n")
    }

    /// A broker that keeps sessions across its own restarts (saved at SIGTERM), and queues
    /// without limit for subscribers that are away.
    pub fn start_persistent(port: u16, dir: &Path) -> Broker {
        // Started as root, Mosquitto drops to its own user: its database directory must be
        // writable by that user, or the sessions are silently not saved.
        let db = dir.join("mosquitto");
        std::fs::create_dir_all(&db).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&db, std::fs::Permissions::from_mode(0o777)).unwrap();
        }
        Self::start_with(
            port,
            &format!(
                "persistence true\npersistence_location {}/\nmax_queued_messages 0\n",
                db.display()
            ),
        )
    }

    /// A broker with extra listener lines; `wait_port` is the one to wait for.
    pub fn start_with_config(port: u16, extra: &str, wait_port: u16) -> Broker {
        let b = Self::start_with(port, extra);
        let deadline = Instant::now() + Duration::from_secs(5);
        while std::net::TcpStream::connect(("127.0.0.1", wait_port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "mosquitto did not listen on {wait_port}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        b
    }

    /// A broker that also listens on a Unix socket at `socket` (Mosquitto >= 2.0:
    /// `listener 0 <path>`), returned once the socket takes connections.
    pub fn start_with_socket(port: u16, socket: &Path) -> Broker {
        // Started as root, Mosquitto drops to its own user before it binds: the socket's
        // directory must be writable by that user, or the listener fails.
        let dir = socket.parent().expect("socket in a directory");
        std::fs::create_dir_all(dir).unwrap();
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(dir, std::fs::Permissions::from_mode(0o777)).unwrap();
        }
        let b = Self::start_with(
            port,
            &format!(
                "persistence false\nmax_queued_messages 0\nlistener 0 {}\n",
                socket.display()
            ),
        );
        let deadline = Instant::now() + Duration::from_secs(5);
        while std::os::unix::net::UnixStream::connect(socket).is_err() {
            assert!(
                Instant::now() < deadline,
                "mosquitto did not listen on {}",
                socket.display()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        b
    }

    fn start_with(port: u16, extra: &str) -> Broker {
        let conf = std::env::temp_dir().join(format!("pulsegate-mosquitto-{port}.conf"));
        std::fs::write(
            &conf,
            format!("listener {port} 127.0.0.1\nallow_anonymous true\n{extra}"),
        )
        .unwrap();
        let mosquitto = ["/usr/sbin/mosquitto", "/usr/bin/mosquitto"]
            .into_iter()
            .find(|p| Path::new(p).exists())
            .expect("mosquitto is not installed: run the README's test command (scripts/test), which installs it");
        let child = Command::new(mosquitto)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto");
        let deadline = Instant::now() + Duration::from_secs(5);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "mosquitto did not start on port {port}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        Broker { port, child, conf }
    }

    /// The broker's process id (to stop and continue it).
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    pub fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// SIGTERM: the broker saves its sessions and exits.
    pub fn terminate(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let _ = self.child.wait();
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        self.stop();
        let _ = std::fs::remove_file(&self.conf);
    }
}

/// One received MQTT message.
#[derive(Debug, Clone)]
pub struct Message {
    pub topic: String,
    pub payload: String,
    pub retain: bool,
    pub at: Instant,
    pub correlation: Option<Vec<u8>>,
}

impl Message {
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.payload).unwrap_or(serde_json::Value::Null)
    }
}

/// A subscriber that records everything under a topic filter.
pub struct Subscriber {
    pub client: AsyncClient,
    messages: Arc<Mutex<Vec<Message>>>,
}

impl Subscriber {
    pub async fn start(port: u16, filter: &str) -> Subscriber {
        Self::start_with(port, filter, None, None).await
    }

    /// A subscriber whose session (and subscription) the broker keeps while it is away.
    pub async fn start_persistent(port: u16, filter: &str, client_id: &str) -> Subscriber {
        Self::start_with(port, filter, Some(client_id), None).await
    }

    /// A subscriber that logs in.
    pub async fn start_with_login(
        port: u16,
        filter: &str,
        user: &str,
        password: &str,
    ) -> Subscriber {
        Self::start_with(port, filter, None, Some((user, password))).await
    }

    async fn start_with(
        port: u16,
        filter: &str,
        persistent_id: Option<&str>,
        login: Option<(&str, &str)>,
    ) -> Subscriber {
        let id = persistent_id.map_or_else(|| format!("test-sub-{}", free_port()), str::to_string);
        let mut options = MqttOptions::new(id, "127.0.0.1", port);
        if let Some((u, p)) = login {
            options.set_credentials(u, p);
        }
        options.set_keep_alive(Duration::from_secs(30));
        // Tests send hostile commands larger than rumqttc's 10 KiB default; the recorder must
        // not be the one disconnected by them.
        options.set_max_packet_size(Some(1 << 20));
        if persistent_id.is_some() {
            options.set_clean_start(false);
            options.set_session_expiry_interval(Some(3600));
        }
        let (client, mut eventloop) = AsyncClient::new(options, 100);
        let messages = Arc::new(Mutex::new(Vec::new()));
        let sink = messages.clone();
        let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
        let mut ready_tx = Some(ready_tx);
        let sub = client.clone();
        let filter = filter.to_string();
        tokio::spawn(async move {
            loop {
                match eventloop.poll().await {
                    Ok(Event::Incoming(Packet::ConnAck(_))) => {
                        let _ = sub.try_subscribe(filter.clone(), QoS::AtLeastOnce);
                    }
                    Ok(Event::Incoming(Packet::SubAck(_))) => {
                        if let Some(tx) = ready_tx.take() {
                            let _ = tx.send(());
                        }
                    }
                    Ok(Event::Incoming(Packet::Publish(p))) => sink.lock().unwrap().push(Message {
                        topic: String::from_utf8_lossy(&p.topic).into(),
                        payload: String::from_utf8_lossy(&p.payload).into(),
                        retain: p.retain,
                        at: Instant::now(),
                        correlation: p
                            .properties
                            .and_then(|pr| pr.correlation_data)
                            .map(|b| b.to_vec()),
                    }),
                    Ok(_) => {}
                    Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
                }
            }
        });
        tokio::time::timeout(Duration::from_secs(5), ready_rx)
            .await
            .expect("subscribed")
            .unwrap();
        Subscriber { client, messages }
    }

    /// Publishes `payload` on `topic` as a command sender does: QoS 1, not retained.
    pub async fn send(&self, topic: &str, payload: impl Into<String>) {
        self.client
            .publish(topic, QoS::AtLeastOnce, false, payload.into())
            .await
            .unwrap();
    }

    pub fn all(&self) -> Vec<Message> {
        self.messages.lock().unwrap().clone()
    }

    pub fn on(&self, topic: &str) -> Vec<Message> {
        self.all()
            .into_iter()
            .filter(|m| m.topic == topic)
            .collect()
    }

    /// Waits until a message on `topic` satisfies `pred`; returns it.
    pub async fn wait_for(
        &self,
        topic: &str,
        timeout: Duration,
        pred: impl Fn(&Message) -> bool,
    ) -> Option<Message> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(m) = self.on(topic).into_iter().find(|m| pred(m)) {
                return Some(m);
            }
            if Instant::now() >= deadline {
                return None;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Waits until more than `n` messages arrived on `topic`, at most `timeout`; returns how
    /// many did (a generous deadline instead of a fixed sleep: a loaded machine gets its time,
    /// a fast one goes on at once).
    pub async fn wait_more_than(&self, topic: &str, n: usize, timeout: Duration) -> usize {
        let deadline = Instant::now() + timeout;
        loop {
            let got = self.on(topic).len();
            if got > n || Instant::now() >= deadline {
                return got;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Asserts that something arrives on `topic` within `timeout` (the gateway is up and
    /// publishing).
    pub async fn expect_any(&self, topic: &str, timeout: Duration) {
        assert!(
            self.wait_for(topic, timeout, |_| true).await.is_some(),
            "nothing on {topic} within {timeout:?}"
        );
    }

    pub fn clear(&self) {
        self.messages.lock().unwrap().clear();
    }
}

/// The gateway binary, killed on drop.
pub struct Gateway {
    child: Child,
    pub config: PathBuf,
    pub log: PathBuf,
}

pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_pulsegate")
}

impl Gateway {
    pub fn start(config: &Path) -> Gateway {
        Self::start_with_env(config, &[])
    }

    /// Starts the gateway with extra environment variables (e.g. libfaketime's).
    pub fn start_with_env(config: &Path, env: &[(&str, &str)]) -> Gateway {
        Self::spawn(config, env, &[])
    }

    /// Starts the gateway under `wrapper`, a command that sets something up and then runs its
    /// remaining arguments in its own process (`prlimit --nofile=64:64`): same process id.
    pub fn start_under(config: &Path, wrapper: &[&str]) -> Gateway {
        Self::spawn(config, &[], wrapper)
    }

    fn spawn(config: &Path, env: &[(&str, &str)], wrapper: &[&str]) -> Gateway {
        let log = config.with_extension("log");
        let mut command = match wrapper {
            [] => Command::new(bin()),
            [first, rest @ ..] => {
                let mut c = Command::new(first);
                c.args(rest).arg(bin());
                c
            }
        };
        let child = command
            .args(["run", "--config"])
            .arg(config)
            .envs(env.iter().copied())
            .env("RUST_LOG", "info,pulsegate=debug")
            .env_remove("PULSEGATE__MQTT__PORT")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .expect("start gateway");
        Gateway {
            child,
            config: config.to_path_buf(),
            log,
        }
    }

    pub fn pid(&self) -> i32 {
        self.child.id() as i32
    }

    pub fn signal(&self, sig: &str) {
        let _ = Command::new("kill")
            .args([&format!("-{sig}"), &self.pid().to_string()])
            .status();
    }

    /// SIGKILL: no chance to save anything.
    pub fn kill(mut self) {
        self.signal("KILL");
        let _ = self.child.wait();
    }

    /// SIGTERM and wait; returns the exit status and how long it took.
    pub fn terminate(mut self) -> (std::process::ExitStatus, Duration) {
        let t = Instant::now();
        self.signal("TERM");
        let status = self.child.wait().unwrap();
        (status, t.elapsed())
    }

    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Waits for the gateway to exit by itself, at most `timeout`; its status.
    pub fn wait_exit(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            if Instant::now() >= deadline {
                return None;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Gateway config text for a running plant: one bus per plant bus, with the devices given as
/// (bus, device, unit, model, poll) and extra TOML appended.
pub fn gateway_toml(
    plant: &Plant,
    broker_port: u16,
    state_dir: &Path,
    devices: &[(&str, &str, u8, &str, &str)],
    extra: &str,
) -> String {
    let t = pulsegate::sim::gateway::GatewayToml {
        id: "test",
        state_dir,
        gateway: "state_flush = \"500ms\"\n",
        mqtt_host: "127.0.0.1",
        mqtt_port: Some(broker_port),
        mqtt: "",
        serial: "baud = 115200\ntimeout = \"100ms\"\nbackoff_min = \"500ms\"\nbackoff_max = \"2s\"\n",
        tcp: "timeout = \"100ms\"\n",
    }
    .render(plant, devices);
    t + extra
}

/// Starts a plant from TOML.
/// A plant of one YL67 at factory state: `meter`, unit 1 on line1.
pub const ONE_METER: &str = "[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n";

/// The config of a gateway polling the one meter of `ONE_METER` every 200 ms.
pub fn one_meter_toml(plant: &Plant, broker_port: u16, dir: &Path, extra: &str) -> String {
    gateway_toml(
        plant,
        broker_port,
        dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        extra,
    )
}

pub async fn plant(toml: &str) -> Plant {
    Plant::start(&SimConfig::from_toml(toml).unwrap())
        .await
        .unwrap()
}

/// Writes `text` to `dir/pulsegate.toml`.
/// Wires a module of `model` in work `modes` at `unit` onto the running `bus` of the plant (in
/// place of whatever answered there).
pub fn wire_module(plant: &Plant, bus: &str, unit: u8, model: &str, modes: &[u16]) {
    let profiles = pulsegate::profile::Profiles::builtin();
    let profile = profiles.get(model).unwrap();
    let module = pulsegate::modbus::sim::SimModule::new(profile, modes).unwrap();
    plant
        .bus(bus)
        .unwrap()
        .modules
        .lock()
        .unwrap()
        .insert(unit, module);
}

pub fn write_config(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("pulsegate.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// Readings of one channel in arrival order, as JSON.
pub fn readings(sub: &Subscriber, topic: &str) -> Vec<serde_json::Value> {
    sub.on(topic).iter().map(Message::json).collect()
}

/// Writes the gateway config for `plant` (as [`gateway_toml`]) to `dir` and starts the gateway.
pub fn start_gateway(
    plant: &Plant,
    broker_port: u16,
    dir: &Path,
    devices: &[(&str, &str, u8, &str, &str)],
    extra: &str,
) -> Gateway {
    Gateway::start(&write_config(
        dir,
        &gateway_toml(plant, broker_port, dir, devices, extra),
    ))
}

/// Stops the pulses of `a0` on unit 1 of line1 (after `settle` of counting), lets the gateway
/// read that, stops the gateway cleanly, and returns the pulses the module generated.
pub async fn stop_counting_and_gateway(plant: &Plant, gw: Gateway, settle: Duration) -> i64 {
    tokio::time::sleep(settle).await;
    plant
        .with_module("line1", 1, |m, now| assert!(m.set_rate(now, "a0", 0.0)))
        .unwrap();
    tokio::time::sleep(Duration::from_secs(2)).await;
    let (status, _) = gw.terminate();
    assert!(status.success());
    plant
        .with_module("line1", 1, |m, now| m.channel("a0").unwrap().generated(now))
        .unwrap()
}

/// Runs openssl in `dir` (scripts/test installs it).
fn openssl(dir: &Path, args: &[&str]) {
    let ok = Command::new("openssl")
        .args(args)
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .expect("openssl (scripts/test installs it)");
    assert!(ok.success(), "openssl {args:?}");
}

/// A CA (`ca.pem`, `ca.key`) and a server certificate for 127.0.0.1 (`server.pem`,
/// `server.key`, readable by Mosquitto's own user), valid 30 days, made with openssl.
pub fn make_certs(dir: &Path) {
    openssl(
        dir,
        &[
            "req",
            "-x509",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            "ca.key",
            "-out",
            "ca.pem",
            "-days",
            "30",
            "-subj",
            "/CN=pulsegate test CA",
        ],
    );
    openssl(
        dir,
        &[
            "req",
            "-newkey",
            "rsa:2048",
            "-nodes",
            "-keyout",
            "server.key",
            "-out",
            "server.csr",
            "-subj",
            "/CN=127.0.0.1",
        ],
    );
    std::fs::write(dir.join("san.ext"), "subjectAltName=IP:127.0.0.1\n").unwrap();
    openssl(
        dir,
        &[
            "x509",
            "-req",
            "-in",
            "server.csr",
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-out",
            "server.pem",
            "-days",
            "30",
            "-extfile",
            "san.ext",
        ],
    );
    use std::os::unix::fs::PermissionsExt;
    for f in ["server.key", "ca.pem", "server.pem"] {
        std::fs::set_permissions(dir.join(f), std::fs::Permissions::from_mode(0o644)).unwrap();
    }
}

/// A client certificate for `cn` signed by [`make_certs`]'s CA, valid `days`:
/// `<name>.pem` and `<name>.key` (X.509 v3: rustls refuses v1).
pub fn client_certificate(dir: &Path, cn: &str, days: u32, name: &str) {
    let (key, csr, pem) = (
        format!("{name}.key"),
        format!("{name}.csr"),
        format!("{name}.pem"),
    );
    let subject = format!("/CN={cn}");
    openssl(
        dir,
        &[
            "req", "-newkey", "rsa:2048", "-nodes", "-keyout", &key, "-out", &csr, "-subj",
            &subject,
        ],
    );
    std::fs::write(dir.join("client.ext"), "extendedKeyUsage=clientAuth\n").unwrap();
    let days = days.to_string();
    openssl(
        dir,
        &[
            "x509",
            "-req",
            "-in",
            &csr,
            "-CA",
            "ca.pem",
            "-CAkey",
            "ca.key",
            "-CAcreateserial",
            "-out",
            &pem,
            "-days",
            &days,
            "-extfile",
            "client.ext",
        ],
    );
}

/// Waits until `done` holds, looking every 50 ms, and panics with `what` (and `why()`, e.g. the
/// gateway's log) when it does not within `within`: the condition wait that replaces a fixed
/// sleep (a loaded machine gets its time, a fast one goes on at once).
pub async fn until(
    within: Duration,
    what: &str,
    mut done: impl FnMut() -> bool,
    why: impl Fn() -> String,
) {
    let deadline = Instant::now() + within;
    while !done() {
        assert!(
            Instant::now() < deadline,
            "{what}: not within {within:?}\n{}",
            why()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Waits until the file at `path` was written `n` times more (its modification time moved `n`
/// times, e.g. a bus's state saved every `state_flush`), at most 30 s.
pub async fn saves_pass(path: &Path, n: usize) {
    let modified = || std::fs::metadata(path).and_then(|m| m.modified()).ok();
    let mut last = modified();
    let mut seen = 0;
    let deadline = Instant::now() + Duration::from_secs(30);
    while seen < n {
        assert!(
            Instant::now() < deadline,
            "{} saved {seen} of {n} times",
            path.display()
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
        let now = modified();
        if now != last {
            seen += 1;
            last = now;
        }
    }
}
