//! The `pulsegate` command: a thin shell over the library.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;
use clap::{Parser, Subcommand, ValueEnum};
use tokio_util::sync::CancellationToken;

use pulsegate::config::{Config, DEFAULT_PATH};

#[derive(Parser)]
#[command(
    version,
    about = "Pulse counters, encoders and meters → MQTT, SCADA, Prometheus and PLCs"
)]
struct Cli {
    /// Log format.
    #[arg(long, global = true, value_enum, default_value_t = LogFormat::Human)]
    log_format: LogFormat,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum StateAction {
    /// Every saved channel: bus, unit/model/channel, total, count, and its device.
    List,
    /// Remove saved state that matches no configured device (a dry run unless --apply).
    /// Stop the gateway first: a running one saves what it holds.
    Prune {
        #[arg(long)]
        apply: bool,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum LogFormat {
    Human,
    Json,
}

#[derive(Subcommand)]
enum Command {
    /// Run the gateway.
    Run {
        #[arg(long, default_value = DEFAULT_PATH)]
        config: PathBuf,
    },
    /// Validate a config and print its poll plan; exit 0 when valid.
    Check {
        #[arg(long, default_value = DEFAULT_PATH)]
        config: PathBuf,
        /// Print the register map of the Modbus server outputs (docs/plc.md) instead of the
        /// poll plan.
        #[arg(long)]
        register_map: bool,
        /// With --register-map: the map as a JSON list on standard output, nothing else there.
        #[arg(long, requires = "register_map")]
        json: bool,
    },
    /// Print the billing periods each metered channel keeps (the state files'; 12 by default).
    Billing {
        #[arg(long, default_value = DEFAULT_PATH)]
        config: PathBuf,
        /// One JSON object per period and channel, one a line.
        #[arg(long)]
        json: bool,
        /// How many periods per channel, the newest last.
        #[arg(long, default_value_t = 12)]
        last: usize,
    },
    /// Check signed interval and billing records (docs/metering.md): each is valid, tampered,
    /// or missing (a seq skipped). Exit 0 when every record is valid and none is missing.
    Verify {
        /// Captured lines (`mosquitto_sub -v` or plain JSON, one a line); `-` for standard input.
        #[arg(required_unless_present = "topic")]
        file: Option<PathBuf>,
        /// Read this topic (e.g. `pulsegate/+/+/billing`) from the broker of --config instead.
        #[arg(long, conflicts_with = "file", requires = "seconds")]
        topic: Option<String>,
        /// With --topic: how long to listen.
        #[arg(long)]
        seconds: Option<u64>,
        /// The gateway's public key (base64 of 32 bytes); default: from its `<root>/gateway`
        /// marker in the capture.
        #[arg(long)]
        key: Option<String>,
        #[arg(long, default_value = DEFAULT_PATH)]
        config: PathBuf,
    },
    /// Print the compiled poll plan per bus with line time per cycle.
    Plan {
        #[arg(long, default_value = DEFAULT_PATH)]
        config: PathBuf,
    },
    /// Show the saved counter state, or prune what matches no configured device.
    State {
        #[arg(long, default_value = DEFAULT_PATH, global = true)]
        config: PathBuf,
        #[command(subcommand)]
        action: StateAction,
    },
    /// Set a channel's meter reading to the meter's display (the running gateway does it; the
    /// total, the deltas and the intervals do not move, and nothing is written to the module).
    SetReading {
        #[arg(long, default_value = DEFAULT_PATH)]
        config: PathBuf,
        device: String,
        channel: String,
        /// The meter's display, in the channel's unit (e.g. 12345.678).
        value: String,
        /// How long to wait for the gateway's result.
        #[arg(long, default_value = "10s")]
        wait: humantime::Duration,
    },
    /// Serve simulated modules on pseudo-terminals and TCP ports.
    Simulate {
        #[arg(long)]
        config: PathBuf,
    },
    /// A simulated plant of every supported module and the gateway, with a live table.
    Demo {
        /// Use this broker instead of the embedded one.
        #[arg(long, value_name = "HOST:PORT")]
        mqtt: Option<String>,
        /// Stop after this long (default: until Ctrl-C).
        #[arg(long)]
        duration: Option<humantime::Duration>,
    },
    /// Keys and signed pushes for `[remote] trusted_keys` (docs/operations.md).
    Config {
        #[command(subcommand)]
        action: ConfigAction,
    },
    #[command(flatten)]
    Commission(Box<pulsegate::commission::Commission>),
}

#[derive(Subcommand)]
enum ConfigAction {
    /// A new Ed25519 signing key (PKCS#8 PEM, as `openssl genpkey -algorithm ed25519` writes);
    /// prints its public key for `[remote] trusted_keys`.
    Keygen {
        /// Write the key here (mode 0600, never over an existing file); without it the key goes
        /// to standard output and the public key to standard error.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Prints the JSON to publish on `<root>/config/set`: FILE signed for one gateway.
    Sign {
        /// The signing key (PKCS#8 PEM).
        #[arg(long)]
        key: PathBuf,
        /// The gateway's id (`gateway.id`): the push is taken by that gateway only.
        #[arg(long)]
        gateway: String,
        /// The push's id, echoed in its results.
        #[arg(long)]
        id: String,
        /// Greater than the last serial the gateway took.
        #[arg(long)]
        serial: u64,
        file: PathBuf,
    },
}

/// Logs to journald when systemd started us with the journal on stderr (JOURNAL_STREAM), as
/// readable text on stderr otherwise (colours only on a terminal), or as JSON lines with
/// `--log-format json`.
fn init_logging(format: LogFormat, default_filter: &str) {
    use std::io::IsTerminal;
    use tracing_subscriber::prelude::*;
    let filter = || {
        tracing_subscriber::EnvFilter::try_from_default_env()
            .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter))
    };
    if matches!(format, LogFormat::Human)
        && std::env::var_os("JOURNAL_STREAM").is_some()
        && let Ok(journald) = tracing_journald::layer()
    {
        tracing_subscriber::registry()
            .with(filter())
            .with(journald.with_syslog_identifier("pulsegate".into()))
            .init();
        return;
    }
    // A closed stderr (a pipe whose reader went away) must not panic the gateway: write errors
    // are dropped, not reported on the very stderr that failed.
    let builder = tracing_subscriber::fmt()
        .log_internal_errors(false)
        .with_env_filter(filter())
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr);
    match format {
        LogFormat::Human => builder.init(),
        LogFormat::Json => builder.json().init(),
    }
}

/// Cancels `token` at SIGTERM or SIGINT; a second signal exits at once.
fn on_signals(token: CancellationToken) -> anyhow::Result<()> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate())?;
    let mut int = signal(SignalKind::interrupt())?;
    tokio::spawn(async move {
        tokio::select! { _ = term.recv() => {}, _ = int.recv() => {} }
        tracing::info!("shutting down");
        token.cancel();
        tokio::select! { _ = term.recv() => {}, _ = int.recv() => {} }
        std::process::exit(130);
    });
    Ok(())
}

