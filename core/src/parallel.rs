//! Parallel stages started from a thread of one's own (the back end's, the map's): a rayon
//! pool that the thread itself belongs to.
//!
//! A thread that hands its parallel work to rayon's global pool blocks while the pool's
//! workers run it. Measured on a 2-core machine (rayon-core 1.13, Linux), that costs whole
//! frames of parallelism: after the thread has done a millisecond or two of serial work,
//! 5-10 % of its parallel sections ran at one worker's speed, though both workers were
//! awake (most likely the scheduler placing them on one CPU until it balances the load).
//! A thread that is one of the pool's workers keeps working in its own joins, and the
//! stall went away: `stride bench map` 8.7 -> 4.5 ms p95 per VGA frame (median 4.5 -> 4.3),
//! the back end's bundle adjustment 13 -> 6 ms per keyframe in the median on teddy_200. A
//! plain channel-fed helper thread does not stall either; rayon's `install` and
//! `broadcast` from outside the pool do.
//!
//! Results never depend on which pool runs a stage: every parallel stage of the workspace
//! splits its work into a fixed number of parts.

/// A rayon pool of as many threads as rayon's global pool has (by default
/// `RAYON_NUM_THREADS`, else the logical CPUs), whose worker 0 is the calling thread: the
/// parallel stages the thread starts from now on run on this pool, with the thread taking
/// part (see the module documentation), for as long as the returned pool lives. Build it
/// once, at the start of the thread; a thread belongs to at most one pool, so a second call
/// on the same thread fails. The other workers are named `{name}-1`, `{name}-2`, ...
pub fn join_own_pool(name: &str) -> Result<rayon::ThreadPool, PoolError> {
    let owned = name.to_owned();
    rayon::ThreadPoolBuilder::new()
        .num_threads(rayon::current_num_threads())
        .thread_name(move |i| format!("{owned}-{i}"))
        .use_current_thread()
        .build()
        .map_err(|source| PoolError {
            name: name.to_owned(),
            source,
        })
}

/// Why [`join_own_pool`] could not start a thread's pool (its threads could not be spawned,
/// or the thread already belongs to a pool).
#[derive(Debug, thiserror::Error)]
#[error("could not start the worker pool of thread {name}: {source}")]
pub struct PoolError {
    /// The thread's name, as given to [`join_own_pool`].
    pub name: String,
    /// rayon's reason.
    #[source]
    pub source: rayon::ThreadPoolBuildError,
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn the_calling_thread_is_worker_0_and_its_parallel_work_runs_on_the_pool() {
        std::thread::spawn(|| {
            assert_eq!(rayon::current_thread_index(), None);
            let pool = join_own_pool("test").unwrap();
            assert_eq!(rayon::current_thread_index(), Some(0));
            assert_eq!(rayon::current_num_threads(), pool.current_num_threads());
            // Parallel work started here runs on this pool's workers (index Some), the
            // caller's share on worker 0.
            let on_pool = (0..64)
                .into_par_iter()
                .map(|_| rayon::current_thread_index().is_some())
                .all(|b| b);
            assert!(on_pool);
            assert!(join_own_pool("again").is_err(), "a thread joins one pool");
        })
        .join()
        .unwrap();
    }
}
