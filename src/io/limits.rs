//! The run's memory ceiling (`--max-memory`) and the checks every input parser makes
//! against it before allocating: a hostile header can claim gigabytes in a few bytes,
//! and a kiosk must refuse such a file with a message instead of being killed.
//!
//! One decoded input (a photo, a depth map, an embedded depth image) may use at most a
//! quarter of the ceiling, because the pipeline keeps several working copies of
//! photo-sized buffers; files are refused before they are read when they are larger than
//! that. [`apply_process_limit`] also asks the kernel to hold the process's heap to the
//! ceiling, so that what the checks cannot foresee ends the run instead of the machine.

use std::fmt;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// The ceiling when `--max-memory` is not given: room for a 50-megapixel photo on a
/// small board computer with 4 GiB or more.
pub const DEFAULT_MAX_MEMORY: u64 = 4 << 30;
/// Below this not even a small photo and the shipped depth network fit.
pub const MIN_MAX_MEMORY: u64 = 64 << 20;
/// What one decoded input may use, as a fraction (1/n) of the ceiling.
const INPUT_SHARE: u64 = 4;

static MAX_MEMORY: AtomicU64 = AtomicU64::new(DEFAULT_MAX_MEMORY);

/// The memory ceiling of this run, in bytes.
pub fn max_memory() -> u64 {
    MAX_MEMORY.load(Ordering::Relaxed)
}

/// Sets the ceiling for the checks of this process (not the kernel limit).
pub fn set_max_memory(bytes: u64) {
    MAX_MEMORY.store(bytes.max(MIN_MAX_MEMORY), Ordering::Relaxed);
}

/// Bytes one decoded input may use.
pub fn input_budget() -> u64 {
    max_memory() / INPUT_SHARE
}

/// An input that would need more memory than the ceiling allows.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "{what} would need {} of memory, more than the {} one input may use \
     (a quarter of --max-memory {}); raise --max-memory to read it",
    Bytes(*.needed), Bytes(*.budget), Bytes(*.budget * INPUT_SHARE)
)]
pub struct TooLarge {
    pub what: String,
    pub needed: u64,
    pub budget: u64,
}

/// Checks that `count` values of `size` bytes each fit one input's budget; `what` says
/// what they are ("a 9000x9000 depth map").
pub fn check_alloc(what: impl fmt::Display, count: u64, size: u64) -> Result<(), TooLarge> {
    let needed = count.saturating_mul(size);
    let budget = input_budget();
    if needed > budget {
        return Err(TooLarge {
            what: what.to_string(),
            needed,
            budget,
        });
    }
    Ok(())
}

/// Reads a whole input file, refusing it by its size before reading. Only regular
/// files are opened: a FIFO, socket or device would block or never end.
pub fn read_input(path: &Path) -> Result<Vec<u8>, ReadError> {
    let meta = std::fs::metadata(path).map_err(ReadError::Io)?;
    if !meta.is_file() {
        return Err(ReadError::Io(not_a_regular_file(&meta)));
    }
    let len = meta.len();
    check_alloc(format!("a file of {len} bytes"), len, 1).map_err(ReadError::TooLarge)?;
    std::fs::read(path).map_err(ReadError::Io)
}

/// The error for an input that is a directory, FIFO, socket or device.
pub fn not_a_regular_file(meta: &std::fs::Metadata) -> std::io::Error {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    let what = if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_socket() {
        "a socket"
    } else if t.is_block_device() || t.is_char_device() {
        "a device"
    } else {
        "something other than a file"
    };
    std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("it is {what}, not a regular file; it was not opened"),
    )
}

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error(transparent)]
    Io(std::io::Error),
    #[error(transparent)]
    TooLarge(TooLarge),
}

