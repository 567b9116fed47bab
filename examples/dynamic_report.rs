//! Measures what motion costs and how the bounced light keeps up with it: the numbers of
//! `docs/dynamic.md`.
//!
//! ```text
//! cargo run --release --features tools --example dynamic_report -- [--section NAME]... [--rounds N] [--docs docs/dynamic.md]
//! ```
//! Sections: `motion` (all six methods while things move: frame time, hitches, main-thread cost, and
//! how long the CPU methods' background work takes to catch up), `cost` (frame-time ratios to the frame without GI, at 256² and 512²), `triangles` (every method with one moving
//! mesh in scenes of 1 k, 50 k and 500 k triangles), `snapshot` (the scene snapshot's main-thread update,
//! without a renderer), `accuracy` (error while a light and a box move, against the ground truth of each
//! frame's pose, and the recovery after the motion stops), `stability` (frame-to-frame change). Each prints
//! a Markdown table; with `--docs FILE` it also replaces the text between `<!-- dynamic_report:NAME -->`
//! and `<!-- /dynamic_report:NAME -->`. Renders run one after another in this process on whatever Vulkan
//! device wgpu picks (lavapipe on CI machines); times are medians of the last frames of each run, quoted as
//! ratios to the frame without GI measured in the same round.

#[path = "common/mod.rs"]
mod common;

use std::process::ExitCode;

use bevy::prelude::*;
use bevy_diffuse_gi::camera::GiMethod;
use bevy_diffuse_gi::hdr_image::HdrImage;
use bevy_diffuse_gi::headless::{self, HeadlessMethod, HeadlessOptions, HeadlessReport};
use bevy_diffuse_gi::metrics;
use bevy_diffuse_gi::scene::{SceneSnapshot, SceneSnapshotPlugin, SnapshotTimings};
use bevy_diffuse_gi::scenes::StandardScene;

const SECTIONS: &[&str] = &["motion", "cost", "triangles", "snapshot", "accuracy", "stability"];
/// Frames of a timed run and the intervals at its end that the medians use.
const TIMED_RUN: u32 = 24;
const TIMED_FRAMES: usize = 12;
const METHODS: [GiMethod; 2] = [GiMethod::RadianceHints, GiMethod::Vpl];

fn main() -> ExitCode {
    if std::env::args().nth(1).as_deref() == Some(CHILD) {
        return child();
    }
    common::report_main("dynamic_report", run)
}

/// The first argument of a child process that renders one run (`render`).
const CHILD: &str = "--headless-child";

