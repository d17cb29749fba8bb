//! The spool and `boot.json` tell the truth under faults (issue 31): a full disk is never a
//! success, a bad line costs only that line, only the spool's own files are ever removed, a
//! missing `boot.json` is not a second gateway, and binary payloads are kept as bytes.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use crate::hostile::{KILLED_ENCODER, consume, stop_and_collect};
use crate::support::*;

/// A tmpfs of `size` mounted at a fresh directory, unmounted on drop (the tests run as root).
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(at: &Path, size: &str) -> Tmpfs {
        std::fs::create_dir_all(at).unwrap();
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(at)
            .status()
            .is_ok_and(|s| s.success());
        assert!(
            mounted,
            "the full-disk test mounts a small tmpfs: run the tests as root (scripts/test)"
        );
        Tmpfs(at.to_path_buf())
    }

    /// Writes a file until the disk is full; returns it (remove it and the disk is back).
    fn fill(&self) -> PathBuf {
        let filler = self.0.join("filler");
        let mut f = std::fs::File::create(&filler).unwrap();
        while f.write_all(&[0u8; 4096]).is_ok() {}
        let _ = f.sync_all();
        filler
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// Every file under `dir`, recursively (links not followed).
fn files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let t = e.file_type().unwrap();
        if t.is_dir() {
            out.extend(files(&e.path()));
        } else {
            out.push(e.path());
        }
    }
    out
}

/// Entries in the spool's segment files under `state`.
fn entries_on_disk(state: &Path) -> usize {
    files(&state.join("spool"))
        .iter()
        .filter(|p| pulsegate::publish::spool::is_segment_name(&name_of(p)))
        .map(|p| {
            std::fs::read(p)
                .unwrap_or_default()
                .split(|&b| b == b'\n')
                .filter(|l| serde_json::from_slice::<serde_json::Value>(l).is_ok())
                .count()
        })
        .sum()
}

fn name_of(p: &Path) -> String {
    p.file_name().unwrap().to_string_lossy().into_owned()
}

/// The `messages=N` of the log line that contains `what`, if there is one.
fn messages_in(log: &str, what: &str) -> Option<usize> {
    let line = log.lines().find(|l| l.contains(what))?;
    let at = line.find("messages=")? + "messages=".len();
    line[at..]
        .split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()
}

/// A full disk and the broker away, then the gateway stopped: it claims to keep only what is
/// on disk and says what it could not write; the spool's errors stay within their budget; no
/// temp file is left. With the disk and the broker back, a consumer's count is still exact.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_is_never_reported_as_kept_and_the_count_stays_exact() {
    let dir = temp_dir("spool-full-disk");
    let disk = Tmpfs::mount(&dir.join("state"), "1m");
    let state = disk.0.clone();
    let port = free_port();
    let mut broker = Broker::start_persistent(port, &dir);
    let plant = plant(KILLED_ENCODER).await;
    let topic = "pulsegate/test/m/a0";
    let sub = Subscriber::start_persistent(port, topic, "spool-full-disk-consumer").await;
    let devices = [("line1", "m", 1, "yl67", "100ms")];
    let config = write_config(&dir, &gateway_toml(&plant, port, &state, &devices, ""));
    let gw = Gateway::start(&config);
    sub.wait_more_than(topic, 5, Duration::from_secs(10)).await;

    let filler = disk.fill();
    broker.terminate();
    // The spool's first write fails (said in an ERROR line); a few seconds more of failing
    // writes, polled ten times a second, to hold its errors to their budget.
    let failing = || {
        let log = gw.log_text();
        log.lines()
            .any(|l| l.contains("ERROR") && l.contains("spool"))
    };
    until(
        Duration::from_secs(20),
        "a failed spool write",
        failing,
        || gw.log_text(),
    )
    .await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    let log_path = gw.log.clone();
    let (status, _) = gw.terminate();
    assert!(status.success());
    let log = std::fs::read_to_string(&log_path).unwrap();

    let on_disk = entries_on_disk(&state);
    let kept = messages_in(&log, "unsent messages kept for the next start").unwrap_or(0);
    assert_eq!(
        kept, on_disk,
        "the stop claims only what is on disk:\n{log}"
    );
    let lost = messages_in(&log, "could not be written to the spool");
    assert!(lost.is_some_and(|n| n > 0), "and says what is not:\n{log}");
    let errors: Vec<&str> = log.lines().filter(|l| l.contains("ERROR")).collect();
    let spool_errors = errors.iter().filter(|l| l.contains("spool")).count();
    assert!(
        spool_errors <= 6,
        "{spool_errors} spool errors in a few seconds:\n{}",
        errors.join("\n")
    );
    assert!(errors.len() <= 10, "{}", errors.join("\n"));
    println!("with the disk full:\n{}", errors.join("\n"));
    let temps: Vec<PathBuf> = files(&state)
        .into_iter()
        .filter(|p| name_of(p).ends_with(".tmp"))
        .collect();
    assert!(temps.is_empty(), "temp files left: {temps:?}");

    std::fs::remove_file(filler).unwrap();
    let _broker = Broker::start_persistent(port, &dir);
    let gw = Gateway::start(&config);
    let (all, generated) = stop_and_collect(&plant, &sub, gw, topic).await;
    let first_count = all[0]["count"].as_i64().unwrap();
    let last = all.last().unwrap();
    assert_eq!(
        last["total"].as_i64().unwrap(),
        generated - first_count,
        "total"
    );
    assert_eq!(consume(&all), generated - first_count, "summed deltas");
}