/// SIGHUP reloads the config file: a valid one goes to the running gateway, a bad one is
/// refused (logged) and the old one keeps running.
fn on_hangup(path: PathBuf) -> anyhow::Result<tokio::sync::mpsc::UnboundedReceiver<Config>> {
    use tokio::signal::unix::{SignalKind, signal};
    let mut hup = signal(SignalKind::hangup())?;
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        while hup.recv().await.is_some() {
            match Config::load(&path) {
                Ok(c) => {
                    tracing::info!(config = %path.display(), "reloading the config");
                    if tx.send(c).is_err() {
                        break;
                    }
                }
                Err(e) => tracing::error!(
                    "new config refused, the old one keeps running: {}",
                    e.to_string().trim_end()
                ),
            }
        }
    });
    Ok(rx)
}

/// Starts this program again in this process (same arguments, same pid: systemd's notify and
/// watchdog go on), for a pushed config only a new start applies. Returns only when that
/// fails: then the exit status asks the service to start it.
fn start_again() -> ExitCode {
    use std::os::unix::process::CommandExt;
    let exe = match std::env::current_exe() {
        Ok(e) => e,
        Err(e) => {
            tracing::error!("cannot find this program to start it again: {e}");
            return ExitCode::from(pulsegate::app::REBOOT_STATUS);
        }
    };
    tracing::info!("starting again for the pushed config");
    let e = std::process::Command::new(exe)
        .args(std::env::args_os().skip(1))
        .exec();
    tracing::error!("cannot start again: {e}; exiting for the service to start the gateway");
    ExitCode::from(pulsegate::app::REBOOT_STATUS)
}

