//! Issue 24's attacks on `btfrig serve`, reproduced as found, each followed by the fixed
//! behaviour: a viewer reading host files through plan errors (item 1), a linked dataset
//! directory escaping the data directory (item 3), and the generated token file (item 6).

mod support;

use std::path::Path;
use std::process::Stdio;

use support::http::{Daemon, AUTH};
use support::{repo, scratch};

/// A secret on the host that no API answer may contain (it is valid TOML up to a line that
/// is not, so a parser's error would quote that line).
const SECRET: &str = "TOPSECRET-4711";

fn plan_naming(rig_config: &str, material: &str) -> String {
    format!(
        r#"name = "hardening"
[rig]
config = "{rig_config}"
material = "{material}"
seed = 3
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 15 }}
view = {{ preset = "bonn81", theta_max_deg = 15 }}
[texture]
size = 16
[skip]
max_captures = 4
"#
    )
}

fn body(plan_text: &str) -> String {
    serde_json::json!({ "plan_text": plan_text }).to_string()
}

/// Every way the plans API reads a plan: validate and dry-run (viewer) and start (operator).
/// Returns the answers' texts, after checking none is a success.
fn refused_everywhere(d: &Daemon, plan_text: &str) -> Vec<String> {
    let mut texts = Vec::new();
    for path in ["/api/v1/plans/validate", "/api/v1/plans/dry-run"] {
        let r = d.post(path, "viewer-token", &body(plan_text));
        assert_eq!(r.status, 200, "{path}: {}", r.text());
        assert_eq!(r.json()["valid"], false, "{path} accepted a plan naming a host file: {}", r.text());
        texts.push(r.text());
    }
    let r = d.post("/api/v1/runs", "operator-ada", &body(plan_text));
    assert_eq!(r.status, 422, "start: {}", r.text());
    assert_eq!(r.header("content-type"), Some("application/problem+json"));
    texts.push(r.text());
    texts
}

#[test]
fn a_plan_sent_over_the_api_cannot_read_host_files() {
    let dir = scratch("hardening_plan_files");
    let (auth, data, plans) = (dir.join("auth.toml"), dir.join("data"), dir.join("plans"));
    std::fs::write(&auth, AUTH).unwrap();
    std::fs::create_dir_all(&data).unwrap();
    std::fs::create_dir_all(plans.join("mats")).unwrap();
    // A host file outside every allowed place, and one in the data directory (where the
    // generated token lives and where API plans used to resolve relative paths).
    let outside = dir.join("outside.toml");
    std::fs::write(&outside, format!("name = \"x\"\n{SECRET} here\n")).unwrap();
    std::fs::write(data.join("secret.toml"), format!("{SECRET} = [\n")).unwrap();
    // The plans directory: a real material, a file that is no material, a link out of it.
    std::fs::copy(repo("sim/materials/leather.toml"), plans.join("mats/leather.toml")).unwrap();
    std::fs::write(plans.join("broken.toml"), format!("{SECRET} = [\n")).unwrap();
    std::os::unix::fs::symlink(&outside, plans.join("link.toml")).unwrap();
    let d = Daemon::start(&[
        "--auth",
        auth.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--plans",
        plans.to_str().unwrap(),
    ]);

    let rig = "builtin:bonn-gonio-sim";
    let outside_s = outside.to_str().unwrap();
    let attacks = [
        // As found: `[rig] config` naming any host file.
        plan_naming("/etc/passwd", "leather"),
        plan_naming("/proc/self/environ", "leather"),
        plan_naming(outside_s, "leather"),
        plan_naming("../data/secret.toml", "leather"),
        // A `.toml` material naming a host file, directly and through a link in the plans dir.
        plan_naming(rig, outside_s),
        plan_naming(rig, "../data/secret.toml"),
        plan_naming(rig, "link.toml"),
        // A fault scenario file.
        format!("{}[run]\nfault_scenario = \"{outside_s}\"\n", plan_naming(rig, "leather")),
    ];
    for plan in &attacks {
        for t in refused_everywhere(&d, plan) {
            assert!(!t.contains(SECRET) && !t.contains("root:"), "a host file leaked: {t}");
            assert!(t.contains("may not name this file"), "the refusal says why: {t}");
            assert!(t.contains("allowed: embedded names"), "the refusal says what is allowed: {t}");
        }
    }
    // A file inside the plans directory that is no material: refused with where the parser
    // stopped, never with its text.
    for t in refused_everywhere(&d, &plan_naming(rig, "broken.toml")) {
        assert!(t.contains("does not load as a material (parse error at line 1"), "{t}");
        assert!(!t.contains(SECRET), "the file's text leaked: {t}");
    }
    // What is allowed still works: embedded names, and a material file inside the plans directory.
    for plan in [plan_naming(rig, "leather"), plan_naming(rig, "mats/leather.toml")] {
        let r = d.post("/api/v1/plans/validate", "viewer-token", &body(&plan));
        assert_eq!(r.json()["valid"], true, "{}", r.text());
    }
    // Nothing was created by the refused starts.
    let entries: Vec<_> = std::fs::read_dir(&data).unwrap().flatten().map(|e| e.file_name()).collect();
    assert_eq!(entries, ["secret.toml"], "refused starts created nothing");
}