/// A spool file from an earlier run with a line that is not UTF-8 between two messages: both
/// messages are sent, the bad line is logged with its offset, and the file is kept aside
/// rather than deleted.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_line_in_a_spool_file_costs_only_that_line() {
    let broker = Broker::start();
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("spool-bad-line");
    let spool = dir.join("spool").join("json");
    std::fs::create_dir_all(&spool).unwrap();
    let name = format!("{:020}.jsonl", 1);
    let mut text = Vec::new();
    text.extend_from_slice(
        br#"{"seq":1,"topic":"app/before","payload":"one","qos":1,"retain":false}"#,
    );
    text.push(b'\n');
    let bad_at = text.len();
    text.extend_from_slice(b"{\"seq\":2,\"topic\":\"app/\xff\xfe\",\"payload\":\"x\"}\n");
    text.extend_from_slice(
        br#"{"seq":3,"topic":"app/after","payload":"three","qos":1,"retain":false}"#,
    );
    text.push(b'\n');
    std::fs::write(spool.join(&name), &text).unwrap();
    let sub = Subscriber::start(broker.port, "app/#").await;
    let gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        "",
    );
    for (topic, payload) in [("app/before", "one"), ("app/after", "three")] {
        assert!(
            sub.wait_for(topic, Duration::from_secs(10), |m| m.payload == payload)
                .await
                .is_some(),
            "{topic} is sent:\n{}",
            gw.log_text()
        );
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    let aside = spool.join(format!("{name}.unreadable"));
    while !aside.exists() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(aside.exists(), "kept aside: {:?}", files(&spool));
    assert!(!spool.join(&name).exists(), "never sent twice");
    let log = gw.log_text();
    assert!(
        log.contains(&format!("line at byte {bad_at} of")),
        "the offset is logged:\n{log}"
    );
}

/// Files in the spool directory that are not the spool's, in the directory of an output that
/// is a symlink, and in the old shared one: none is read, moved or removed, while messages are
/// spooled through that directory and sent.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn foreign_files_in_the_spool_directories_survive() {
    let port = free_port();
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("spool-foreign");
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    std::fs::create_dir_all(dir.join("spool")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, dir.join("spool").join("json")).unwrap();
    let foreign = [
        elsewhere.join("notes.jsonl"),
        elsewhere.join("readme.txt"),
        elsewhere.join("1.jsonl"),
        dir.join("spool").join("notes.jsonl"),
    ];
    for f in &foreign {
        std::fs::write(f, "").unwrap();
    }
    let topic = "pulsegate/test/meter/enc0";
    let gw = start_gateway(
        &plant,
        port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        "",
    );
    // No broker: readings are spooled, through the linked directory.
    let segments = || {
        files(&elsewhere)
            .into_iter()
            .filter(|p| pulsegate::publish::spool::is_segment_name(&name_of(p)))
            .count()
    };
    until(
        Duration::from_secs(10),
        "spooled through the link",
        || segments() > 0,
        || format!("{:?}\n{}", files(&elsewhere), gw.log_text()),
    )
    .await;
    let _broker = Broker::start_on(port);
    let sub = Subscriber::start(port, "pulsegate/#").await;
    assert!(
        sub.wait_for(topic, Duration::from_secs(15), |_| true)
            .await
            .is_some(),
        "nothing on {topic}:\n{}",
        gw.log_text()
    );
    // Sent: the spool removes its segments, and only them.
    until(
        Duration::from_secs(15),
        "the segments removed",
        || segments() == 0,
        || format!("{:?}\n{}", files(&elsewhere), gw.log_text()),
    )
    .await;
    drop(gw);
    for f in &foreign {
        assert!(f.exists(), "{} survives", f.display());
    }
}