/// A child process: the headless renderer's flags after [`CHILD`]; writes the EXR, its siblings and the
/// JSON sidecar.
fn child() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(2).collect();
    let options = headless::parse_args(args.iter().map(String::as_str)).unwrap_or_else(|e| e.exit());
    match headless::run_and_write(&options) {
        Ok(_) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("dynamic_report child: {message}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    let args = common::start_report("dynamic_report", SECTIONS);
    for section in &args.sections {
        let table = match section.as_str() {
            "motion" => motion(args.rounds)?,
            "cost" => cost(args.rounds)?,
            "triangles" => triangles(args.rounds)?,
            "snapshot" => snapshot(),
            "accuracy" => accuracy()?,
            "stability" => stability()?,
            _ => unreachable!(),
        };
        println!("\n## {section}\n\n{table}");
        if let Some(docs) = &args.docs {
            common::replace_section(docs, "dynamic_report", section, &table)?;
        }
    }
    Ok(())
}

/// Renders one run in a child process of this tool: one process rendering dozens of apps in a row
/// grows by gigabytes and ends in a lavapipe crash (a JIT thread jumping into freed code, seen after
/// about 30 runs). Takes the options this report sets (scene, method, size, frames, indirect-only,
/// samples, the dynamic scene's motion, the background wait, extra triangles); the others must be the
/// defaults.
fn render(options: &HeadlessOptions) -> Result<HeadlessReport, String> {
    eprint!(".");
    let out = std::env::temp_dir().join(format!("dynamic_report_{}.exr", std::process::id()));
    let mut args: Vec<String> = vec![
        "--scene".into(),
        options.scene.name(),
        "--method".into(),
        options.method.name().into(),
        "--size".into(),
        format!("{}x{}", options.size.x, options.size.y),
        "--frames".into(),
        options.frames.to_string(),
        "--spp".into(),
        options.spp.to_string(),
        "--pose-frame".into(),
        options.pose_frame.to_string(),
        "--animate-meshes".into(),
        options.animate_meshes.to_string(),
        "--extra-triangles".into(),
        options.extra_triangles.to_string(),
        "--out".into(),
        out.display().to_string(),
    ];
    if options.indirect_only {
        args.push("--indirect-only".into());
    }
    if options.animate_light {
        args.push("--animate-light".into());
    }
    if let Some(stop) = options.stop_animation_at {
        args.extend(["--stop-animation-at".into(), stop.to_string()]);
    }
    if let Some(wait) = options.wait_background {
        args.extend(["--wait-background".into(), wait.to_string()]);
    }
    let exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let status = std::process::Command::new(exe).arg(CHILD).args(&args).status().map_err(|e| e.to_string())?;
    if !status.success() {
        return Err(format!("a headless run ({}) ended with {status}", args.join(" ")));
    }
    let image = HdrImage::read(&out).map_err(|e| e.to_string())?;
    let json = out.with_extension("json");
    let text = std::fs::read_to_string(&json).map_err(|e| format!("{}: {e}", json.display()))?;
    let sidecar: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{}: {e}", json.display()))?;
    // The one sibling image this report reads.
    let previous = headless::sibling(&out, "previous", "exr");
    let extra_images = if previous.exists() { vec![("previous", HdrImage::read(&previous).map_err(|e| e.to_string())?)] } else { Vec::new() };
    for path in [out.clone(), json, previous] {
        let _ = std::fs::remove_file(path);
    }
    Ok(HeadlessReport { image, extra_images, sidecar })
}

fn dynamic(method: HeadlessMethod, size: u32) -> HeadlessOptions {
    HeadlessOptions {
        scene: StandardScene::Dynamic,
        method,
        size: UVec2::splat(size),
        frames: TIMED_RUN,
        ..Default::default()
    }
}

/// The plugin's main-thread milliseconds of every frame of a run.
fn main_thread_series(report: &HeadlessReport) -> Vec<f64> {
    report.sidecar["main_thread_ms"].as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect()).unwrap_or_default()
}

/// Median main-thread milliseconds of the plugin over the last frames of a run.
fn main_ms(report: &HeadlessReport) -> f64 {
    let v = main_thread_series(report);
    common::median(&v[v.len().saturating_sub(TIMED_FRAMES)..])
}

/// Frames a `--wait-background` run rendered after its motion stopped until the CPU methods' background
/// work had caught up (∞ when it had not within the wait).
fn caught_up(report: &HeadlessReport) -> f64 {
    let wait = report.sidecar["background_wait_frames"].as_f64().unwrap_or(f64::NAN);
    if report.sidecar["background_timed_out"] == true { f64::INFINITY } else { (wait - headless::SETTLE_READBACKS as f64).max(0.0) }
}

/// A [`caught_up`] count for a table.
fn frames_text(frames: f64) -> String {
    if frames.is_infinite() { format!("not within {MOTION_WAIT_S} s") } else { format!("{frames:.0}") }
}

/// Motion cases: (name, light moves, meshes moving).
const CASES: [(&str, bool, u32); 4] = [("still", false, 0), ("light moving", true, 0), ("one mesh moving", false, 1), ("ten meshes moving", false, 10)];

