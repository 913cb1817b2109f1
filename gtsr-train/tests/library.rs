//! The run as a library: `run_with` on a tiny generated scene reports every step, each
//! evaluation along the run and each checkpoint, in order.

use clap::Parser;
use gtsr_train::{Args, Outcome, RunEvent, run_with};

mod common;

#[test]
fn run_with_reports_the_steps_evaluations_and_checkpoints() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene");
    common::tiny_scene(&scene);
    let out = tmp.path().join("out");
    let args = Args::parse_from([
        "gtsr-train",
        "--data",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--iterations",
        "20",
        "--resolution",
        "24",
        "--eval-points",
        "2",
        "--checkpoint-every",
        "10",
    ]);
    let mut steps = Vec::new();
    let mut evaluations = Vec::new();
    let mut checkpoints = Vec::new();
    let mut last_seconds = 0.0;
    let outcome = run_with(&args, |event| match event {
        RunEvent::Step {
            step,
            of,
            report,
            train_seconds,
        } => {
            assert_eq!(of, 20);
            assert!(report.loss.is_finite());
            assert!(train_seconds >= last_seconds);
            last_seconds = train_seconds;
            steps.push(step);
        }
        RunEvent::Evaluation {
            step, evaluation, ..
        } => {
            assert!(evaluation.psnr.is_finite());
            evaluations.push(step);
        }
        RunEvent::Checkpoint { step, path } => {
            assert!(path.is_file());
            checkpoints.push(step);
        }
    })
    .expect("the tiny run");
    assert!(matches!(outcome, Outcome::Finished));
    assert_eq!(steps, (1..=20).collect::<Vec<_>>());
    assert_eq!(evaluations.len(), 2, "{evaluations:?}");
    assert_eq!(evaluations.last(), Some(&20));
    // Every tenth step, and the end of the run.
    assert_eq!(checkpoints, [10, 20, 20]);
    assert!(out.join("mesh.ply").is_file());
}