/// Limits for the `image` crate's decoders: sides up to `max_side` and the input budget
/// for their own buffers. (The decoded image itself is checked by the caller: `image`
/// allocates it without consulting the limit.)
pub fn image_limits(max_side: u32) -> image::Limits {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(max_side);
    limits.max_image_height = Some(max_side);
    limits.max_alloc = Some(input_budget());
    limits
}

/// Parses a size such as `4G`, `512M`, `1.5GiB` or `1073741824` (bytes); the units are
/// binary (K = 1024).
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let shift = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        other => {
            return Err(format!(
                "unknown unit {other:?} in {text:?}: use K, M, G or T"
            ))
        }
    };
    let value: f64 = number
        .parse()
        .map_err(|_| format!("{text:?} is not a size such as 4G or 512M"))?;
    let bytes = value * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= MIN_MAX_MEMORY as f64 && bytes < u64::MAX as f64) {
        return Err(format!(
            "{text:?} is out of range: give at least {}",
            Bytes(MIN_MAX_MEMORY)
        ));
    }
    Ok(bytes as u64)
}

/// Keeps every thread's allocations in one glibc heap. By default each thread that
/// allocates gets a heap (arena) of its own, reserved in 64 MiB pieces that count
/// against the data-segment limit, and memory freed in one stays with it: with the views
/// relocated on both cores, a Portrait render of the example photo peaked 30 % higher.
/// With one heap the peak stays near what is live; the threads allocate few, large
/// buffers, so they hardly contend for it. Call before any thread starts.
pub fn share_one_heap() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt changes a setting of the allocator and touches no memory of ours.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
}

/// Hands memory the allocator holds but nothing uses back to the kernel, so that the
/// resident size is what is live: a process that runs several jobs one after another
/// (`bench`'s cases) then measures each job's own peak, not the pages an earlier one freed.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages of the allocator's heaps to the kernel.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Asks the kernel to hold the process's data segment (heap and private writable
/// mappings) to `bytes`, so that an allocation the checks did not foresee fails (and
/// aborts the run) instead of swapping or waking the OOM killer.
pub fn apply_process_limit(bytes: u64) -> std::io::Result<()> {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: the pointer is to a live rlimit struct.
    if unsafe { libc::getrlimit(libc::RLIMIT_DATA, &mut limit) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    // Only the soft limit: the hard one stays, so child processes may raise theirs.
    limit.rlim_cur = (bytes as libc::rlim_t).min(limit.rlim_max);
    // SAFETY: as above.
    if unsafe { libc::setrlimit(libc::RLIMIT_DATA, &limit) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// Raises the process's data-segment limit back to its hard limit, for a run that is
/// ending anyway (see [`install_panic_hook`]).
fn lift_process_limit() {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: the pointer is to a live rlimit struct.
    if unsafe { libc::getrlimit(libc::RLIMIT_DATA, &mut limit) } == 0 {
        limit.rlim_cur = limit.rlim_max;
        // SAFETY: as above. A failure leaves the limit as it was, which is no worse.
        unsafe { libc::setrlimit(libc::RLIMIT_DATA, &limit) };
    }
}

/// Whether a panic's message reports a failed allocation: tract panics ("failed to
/// allocate …") when the kernel refuses one of its buffers under the ceiling.
pub fn is_out_of_memory(panic_message: &str) -> bool {
    panic_message.contains("failed to allocate")
}

/// The message of a panic payload (a `&str` or a `String`), without allocating.
pub fn panic_text(payload: &(dyn std::any::Any + Send)) -> &str {
    payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("")
}

static RAN_OUT_OF_MEMORY: AtomicBool = AtomicBool::new(false);

/// Whether a panic of this process was a failed allocation (see [`install_panic_hook`]).
pub fn ran_out_of_memory() -> bool {
    RAN_OUT_OF_MEMORY.load(Ordering::Relaxed)
}

/// Replaces the default panic hook so that running out of memory under the ceiling ends
/// the run instead of hanging it. With `RUST_BACKTRACE` set, the default hook holds
/// std's backtrace lock while it resolves the backtrace, which allocates; when that
/// allocation fails too, std's out-of-memory handler waits for the same lock to print
/// its own backtrace, and the process hangs for ever. So a failed allocation's panic is
/// only recorded (the caller that catches it reports it: a model load, a gallery photo,
/// or `main`, as [`OutOfMemory`]), and before any other panic is printed the ceiling is
/// lifted, so that printing it cannot run out of memory.
pub fn install_panic_hook() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if is_out_of_memory(panic_text(info.payload())) {
            RAN_OUT_OF_MEMORY.store(true, Ordering::Relaxed);
            return;
        }
        lift_process_limit();
        default(info);
    }));
}

