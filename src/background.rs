//! Background work of the CPU methods: nothing they compute on the CPU blocks a frame.
//!
//! Radiosity's links and gathering and the photon grid's photons, R-grid and SH field take from tens of
//! milliseconds to seconds; the VPL walks a few milliseconds, every frame something moves. They run as a task on the crate's own background thread pool over a *copy*
//! of their inputs (the [`SceneSnapshot`](crate::scene::SceneSnapshot) clones cheaply: geometry and
//! texels are shared), with the method's persistent state (its elements, links, voxels) moved into the
//! task and handed back with the result. Each frame the method's main-world system:
//!
//! 1. polls the running task ([`BackgroundJob::poll`], never waiting) and, when it is done, takes the
//!    state back and starts [blending](Blend) the new result over the one shown;
//! 2. if its inputs differ from what the last result was made from and no task runs, starts a new one
//!    ([`BackgroundJob::start`]).
//!
//! A task is never cut short. Under continuous change (a mesh moving every frame) each finished result
//! is shown, at most one task old, and the next task starts at once from the newest inputs: the changes
//! made while a task ran are coalesced into the next one rather than queued. Cutting a stale task short
//! would, under continuous change, never show anything.
//!
//! # Why a pool of its own, not Bevy's `AsyncComputeTaskPool`
//! The tasks parallelise inside with rayon. Run from Bevy's async compute pool, their rayon jobs filled
//! rayon's *global* pool, and the main thread's own short rayon work (the snapshot's top-level BVH,
//! rebuilt with `obvhs` whenever a mesh moves) queued behind them: measured on `dynamic` with one mesh
//! moving, frames of 3 610 ms (radiosity) and 550 ms (photon grid) of main-thread time, as bad as before.
//! Bevy's async compute pool also has a single thread on a two-core machine, which pipeline compilation
//! shares. So the tasks run on a rayon pool of their own ([`pool`], one thread per core, named
//! `diffuse_gi background N`): their nested `par_iter`s stay on it, the global pool stays free for the
//! frame, and the operating system shares the cores between the two.
//!
//! The main thread's cost is the poll, the copy of the snapshot when a task starts (O(instances)) and
//! the blend (O(the result's size) for [`BLEND_FRAMES`] frames); [`crate::MainThreadCost`] reports it.
//! A task that panics is reported with one `error!` and its method starts again from scratch at the
//! next change of its inputs.

use std::marker::PhantomData;
use std::sync::{Arc, Mutex, OnceLock};

/// Frames over which a new background result replaces the shown one (linearly), so that it does not
/// pop. Counted in frames rather than seconds so that a run renders the same images on any machine.
pub const BLEND_FRAMES: u32 = 6;

/// The thread pool the background tasks run on (created at the first task): one thread per core.
pub fn pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("diffuse_gi background {i}"))
            .build()
            .expect("the background thread pool")
    })
}

/// Where a task leaves its result (or its panic).
type Slot<T> = Arc<Mutex<Option<std::thread::Result<T>>>>;

/// One background computation of a method: at most one task at a time, tagged with the key of the
/// inputs it was started from.
pub struct BackgroundJob<K, T> {
    running: Option<(K, Slot<T>)>,
    /// The key of the last result taken from a finished task.
    done: Option<K>,
    _marker: PhantomData<fn() -> T>,
}

impl<K, T> Default for BackgroundJob<K, T> {
    fn default() -> Self {
        Self { running: None, done: None, _marker: PhantomData }
    }
}

impl<K: PartialEq + Clone, T: Send + 'static> BackgroundJob<K, T> {
    /// The finished task's key and result, once; `None` while it runs or when none runs. Never waits.
    /// A task that panicked is logged and yields nothing; its key counts as done, so that the same
    /// inputs do not start it again.
    pub fn poll(&mut self) -> Option<(K, T)> {
        let (_, slot) = self.running.as_ref()?;
        let result = slot.lock().unwrap_or_else(|p| p.into_inner()).take()?;
        let (key, _) = self.running.take().expect("a running task");
        self.done = Some(key.clone());
        match result {
            Ok(result) => Some((key, result)),
            Err(panic) => {
                let message = panic.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| panic.downcast_ref::<String>().cloned());
                bevy::log::error!("bevy_diffuse_gi: a background GI task panicked: {}", message.unwrap_or_default());
                None
            }
        }
    }

    /// Whether a task is running.
    pub fn is_running(&self) -> bool {
        self.running.is_some()
    }

    /// Whether the last finished task was started from `key`.
    pub fn is_current(&self, key: &K) -> bool {
        self.done.as_ref() == Some(key)
    }

    /// Whether a task should start for `key`: none runs and the last result was made from other inputs.
    pub fn wants(&self, key: &K) -> bool {
        self.running.is_none() && !self.is_current(key)
    }

    /// Starts `work` on the background [`pool`] for the inputs `key`. A task already running is
    /// abandoned (it runs to its end; its result is dropped). Callers start only when
    /// [`wants`](Self::wants) says so.
    pub fn start(&mut self, key: K, work: impl FnOnce() -> T + Send + 'static) {
        let slot: Slot<T> = Arc::default();
        let sender = slot.clone();
        pool().spawn(move || {
            let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
            *sender.lock().unwrap_or_else(|p| p.into_inner()) = Some(result);
        });
        self.running = Some((key, slot));
    }

    /// Forgets everything: the running task is abandoned (its result is never used) and the next
    /// [`wants`](Self::wants) is true.
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}

