//! The lab binary's error path.

use std::process::Command;

#[test]
fn an_error_is_one_message_naming_the_file_without_a_backtrace() {
    let missing = std::env::temp_dir().join("gtsr-lab-no-such-run");
    let o = Command::new(env!("CARGO_BIN_EXE_lab"))
        .arg("diagnose-surface")
        .arg("--run")
        .arg(&missing)
        .arg("--data")
        .arg(&missing)
        .env("RUST_BACKTRACE", "1")
        .env("RUST_LIB_BACKTRACE", "1")
        .output()
        .expect("running lab");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.starts_with("lab: error: "), "{err}");
    assert!(err.contains("gtsr-lab-no-such-run"), "{err}");
    assert!(!err.to_lowercase().contains("backtrace"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
}
