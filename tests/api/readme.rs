//! The README's examples stay true: every job request body in it (`curl -d '…'` and ```json
//! blocks) passes the kind's parameter validation, and every `caliper run` line parses with
//! the binary's real flags (run in an empty folder, it may only fail for want of its input
//! files, never for an unknown flag, value or kind).

use std::process::Command;

use crate::common::caliper_bin;

fn readme() -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md");
    std::fs::read_to_string(path).expect("README.md")
}

/// Lines of the README's code blocks, with `\` continuations joined.
fn code_lines(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_block = false;
    let mut pending = String::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            continue;
        }
        if !in_block {
            continue;
        }
        let l = line.trim_end();
        if let Some(stripped) = l.strip_suffix('\\') {
            pending.push_str(stripped);
            pending.push(' ');
            continue;
        }
        pending.push_str(l);
        out.push(std::mem::take(&mut pending));
    }
    out
}

/// The JSON job requests of the README: `-d '…'` bodies and whole ```json blocks.
fn job_bodies(text: &str) -> Vec<serde_json::Value> {
    let mut out = Vec::new();
    for l in code_lines(text) {
        if let Some(i) = l.find("-d '") {
            let rest = &l[i + 4..];
            if let Some(j) = rest.find('\'') {
                let v: serde_json::Value =
                    serde_json::from_str(&rest[..j]).expect("README -d body is JSON");
                if v.get("kind").is_some() {
                    out.push(v);
                }
            }
        }
    }
    let mut block = None::<String>;
    for line in text.lines() {
        match (&mut block, line.trim_start()) {
            (None, "```json") => block = Some(String::new()),
            (Some(b), "```") => {
                if let Ok(v) = serde_json::from_str::<serde_json::Value>(b)
                    && v.get("kind").is_some()
                {
                    out.push(v);
                }
                block = None;
            }
            (Some(b), _) => {
                b.push_str(line);
                b.push('\n');
            }
            _ => {}
        }
    }
    out
}

#[test]
fn readme_job_bodies_pass_validation() {
    let bodies = job_bodies(&readme());
    assert!(bodies.len() >= 5, "found only {} job bodies", bodies.len());
    for b in bodies {
        let name = b["kind"].as_str().expect("kind");
        let kind = caliper_service::jobs::find_kind(name)
            .unwrap_or_else(|| panic!("README names unknown kind {name}"));
        let params = b.get("params").cloned().unwrap_or(serde_json::json!({}));
        kind.normalize_params(&params)
            .unwrap_or_else(|e| panic!("README body for {name} is refused: {e}\n{b}"));
    }
}

/// The token requests of the README (`-d` bodies with a `scope`) are valid requests.
#[test]
fn readme_token_bodies_are_valid() {
    let mut n = 0;
    for l in code_lines(&readme()) {
        let Some(i) = l.find("-d '") else { continue };
        let rest = &l[i + 4..];
        let Some(j) = rest.find('\'') else { continue };
        let v: serde_json::Value = serde_json::from_str(&rest[..j]).expect("JSON body");
        if v.get("scope").is_none() {
            continue;
        }
        let req: caliper_service::api::tokens::CreateTokenRequest =
            serde_json::from_value(v.clone()).unwrap_or_else(|e| panic!("{v}: {e}"));
        caliper_service::auth::generate(&req.name, req.scope, req.devices, 0)
            .unwrap_or_else(|e| panic!("{v}: {e}"));
        n += 1;
    }
    assert!(n >= 2, "found {n} token bodies");
}

#[test]
fn readme_cli_lines_parse() {
    let bin = caliper_bin();
    let dir = tempfile::tempdir().expect("tempdir");
    let lines: Vec<String> = code_lines(&readme())
        .into_iter()
        .filter_map(|l| {
            let l = l.split("  #").next().unwrap_or(&l).trim().to_string();
            l.strip_prefix("caliper run ").map(String::from)
        })
        .collect();
    assert!(lines.len() >= 10, "found only {} CLI lines", lines.len());
    for l in lines {
        let args = shell_words(&l);
        let out = Command::new(&bin)
            .arg("run")
            .args(&args)
            .current_dir(dir.path())
            .output()
            .expect("run caliper");
        let err = String::from_utf8_lossy(&out.stderr);
        for clap_error in [
            "unexpected argument",
            "unrecognized subcommand",
            "invalid value",
            "required arguments were not provided",
            "--params is not JSON",
            "--options is not JSON",
            "must be COLSxROWS",
        ] {
            assert!(
                !err.contains(clap_error),
                "`caliper run {l}` does not parse: {err}"
            );
        }
    }
}

/// `caliper token …` lines run as written (in an empty folder) and succeed.
#[test]
fn readme_token_lines_run() {
    let bin = caliper_bin();
    let dir = tempfile::tempdir().expect("tempdir");
    let lines: Vec<String> = code_lines(&readme())
        .into_iter()
        .filter_map(|l| {
            let l = l.split("  #").next().unwrap_or(&l).trim().to_string();
            l.strip_prefix("caliper token ").map(String::from)
        })
        .collect();
    assert!(lines.len() >= 2, "found only {} token lines", lines.len());
    // Lines for the production profile run against a fresh PostgreSQL database when the
    // tests have one (CALIPER_TEST_POSTGRES_URL), in place of the README's host.
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let db = rt.block_on(crate::postgres::TestDb::create());
    for l in lines {
        let mut words = shell_words(&l);
        if let Some(i) = words.iter().position(|w| w == "--database-url") {
            let Some(db) = &db else {
                eprintln!("*** README line NOT RUN (no PostgreSQL): caliper token {l}");
                continue;
            };
            if let Some(url) = words.get_mut(i + 1) {
                *url = db.url.clone();
            }
        }
        let out = Command::new(&bin)
            .arg("token")
            .args(&words)
            .current_dir(dir.path())
            .output()
            .expect("run caliper");
        assert!(
            out.status.success(),
            "`caliper token {l}` failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    if let Some(db) = db {
        rt.block_on(db.drop_db());
    }
}

/// Split a shell line into words (single quotes only, as the README uses).
fn shell_words(line: &str) -> Vec<String> {
    let mut words = Vec::new();
    let mut cur = String::new();
    let mut quoted = false;
    let mut any = false;
    for c in line.chars() {
        match c {
            '\'' => {
                quoted = !quoted;
                any = true;
            }
            c if c.is_whitespace() && !quoted => {
                if any {
                    words.push(std::mem::take(&mut cur));
                    any = false;
                }
            }
            c => {
                cur.push(c);
                any = true;
            }
        }
    }
    if any {
        words.push(cur);
    }
    words
}
