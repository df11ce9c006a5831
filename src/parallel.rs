//! Work spread over the cores: independent jobs (the views of a photo, rendered one per
//! thread at a time and returned in view order) and bands of rows of one image.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;

/// The cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// `job(0)` … `job(n − 1)` on up to `threads` threads, their results in index order. A
/// thread takes the next index as soon as it finishes one, so jobs of unequal cost
/// keep every thread busy. Once a job fails no new one starts, and the first failure
/// (by index) is returned.
pub fn map<T: Send, E: Send>(
    n: usize,
    threads: usize,
    job: impl Fn(usize) -> Result<T, E> + Sync,
) -> Result<Vec<T>, E> {
    let workers = threads.clamp(1, n.max(1));
    if workers == 1 {
        return (0..n).map(job).collect();
    }
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let slots: Vec<Mutex<Option<Result<T, E>>>> = (0..n).map(|_| Mutex::new(None)).collect();
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                while !failed.load(Ordering::Relaxed) {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= n {
                        break;
                    }
                    let result = job(i);
                    if result.is_err() {
                        failed.store(true, Ordering::Relaxed);
                    }
                    *slots[i].lock().unwrap_or_else(|p| p.into_inner()) = Some(result);
                }
            });
        }
    });
    // Indices are handed out in order, so every job that never ran comes after one
    // that failed: walking in order meets the failure first.
    slots
        .into_iter()
        .map(|slot| {
            slot.into_inner()
                .unwrap_or_else(|p| p.into_inner())
                .expect("a job left unrun follows a failed one")
        })
        .collect()
}

/// Runs `f(first_row, band)` over bands of `out` (`rows` rows of `row_len` values), one
/// band per thread on up to `threads` threads: for work whose cost is even across rows.
pub fn bands<T: Send>(
    threads: usize,
    rows: usize,
    row_len: usize,
    out: &mut [T],
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let threads = threads.clamp(1, rows.max(1));
    if threads == 1 || row_len == 0 {
        f(0, out);
        return;
    }
    let per = rows.div_ceil(threads);
    std::thread::scope(|s| {
        for (b, band) in out.chunks_mut(per * row_len).enumerate() {
            let f = &f;
            s.spawn(move || f(b * per, band));
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn results_come_back_in_index_order() {
        for threads in [1, 2, 5] {
            let out: Result<Vec<usize>, ()> = map(37, threads, |i| {
                // Early jobs are the slow ones, so later ones finish first.
                std::thread::sleep(std::time::Duration::from_micros(((37 - i) * 20) as u64));
                Ok(i * i)
            });
            assert_eq!(out.unwrap(), (0..37).map(|i| i * i).collect::<Vec<_>>());
        }
    }

    #[test]
    fn the_first_failure_is_returned_and_later_jobs_do_not_start() {
        let started = AtomicUsize::new(0);
        let out: Result<Vec<()>, usize> = map(1000, 2, |i| {
            started.fetch_add(1, Ordering::Relaxed);
            if i >= 3 {
                Err(i)
            } else {
                Ok(())
            }
        });
        assert_eq!(out, Err(3));
        assert!(started.load(Ordering::Relaxed) < 1000);
    }

    #[test]
    fn no_jobs_no_threads() {
        let out: Result<Vec<()>, ()> = map(0, 4, |_| unreachable!());
        assert_eq!(out, Ok(Vec::new()));
    }

    #[test]
    fn bands_cover_every_row_once_whatever_the_thread_count() {
        for threads in [1, 2, 3, 7, 50] {
            let mut out = vec![0usize; 5 * 4];
            bands(threads, 5, 4, &mut out, |y0, rows| {
                for (i, v) in rows.iter_mut().enumerate() {
                    *v += y0 * 4 + i;
                }
            });
            assert_eq!(out, (0..20).collect::<Vec<_>>(), "{threads} threads");
        }
    }
}
