//! Running a test inside a network namespace of its own that has only loopback, so that
//! nothing a GenICam test does (discovery broadcasts, GVCP, GVSP) can leave the machine and
//! each test has 127.0.0.1:3956 to itself. The test re-executes its own binary, filtered to
//! itself, under `unshare --net` (util-linux; needs root or CAP_SYS_ADMIN, as CI has).

#![allow(dead_code)]

use std::process::{Child, Command, Stdio};

const INSIDE: &str = "BTFRIG_GENICAM_NETNS";

/// True inside the namespace: run the test's body. Outside, runs the test `name` again in a
/// fresh namespace, prints its output and fails if it failed; then returns false.
pub fn in_netns(name: &str) -> bool {
    if std::env::var_os(INSIDE).is_some() {
        return true;
    }
    let exe = std::env::current_exe().unwrap();
    let out = Command::new("unshare")
        .args(["--net", "--", "sh", "-c", "ip link set lo up && exec \"$0\" \"$@\""])
        .arg(&exe)
        .args([name, "--exact", "--nocapture", "--test-threads=1"])
        .env(INSIDE, "1")
        .output()
        .unwrap_or_else(|e| panic!("cannot run unshare (util-linux) for a loopback-only network namespace: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("--- {name} in its own network namespace ---\n{stdout}\n{stderr}");
    assert!(
        out.status.success(),
        "{name} failed in its network namespace ({}); unshare --net needs root or CAP_SYS_ADMIN",
        out.status
    );
    assert!(stdout.contains("1 passed"), "{name} did not run in the namespace:\n{stdout}");
    false
}

/// Only loopback here, and it is up: nothing can be broadcast off the machine.
pub fn assert_loopback_only() {
    // /proc/self/net is the namespace's own view (/sys/class/net is the mount's, not ours).
    let dev = std::fs::read_to_string("/proc/self/net/dev").unwrap();
    let links: Vec<&str> = dev.lines().skip(2).filter_map(|l| l.split(':').next()).map(str::trim).collect();
    assert_eq!(links, ["lo"], "network interfaces in the test's namespace");
}

/// Starts Aravis's GigE Vision fake camera (`arv-fake-gv-camera-0.8`, Debian's aravis-tools)
/// on 127.0.0.1 with `serial`; the caller waits until it answers.
pub fn spawn_fake_gv(serial: &str) -> Child {
    Command::new("arv-fake-gv-camera-0.8")
        .args(["-i", "127.0.0.1", "-s", serial])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("arv-fake-gv-camera-0.8 (Debian's aravis-tools; tests/install-deps.sh installs it)")
}