#[test]
fn without_a_plans_directory_an_api_plan_may_name_no_file_at_all() {
    let dir = scratch("hardening_no_plans_dir");
    let (auth, data) = (dir.join("auth.toml"), dir.join("data"));
    std::fs::write(&auth, AUTH).unwrap();
    let d = Daemon::start(&["--auth", auth.to_str().unwrap(), "--data", data.to_str().unwrap()]);
    // Relative paths used to resolve in DATA, where the generated token and datasets live.
    std::fs::write(data.join("mine.toml"), format!("{SECRET} = [\n")).unwrap();
    for t in refused_everywhere(&d, &plan_naming("mine.toml", "leather")) {
        assert!(!t.contains(SECRET), "a file of the data directory leaked: {t}");
        assert!(t.contains("no files: the daemon was started without --plans DIR"), "{t}");
    }
}

#[test]
fn a_linked_dataset_directory_does_not_escape_the_data_directory() {
    let dir = scratch("hardening_dataset_link");
    let (auth, data) = (dir.join("auth.toml"), dir.join("data"));
    std::fs::write(&auth, AUTH).unwrap();
    std::fs::create_dir_all(&data).unwrap();
    // As found: DATA/x -> / served /etc/passwd.
    std::os::unix::fs::symlink("/", data.join("x")).unwrap();
    // A link to a directory that looks like a dataset, outside DATA.
    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    std::fs::write(elsewhere.join("manifest.json"), format!("{{\"secret\": \"{SECRET}\"}}")).unwrap();
    std::os::unix::fs::symlink(&elsewhere, data.join("y")).unwrap();
    let d = Daemon::start(&["--auth", auth.to_str().unwrap(), "--data", data.to_str().unwrap()]);
    for path in [
        "/api/v1/datasets/x/files/etc/passwd",
        "/api/v1/datasets/x/files/proc/self/environ",
        "/api/v1/datasets/x",
        "/api/v1/datasets/y",
        "/api/v1/datasets/y/files/manifest.json",
    ] {
        let r = d.get(path, "viewer-token");
        assert_eq!(r.status, 404, "{path}: {}", r.text());
        assert_eq!(r.header("content-type"), Some("application/problem+json"), "{path}");
        assert!(!r.text().contains("root:") && !r.text().contains(SECRET), "{path} leaked: {}", r.text());
    }
    let list = d.get("/api/v1/datasets", "viewer-token");
    assert!(!list.text().contains(SECRET) && !list.text().contains("\"y\""), "listed a link: {}", list.text());
    // A run does not write through the link either.
    let start = serde_json::json!({ "plan": "demo", "dataset": "y" }).to_string();
    let r = d.post("/api/v1/runs", "operator-ada", &start);
    assert_eq!(r.status, 409, "{}", r.text());
    assert!(r.json()["detail"].as_str().unwrap().contains("not a directory"), "{}", r.text());
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 1, "nothing written through the link");
}

