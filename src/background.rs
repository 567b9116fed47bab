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
//! On Linux the pool's threads run under `SCHED_BATCH`: the same share of the CPU as any other thread,
//! but a woken one does not preempt the thread that woke it. Under the default policy, starting a task
//! woke a pool thread that took the main thread's core at once: with the VPLs, which start a walk
//! almost every frame while something moves, 6–31 of 75 frames in `dynamic` (256², lavapipe, two cores)
//! spent 2–9 ms of main-thread time inside `update_vpls` with 0.03 ms of it on the CPU, the main thread
//! waiting for its core; with `SCHED_BATCH`, 1–2 of 75 (the pool thread still takes the core at the next
//! scheduler tick when the tick falls inside the system), worst 4.3–5.4 ms against 6.8–9.1 (five runs
//! of each, alternating). Frame times and walk times did not change beyond their noise.
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
            .start_handler(|_| batch_scheduling())
            .build()
            .expect("the background thread pool")
    })
}

/// Puts the calling thread under Linux's `SCHED_BATCH` policy: the same share of the CPU as any
/// other thread of its nice level, but waking it never preempts the running thread.
fn batch_scheduling() {
    #[cfg(target_os = "linux")]
    {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: `sched_setscheduler` on the calling thread (pid 0) with a valid parameter.
        let result = unsafe { libc::sched_setscheduler(0, libc::SCHED_BATCH, &param) };
        if result != 0 {
            bevy::log::debug!("bevy_diffuse_gi: SCHED_BATCH for a background thread: {}", std::io::Error::last_os_error());
        }
    }
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

/// What a CPU method's result depends on in the scene: the snapshot's generations, the lights that
/// bounce and the camera's exposure (the emission of `emissive.alpha < 1` materials depends on it).
#[derive(Clone, Debug, PartialEq)]
pub struct SceneInputs {
    pub geometry: u64,
    pub lights: u64,
    /// The [`GiLight`](crate::light::GiLight) entities, sorted.
    pub gi_lights: Vec<bevy::prelude::Entity>,
    /// The exposure's bits.
    pub exposure: u32,
    pub environment: u64,
}

impl SceneInputs {
    pub fn of(snapshot: &crate::scene::SceneSnapshot, gi_lights: impl Iterator<Item = bevy::prelude::Entity>, exposure: f32) -> Self {
        let mut gi_lights: Vec<_> = gi_lights.collect();
        gi_lights.sort();
        Self {
            geometry: snapshot.geometry_generation,
            lights: snapshot.light_generation,
            gi_lights,
            exposure: exposure.to_bits(),
            environment: snapshot.environment_generation,
        }
    }

    /// The exposure.
    pub fn exposure(&self) -> f32 {
        f32::from_bits(self.exposure)
    }
}

/// The inputs of one background task of a CPU method: the scene's and the settings the task reads
/// (not those applied when drawing, whose change starts no task).
#[derive(Clone, Debug, PartialEq)]
pub struct JobKey<S> {
    pub scene: SceneInputs,
    pub settings: S,
}

/// The scaffold of a method that solves on the CPU (radiosity, the photon grid): the state its
/// background work keeps between runs (`C`: elements and links, voxels), moved into each task and
/// handed back with its result `R`, and the running task.
pub struct CpuJob<S, C, R> {
    /// `None` while a task holds it (or before the first).
    core: Option<Box<C>>,
    job: BackgroundJob<JobKey<S>, (Box<C>, R)>,
    /// The running task's [`Superseded`] flag.
    superseded: Superseded,
}

/// Set by the main thread ([`CpuJob::supersede_if_stale`]) when the inputs changed again while a task
/// runs: the task may then stop after a stage whose work the next task keeps, instead of finishing a
/// result that is already stale.
#[derive(Clone, Debug, Default)]
pub struct Superseded(Arc<std::sync::atomic::AtomicBool>);

impl Superseded {
    /// Whether newer inputs wait for the task's end.
    pub fn is_set(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }
}

impl<S, C, R> Default for CpuJob<S, C, R> {
    fn default() -> Self {
        Self { core: None, job: BackgroundJob::default(), superseded: Superseded::default() }
    }
}

impl<S: Clone + PartialEq + Send + Sync + 'static, C: Default + Send + 'static, R: Send + 'static> CpuJob<S, C, R> {
    /// Whether anything is kept or running (false after [`reset`](Self::reset)).
    pub fn is_active(&self) -> bool {
        self.core.is_some() || self.job.is_running()
    }

    /// Forgets the kept state and abandons the running task (the method was switched off).
    pub fn reset(&mut self) {
        self.job.reset();
        self.core = None;
    }

    /// The result of a finished task, once; its state comes back. Never waits.
    pub fn poll(&mut self) -> Option<R> {
        let (_, (core, result)) = self.job.poll()?;
        self.core = Some(core);
        Some(result)
    }

    /// Whether a task should start for `key`: none runs and the last one had other inputs (changes
    /// made while a task runs are coalesced into the next).
    pub fn wants(&self, key: &JobKey<S>) -> bool {
        self.job.wants(key)
    }

    /// Starts `work` on the kept state for the inputs `key`, on the background pool. Callers start only
    /// when [`wants`](Self::wants) says so.
    pub fn start(&mut self, key: &JobKey<S>, work: impl FnOnce(&mut C, &JobKey<S>) -> R + Send + 'static) {
        self.start_supersedable(key, move |core, key, _| work(core, key));
    }

    /// [`start`](Self::start), with the task's [`Superseded`] flag for `work` to read.
    pub fn start_supersedable(&mut self, key: &JobKey<S>, work: impl FnOnce(&mut C, &JobKey<S>, &Superseded) -> R + Send + 'static) {
        let mut core = self.core.take().unwrap_or_default();
        let task_key = key.clone();
        self.superseded = Superseded::default();
        let superseded = self.superseded.clone();
        self.job.start(key.clone(), move || {
            let result = work(&mut core, &task_key, &superseded);
            (core, result)
        });
    }

    /// Tells the running task, if it was started from other inputs than `key`, that it is superseded.
    pub fn supersede_if_stale(&self, key: &JobKey<S>) {
        if self.job.running.as_ref().is_some_and(|(k, _)| k != key) {
            self.superseded.0.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }

    /// Whether the result shown is not yet that of `key`: a task runs, or the last one had other inputs.
    pub fn is_stale(&self, key: &JobKey<S>) -> bool {
        self.job.is_running() || !self.job.is_current(key)
    }
}

/// The first active camera using `method`, with its settings (sanitised; the defaults when it has
/// none) and its exposure: the camera whose settings a scene-wide CPU method follows.
pub fn active_camera<S: crate::settings::GiSettings + Default>(
    cameras: &bevy::prelude::Query<(&bevy::prelude::Camera, &crate::camera::DiffuseGi, Option<&S>, Option<&bevy::camera::Exposure>)>,
    method: crate::camera::GiMethod,
) -> Option<(S, f32)> {
    let (_, _, settings, exposure) =
        cameras.iter().find(|(camera, gi, _, _)| camera.is_active && gi.enabled && gi.method == method)?;
    Some((settings.cloned().unwrap_or_default().sanitized().0, exposure.copied().unwrap_or_default().exposure()))
}

/// What every CPU method's main-world update reads (the cameras with the method's settings `S`, the
/// GI lights, the snapshot) and where it reports (its main-thread cost, its status, its stage times).
#[derive(bevy::ecs::system::SystemParam)]
pub struct CpuMethodParams<'w, 's, S: crate::settings::GiSettings + Default> {
    commands: bevy::prelude::Commands<'w, 's>,
    cameras: bevy::prelude::Query<
        'w,
        's,
        (
            &'static bevy::prelude::Camera,
            &'static crate::camera::DiffuseGi,
            Option<&'static S>,
            Option<&'static bevy::camera::Exposure>,
        ),
    >,
    gi_lights: bevy::prelude::Query<'w, 's, bevy::prelude::Entity, bevy::prelude::With<crate::light::GiLight>>,
    pub snapshot: Option<bevy::prelude::Res<'w, crate::scene::SceneSnapshot>>,
    pub cost: bevy::prelude::ResMut<'w, crate::MainThreadCost>,
    pub status: bevy::prelude::Res<'w, crate::method::GiMethodStatus>,
    pub diagnostics: bevy::diagnostic::Diagnostics<'w, 's>,
}

/// Whether a camera uses a CPU method this frame.
pub enum MethodUse<S> {
    /// No active camera uses it: its state is dropped.
    Off,
    /// Used, but the scene snapshot does not exist yet (it is requested).
    Waiting,
    /// Used, with the first camera's settings, over the scene as the snapshot has it now.
    On { settings: S, scene: SceneInputs },
}

impl<S: crate::settings::GiSettings + Default> CpuMethodParams<'_, '_, S> {
    /// Whether a camera uses `method` and, when the snapshot exists, with what settings and scene.
    pub fn method_use(&mut self, method: crate::camera::GiMethod) -> MethodUse<S> {
        let Some((settings, exposure)) = active_camera(&self.cameras, method) else {
            return MethodUse::Off;
        };
        let Some(snapshot) = self.snapshot.as_deref() else {
            self.commands.init_resource::<crate::scene::SceneSnapshot>();
            return MethodUse::Waiting;
        };
        MethodUse::On { scene: SceneInputs::of(snapshot, self.gi_lights.iter(), exposure), settings }
    }
}

/// The plugin steps of a CPU method: its stage diagnostics (ms), its main-world state, output and
/// activity resources, the output's extraction, and its update system (after the snapshot's).
pub(crate) fn add_cpu_method<State, Output, Activity, Marker>(
    app: &mut bevy::prelude::App,
    stages: &[bevy::diagnostic::DiagnosticPath],
    update: impl bevy::prelude::IntoScheduleConfigs<bevy::ecs::system::ScheduleSystem, Marker>,
) where
    State: bevy::prelude::Resource + Default,
    Output: bevy::prelude::Resource<Mutability = bevy::ecs::component::Mutable>
        + bevy::render::extract_resource::ExtractResource<Source = Output>
        + Default,
    Activity: bevy::prelude::Resource + Default,
{
    use bevy::diagnostic::{Diagnostic, RegisterDiagnostic};
    for path in stages {
        app.register_diagnostic(Diagnostic::new(path.clone()).with_suffix(" ms"));
    }
    app.init_resource::<State>()
        .init_resource::<Output>()
        .init_resource::<Activity>()
        .add_plugins(bevy::render::extract_resource::ExtractResourcePlugin::<Output>::default())
        .add_systems(bevy::prelude::PostUpdate, update.after(crate::scene::SceneSnapshotSystems::Update));
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
