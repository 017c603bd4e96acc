//! Broken plans: every file in `tests/bad-plans/` states on its first line the field(s) its
//! error must name and a fragment of the expected message (which includes the allowed values):
//!
//! ```text
//! # field: texture.size | expect: = 5000 is out of range: allowed 8..=4096
//! # fields: a.b, c.d | expect: 2 problems
//! ```

use std::path::{Path, PathBuf};

use btfrig_core::plan::{ExistingDataset, Plan, PlanContext, PlanError, PlanErrors};

fn bad_plans() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad-plans");
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    files
}

/// (fields, expected fragment) from the first line.
fn header(text: &str, path: &Path) -> (Vec<String>, String) {
    let first = text.lines().next().unwrap_or_default();
    let body = first
        .strip_prefix("# fields: ")
        .or_else(|| first.strip_prefix("# field: "))
        .unwrap_or_else(|| panic!("{}: first line must be `# field: F | expect: TEXT`", path.display()));
    let (fields, expect) =
        body.split_once(" | expect: ").unwrap_or_else(|| panic!("{}: no ` | expect: `", path.display()));
    (fields.split(", ").map(str::to_string).collect(), expect.to_string())
}

fn check(path: &Path) -> PlanErrors {
    let text = std::fs::read_to_string(path).unwrap();
    let (fields, expect) = header(&text, path);
    let origin = path.display().to_string();
    let err = match Plan::load_and_validate(&text, &origin, &PlanContext::with_builtin_names()) {
        Ok(_) => panic!("{origin}: expected an error, the plan validated"),
        Err(e) => e,
    };
    let shown = err.to_string();
    assert!(shown.starts_with(&origin), "{origin}: the message names the file: {shown}");
    assert!(shown.contains(&expect), "{origin}: expected {expect:?} in:\n{shown}");
    for field in &fields {
        let named = err.errors.iter().any(|e| match e {
            // Schema errors come from serde: the key is in the message (and line, column).
            PlanError::Syntax { message, line, .. } => {
                *line > 0
                    && (message.contains(field.rsplit('.').next().unwrap()) || text.contains(&format!("[{field}]")))
            }
            other => other.field() == field && other.to_string().starts_with(field.as_str()),
        });
        assert!(named, "{origin}: no error names field {field}:\n{shown}");
    }
    // Every message says what is allowed (serde's schema errors say "expected").
    for e in &err.errors {
        let s = e.to_string();
        match e {
            PlanError::Syntax { .. } => {}
            _ => assert!(s.contains("allowed"), "{origin}: {s} does not say what is allowed"),
        }
    }
    err
}

#[test]
fn every_bad_plan_is_rejected_naming_its_field_and_the_allowed_values() {
    let files = bad_plans();
    let mut kinds = std::collections::HashSet::new();
    for path in &files {
        let err = check(path);
        for e in &err.errors {
            kinds.insert(std::mem::discriminant(e));
        }
    }
    assert!(files.len() >= 10, "at least ten kinds of broken plans, found {}", files.len());
    // Out of range, unknown, invalid, unreachable, syntax: all exercised.
    assert_eq!(kinds.len(), 5, "every kind of plan error is exercised");
}

#[test]
fn a_plan_with_several_errors_reports_all_of_them() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad-plans/many-errors.toml");
    let err = check(&path);
    assert_eq!(err.errors.len(), 8, "{err}");
}

#[test]
fn an_output_directory_holding_another_dataset_is_refused_and_the_same_plan_resumes() {
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../rig-configs/plans/demo.toml"))
        .unwrap();
    let plan = Plan::from_toml(&text, "demo.toml").unwrap();
    let mut ctx = PlanContext::with_builtin_names();
    ctx.existing_dataset = Some(ExistingDataset { plan_hash: 0x1234, path: "/data/old".into() });
    let err = plan.validate(&ctx).unwrap_err();
    assert_eq!(err.errors.len(), 1, "{err}");
    let s = err.to_string();
    assert!(s.contains("output = \"/data/old\" already holds a dataset of another plan"), "{s}");
    assert!(s.contains("allowed an empty or new directory, or the same plan to resume"), "{s}");
    ctx.existing_dataset = Some(ExistingDataset { plan_hash: plan.content_hash(), path: "/data/old".into() });
    assert!(plan.validate(&ctx).unwrap().resume);
}