fn cost(rounds: usize) -> Result<String, String> {
    let mut out = String::from(
        "| size | method | case | frame (ms) | × frame without GI | main thread (ms) |\n|---|---|---|---|---|---|\n",
    );
    for size in [256u32, 512] {
        let mut none = Vec::new();
        let mut rows: Vec<Vec<(f64, f64)>> = vec![Vec::new(); METHODS.len() * CASES.len()];
        for _ in 0..rounds {
            none.push(common::frame_ms(&render(&dynamic(HeadlessMethod::None, size))?, TIMED_FRAMES));
            for (m, method) in METHODS.iter().enumerate() {
                for (c, (_, light, meshes)) in CASES.iter().enumerate() {
                    let mut o = dynamic(HeadlessMethod::Gi(*method), size);
                    o.animate_light = *light;
                    o.animate_meshes = *meshes;
                    // Still: long enough that the volume has converged and stopped updating.
                    if !*light && *meshes == 0 {
                        o.frames = 48;
                    }
                    let r = render(&o)?;
                    rows[m * CASES.len() + c].push((common::frame_ms(&r, TIMED_FRAMES), main_ms(&r)));
                }
            }
        }
        let base = common::median(&none);
        out += &format!("| {size}² | none (Bevy alone) | still | {base:.0} | 1.0 | – |\n");
        for (m, method) in METHODS.iter().enumerate() {
            for (c, (case, ..)) in CASES.iter().enumerate() {
                let row = &rows[m * CASES.len() + c];
                let frame = common::median(&row.iter().map(|r| r.0).collect::<Vec<_>>());
                let main = common::median(&row.iter().map(|r| r.1).collect::<Vec<_>>());
                out += &format!("| {size}² | {} | {case} | {frame:.0} | {:.1} | {main:.2} |\n", method.name(), frame / base);
            }
        }
    }
    Ok(out)
}

/// Frames of motion in a `motion` run before it stops, and the frames timed at its end.
const MOTION_FRAMES: u32 = 32;
/// Frames a long `motion` run moves before those (the CPU methods reach their steady state).
const MOTION_WARMUP: u32 = 120;
const MOTION_TIMED: usize = 24;
/// The most a `motion` run waits for the CPU methods' background work after the motion stops, seconds.
const MOTION_WAIT_S: u32 = 300;

/// Every method while something moves in `dynamic` at 256²: the median frame against the frame without
/// GI of the same round, the worst frame against the median (a hitch), the main thread's median and
/// worst milliseconds (all at the end of a long motion), and for the CPU methods how many frames after
/// the motion stops their background work took to catch up with the final pose (`--wait-background`),
/// after a short first move and after a long motion.
fn motion(rounds: usize) -> Result<String, String> {
    const SIZE: u32 = 256;
    let cases: [(&str, bool, u32); 3] = [("one mesh moving", false, 1), ("ten meshes moving", false, 10), ("light orbiting", true, 0)];
    let mut out = String::from(
        "| method | case | frame × without GI | worst frame × median | main thread median / worst (ms) | frames to catch up: first move / moving for long |\n\
         |---|---|---|---|---|---|\n",
    );
    let mut none = Vec::new();
    let mut rows: Vec<Vec<[f64; 6]>> = vec![Vec::new(); GiMethod::ALL.len() * cases.len()];
    for _ in 0..rounds {
        none.push(common::frame_ms(&render(&dynamic(HeadlessMethod::None, SIZE))?, MOTION_TIMED));
        for (m, method) in GiMethod::ALL.iter().enumerate() {
            for (c, (_, light, meshes)) in cases.iter().enumerate() {
                // The motion stops after `frames`; the run goes on until the background work caught up.
                let run = |frames: u32| {
                    let mut o = dynamic(HeadlessMethod::Gi(*method), SIZE);
                    (o.animate_light, o.animate_meshes) = (*light, *meshes);
                    o.frames = frames;
                    o.stop_animation_at = Some(frames as f32);
                    o.wait_background = Some(MOTION_WAIT_S);
                    render(&o)
                };
                // A first move: the CPU methods start from the still scene's solution (radiosity then
                // makes the links it keeps while the mesh moves, a full solve's cost once).
                let first = run(MOTION_FRAMES)?;
                // Moving for long: the steady state a game with a walking character is in.
                let long = run(MOTION_WARMUP + MOTION_FRAMES)?;
                // The last frames of the motion only (the wait after it is not timed).
                let frames = common::frame_intervals(&long);
                let motion_end = frames.len().min((MOTION_WARMUP + MOTION_FRAMES) as usize);
                let moving = &frames[motion_end.saturating_sub(MOTION_TIMED)..motion_end];
                let main = main_thread_series(&long);
                let main = &main[..main.len().min(motion_end)];
                rows[m * cases.len() + c].push([
                    common::median(moving),
                    moving.iter().copied().fold(0.0, f64::max),
                    common::median(main),
                    main.iter().copied().fold(0.0, f64::max),
                    caught_up(&first),
                    caught_up(&long),
                ]);
            }
        }
    }
    let base = common::median(&none);
    for (m, method) in GiMethod::ALL.iter().enumerate() {
        for (c, (case, ..)) in cases.iter().enumerate() {
            let row = &rows[m * cases.len() + c];
            let col = |i: usize| common::median(&row.iter().map(|r| r[i]).collect::<Vec<_>>());
            out += &format!(
                "| {} | {case} | {:.1} | {:.1} | {:.2} / {:.2} | {} / {} |\n",
                method.name(),
                col(0) / base,
                col(1) / col(0),
                col(2),
                col(3),
                frames_text(col(4)),
                frames_text(col(5)),
            );
        }
    }
    out += &format!(
        "\nFrame without GI: {base:.0} ms (median of {rounds} run(s)); the frame times and main-thread costs are those of \
         the last {MOTION_TIMED} frames of a motion of {} frames. \"Frames to catch up\" counts the frames after the \
         motion stopped until the CPU methods' background work (radiosity, photon grid, VPL walks) had reached the \
         final pose and blended in (0 for the methods with none; Radiance Hints' volume refinement after a change is in \
         the accuracy section's recovery rows): after a first move of {MOTION_FRAMES} frames from the still scene, and \
         after a motion of {} frames. On lavapipe the background work and the rasteriser share the two CPU cores, so \
         the frame ratios of the CPU methods while moving include that contention.\n",
        MOTION_WARMUP + MOTION_FRAMES,
        MOTION_WARMUP + MOTION_FRAMES,
    );
    Ok(out)
}