/// `boot.json` gone (a wiped or restored state directory), and one the last run could not
/// write: the restart says so, and never that another gateway publishes under the root. A
/// real second gateway still is.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_or_unwritten_boot_json_is_not_a_second_gateway() {
    let broker = Broker::start();
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("spool-boot");
    let devices = [("line1", "meter", 1, "yl67", "200ms")];
    let config = write_config(&dir, &gateway_toml(&plant, broker.port, &dir, &devices, ""));
    let sub = Subscriber::start(broker.port, "pulsegate/test/gateway").await;
    let run = |config: &Path| {
        let gw = Gateway::start(config);
        let since = Instant::now();
        let sub = &sub;
        async move {
            assert!(
                sub.wait_for("pulsegate/test/gateway", Duration::from_secs(10), |m| m.at
                    > since)
                    .await
                    .is_some(),
                "a boot marker"
            );
            tokio::time::sleep(Duration::from_millis(1500)).await;
            gw
        }
    };
    let alarm = "another gateway publishes under this topic root";

    let first = run(&config).await;
    first.terminate();
    std::fs::remove_file(dir.join("boot.json")).unwrap();
    let second = run(&config).await;
    let log = second.log_text();
    assert!(!log.contains(alarm), "{log}");
    assert!(
        log.contains("boot.json"),
        "the missing file is named:\n{log}"
    );
    assert!(log.contains("previous run"), "{log}");

    // This run cannot write boot.json (a directory is in the way of its temp file).
    second.terminate();
    std::fs::create_dir_all(dir.join("boot.json.tmp/x")).unwrap();
    let third = run(&config).await;
    assert!(
        third.log_text().contains("cannot write"),
        "{}",
        third.log_text()
    );
    third.terminate();
    std::fs::remove_dir_all(dir.join("boot.json.tmp")).unwrap();
    let fourth = run(&config).await;
    let log = fourth.log_text();
    assert!(!log.contains(alarm), "{log}");

    let other_dir = temp_dir("spool-boot-other");
    let other_plant = crate::support::plant(ONE_METER).await;
    let other = start_gateway(&other_plant, broker.port, &other_dir, &devices, "");
    let deadline = Instant::now() + Duration::from_secs(10);
    while !other.log_text().contains(alarm) && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(
        other.log_text().contains(alarm),
        "a live second gateway is still reported:\n{}",
        other.log_text()
    );
}

/// A Sparkplug node with the broker away: its spooled DDATA, binary, take at most 1.5 times
/// their size in the spool's files (an earlier version wrote arrays of byte values, 3–4 times).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_spooled_sparkplug_payload_takes_at_most_one_and_a_half_times_its_size() {
    let dir = temp_dir("spool-binary");
    let mut broker = Broker::start();
    let plant = plant(ONE_METER).await;
    let devices = [("line1", "meter", 1, "yl67", "100ms")];
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &devices,
        "[sparkplug]\ngroup_id = \"plant\"\n",
    )
    .replacen("[mqtt]\n", "[mqtt]\nformat = [\"sparkplug\"]\n", 1);
    let sub = Subscriber::start(broker.port, "spBv1.0/#").await;
    let gw = Gateway::start(&write_config(&dir, &text));
    let deadline = Instant::now() + Duration::from_secs(10);
    while !sub.all().iter().any(|m| m.topic.contains("/DDATA/")) {
        assert!(Instant::now() < deadline, "no DDATA:\n{}", gw.log_text());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    broker.stop();
    let spooled = || {
        let segments = files(&dir.join("spool"));
        let segments = segments
            .iter()
            .filter(|p| pulsegate::publish::spool::is_segment_name(&name_of(p)));
        segments
            .map(|p| std::fs::read_to_string(p).unwrap_or_default())
            .map(|text| text.lines().filter(|l| l.contains("/DDATA/")).count())
            .sum::<usize>()
    };
    until(
        Duration::from_secs(20),
        "a dozen DDATA spooled",
        || spooled() >= 12,
        || gw.log_text(),
    )
    .await;
    let log_path = gw.log.clone();
    gw.terminate();
    let log = std::fs::read_to_string(log_path).unwrap();

    let (mut payload, mut cost, mut lines) = (0usize, 0usize, 0usize);
    for file in files(&dir.join("spool")) {
        if !pulsegate::publish::spool::is_segment_name(&name_of(&file)) {
            continue;
        }
        for line in std::fs::read_to_string(&file).unwrap().lines() {
            let mut v: serde_json::Value = serde_json::from_str(line).unwrap();
            if !v["topic"].as_str().unwrap().contains("/DDATA/") {
                continue;
            }
            let entry: pulsegate::outbox::Entry = serde_json::from_str(line).unwrap();
            let n = entry.payload.len();
            // What the payload adds to its line: the line against the same line without it.
            let obj = v.as_object_mut().unwrap();
            obj.remove("payload_b64");
            obj.insert("payload".into(), "".into());
            let bare = serde_json::to_string(&v).unwrap().len();
            let c = line.len() - bare;
            assert!(
                c as f64 <= 1.5 * n as f64,
                "{n} bytes take {c} on disk: {line}"
            );
            payload += n;
            cost += c;
            lines += 1;
        }
    }
    assert!(lines >= 10, "DDATA spooled: {lines}\n{log}");
    println!(
        "{lines} spooled DDATA: {payload} payload bytes take {cost} ({:.2}x)",
        cost as f64 / payload as f64
    );
}