/// Records the stage times of a finished background task in Bevy's diagnostics, one measurement per
/// stage that ran (a stage that did not run reports 0 and is left out).
pub fn record_stages(diagnostics: &mut bevy::diagnostic::Diagnostics, stages: &[(&bevy::diagnostic::DiagnosticPath, f32)]) {
    for &(path, ms) in stages {
        if ms > 0.0 {
            diagnostics.add_measurement(path, || ms as f64);
        }
    }
}

/// A linear blend from the result shown to a new one over [`BLEND_FRAMES`] frames.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Blend {
    /// Frames blended so far; the blend is done at [`BLEND_FRAMES`].
    frame: u32,
}

impl Blend {
    /// A finished blend (the new result shown whole).
    pub const DONE: Self = Self { frame: BLEND_FRAMES };

    /// A blend that starts now.
    pub fn start() -> Self {
        Self { frame: 0 }
    }

    /// Advances one frame and returns the new result's weight, in `(0, 1]`; `None` when the blend was
    /// already done (nothing to redraw).
    pub fn advance(&mut self) -> Option<f32> {
        if self.is_done() {
            return None;
        }
        self.frame += 1;
        Some(self.frame as f32 / BLEND_FRAMES as f32)
    }

    /// `from` blended towards `to` (element by element, with `lerp`) at the weight now; `to` itself once
    /// the blend is done.
    pub fn mix<T: Copy>(&self, from: &[T], to: &[T], lerp: impl Fn(T, T, f32) -> T) -> Vec<T> {
        let t = self.weight();
        if t >= 1.0 {
            return to.to_vec();
        }
        from.iter().zip(to).map(|(a, b)| lerp(*a, *b, t)).collect()
    }

    /// The new result's weight now, in `[0, 1]`.
    pub fn weight(&self) -> f32 {
        (self.frame as f32 / BLEND_FRAMES as f32).min(1.0)
    }

    pub fn is_done(&self) -> bool {
        self.frame >= BLEND_FRAMES
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wait<K: PartialEq + Clone, T: Send + 'static>(job: &mut BackgroundJob<K, T>) -> (K, T) {
        let start = std::time::Instant::now();
        loop {
            if let Some(done) = job.poll() {
                return done;
            }
            assert!(start.elapsed().as_secs() < 30, "the task did not finish");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
    }

    #[test]
    fn a_job_runs_off_the_calling_thread_and_reports_its_key_once() {
        let mut job = BackgroundJob::<u32, std::thread::ThreadId>::default();
        assert!(job.wants(&1) && !job.is_running());
        job.start(1, || std::thread::current().id());
        assert!(job.is_running() && !job.wants(&1) && !job.wants(&2));
        let (key, thread) = wait(&mut job);
        assert_eq!(key, 1);
        assert_ne!(thread, std::thread::current().id(), "the work ran on the calling thread");
        assert!(pool().current_thread_index().is_none(), "the test thread is not a pool thread");
        assert!(job.poll().is_none(), "a result is handed out once");
        assert!(job.is_current(&1) && !job.wants(&1) && job.wants(&2));
        job.reset();
        assert!(job.wants(&1));
    }

    #[test]
    fn polling_never_waits_for_the_task() {
        let mut job = BackgroundJob::<u32, ()>::default();
        let (sender, receiver) = std::sync::mpsc::channel::<()>();
        job.start(7, move || {
            let _ = receiver.recv_timeout(std::time::Duration::from_secs(20));
        });
        let start = std::time::Instant::now();
        for _ in 0..100 {
            assert!(job.poll().is_none());
        }
        assert!(start.elapsed().as_millis() < 1000, "polling a running task blocked");
        sender.send(()).unwrap();
        assert_eq!(wait(&mut job).0, 7);
    }

    #[test]
    fn a_task_that_panics_is_reported_once_and_not_restarted_for_the_same_inputs() {
        let mut job = BackgroundJob::<u32, u32>::default();
        job.start(3, || panic!("deliberate"));
        let start = std::time::Instant::now();
        while job.is_running() {
            assert!(job.poll().is_none());
            assert!(start.elapsed().as_secs() < 30, "the task did not finish");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert!(!job.wants(&3) && job.wants(&4));
    }

    #[test]
    fn nested_parallel_work_stays_on_the_background_pool() {
        use rayon::prelude::*;
        let mut job = BackgroundJob::<u32, Vec<Option<usize>>>::default();
        job.start(1, || (0..64).into_par_iter().map(|_| pool().current_thread_index()).collect());
        let (_, threads) = wait(&mut job);
        assert!(threads.iter().all(Option::is_some), "a nested par_iter ran outside the background pool");
    }

    #[test]
    fn a_blend_reaches_the_new_result_in_blend_frames_and_then_stops() {
        let mut blend = Blend::start();
        let weights: Vec<f32> = std::iter::from_fn(|| blend.advance()).collect();
        assert_eq!(weights.len(), BLEND_FRAMES as usize);
        assert!(weights.windows(2).all(|w| w[0] < w[1]) && weights[0] > 0.0);
        assert_eq!(*weights.last().unwrap(), 1.0);
        assert!(blend.is_done() && Blend::DONE.is_done());
        assert_eq!((Blend::start().weight(), Blend::DONE.weight()), (0.0, 1.0));
        let mut half = Blend::start();
        for _ in 0..BLEND_FRAMES / 2 {
            half.advance();
        }
        let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
        assert_eq!(half.mix(&[0.0, 2.0], &[2.0, 4.0], lerp), vec![1.0, 3.0]);
        assert_eq!(Blend::DONE.mix(&[0.0], &[5.0], lerp), vec![5.0]);
    }
}
