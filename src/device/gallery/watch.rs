//! `reshader watch`: converts photos as they land in a folder.
//!
//! inotify wakes the loop and says which file changed; a periodic rescan of the folder
//! backs it up (missed events, queue overflow) and is the whole mechanism where inotify
//! is unavailable. A file is converted once it is complete: unchanged in size and mtime
//! across two polls, and closed after writing or moved into the folder (inotify) or
//! unchanged for the settle time; and its content must be whole (a JPEG up to its
//! end-of-image marker, a PNG up to IEND), since a writer may close a file it has not
//! finished (a sync tool writing in pieces, an interrupted copy). A file inotify saw
//! being written, or one whose content is cut off, waits, however long the writer
//! pauses, up to [`OPEN_WRITER_LIMIT`] settle times (a lost close event must not block
//! it forever; a file still cut off then fails as truncated). A new or changed depth
//! sidecar (`NAME_depth.png`, …) sends its photo round again. The done-markers make a
//! restart skip what an earlier run finished.

use std::collections::HashMap;
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime};

use inotify::{EventMask, Inotify, WatchMask};

use super::{convert_one, Converter, OutLayout, PhotoReport, Summary};
use crate::pipeline::progress::Progress;

/// How many settle times a file that is still open for writing may stay unchanged
/// before it is converted anyway.
pub const OPEN_WRITER_LIMIT: u32 = 30;

/// Photo types the runtime decodes.
const PHOTO_EXTENSIONS: &[&str] = &["jpg", "jpeg", "png"];

#[derive(Debug, thiserror::Error)]
pub enum WatchError {
    #[error("cannot watch {path}: {source}")]
    Dir {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0} is not a directory")]
    NotADir(PathBuf),
    #[error("watched directory {0} was removed or moved away")]
    DirGone(PathBuf),
}

#[derive(Clone, Debug)]
pub struct WatchOptions {
    pub dir: PathBuf,
    pub layout: OutLayout,
    /// How long a file must stay unchanged to count as complete when no close or move
    /// event says so.
    pub settle: Duration,
    /// How often the folder is rescanned.
    pub rescan: Duration,
    /// Use inotify when available; false forces polling.
    pub inotify: bool,
    /// A bar over the photos found so far, on a terminal.
    pub progress: Progress,
}

impl WatchOptions {
    pub fn new(dir: &Path, layout: OutLayout) -> Self {
        Self {
            dir: dir.into(),
            layout,
            settle: Duration::from_secs(2),
            rescan: Duration::from_secs(1),
            inotify: true,
            progress: Progress::hidden(),
        }
    }
}

/// A file's identity for "has it changed": size and modification time.
type Signature = (u64, SystemTime);

struct Candidate {
    signature: Signature,
    changed_at: Instant,
    state: WriteState,
    /// Polls that found the file with this signature.
    polls: u32,
    /// Whether the content is whole, once checked for this signature.
    whole: Option<bool>,
}

impl Candidate {
    fn new(signature: Signature, state: WriteState) -> Self {
        Self {
            signature,
            changed_at: Instant::now(),
            state,
            polls: 0,
            whole: None,
        }
    }
}

/// Polls that must find a file unchanged before it counts as complete.
const STABLE_POLLS: u32 = 2;

/// What inotify said about a file since its last change.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteState {
    /// Nothing (found by a scan, or no inotify): complete once it settles.
    Unknown,
    /// Created or modified: a writer has it open.
    Writing,
    /// Closed after writing, or moved into the folder: complete.
    Closed,
}

/// The stem of the photo whose depth sidecar `path` is (`a_depth.npy` → `a`).
fn sidecar_of(path: &Path) -> Option<String> {
    let name = path.file_name()?.to_str()?;
    let (stem, ext) = name.rsplit_once('.')?;
    if name.starts_with('.')
        || !super::photos::DEPTH_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str())
    {
        return None;
    }
    super::photos::DEPTH_SIDECARS
        .iter()
        .find_map(|(suffix, _)| stem.strip_suffix(suffix))
        .filter(|s| !s.is_empty())
        .map(str::to_string)
}

/// Whether `path` is a photo the watcher should convert: a visible jpg/jpeg/png that is
/// not a depth sidecar (`NAME_depth.png`, `NAME_disparity.png`).
pub fn is_watched_photo(path: &Path) -> bool {
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
        return false;
    };
    let Some((stem, ext)) = name.rsplit_once('.') else {
        return false;
    };
    !name.starts_with('.')
        && PHOTO_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str())
        && !super::photos::DEPTH_SIDECARS
            .iter()
            .any(|(suffix, _)| stem.ends_with(suffix))
}

