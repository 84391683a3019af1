//! `caliper run <kind>`: run a job kind on local files, without a server, and print the
//! document the service would store (same core code, same validation, same document builder).
//!
//! The subcommands come from the job-kind registry: each kind contributes its flags
//! ([`crate::jobs::Kind::Cli`]) and turns them into a parameters object; the flags every kind
//! shares ([`CommonArgs`]) are added here.

mod inputs;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::{ArgMatches, Args, FromArgMatches};
use serde_json::Value;

pub use inputs::expand;

use crate::jobs::{CliContext, JobInput, JobKind, RunError, document, kinds};
use crate::store::DatasetFile;

/// Flags shared by every offline kind.
#[derive(Debug, Args)]
pub struct CommonArgs {
    /// Write artifacts (plots, images, DSO files) into this directory.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Pretty-print the document (default: canonical JSON, byte-identical to the service's).
    #[arg(long)]
    pub pretty: bool,
    /// Print this export of the document instead (the formats its kind offers, e.g.
    /// opencv-yaml for camera_calibration, kalibr-yaml for imu_noise).
    #[arg(long)]
    pub export: Option<String>,
    /// Input files (directories are expanded to their files, sorted by name).
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
}

/// The `caliper run` command with one subcommand per registered kind.
pub fn command(run: clap::Command) -> clap::Command {
    kinds().iter().fold(
        run.subcommand_required(true).arg_required_else_help(true),
        // The kind's description, not the doc comment of the flag structs, is the help text.
        |cmd, k| cmd.subcommand(CommonArgs::augment_args(k.cli_command()).about(k.description())),
    )
}

/// Run the parsed `caliper run` subcommand; returns the text to print.
pub fn run(m: &ArgMatches) -> Result<String, RunError> {
    let Some((name, sub)) = m.subcommand() else {
        return Err(RunError::Input(
            "name a job kind: caliper run <kind> …".into(),
        ));
    };
    let kind = kinds()
        .iter()
        .copied()
        .find(|k| k.name().replace('_', "-") == name)
        .ok_or_else(|| RunError::Input(format!("unknown job kind {name}")))?;
    let common = CommonArgs::from_arg_matches(sub).map_err(|e| RunError::Input(e.to_string()))?;
    let params = kind.cli_params(
        sub,
        &CliContext {
            inputs: &common.inputs,
        },
    )?;
    let aux = kind.cli_aux_file(sub, &params);
    let doc = run_kind(kind, params, aux, &common)?;
    match &common.export {
        None => Ok(doc),
        Some(f) => {
            let v: Value = serde_json::from_str(&doc).map_err(|e| RunError::Job(e.to_string()))?;
            crate::exports::render(&v, f)
                .map(|r| r.body)
                .map_err(|e| RunError::Input(e.detail.unwrap_or_default()))
        }
    }
}

/// Run `kind` on the inputs; returns the sealed document (canonical JSON, or pretty).
/// `aux` is the local file standing in for the second dataset the kind reads, if any.
fn run_kind(
    kind: &dyn JobKind,
    params: Value,
    aux: Option<PathBuf>,
    common: &CommonArgs,
) -> Result<String, RunError> {
    let params = kind.normalize_params(&params)?;
    let paths = inputs::expand(&common.inputs)?;
    let described = match kind.dataset_kind() {
        crate::store::DatasetKind::Images
            if kind.accepts_video() && inputs::single_video(&paths) =>
        {
            inputs::video_file(&paths)?
        }
        crate::store::DatasetKind::Images => inputs::image_files(&paths)?,
        _ => inputs::log_file(&paths)?,
    };
    if described.is_empty() {
        return Err(RunError::Input("no images among the inputs".into()));
    }
    let aux_described = match aux {
        Some(p) => inputs::log_file(&[(p, false)])?,
        None => Vec::new(),
    };
    let by_sha: std::collections::HashMap<String, PathBuf> = described
        .iter()
        .chain(&aux_described)
        .map(|(f, p)| (f.sha256.clone(), p.clone()))
        .collect();
    let by_sha2 = by_sha.clone();
    let files: Vec<DatasetFile> = described.into_iter().map(|(f, _)| f).collect();
    let input = JobInput {
        files: files.clone(),
        aux_files: aux_described.into_iter().map(|(f, _)| f).collect(),
        params: params.clone(),
        load: Arc::new(move |f| {
            let p = by_sha
                .get(&f.sha256)
                .ok_or_else(|| std::io::Error::other("unknown file"))?;
            std::fs::read(p)
        }),
        open: Arc::new(move |f| {
            let p = by_sha2
                .get(&f.sha256)
                .ok_or_else(|| std::io::Error::other("unknown file"))?;
            Ok(Box::new(std::fs::File::open(p)?) as Box<dyn std::io::Read + Send>)
        }),
    };
    let output = kind
        .run(&input, &caliper_core::NoProgress)
        .map_err(|e| RunError::Job(e.to_string()))?;
    if let Some(dir) = &common.out {
        write_artifacts(dir, &output.artifacts)?;
    }
    let manifest = crate::document::manifest_sha256(&files);
    let doc = document::build(
        kind,
        &output,
        &document::Provenance {
            job: None,
            dataset: None,
            dataset_sha256: Some(&manifest),
            files: &files,
            params: &params,
            device: None,
            sensor: None,
        },
        crate::clock::now_ms(),
    );
    let (body, _) = crate::document::seal(doc, None);
    if common.pretty {
        let v: Value = serde_json::from_str(&body).map_err(|e| RunError::Job(e.to_string()))?;
        Ok(serde_json::to_string_pretty(&v).unwrap_or(body))
    } else {
        Ok(body)
    }
}

fn write_artifacts(dir: &Path, artifacts: &[crate::jobs::Artifact]) -> Result<(), RunError> {
    std::fs::create_dir_all(dir)?;
    for a in artifacts {
        std::fs::write(dir.join(&a.name), &a.data)?;
    }
    Ok(())
}