/// The exit status of a run that hit a bug (a panic): sysexits.h's EX_SOFTWARE, so that
/// no command answers with Rust's 101.
pub const INTERNAL_ERROR_EXIT: u8 = 70;

/// Runs a command's body and gives its exit status: 0, or 1 with `error: …` for its error
/// or for running out of memory under the ceiling, or [`INTERNAL_ERROR_EXIT`] for any
/// other panic (printed by the panic hook, then said to be a bug).
pub fn run_guarded<E: fmt::Display>(body: impl FnOnce() -> Result<(), E>) -> u8 {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(body)) {
        Ok(Ok(())) => 0,
        Ok(Err(e)) => {
            eprintln!("error: {e}");
            1
        }
        // A failed allocation is the ceiling, not a bug: an error like any other.
        Err(_) if ran_out_of_memory() => {
            eprintln!("error: {}", OutOfMemory::now(""));
            1
        }
        Err(_) => {
            eprintln!(
                "error: internal error (a bug in reshader, not in your input): please report \
                 it with the command and the message above"
            );
            INTERNAL_ERROR_EXIT
        }
    }
}

/// A run that ran out of memory under the ceiling although the estimate made before it
/// said it would fit.
#[derive(Clone, Debug, thiserror::Error)]
#[error(
    "ran out of memory under --max-memory {}{what}; raise --max-memory (the memory \
     estimate made before the run was too low: please report the command)",
    Bytes(*.ceiling)
)]
pub struct OutOfMemory {
    /// What was running, with a leading space and a preposition (" while loading …"),
    /// or empty.
    pub what: String,
    pub ceiling: u64,
}

impl OutOfMemory {
    pub fn now(what: impl Into<String>) -> Self {
        Self {
            what: what.into(),
            ceiling: max_memory(),
        }
    }
}

/// A byte count for messages: "1.5 GiB", "300 MiB".
pub struct Bytes(pub u64);

impl fmt::Display for Bytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let units = [("GiB", 30), ("MiB", 20), ("KiB", 10)];
        for (name, shift) in units {
            if self.0 >= 1 << shift {
                let v = self.0 as f64 / (1u64 << shift) as f64;
                return if v.fract() == 0.0 {
                    write!(f, "{v:.0} {name}")
                } else {
                    write!(f, "{v:.1} {name}")
                };
            }
        }
        write!(f, "{} bytes", self.0)
    }
}

/// The system allocator, remembering the size of the largest allocation it could not make.
/// Outside tract, Rust answers a failed allocation by aborting the process (SIGABRT, exit
/// 134) after printing "memory allocation of N bytes failed"; with this allocator in
/// place, [`install_abort_report`] turns that abort into the ceiling's error and exit 1.
/// Fallible allocations (`try_reserve`) still see their null pointer.
pub struct Allocator;

static FAILED_ALLOCATION: AtomicU64 = AtomicU64::new(0);

impl Allocator {
    fn note(ptr: *mut u8, size: usize) -> *mut u8 {
        if ptr.is_null() {
            FAILED_ALLOCATION.fetch_max(size as u64, Ordering::Relaxed);
        }
        ptr
    }
}

