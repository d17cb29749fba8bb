//! The files of a push: the config it replaces (written keeping its mode and owner, the
//! previous beside it with the same), the watch kept in the state directory until the final
//! result, and the last serial taken. Every write is atomic (a crash leaves the old file or
//! the new one).

use std::os::unix::fs::{MetadataExt as _, PermissionsExt as _};
use std::path::{Path, PathBuf};

use crate::config::Config;
use crate::remote::Record;

fn record_path(config: &Config) -> PathBuf {
    config.gateway.state_dir.join("remote-watch.json")
}

fn serial_path(config: &Config) -> PathBuf {
    config.gateway.state_dir.join("remote-serial")
}

/// `path` with `.previous` appended: the file a rollback goes back to.
pub(super) fn previous_path(path: &Path) -> PathBuf {
    PathBuf::from(format!("{}.previous", path.display()))
}

/// The watch a push left, if any (an unreadable one is logged and dropped).
pub(super) fn load_record(config: &Config) -> Option<Record> {
    let path = record_path(config);
    let bytes = std::fs::read(&path).ok()?;
    match serde_json::from_slice(&bytes) {
        Ok(r) => Some(r),
        Err(e) => {
            tracing::error!(file = %path.display(), "a pushed config's watch cannot be read ({e}): it is dropped, nothing is rolled back");
            let _ = std::fs::remove_file(&path);
            None
        }
    }
}

pub(super) fn save_record(config: &Config, record: &Record) -> std::io::Result<()> {
    let bytes = serde_json::to_vec_pretty(record).map_err(std::io::Error::other)?;
    write_atomic(&record_path(config), &bytes, None)
}

pub(super) fn remove_record(config: &Config) {
    let path = record_path(config);
    match std::fs::remove_file(&path) {
        Ok(()) => {
            let _ = crate::state::sync_dir(&config.gateway.state_dir);
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => {
            tracing::error!(file = %path.display(), "cannot remove a finished push's watch: {e}")
        }
    }
}

/// The hash of the config file in force as it is on disk now (none when it does not load).
pub(super) fn hash_of_file(config: &Config) -> Option<String> {
    Config::load(&config.source)
        .ok()
        .map(|c| c.hash().to_string())
}

/// The pushed text over the config file, the file in force kept as `<file>.previous`, both
/// with the mode and owner the config file had.
pub(super) fn replace_config(source: &Path, toml: &str) -> std::io::Result<()> {
    let meta = std::fs::metadata(source)?;
    let old = std::fs::read(source)?;
    write_atomic(&previous_path(source), &old, Some(&meta))?;
    write_atomic(source, toml.as_bytes(), Some(&meta))
}

/// The previous file's text back over the config file, keeping the config file's mode and
/// owner.
pub(super) fn restore(previous: &Path, source: &Path) -> Result<(), String> {
    let meta = std::fs::metadata(source).map_err(|e| e.to_string())?;
    let bytes = std::fs::read(previous).map_err(|e| format!("{}: {e}", previous.display()))?;
    write_atomic(source, &bytes, Some(&meta)).map_err(|e| e.to_string())
}

/// The last serial a signed push used.
pub(super) fn last_serial(config: &Config) -> Result<Option<u64>, String> {
    let path = serial_path(config);
    match std::fs::read_to_string(&path) {
        Ok(text) => text.trim().parse().map(Some).map_err(|_| {
            format!(
                "{} is not a serial: pushes are refused until it is fixed on site",
                path.display()
            )
        }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(format!("{}: {e}", path.display())),
    }
}

pub(super) fn take_serial(config: &Config, serial: u64) -> std::io::Result<()> {
    write_atomic(&serial_path(config), format!("{serial}\n").as_bytes(), None)
}

/// `bytes` over `path` atomically; with `like`, the new file takes its mode and owner before
/// it is renamed into place (so it is never readable by more than the old one was).
fn write_atomic(
    path: &Path,
    bytes: &[u8],
    like: Option<&std::fs::Metadata>,
) -> std::io::Result<()> {
    let tmp = PathBuf::from(format!("{}.remote-tmp", path.display()));
    let _ = std::fs::remove_file(&tmp);
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let written = create_like(&tmp, like).and_then(|mut f| {
        use std::io::Write as _;
        f.write_all(bytes)?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|()| std::fs::rename(&tmp, path)) {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    crate::state::sync_dir(dir)
}

/// A new file with the mode (and, where permitted, the owner) of `like`; private otherwise.
fn create_like(path: &Path, like: Option<&std::fs::Metadata>) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt as _;
    let mode = like.map_or(0o600, |m| m.permissions().mode() & 0o7777);
    let file = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(mode & 0o700)
        .open(path)?;
    if let Some(m) = like {
        let owned = (m.uid(), m.gid());
        // Root may give the file back to its owner; anyone else keeps its own (a failure to
        // chown to another user is only possible, and harmless, when the owner is not us).
        let _ = std::os::unix::fs::fchown(&file, Some(owned.0), Some(owned.1));
    }
    file.set_permissions(std::fs::Permissions::from_mode(mode))?;
    Ok(file)
}