/// Writes to stderr, ignoring failure (`eprint!` panics when stderr is closed).
fn say_err(text: std::fmt::Arguments<'_>) {
    use std::io::Write as _;
    let _ = std::io::stderr().write_fmt(text);
}

fn load(path: &std::path::Path) -> Result<Config, ExitCode> {
    Config::load(path).map_err(|e| {
        say_err(format_args!("{e}"));
        ExitCode::from(2)
    })
}

/// One thread does the gateway's work: it waits on I/O nearly all the time, and one thread
/// wakes far less often than a pool handing tasks to each other (the 1000-device benchmark
/// measures this). Blocking work (state files, precise sleeps) goes to tokio's blocking pool.
fn main() -> ExitCode {
    let cli = Cli::parse();
    // Commissioning commands talk to a person: the poller's info logs would only be noise.
    let quiet = pulsegate::protocols::QUIET_LIBRARIES;
    let default_filter = match cli.command {
        Command::Commission(_) => format!("warn,{quiet}"),
        _ => format!("info,{quiet},rumqttc=warn,rumqttd=off"),
    };
    init_logging(cli.log_format, &default_filter);
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(r) => r,
        Err(e) => {
            say_err(format_args!("error: cannot start the async runtime: {e}\n"));
            return ExitCode::FAILURE;
        }
    };
    match runtime.block_on(run(cli.command)) {
        Ok(code) => code,
        Err(e) => {
            say_err(format_args!("error: {e:#}\n"));
            ExitCode::FAILURE
        }
    }
}

