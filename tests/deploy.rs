//! The deployment files in deploy/ and the Debian package metadata in Cargo.toml agree with each
//! other, and the service unit stays hardened (`systemd-analyze security` exposure ≤ 2.0).
//! scripts/package-test goes further: it builds and installs the package.

use std::path::{Path, PathBuf};
use std::process::Command;

const MAX_EXPOSURE: f64 = 2.0;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    let path = repo().join(rel);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

/// `Key=value` settings of the unit (all sections, in order; comments and blanks skipped).
fn unit_settings() -> Vec<(String, String)> {
    read("deploy/pulsegate.service")
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#') && !l.starts_with(';'))
        .filter(|l| !l.starts_with('['))
        .filter_map(|l| l.split_once('='))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect()
}

fn unit_value(key: &str) -> String {
    let values: Vec<String> = unit_settings()
        .into_iter()
        .filter(|(k, _)| k == key)
        .map(|(_, v)| v)
        .collect();
    assert_eq!(
        values.len(),
        1,
        "expected exactly one {key}= in the unit, got {values:?}"
    );
    values.into_iter().next().unwrap()
}

/// The overall exposure score from `systemd-analyze security --offline=yes UNIT`.
fn exposure_score(unit: &Path) -> (f64, String) {
    let output = Command::new("systemd-analyze")
        .args(["security", "--offline=yes"])
        .arg(unit)
        .env("SYSTEMD_COLORS", "0")
        .env("SYSTEMD_PAGER", "")
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run systemd-analyze ({e}); install it with `apt-get install systemd` \
                 (scripts/test does this when it is missing)"
            )
        });
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    let line = stdout
        .lines()
        .find(|l| l.contains("Overall exposure level for"))
        .unwrap_or_else(|| {
            panic!("no 'Overall exposure level' line from systemd-analyze:\n{stdout}\n{stderr}")
        })
        .trim()
        .to_string();
    let score = line
        .rsplit_once(": ")
        .and_then(|(_, rest)| rest.split_whitespace().next())
        .and_then(|n| n.parse::<f64>().ok())
        .unwrap_or_else(|| panic!("cannot read the score in {line:?}"));
    (score, line)
}

#[test]
fn the_service_unit_scores_at_most_2_0_in_systemd_analyze_security() {
    let (score, line) = exposure_score(&repo().join("deploy/pulsegate.service"));
    assert!(
        score <= MAX_EXPOSURE,
        "deploy/pulsegate.service exposure {score} > {MAX_EXPOSURE}: {line}\n\
         run `systemd-analyze security --offline=yes deploy/pulsegate.service` for the details"
    );
}

#[test]
fn the_service_unit_keeps_what_the_daemon_needs() {
    assert_eq!(unit_value("Type"), "notify");
    assert_eq!(unit_value("NotifyAccess"), "main");
    assert_eq!(unit_value("User"), "pulsegate");
    // The state, and beside it the directory a config managed from the broker lives in (the
    // service owns it; /etc stays read-only under ProtectSystem=strict).
    assert_eq!(unit_value("StateDirectory"), "pulsegate pulsegate/remote");
    assert!(
        read("deploy/remote-config.conf")
            .contains("--config /var/lib/pulsegate/remote/pulsegate.toml"),
        "the drop-in points the service at the writable directory"
    );
    assert_eq!(unit_value("ConfigurationDirectory"), "pulsegate");
    assert_eq!(unit_value("ExecReload"), "/bin/kill -HUP $MAINPID");
    let groups = unit_value("SupplementaryGroups");
    assert!(
        groups.split_whitespace().any(|g| g == "dialout"),
        "SupplementaryGroups={groups}"
    );
    // AF_UNIX carries sd-notify and journald; AF_INET/AF_INET6 the broker and Modbus TCP.
    let families = unit_value("RestrictAddressFamilies");
    for family in ["AF_UNIX", "AF_INET", "AF_INET6"] {
        assert!(
            families.split_whitespace().any(|f| f == family),
            "{family} missing: {families}"
        );
    }
    // Serial ports must stay reachable: these settings would hide or unmap them.
    let settings = unit_settings();
    for (key, value) in &settings {
        assert!(
            !(matches!(
                key.as_str(),
                "PrivateDevices" | "PrivateUsers" | "DynamicUser"
            ) && matches!(value.as_str(), "yes" | "true" | "1" | "on")),
            "{key}={value} would cut the service off the serial ports or the dialout group"
        );
    }
    let allowed: Vec<&str> = settings
        .iter()
        .filter(|(k, _)| k == "DeviceAllow")
        .map(|(_, v)| v.as_str())
        .collect();
    for dev in [
        "char-ttyUSB rw",
        "char-ttyACM rw",
        "char-ttyS rw",
        // Raspberry Pi PL011, SC16IS7xx RS-485 HATs, i.MX boards (issue 11).
        "char-ttyAMA rw",
        "char-ttySC rw",
        "char-ttymxc rw",
    ] {
        assert!(
            allowed.contains(&dev),
            "DeviceAllow={dev} missing: {allowed:?}"
        );
    }
}