/// Watches until `stop` is set, converting each complete photo once and calling `emit`
/// with its report. Returns the counts of this run.
pub fn watch(
    opts: &WatchOptions,
    converter: &dyn Converter,
    stop: &AtomicBool,
    mut emit: impl FnMut(&PhotoReport),
) -> Result<Summary, WatchError> {
    if !opts.dir.is_dir() {
        return Err(WatchError::NotADir(opts.dir.clone()));
    }
    let mut events = if opts.inotify {
        Events::open(&opts.dir)
    } else {
        None
    };
    if events.is_none() {
        log::info!(
            "watching {} by polling every {:.1} s",
            opts.dir.display(),
            opts.rescan.as_secs_f64()
        );
    }
    let mut state = State::default();
    let mut summary = Summary::default();
    let mut last_scan: Option<Instant> = None;
    let tick = Duration::from_millis(100).min(opts.rescan);
    while !stop.load(Ordering::SeqCst) {
        let mut rescan = last_scan.is_none_or(|t| t.elapsed() >= opts.rescan);
        match events.as_mut() {
            Some(ev) => {
                for (name, write_state) in ev.wait(tick, &mut rescan, &opts.dir)? {
                    state.note(&opts.dir.join(name), write_state);
                }
            }
            None => std::thread::sleep(tick),
        }
        if rescan {
            state.scan(&opts.dir)?;
            last_scan = Some(Instant::now());
        }
        let ready = state.ready(opts.settle);
        opts.progress.grow(ready.len() as u64);
        for photo in ready {
            if stop.load(Ordering::SeqCst) {
                break;
            }
            let report = convert_one(&photo, &opts.layout.out_dir(&photo), false, converter);
            state.handled(&photo);
            summary.add(report.status);
            emit(&report);
            opts.progress.inc(1);
        }
    }
    Ok(summary)
}

#[derive(Default)]
struct State {
    pending: HashMap<PathBuf, Candidate>,
    /// The signature each file had when it was last converted, skipped or failed.
    done: HashMap<PathBuf, Signature>,
    /// The signature each depth sidecar had when last seen.
    sidecars: HashMap<PathBuf, Signature>,
}

impl State {
    fn note(&mut self, path: &Path, event: WriteState) {
        if let Some(stem) = sidecar_of(path) {
            self.note_sidecar(path, &stem);
            return;
        }
        if !is_watched_photo(path) {
            return;
        }
        let Some(signature) = signature(path) else {
            self.pending.remove(path);
            return;
        };
        if self.done.get(path) == Some(&signature) {
            return;
        }
        match self.pending.get_mut(path) {
            Some(c) if c.signature == signature => {
                if event != WriteState::Unknown {
                    c.state = event;
                }
            }
            previous => {
                // A scan that sees a change before its inotify event must not make an
                // open file look finished.
                let state = match (event, previous.map(|c| c.state)) {
                    (WriteState::Unknown, Some(WriteState::Writing)) => WriteState::Writing,
                    _ => event,
                };
                self.pending
                    .insert(path.into(), Candidate::new(signature, state));
            }
        }
    }

    /// A new or changed depth sidecar: its photos are converted again (the done-marker
    /// holds the sidecar's hash), once the sidecar too has settled.
    fn note_sidecar(&mut self, sidecar: &Path, stem: &str) {
        let signature = signature(sidecar);
        let changed = match signature {
            Some(sig) => self.sidecars.insert(sidecar.into(), sig) != Some(sig),
            None => self.sidecars.remove(sidecar).is_some(),
        };
        if !changed {
            return;
        }
        let Some(dir) = sidecar.parent() else {
            return;
        };
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for entry in entries.flatten() {
            let photo = entry.path();
            let same_stem = photo.file_stem().and_then(|s| s.to_str()) == Some(stem);
            if !same_stem || !is_watched_photo(&photo) {
                continue;
            }
            let Some(photo_signature) = self::signature(&photo) else {
                continue;
            };
            self.done.remove(&photo);
            self.pending
                .insert(photo, Candidate::new(photo_signature, WriteState::Unknown));
        }
    }

    fn scan(&mut self, dir: &Path) -> Result<(), WatchError> {
        let entries = std::fs::read_dir(dir).map_err(|source| WatchError::Dir {
            path: dir.into(),
            source,
        })?;
        for entry in entries.flatten() {
            if entry.file_type().is_ok_and(|t| t.is_file()) {
                self.note(&entry.path(), WriteState::Unknown);
            }
        }
        Ok(())
    }