async fn run(command: Command) -> anyhow::Result<ExitCode> {
    match command {
        Command::Commission(c) => Ok(pulsegate::protocols::commission(*c).await),
        Command::Check {
            config,
            register_map,
            json,
        } => check(&config, register_map, json),
        Command::Plan { config } => check(&config, false, false),
        Command::Billing { config, json, last } => {
            let config = match load(&config) {
                Ok(c) => c,
                Err(code) => return Ok(code),
            };
            match pulsegate::billing_report::billing(&config, json, last) {
                Ok(text) => print!("{text}"),
                Err(e) => anyhow::bail!(e),
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Run { config: path } => run_gateway(path).await,
        Command::State { config, action } => {
            let config = match load(&config) {
                Ok(c) => c,
                Err(code) => return Ok(code),
            };
            state_command(&config, action)
        }
        Command::SetReading {
            config,
            device,
            channel,
            value,
            wait,
        } => set_reading(&config, &device, &channel, &value, wait.into()).await,
        Command::Simulate { config } => simulate(&config).await,
        Command::Config { action } => config_command(action),
        Command::Verify {
            file,
            topic,
            seconds,
            key,
            config,
        } => verify_command(file, topic, seconds, key, &config).await,
        Command::Demo { mqtt, duration } => {
            if duration.is_some_and(|d| *d > std::time::Duration::from_secs(7 * 24 * 3600)) {
                anyhow::bail!("--duration: at most 7 days");
            }
            let shutdown = CancellationToken::new();
            on_signals(shutdown.clone())?;
            pulsegate::demo::run(mqtt.as_deref(), duration.map(Into::into), shutdown).await?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// `pulsegate run`: the gateway until SIGTERM, reloading at SIGHUP.
async fn run_gateway(path: PathBuf) -> anyhow::Result<ExitCode> {
    let config = match load(&path) {
        Ok(c) => c,
        Err(code) => return Ok(code),
    };
    let shutdown = CancellationToken::new();
    on_signals(shutdown.clone())?;
    let reloads = on_hangup(path)?;
    tracing::info!(config = %config.source.display(), gateway = %config.gateway.id, "pulsegate starting");
    if let Some(host) = &config.gateway.id_from_hostname {
        tracing::warn!(hostname = %host, gateway = %config.gateway.id, "gateway.id is not set: using one derived from the hostname; set gateway.id to make it explicit");
    }
    match pulsegate::app::run_with_reloads(config, shutdown, reloads).await {
        pulsegate::app::Ended::Stopped => Ok(ExitCode::SUCCESS),
        pulsegate::app::Ended::Reboot => Ok(ExitCode::from(pulsegate::app::REBOOT_STATUS)),
        pulsegate::app::Ended::Restart => Ok(start_again()),
    }
}

/// `pulsegate simulate`: simulated modules until SIGTERM.
async fn simulate(config: &std::path::Path) -> anyhow::Result<ExitCode> {
    let text =
        std::fs::read_to_string(config).with_context(|| format!("reading {}", config.display()))?;
    let sim = pulsegate::sim::SimConfig::from_toml(&text)?;
    let plant = pulsegate::sim::Plant::start(&sim).await?;
    for endpoint in plant.endpoints() {
        println!("{endpoint}");
    }
    let shutdown = CancellationToken::new();
    on_signals(shutdown.clone())?;
    shutdown.cancelled().await;
    plant.stop();
    Ok(ExitCode::SUCCESS)
}

/// `pulsegate check` (and `plan`): the poll plan and warnings, or the register map.
fn check(path: &std::path::Path, register_map: bool, json: bool) -> anyhow::Result<ExitCode> {
    let config = match load(path) {
        Ok(c) => c,
        Err(code) => return Ok(code),
    };
    if register_map {
        if let Some(note) = config.outputs.register_map_note() {
            say_err(format_args!("{note}\n"));
        }
        print!("{}", pulsegate::report::register_map(&config, json));
        return Ok(ExitCode::SUCCESS);
    }
    print!("{}", pulsegate::report::poll_plan(&config));
    if let Some(cal) = &config.gateway.tariffs {
        let now = pulsegate::reading::unix_ms(std::time::SystemTime::now()) as i64;
        let clock = &config.gateway.clock;
        print!(
            "{}",
            pulsegate::metering::tariff::describe(cal, clock, now, 6)
        );
    }
    let spool = config.gateway.state_dir.join("spool");
    if let Err(e) = pulsegate::publish::spool_place::usable(&spool) {
        println!(
            "warning: the spool cannot be kept in {} ({e}): the gateway would spool in a fresh private temporary directory, lost at reboot",
            spool.display()
        );
    }
    if let Some(host) = &config.gateway.id_from_hostname {
        println!(
            "gateway.id is not set: \"{}\" (from the hostname {host:?})",
            config.gateway.id
        );
    }
    if let Some(why) = pulsegate::remote::writable::problem(&config) {
        println!("warning: {why}");
    }
    println!("config {} is valid", config.source.display());
    Ok(ExitCode::SUCCESS)
}

/// `pulsegate set-reading`: prints the gateway's result; exit 0 when it says ok.
async fn set_reading(
    config: &std::path::Path,
    device: &str,
    channel: &str,
    value: &str,
    wait: std::time::Duration,
) -> anyhow::Result<ExitCode> {
    let config = match load(config) {
        Ok(c) => c,
        Err(code) => return Ok(code),
    };
    let result = pulsegate::setreading::run(&config, device, channel, value, wait).await?;
    println!("{result}");
    Ok(if result["ok"] == true {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// `pulsegate verify`: the lines of a file, or of a topic read from the broker, judged.
async fn verify_command(
    file: Option<PathBuf>,
    topic: Option<String>,
    seconds: Option<u64>,
    key: Option<String>,
    config: &std::path::Path,
) -> anyhow::Result<ExitCode> {
    let lines = match (file, topic) {
        (Some(file), _) => read_lines(&file)?,
        (None, Some(topic)) => {
            let config = match load(config) {
                Ok(c) => c,
                Err(code) => return Ok(code),
            };
            let secs = std::time::Duration::from_secs(seconds.unwrap_or(10));
            pulsegate::verify::capture(&config, &topic, secs).await?
        }
        (None, None) => anyhow::bail!("give a file of captured records or --topic"),
    };
    verify(key.as_deref(), &lines)
}

/// The lines of `file` (`-`: standard input).
fn read_lines(file: &std::path::Path) -> anyhow::Result<Vec<String>> {
    let text = if file == std::path::Path::new("-") {
        std::io::read_to_string(std::io::stdin())?
    } else {
        std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?
    };
    Ok(text.lines().map(str::to_string).collect())
}

/// Prints what each captured line says; fails when one is not what the gateway signed.
fn verify(key: Option<&str>, lines: &[String]) -> anyhow::Result<ExitCode> {
    use pulsegate::verify::{Finding, judge_all, parse_key};
    let key = key.map(parse_key).transpose().map_err(anyhow::Error::msg)?;
    let found = judge_all(key, lines);
    for f in &found {
        println!("{f}");
    }
    let valid = found
        .iter()
        .filter(|f| matches!(f, Finding::Valid { .. }))
        .count();
    let bad = found.iter().filter(|f| f.is_bad()).count();
    println!("{valid} valid, {bad} not");
    Ok(if bad == 0 && valid > 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}

/// `pulsegate config keygen|sign`.
fn config_command(action: ConfigAction) -> anyhow::Result<ExitCode> {
    use pulsegate::remote::signature::{SigningKey, signed_push};
    match action {
        ConfigAction::Keygen { out } => {
            let pem = SigningKey::generate_pem()?;
            let public = SigningKey::from_pem(&pem)?.public_base64();
            match out {
                Some(path) => {
                    use std::io::Write as _;
                    use std::os::unix::fs::OpenOptionsExt as _;
                    let mut f = std::fs::OpenOptions::new()
                        .write(true)
                        .create_new(true)
                        .mode(0o600)
                        .open(&path)
                        .with_context(|| format!("writing {}", path.display()))?;
                    f.write_all(pem.as_bytes())?;
                    println!("{public}");
                }
                None => {
                    print!("{pem}");
                    say_err(format_args!("public key: {public}\n"));
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        ConfigAction::Sign {
            key,
            gateway,
            id,
            serial,
            file,
        } => {
            let pem = std::fs::read_to_string(&key)
                .with_context(|| format!("reading {}", key.display()))?;
            let key = SigningKey::from_pem(&pem).with_context(|| key.display().to_string())?;
            let toml = std::fs::read_to_string(&file)
                .with_context(|| format!("reading {}", file.display()))?;
            println!("{}", signed_push(&key, &gateway, &id, serial, &toml));
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// `pulsegate state list|prune`.
fn state_command(config: &Config, action: StateAction) -> anyhow::Result<ExitCode> {
    use pulsegate::state::BusState;
    use pulsegate::state::prune;
    let files = prune::files(&config.gateway.state_dir)?;
    // A prune that writes claims the state directory as the running gateway does: never both.
    let _lock = match action {
        StateAction::Prune { apply: true } => Some(
            pulsegate::state::lock::StateLock::take(&config.gateway.state_dir)
                .context("state prune --apply")?,
        ),
        _ => None,
    };
    let mut unmatched = 0;
    for (bus, path) in files {
        // Only reads: a file the tool cannot take (a newer format) stays where it is.
        let state = BusState::inspect(&path)?;
        let entries = prune::entries(config, &bus, &state);
        unmatched += entries.iter().filter(|e| e.device.is_none()).count();
        match action {
            StateAction::List => {
                for e in &entries {
                    println!("{}", prune::line(e));
                }
            }
            StateAction::Prune { apply } => {
                for e in entries.iter().filter(|e| e.device.is_none()) {
                    let verb = if apply { "removed" } else { "would remove" };
                    println!("{verb}: {}", prune::line(e));
                }
                let kept = prune::pruned(config, &bus, &state);
                if apply && kept != state {
                    kept.save_from_tool(&path)?;
                }
            }
        }
    }
    if let StateAction::Prune { apply: false } = action
        && unmatched > 0
    {
        println!(
            "dry run: {unmatched} saved channel(s) match no configured device; --apply removes them"
        );
    }
    Ok(ExitCode::SUCCESS)
}