/// Frames one mesh moves in a `triangles` run before the motion stops, and the frames timed at its end.
const TRIANGLES_MOTION: u32 = 48;
const TRIANGLES_TIMED: usize = 16;

/// Every method with object 0 (1 280 triangles) moving in `dynamic` at 256², with 1 k, 50 k and 500 k
/// static triangles added (`--extra-triangles`): the still frame and the moving frame against the frame
/// without GI of the same scene, the worst moving frame against the median (a hitch), the main thread's
/// median and worst milliseconds while moving, and for the CPU methods the frames their background work
/// took after the motion stopped to catch up with the final pose.
fn triangles(rounds: usize) -> Result<String, String> {
    const SIZE: u32 = 256;
    let mut out = String::from(
        "| scene triangles | method | still × none | one mesh moving × none | worst × median | moving − still (ms) | main thread median / worst (ms) | frames to catch up |\n\
         |---|---|---|---|---|---|---|---|\n",
    );
    let mut nones = Vec::new();
    for extra in [1_000u32, 50_000, 500_000] {
        let mut none = Vec::new();
        let mut rows: Vec<Vec<[f64; 6]>> = vec![Vec::new(); GiMethod::ALL.len()];
        for _ in 0..rounds {
            let mut o = dynamic(HeadlessMethod::None, SIZE);
            o.extra_triangles = extra;
            none.push(common::frame_ms(&render(&o)?, TIMED_FRAMES));
            for (m, method) in GiMethod::ALL.iter().enumerate() {
                let mut still = dynamic(HeadlessMethod::Gi(*method), SIZE);
                still.extra_triangles = extra;
                // Long enough that Radiance Hints' volume stopped updating; the CPU methods' first
                // solution is waited for.
                still.frames = 48;
                still.wait_background = Some(MOTION_WAIT_S);
                let still = common::frame_ms(&render(&still)?, TIMED_FRAMES);
                let mut moving = dynamic(HeadlessMethod::Gi(*method), SIZE);
                moving.extra_triangles = extra;
                moving.animate_meshes = 1;
                moving.frames = TRIANGLES_MOTION;
                moving.stop_animation_at = Some(TRIANGLES_MOTION as f32);
                moving.wait_background = Some(MOTION_WAIT_S);
                let r = render(&moving)?;
                let frames = common::frame_intervals(&r);
                let motion_end = frames.len().min(TRIANGLES_MOTION as usize);
                let timed = &frames[motion_end.saturating_sub(TRIANGLES_TIMED)..motion_end];
                let main = main_thread_series(&r);
                let main = &main[main.len().min(motion_end).saturating_sub(TRIANGLES_TIMED)..main.len().min(motion_end)];
                rows[m].push([
                    still,
                    common::median(timed),
                    timed.iter().copied().fold(0.0, f64::max),
                    common::median(main),
                    main.iter().copied().fold(0.0, f64::max),
                    caught_up(&r),
                ]);
            }
        }
        let n = common::median(&none);
        nones.push(format!("{n:.0}"));
        let triangles = bevy_diffuse_gi::scenes::dynamic::dynamic_triangles(extra);
        for (m, method) in GiMethod::ALL.iter().enumerate() {
            let col = |i: usize| common::median(&rows[m].iter().map(|r| r[i]).collect::<Vec<_>>());
            out += &format!(
                "| {triangles} | {} | {:.1} | {:.1} | {:.1} | {:.0} | {:.2} / {:.2} | {} |\n",
                method.name(),
                col(0) / n,
                col(1) / n,
                col(2) / col(1),
                col(1) - col(0),
                col(3),
                col(4),
                frames_text(col(5)),
            );
        }
    }
    out += &format!(
        "\nFrame without GI: {} ms at the three sizes (median of {rounds} run(s)). The moving frames are the last \
         {TRIANGLES_TIMED} of a motion of {TRIANGLES_MOTION} frames; \"frames to catch up\" counts the frames after \
         the motion stopped until the CPU methods' background work had reached the final pose (0 for the methods \
         with none).\n",
        nones.join(" / ")
    );
    Ok(out)
}

