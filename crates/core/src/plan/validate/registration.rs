//! `[registration]`: where each frame's pose comes from and what a failure does.

use super::{OnRegistrationFailure, RegistrationMethod, RegistrationPolicy};
use crate::plan::{PlanError, RegistrationSpec};

pub(super) fn resolve_registration(r: &RegistrationSpec, errors: &mut Vec<PlanError>) -> Option<RegistrationPolicy> {
    let method = match r.method.as_str() {
        "markers" => Some(RegistrationMethod::Markers),
        "nominal" => Some(RegistrationMethod::Nominal),
        other => {
            errors.push(PlanError::unknown("registration.method", other, "\"markers\", \"nominal\""));
            None
        }
    };
    let on_failure = match r.on_failure.as_str() {
        "nominal" => Some(OnRegistrationFailure::Nominal),
        "fail" => Some(OnRegistrationFailure::Fail),
        other => {
            errors.push(PlanError::unknown("registration.on_failure", other, "\"nominal\", \"fail\""));
            None
        }
    };
    Some(RegistrationPolicy { method: method?, on_failure: on_failure? })
}
