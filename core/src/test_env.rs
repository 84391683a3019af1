//! Where tests find what lives outside the repository: the shared sample data and a Python
//! with OpenCV and PyYAML for the interop tests. Both come from environment variables that
//! `.ci/run` sets (`CALIPER_SHARED_DATA`, `CALIPER_PYTHON`), or from the project's sibling
//! `../shared/data`; a test that lacks them says loudly that it did not run and returns.

use std::path::PathBuf;

/// A file or folder of the shared sample data (`rel` from its root), if present.
pub(crate) fn shared_data(rel: &str) -> Option<PathBuf> {
    let roots = [
        std::env::var_os("CALIPER_SHARED_DATA").map(PathBuf::from),
        Some(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")),
    ];
    let found = roots
        .into_iter()
        .flatten()
        .map(|r| r.join(rel))
        .find(|p| p.exists());
    if found.is_none() {
        eprintln!(
            "\n*** NOT RUN: shared data {rel} not found (set CALIPER_SHARED_DATA to the folder) ***\n"
        );
    }
    found
}

/// The Python interpreter for interop tests (`CALIPER_PYTHON`, else `python3`), if it can
/// import `modules` (comma-separated).
pub(crate) fn python(modules: &str) -> Option<PathBuf> {
    let py =
        std::env::var_os("CALIPER_PYTHON").map_or_else(|| PathBuf::from("python3"), PathBuf::from);
    let probe = std::process::Command::new(&py)
        .args(["-c", &format!("import {modules}")])
        .output();
    match probe {
        Ok(o) if o.status.success() => Some(py),
        Ok(o) => {
            eprintln!(
                "\n*** NOT RUN: {} cannot import {modules} (set CALIPER_PYTHON): {} ***\n",
                py.display(),
                String::from_utf8_lossy(&o.stderr).trim()
            );
            None
        }
        Err(e) => {
            eprintln!(
                "\n*** NOT RUN: {} not runnable: {e} (set CALIPER_PYTHON) ***\n",
                py.display()
            );
            None
        }
    }
}