    /// Photos complete now, in name order; files that changed since they were noted
    /// start their settle time again.
    fn ready(&mut self, settle: Duration) -> Vec<PathBuf> {
        let mut ready = Vec::new();
        self.pending.retain(|path, c| match signature(path) {
            None => false,
            Some(now) if now != c.signature => {
                let state = if c.state == WriteState::Closed {
                    WriteState::Unknown
                } else {
                    c.state
                };
                *c = Candidate::new(now, state);
                true
            }
            Some(_) => {
                c.polls = c.polls.saturating_add(1);
                let quiet = c.changed_at.elapsed();
                let patience = settle * OPEN_WRITER_LIMIT;
                let stable = c.polls >= STABLE_POLLS
                    && match c.state {
                        WriteState::Closed => c.signature.0 > 0 || quiet >= settle,
                        WriteState::Unknown => quiet >= settle,
                        WriteState::Writing => quiet >= patience,
                    };
                if stable {
                    let whole = *c.whole.get_or_insert_with(|| content_whole(path));
                    if whole || quiet >= patience {
                        ready.push(path.clone());
                    } else if c.polls == STABLE_POLLS {
                        log::info!(
                            "{} is closed but cut off; waiting for the rest of it",
                            path.display()
                        );
                    }
                }
                true
            }
        });
        ready.sort();
        ready
    }

    fn handled(&mut self, path: &Path) {
        if let Some(c) = self.pending.remove(path) {
            self.done.insert(path.into(), c.signature);
        }
    }
}

/// Whether a photo file's content runs to its end: a JPEG to its end-of-image marker,
/// a PNG to its IEND chunk. Other content (and a file too large to read) counts as
/// whole: the conversion reports what is wrong with it.
fn content_whole(path: &Path) -> bool {
    let Ok(bytes) = crate::io::limits::read_input(path) else {
        return true;
    };
    if bytes.starts_with(&[0xFF, 0xD8]) {
        return crate::io::photo::jpeg_complete(&bytes).is_ok();
    }
    if let Some(chunks) = bytes.strip_prefix(b"\x89PNG\r\n\x1a\n".as_slice()) {
        return png_has_iend(chunks);
    }
    true
}

/// Walks PNG chunks (length, type, data, CRC) to an IEND chunk.
fn png_has_iend(mut chunks: &[u8]) -> bool {
    while chunks.len() >= 12 {
        let len = u32::from_be_bytes([chunks[0], chunks[1], chunks[2], chunks[3]]) as usize;
        if &chunks[4..8] == b"IEND" {
            return true;
        }
        let Some(rest) = chunks.get(len.saturating_add(12)..) else {
            return false;
        };
        chunks = rest;
    }
    false
}

fn signature(path: &Path) -> Option<Signature> {
    let meta = std::fs::metadata(path).ok().filter(|m| m.is_file())?;
    Some((meta.len(), meta.modified().ok()?))
}

/// The inotify side: a watch on the folder, read without blocking after a poll.
struct Events {
    inotify: Inotify,
    buffer: Vec<u8>,
}

impl Events {
    /// `None` (and a log line) when inotify cannot be used, so the caller polls.
    fn open(dir: &Path) -> Option<Self> {
        let result = Inotify::init().and_then(|inotify| {
            inotify.watches().add(
                dir,
                WatchMask::CLOSE_WRITE
                    | WatchMask::MOVED_TO
                    | WatchMask::CREATE
                    | WatchMask::MODIFY
                    | WatchMask::DELETE_SELF
                    | WatchMask::MOVE_SELF,
            )?;
            Ok(inotify)
        });
        match result {
            Ok(inotify) => {
                log::info!("watching {} with inotify", dir.display());
                Some(Self {
                    inotify,
                    buffer: vec![0; 64 * 1024],
                })
            }
            Err(e) => {
                log::warn!(
                    "inotify unavailable for {} ({e}); falling back to polling",
                    dir.display()
                );
                None
            }
        }
    }

    /// Waits up to `timeout` for events and returns what they say about each file;
    /// sets `rescan` when events were lost.
    fn wait(
        &mut self,
        timeout: Duration,
        rescan: &mut bool,
        dir: &Path,
    ) -> Result<Vec<(PathBuf, WriteState)>, WatchError> {
        let mut pollfd = libc::pollfd {
            fd: self.inotify.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd for the inotify descriptor, which self keeps open.
        let n = unsafe { libc::poll(&mut pollfd, 1, timeout.as_millis() as libc::c_int) };
        if n <= 0 {
            return Ok(Vec::new());
        }
        let mut found = Vec::new();
        let events = match self.inotify.read_events(&mut self.buffer) {
            Ok(events) => events,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => return Ok(found),
            Err(source) => {
                return Err(WatchError::Dir {
                    path: dir.into(),
                    source,
                })
            }
        };
        for event in events {
            if event.mask.contains(EventMask::Q_OVERFLOW) {
                *rescan = true;
            }
            if event
                .mask
                .intersects(EventMask::DELETE_SELF | EventMask::MOVE_SELF | EventMask::IGNORED)
            {
                return Err(WatchError::DirGone(dir.into()));
            }
            if let Some(name) = event.name {
                let state = if event
                    .mask
                    .intersects(EventMask::CLOSE_WRITE | EventMask::MOVED_TO)
                {
                    WriteState::Closed
                } else {
                    WriteState::Writing
                };
                found.push((PathBuf::from(name), state));
            }
        }
        Ok(found)
    }
}

#[cfg(test)]
mod tests;
