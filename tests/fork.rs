//! A process that forks after using the GPU (Python's multiprocessing does
//! on Linux): the child must not use the parent's device, whose driver
//! state is the parent's, so it opens its own (`gpu::shared`) and scores
//! as the parent did. Alone in its own test binary: a fork copies only the
//! forking thread, and other tests' threads could hold locks at that
//! moment.
#![cfg(unix)]

use std::time::{Duration, Instant};

use glam::DVec3;
use plausible::gpu::test_context;
use plausible::hypotheses::around_and_random;
use plausible::kernels::score::{GpuScorer, ScoreParams, ScoreRecord};
use plausible::kernels::RenderMesh;
use plausible::mesh::{Mesh, MeshUnits};
use plausible::observation::{RoiSampling, ScoreTarget, DEFAULT_ROI_MARGIN};
use plausible::pose::{axis_angle, Pose};
use plausible::synth::{linemod_camera, observe, SensorNoise};

/// The duck's records for 64 poses on a context opened in this process.
fn score_here() -> (plausible::gpu::Context, Vec<ScoreRecord>) {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/pybullet/duck.obj");
    let mesh = RenderMesh::new(&Mesh::load(path, MeshUnits::Metres).unwrap().0.normalized(0.15)).unwrap();
    let truth = Pose::new(axis_angle(DVec3::new(0.3, 1.0, -0.2), 2.1), DVec3::new(0.02, -0.01, 0.7));
    let (obs, mask) = observe(&mesh, &truth, &linemod_camera(), SensorNoise::default(), 7);
    let target = ScoreTarget::new(&obs, Some(&mask), RoiSampling::Square(128), DEFAULT_ROI_MARGIN).unwrap();
    let poses = around_and_random(&truth, 64, 11);
    let ctx = test_context();
    let (records, _) = GpuScorer::new(&ctx, &mesh, &target, ScoreParams::default(), poses.len()).unwrap().score(&poses).unwrap();
    (ctx, records)
}

#[test]
fn gpu_a_forked_child_opens_its_own_device_and_scores_the_same() {
    let (parent_ctx, parent) = score_here();
    // SAFETY: the child only scores and leaves with _exit; see the module
    // comment for why this test has its binary to itself.
    let pid = unsafe { libc::fork() };
    assert!(pid >= 0, "fork failed");
    if pid == 0 {
        let code = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let (child_ctx, child) = score_here();
            if child_ctx.shares_device_with(&parent_ctx) {
                3 // handed the parent's device
            } else if child != parent {
                4 // scored differently
            } else {
                0
            }
        }))
        .unwrap_or(2);
        // SAFETY: leaves the child without running the parent's exit
        // handlers or destructors.
        unsafe { libc::_exit(code) };
    }
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut status = 0;
    loop {
        // SAFETY: waits for our own child.
        let done = unsafe { libc::waitpid(pid, &mut status, libc::WNOHANG) };
        if done == pid {
            break;
        }
        if Instant::now() > deadline {
            // SAFETY: our own child.
            unsafe {
                libc::kill(pid, libc::SIGKILL);
                libc::waitpid(pid, &mut status, 0);
            }
            panic!("the forked child hung for 120 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(libc::WIFEXITED(status), "the forked child died (status {status:#x})");
    let why = ["", "", "panicked", "was handed the parent's device", "scored differently"];
    let code = libc::WEXITSTATUS(status);
    assert_eq!(code, 0, "the forked child {}", why.get(code as usize).unwrap_or(&"failed"));
}
