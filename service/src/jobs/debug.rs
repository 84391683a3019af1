//! `debug_hang`: a job kind that never returns and never looks at its cancel flag, enabled only
//! by `Config::debug_job_kinds`. It exists so that the test-suite can prove the worker's
//! watchdog on the worst job body there is: the time limit fails it, its worker slot is
//! reused, and a shutdown still ends within its grace period. Never listed by the API.

use caliper_core::Progress;
use serde_json::Value;

use super::{CliContext, JobError, JobInput, JobOutput, JsonParams, Kind, ParamError, RunError};
use crate::store::DatasetKind;

/// The `debug_hang` job kind.
pub struct DebugHang;

/// Its (empty) parameters.
#[derive(Debug, Default, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct DebugHangParams {}

impl Kind for DebugHang {
    const NAME: &'static str = "debug_hang";
    const SCHEMA: &'static str = "caliper.debug_hang/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const DESCRIPTION: &'static str = "Test only: never returns and ignores cancellation.";
    type Params = DebugHangParams;
    type Cli = JsonParams;

    fn check(_: &mut DebugHangParams) -> Result<(), ParamError> {
        Ok(())
    }

    fn cli_params(a: &JsonParams, _: &CliContext<'_>) -> Result<Value, RunError> {
        a.value()
    }

    fn run(
        &self,
        _: DebugHangParams,
        _: &JobInput,
        _: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        loop {
            std::thread::sleep(std::time::Duration::from_secs(3600));
        }
    }
}