// SAFETY: every call goes to the system allocator unchanged; only null results are noted.
unsafe impl std::alloc::GlobalAlloc for Allocator {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        Self::note(std::alloc::System.alloc(layout), layout.size())
    }

    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        Self::note(std::alloc::System.alloc_zeroed(layout), layout.size())
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, size: usize) -> *mut u8 {
        Self::note(std::alloc::System.realloc(ptr, layout, size), size)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        std::alloc::System.dealloc(ptr, layout)
    }
}

/// Exit status of a run that ran out of memory: an error like any other (1), not a crash.
const OUT_OF_MEMORY_EXIT: libc::c_int = 1;

/// Installs a SIGABRT handler that, when [`Allocator`] saw an allocation fail, prints the
/// ceiling's error with the largest that failed (std's handler may fail smaller ones while
/// it prints a backtrace) and exits with status 1. Any other abort stays an abort. The handler
/// only formats into a stack buffer, writes and exits: all async-signal-safe.
pub fn install_abort_report() {
    extern "C" fn on_abort(_: libc::c_int) {
        let size = FAILED_ALLOCATION.load(Ordering::Relaxed);
        if size == 0 {
            return;
        }
        let mut line = Line::default();
        line.push(b"error: ran out of memory: an allocation of ");
        line.number(size.div_ceil(1 << 20));
        line.push(b" MiB failed under --max-memory ");
        line.number(max_memory() >> 20);
        line.push(b" MiB; raise --max-memory, or lower the sizes (board, photo, views)\n");
        // SAFETY: write(2) and _exit(2) are async-signal-safe; the buffer is live.
        unsafe {
            libc::write(2, line.buf.as_ptr().cast(), line.len);
            libc::_exit(OUT_OF_MEMORY_EXIT);
        }
    }
    // SAFETY: a plain handler that only calls async-signal-safe functions.
    unsafe {
        libc::signal(libc::SIGABRT, on_abort as *const () as libc::sighandler_t);
    }
}

/// A message built without allocating, for the signal handler above.
struct Line {
    buf: [u8; 256],
    len: usize,
}

impl Default for Line {
    fn default() -> Self {
        Self {
            buf: [0; 256],
            len: 0,
        }
    }
}

impl Line {
    fn push(&mut self, bytes: &[u8]) {
        let n = bytes.len().min(self.buf.len() - self.len);
        self.buf[self.len..self.len + n].copy_from_slice(&bytes[..n]);
        self.len += n;
    }

    fn number(&mut self, mut n: u64) {
        let mut digits = [0u8; 20];
        let mut i = digits.len();
        loop {
            i -= 1;
            digits[i] = b'0' + (n % 10) as u8;
            n /= 10;
            if n == 0 {
                break;
            }
        }
        self.push(&digits[i..]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_binary_units() {
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("134217728"), Ok(128 << 20));
        assert!(parse_size("4X").unwrap_err().contains("unit"));
        assert!(parse_size("1M").unwrap_err().contains("at least 64 MiB"));
        assert!(parse_size("G").is_err());
        assert!(parse_size("1e400G").is_err());
    }

    #[test]
    fn bytes_print_in_the_largest_whole_unit() {
        assert_eq!(Bytes(4 << 30).to_string(), "4 GiB");
        assert_eq!(Bytes(3 << 29).to_string(), "1.5 GiB");
        assert_eq!(Bytes(300).to_string(), "300 bytes");
    }

    #[test]
    fn allocation_beyond_a_quarter_of_the_ceiling_is_refused() {
        let budget = input_budget();
        assert!(check_alloc("x", budget, 1).is_ok());
        let err = check_alloc("a 9x9 map", budget / 4 + 1, 4).unwrap_err();
        assert_eq!(err.needed, budget + 4);
        let text = err.to_string();
        assert!(text.starts_with("a 9x9 map would need"), "{text}");
        assert!(text.contains("--max-memory"), "{text}");
        assert!(check_alloc("x", u64::MAX, 8).is_err());
    }
}