fn snapshot() -> String {
    let mut out = String::from(
        "| static triangles | instances | full build (ms) | one mesh moving: update (ms, median of 50 frames) |\n|---|---|---|---|\n",
    );
    // 980, 61 440 and 491 520 static triangles (ico 6 once, ico 31 three and 24 times).
    for (level, count) in [(6u32, 1u32), (31, 3), (31, 24)] {
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, AssetPlugin::default(), TransformPlugin, SceneSnapshotPlugin))
            .init_asset::<Mesh>()
            .init_asset::<StandardMaterial>()
            .init_asset::<Image>()
            .init_asset::<bevy::mesh::skinning::SkinnedMeshInverseBindposes>()
            .init_resource::<SceneSnapshot>();
        let world = app.world_mut();
        let static_mesh = world.resource_mut::<Assets<Mesh>>().add(Sphere::new(0.1).mesh().ico(level).unwrap());
        let moving_mesh = world.resource_mut::<Assets<Mesh>>().add(Sphere::new(0.3).mesh().ico(7).unwrap());
        let material = world.resource_mut::<Assets<StandardMaterial>>().add(StandardMaterial::default());
        for k in 0..count {
            world.spawn((Mesh3d(static_mesh.clone()), MeshMaterial3d(material.clone()), Transform::from_xyz(k as f32 * 0.3, 0.0, 0.0), InheritedVisibility::VISIBLE));
        }
        let mover = world
            .spawn((Mesh3d(moving_mesh), MeshMaterial3d(material), Transform::from_xyz(0.0, 1.0, 0.0), InheritedVisibility::VISIBLE))
            .id();
        let started = std::time::Instant::now();
        app.update();
        let build = started.elapsed().as_secs_f64() * 1e3;
        let mut updates = Vec::new();
        for frame in 0..50 {
            app.world_mut().get_mut::<Transform>(mover).unwrap().translation.x = frame as f32 * 0.05;
            app.update();
            updates.push(app.world().resource::<SnapshotTimings>().geometry_ms as f64);
        }
        let s = app.world().resource::<SceneSnapshot>();
        out += &format!(
            "| {} | {} | {build:.1} | {:.3} |\n",
            s.triangle_count() - 1_280,
            s.instances().len(),
            common::median(&updates)
        );
    }
    out
}

fn indirect(method: GiMethod, size: u32) -> HeadlessOptions {
    HeadlessOptions { indirect_only: true, ..dynamic(HeadlessMethod::Gi(method), size) }
}

/// The ground truth of pose `frame` (light and object 0 moved that far).
fn truth(frame: f32, size: u32) -> Result<HdrImage, String> {
    let o = HeadlessOptions {
        method: HeadlessMethod::Reference,
        indirect_only: true,
        spp: 256,
        pose_frame: frame,
        animate_light: true,
        animate_meshes: 1,
        ..dynamic(HeadlessMethod::Reference, size)
    };
    Ok(render(&o)?.image)
}