/// A bad config exits with status 2 (see `main`): systemd must not restart it every 5 s forever.
#[test]
fn a_bad_config_is_not_restarted_forever() {
    let prevent = unit_value("RestartPreventExitStatus");
    assert!(
        prevent.split_whitespace().any(|s| s == "2"),
        "RestartPreventExitStatus={prevent}"
    );
    let dir = std::env::temp_dir().join(format!("pulsegate-deploy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("bad.toml");
    std::fs::write(&config, "[gateway]\nidd = 1\n").unwrap();
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_pulsegate"))
        .args(["run", "--config"])
        .arg(&config)
        .stderr(std::process::Stdio::null())
        .status()
        .unwrap();
    assert_eq!(
        status.code(),
        Some(2),
        "a bad config exits with the status systemd is told"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn sysusers_puts_the_pulsegate_user_in_dialout() {
    let text = read("deploy/sysusers.d/pulsegate.conf");
    let lines: Vec<Vec<&str>> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| l.split_whitespace().collect())
        .collect();
    assert!(
        lines
            .iter()
            .any(|f| f.len() >= 2 && f[0] == "u" && f[1] == "pulsegate"),
        "no `u pulsegate` line in:\n{text}"
    );
    assert!(
        lines.iter().any(|f| f[..] == ["m", "pulsegate", "dialout"]),
        "no `m pulsegate dialout` line in:\n{text}"
    );
}

/// (source, destination) of every asset of `[package.metadata.deb]`, destination absolute and,
/// where it names a directory, completed with the source's file name.
fn deb_assets(deb: &toml::Table) -> Vec<(String, String)> {
    let assets = deb["assets"]
        .as_array()
        .expect("package.metadata.deb.assets is an array");
    assets
        .iter()
        .map(|a| {
            let a = a
                .as_array()
                .expect("an asset is [source, destination, mode]");
            let src = a[0].as_str().unwrap().to_string();
            let mut dest = format!("/{}", a[1].as_str().unwrap().trim_start_matches('/'));
            if dest.ends_with('/') {
                dest.push_str(Path::new(&src).file_name().unwrap().to_str().unwrap());
            }
            (src, dest)
        })
        .collect()
}

fn deb_metadata() -> toml::Table {
    let manifest: toml::Table = read("Cargo.toml").parse().expect("Cargo.toml parses");
    manifest["package"]["metadata"]["deb"]
        .as_table()
        .expect("[package.metadata.deb] in Cargo.toml")
        .clone()
}

fn installed_at(assets: &[(String, String)], src: &str) -> Vec<String> {
    assets
        .iter()
        .filter(|(s, _)| s == src)
        .map(|(_, d)| d.clone())
        .collect()
}

#[test]
fn the_unit_runs_the_binary_and_config_the_package_installs() {
    let deb = deb_metadata();
    let assets = deb_assets(&deb);
    let exec = unit_value("ExecStart");
    let words: Vec<&str> = exec.split_whitespace().collect();

    let binary = installed_at(&assets, "target/release/pulsegate");
    assert_eq!(binary, ["/usr/bin/pulsegate"], "the binary's deb asset");
    assert_eq!(
        words[0], binary[0],
        "ExecStart={exec} does not run the packaged binary"
    );

    let config = words
        .windows(2)
        .find(|w| w[0] == "--config")
        .map(|w| w[1])
        .unwrap_or_else(|| panic!("no --config in ExecStart={exec}"));
    assert!(
        installed_at(&assets, "config/pulsegate.example.toml")
            .iter()
            .any(|d| d == config),
        "ExecStart's --config {config} is not installed by the package"
    );
    let conf_files: Vec<&str> = deb["conf-files"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(
        conf_files.contains(&config),
        "{config} is not a conffile: {conf_files:?}"
    );

    assert_eq!(
        installed_at(&assets, "deploy/pulsegate.service"),
        ["/lib/systemd/system/pulsegate.service"]
    );
    assert_eq!(
        installed_at(&assets, "deploy/sysusers.d/pulsegate.conf"),
        ["/usr/lib/sysusers.d/pulsegate.conf"]
    );
}

#[test]
fn every_deb_asset_and_maintainer_script_exists() {
    let deb = deb_metadata();
    for (src, _) in deb_assets(&deb) {
        if src.starts_with("target/") {
            continue; // built by `cargo deb`
        }
        assert!(
            repo().join(&src).is_file(),
            "deb asset {src} does not exist"
        );
    }
    let scripts = deb["maintainer-scripts"].as_str().unwrap();
    for name in ["postinst", "prerm", "postrm"] {
        let path = repo().join(scripts).join(name);
        let text = std::fs::read_to_string(&path)
            .unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
        assert!(
            text.starts_with("#!/bin/sh\n"),
            "{name} is not a /bin/sh script"
        );
        // systemctl calls that need a running systemd are guarded (package builds, containers).
        for line in text.lines().filter(|l| {
            l.contains("systemctl ") && !l.contains("--no-reload") && !l.trim().starts_with('#')
        }) {
            assert!(
                text.contains("[ -d /run/systemd/system ]"),
                "{name}: `{}` is not guarded by [ -d /run/systemd/system ]",
                line.trim()
            );
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&path).unwrap().permissions().mode();
            assert!(mode & 0o111 != 0, "{name} is not executable");
        }
    }
}