/// `btfrig serve` without `--auth` on `data`, until it prints its listen line or exits:
/// (exited early with this status, stderr so far).
fn serve_without_auth(data: &Path) -> (Option<std::process::ExitStatus>, String, Option<std::process::Child>) {
    use std::io::BufRead;
    let mut child = support::btfrig()
        .args(["serve", "--listen", "127.0.0.1:0", "--data", data.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
    if first.starts_with("listening on") {
        // The lines written before it are the start-up lines; read them without waiting for EOF.
        let mut err = std::io::BufReader::new(child.stderr.take().unwrap());
        let mut lines = String::new();
        while !lines.contains(" named plans") {
            if err.read_line(&mut lines).unwrap() == 0 {
                break;
            }
        }
        return (None, lines, Some(child));
    }
    let out = child.wait_with_output().unwrap();
    (Some(out.status), String::from_utf8_lossy(&out.stderr).into_owned(), None)
}

#[test]
fn the_token_file_is_private_never_written_through_a_link_and_never_printed() {
    use std::os::unix::fs::PermissionsExt;
    let dir = scratch("hardening_token_file");
    let data = dir.join("data");
    std::fs::create_dir_all(&data).unwrap();
    let token_file = data.join("daemon-token");
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;

    // As found: an existing 0644 file kept its mode and received the new token. Now: refused.
    std::fs::write(&token_file, "old\n").unwrap();
    std::fs::set_permissions(&token_file, std::fs::Permissions::from_mode(0o644)).unwrap();
    let (status, err, _) = serve_without_auth(&data);
    assert!(status.is_some_and(|s| !s.success()), "a 0644 token file was accepted: {err}");
    assert!(err.contains("has mode 0644") && err.contains("remove the file"), "{err}");
    assert_eq!(std::fs::read_to_string(&token_file).unwrap(), "old\n", "the 0644 file was written");

    // As found: a link at that path was followed and its target overwritten. Now: refused.
    std::fs::remove_file(&token_file).unwrap();
    let target = dir.join("victim.txt");
    std::fs::write(&target, "precious\n").unwrap();
    std::os::unix::fs::symlink(&target, &token_file).unwrap();
    let (status, err, _) = serve_without_auth(&data);
    assert!(status.is_some_and(|s| !s.success()), "a linked token file was accepted: {err}");
    assert!(err.contains("is a symbolic link"), "{err}");
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "precious\n", "the link's target was overwritten");

    // A fresh start: a 0600 file, and stderr names where the token is, not the token.
    std::fs::remove_file(&token_file).unwrap();
    let (status, err, child) = serve_without_auth(&data);
    assert!(status.is_none(), "the daemon did not start: {err}");
    let token = std::fs::read_to_string(&token_file).unwrap().trim().to_string();
    assert!(token.len() >= 16, "a token was written: {token:?}");
    assert_eq!(mode(&token_file), 0o600);
    assert!(err.contains(&token_file.display().to_string()), "{err}");
    assert!(!err.contains(&token), "the token was printed on stderr: {err}");
    let mut child = child.unwrap();
    let _ = child.kill();
    let _ = child.wait();

    // A restart replaces its own 0600 file with a new token.
    let (status, err, child) = serve_without_auth(&data);
    assert!(status.is_none(), "a restart was refused: {err}");
    let again = std::fs::read_to_string(&token_file).unwrap().trim().to_string();
    assert_ne!(again, token, "a restart writes a new token");
    assert_eq!(mode(&token_file), 0o600);
    let leftovers: Vec<_> = std::fs::read_dir(&data)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    let mut child = child.unwrap();
    let _ = child.kill();
    let _ = child.wait();
}

#[test]
fn serve_refuses_a_rig_whose_device_options_would_fail_a_run() {
    // As found: a NaN `jitter_deg` or an inverted `exposure_range_s` passed `serve --rig`,
    // and every run on that rig then failed.
    let dir = scratch("hardening_serve_rig");
    let rig = std::fs::read_to_string(repo("rig-configs/bonn-gonio-sim.toml")).unwrap();
    for (name, text, field) in [
        ("nan-jitter", rig.replace("jitter_deg = 0.1", "jitter_deg = nan"), "jitter_deg"),
        (
            "inverted-exposure",
            rig.replace("exposure_range_s = [0.0001, 30.0]", "exposure_range_s = [30.0, 0.0001]"),
            "exposure_range_s",
        ),
    ] {
        assert_ne!(text, rig, "{name}: the replacement matched nothing");
        let path = dir.join(format!("{name}.toml"));
        std::fs::write(&path, text).unwrap();
        let data = dir.join(format!("{name}-data"));
        let mut child = support::btfrig()
            .args(["serve", "--listen", "127.0.0.1:0", "--rig", path.to_str().unwrap()])
            .args(["--data", data.to_str().unwrap()])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // Its first line on stdout, or EOF when it exits: a daemon that listens is killed, so
        // the test fails rather than hangs.
        let mut first = String::new();
        std::io::BufRead::read_line(&mut std::io::BufReader::new(child.stdout.take().unwrap()), &mut first).unwrap();
        if first.starts_with("listening") {
            let _ = child.kill();
        }
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!first.starts_with("listening"), "{name}: serve started: {first}{err}");
        assert!(!out.status.success(), "{name}: serve exited 0: {err}");
        assert!(err.contains(field), "{name}: the error names {field}: {err}");
    }
}