fn accuracy() -> Result<String, String> {
    // The light orbits and object 0 moves from pose 0; the motion stops at pose 30.
    const SIZE: u32 = 128;
    const STOP: f32 = 30.0;
    const AFTER: [u32; 7] = [1, 4, 8, 16, 32, 64, 128];
    let mut out = String::from(
        "| method | frame | pose | block rel. RMSE vs that pose's truth | energy | blocks > 50 % off | block rel. RMSE vs the method's still image |\n\
         |---|---|---|---|---|---|---|\n",
    );
    let truth_stop = truth(STOP, SIZE)?;
    let truth_mid = truth(15.0, SIZE)?;
    let mut lag = String::new();
    for method in GiMethod::ALL {
        let row = |frame: &str, pose: &str, m: &metrics::ErrorMetrics, still: Option<&metrics::ErrorMetrics>| {
            let still = still.map_or("–".to_string(), |s| format!("{:.3}", s.block_relative_rmse));
            format!(
                "| {} | {frame} | {pose} | {:.3} | {:.3} | {:.1} % | {still} |\n",
                method.name(),
                m.block_relative_rmse,
                m.energy_ratio,
                100.0 * m.blocks_over_half_off
            )
        };
        // The still scene in the stop pose: the method's converged image (the CPU methods' background
        // work done before the frames are counted).
        let mut still = indirect(method, SIZE);
        still.pose_frame = STOP;
        still.animate_light = true;
        still.animate_meshes = 1;
        still.stop_animation_at = Some(STOP);
        still.frames = 48;
        let converged = render(&still)?.image;
        // While moving: frame 15 of the motion, against the truth of the pose it shows.
        let mut o = indirect(method, SIZE);
        o.animate_light = true;
        o.animate_meshes = 1;
        o.stop_animation_at = Some(STOP);
        o.frames = 15;
        let r = render(&o)?;
        let pose = r.sidecar["dynamic_pose_frame"].as_f64().unwrap_or(f64::NAN);
        let m = metrics::compare(&r.image, &truth_mid).map_err(|e| e.to_string())?;
        out += &row("15, moving", &format!("{pose:.0} (truth: 15)"), &m, None);
        // After the stop: how many frames until the image is within 0.05 of the converged one.
        let mut within = None;
        for after in AFTER {
            o.frames = STOP as u32 + after;
            let r = render(&o)?;
            let m = metrics::compare(&r.image, &truth_stop).map_err(|e| e.to_string())?;
            let to_still = metrics::compare(&r.image, &converged).map_err(|e| e.to_string())?;
            if to_still.block_relative_rmse <= 0.05 {
                within.get_or_insert(after);
            } else {
                within = None;
            }
            out += &row(&format!("{after} after the stop"), &format!("{STOP:.0}"), &m, Some(&to_still));
        }
        let m = metrics::compare(&converged, &truth_stop).map_err(|e| e.to_string())?;
        out += &row("still in that pose (48 frames)", &format!("{STOP:.0}"), &m, None);
        lag += &format!(
            "{}: {}; ",
            method.name(),
            within.map_or(format!("not within {} frames", AFTER[AFTER.len() - 1]), |f| format!("{f}"))
        );
    }
    out += &format!(
        "\nFrames after the stop from which the image stays within 0.05 block relative RMSE of the method's still \
         image of the final pose (of {AFTER:?}): {}.\n",
        lag.trim_end_matches("; ")
    );
    Ok(out)
}

fn stability() -> Result<String, String> {
    let mut out = String::from(
        "| method | case | block rel. RMSE between the last two frames | energy ratio |\n|---|---|---|---|\n",
    );
    for method in METHODS {
        for (case, meshes, frames) in [("still, converged", 0u32, 48u32), ("one object moving", 1, 24)] {
            let mut o = indirect(method, 128);
            o.animate_meshes = meshes;
            o.frames = frames;
            let r = render(&o)?;
            let previous = r.extra_images.iter().find(|(n, _)| *n == "previous").map(|(_, i)| i).ok_or("no previous frame")?;
            let m = metrics::compare(&r.image, previous).map_err(|e| e.to_string())?;
            out += &format!("| {} | {case} | {:.4} | {:.4} |\n", method.name(), m.block_relative_rmse, m.energy_ratio);
        }
    }
    Ok(out)
}
