//! The spool's files: `<20-digit sequence number of the first entry>.jsonl`, one stored entry
//! a line ([`crate::outbox::stored`]). Reading one never stops at a line it cannot read: such a
//! line (not UTF-8, not an entry) is skipped and reported with its byte offset, and the
//! entries after it are read. A last line without its newline is a write a crash cut short.
//!
//! Only files with a segment's name are the spool's; anything else in its directory is never
//! read, moved or removed. A segment with unreadable lines is not removed once its entries are
//! acknowledged but renamed to `<name>.unreadable`, kept for whoever wants to look.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use crate::outbox::Entry;

/// Whether `name` is the name of one of the spool's segment files: `<20 digits>.jsonl`.
pub fn is_segment_name(name: &str) -> bool {
    name.strip_suffix(".jsonl")
        .is_some_and(|stem| stem.len() == 20 && stem.bytes().all(|b| b.is_ascii_digit()))
}

/// The path of the segment whose first entry is `first`.
pub fn path_of(dir: &Path, first: u64) -> PathBuf {
    dir.join(format!("{first:020}.jsonl"))
}

/// One entry as a line of a segment file.
pub fn line(entry: &Entry) -> Vec<u8> {
    let mut line = serde_json::to_vec(entry).expect("an entry serializes");
    line.push(b'\n');
    line
}

/// A line that is not a stored entry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Unreadable {
    /// Where the line starts in its file.
    pub offset: u64,
    pub why: String,
}

/// What reading a segment file found, besides its entries.
#[derive(Debug, Default, PartialEq, Eq)]
pub struct Scan {
    pub count: u64,
    pub first: u64,
    pub last: u64,
    /// Lines that are not entries (skipped), in file order.
    pub unreadable: Vec<Unreadable>,
    /// The offset of a last line cut short (no newline, not an entry): skipped, not counted
    /// as unreadable.
    pub torn: Option<u64>,
    /// The file's length.
    pub bytes: u64,
}

/// Reads the segment at `path`, handing each entry to `each` in file order.
pub fn scan(path: &Path, mut each: impl FnMut(Entry)) -> std::io::Result<Scan> {
    let mut reader = BufReader::new(File::open(path)?);
    let mut scan = Scan {
        first: u64::MAX,
        ..Scan::default()
    };
    let mut buf = Vec::new();
    loop {
        buf.clear();
        let n = reader.read_until(b'\n', &mut buf)?;
        if n == 0 {
            break;
        }
        let offset = scan.bytes;
        scan.bytes += n as u64;
        let complete = buf.last() == Some(&b'\n');
        match serde_json::from_slice::<Entry>(&buf) {
            Ok(entry) => {
                scan.count += 1;
                scan.first = scan.first.min(entry.seq);
                scan.last = scan.last.max(entry.seq);
                each(entry);
            }
            Err(_) if !complete => scan.torn = Some(offset),
            Err(e) => scan.unreadable.push(Unreadable {
                offset,
                why: e.to_string(),
            }),
        }
    }
    if scan.count == 0 {
        scan.first = 0;
    }
    Ok(scan)
}

/// Where a segment with unreadable lines is kept once the spool is done with it: the first of
/// `<name>.unreadable`, `<name>.1.unreadable`, … not taken.
pub fn quarantine_path(path: &Path) -> PathBuf {
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    (0..1000)
        .map(|i| match i {
            0 => path.with_file_name(format!("{name}.unreadable")),
            i => path.with_file_name(format!("{name}.{i}.unreadable")),
        })
        .find(|p| std::fs::symlink_metadata(p).is_err())
        .unwrap_or_else(|| path.with_file_name(format!("{name}.unreadable")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("pulsegate-segment-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn entry(seq: u64) -> Entry {
        Entry {
            seq,
            topic: format!("t/{seq}"),
            payload: bytes::Bytes::from(format!("p{seq}")),
            qos: 1,
            retain: false,
            correlation: None,
        }
    }

    #[test]
    fn only_twenty_digits_and_jsonl_name_a_segment() {
        assert!(is_segment_name("00000000000000000001.jsonl"));
        for name in [
            "1.jsonl",
            "notes.jsonl",
            "00000000000000000001.jsonl.tmp",
            "00000000000000000001.jsonl.unreadable",
            "0000000000000000000a.jsonl",
            "00000000000000000001.json",
        ] {
            assert!(!is_segment_name(name), "{name}");
        }
    }

    #[test]
    fn a_line_that_is_not_utf8_or_not_an_entry_is_skipped_and_the_entries_after_it_are_read() {
        let d = scratch("bad-line");
        let path = path_of(&d, 1);
        let mut bytes = line(&entry(1));
        let bad_at = bytes.len() as u64;
        bytes.extend_from_slice(b"{\"seq\":2,\"topic\":\"t\xff\xfe\"}\n");
        let garbage_at = bytes.len() as u64;
        bytes.extend_from_slice(b"garbage\n");
        bytes.extend_from_slice(&line(&entry(4)));
        std::fs::write(&path, &bytes).unwrap();
        let mut seqs = Vec::new();
        let scan = scan(&path, |e| seqs.push(e.seq)).unwrap();
        assert_eq!(seqs, [1, 4]);
        assert_eq!((scan.count, scan.first, scan.last), (2, 1, 4));
        let offsets: Vec<u64> = scan.unreadable.iter().map(|u| u.offset).collect();
        assert_eq!(offsets, [bad_at, garbage_at]);
        assert_eq!(scan.torn, None);
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_last_line_cut_short_is_torn_not_unreadable() {
        let d = scratch("torn");
        let path = path_of(&d, 1);
        let mut bytes = line(&entry(1));
        let torn_at = bytes.len() as u64;
        bytes.extend_from_slice(&line(&entry(2))[..10]);
        std::fs::write(&path, &bytes).unwrap();
        let scan = scan(&path, |_| {}).unwrap();
        assert_eq!(scan.count, 1);
        assert!(scan.unreadable.is_empty());
        assert_eq!(scan.torn, Some(torn_at));
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_quarantined_segment_never_takes_the_place_of_an_earlier_one() {
        let d = scratch("quarantine");
        let path = path_of(&d, 7);
        let first = quarantine_path(&path);
        assert!(!is_segment_name(
            &first.file_name().unwrap().to_string_lossy()
        ));
        std::fs::write(&first, "kept").unwrap();
        let second = quarantine_path(&path);
        assert_ne!(first, second);
        let _ = std::fs::remove_dir_all(&d);
    }
}
