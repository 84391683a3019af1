//! The `caliper` binary: `serve`, `openapi`, and `run <kind>` for offline jobs.

use std::process::ExitCode;
use std::time::Duration;

use caliper_service::config::ConfigArgs;
use caliper_service::offline;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "caliper",
    version,
    about = "Caliper: calibration service and offline runner"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the HTTP service (embedded profile: SQLite + local blobs in the data directory).
    Serve {
        #[command(flatten)]
        config: Box<ConfigArgs>,
        /// Seconds running jobs get to finish on shutdown before they are re-queued.
        #[arg(long, env = "CALIPER_SHUTDOWN_GRACE_SECS", default_value_t = 20)]
        shutdown_grace_secs: u64,
    },
    /// Print the OpenAPI document.
    Openapi,
    /// Manage access tokens in the store (no running server needed).
    Token(caliper_service::token_cli::TokenArgs),
    /// Run a job kind on local files and print its document (one subcommand per job kind).
    Run,
}

fn main() -> ExitCode {
    // `caliper run`'s subcommands come from the job-kind registry.
    let matches = Cli::command()
        .mut_subcommand("run", offline::command)
        .get_matches();
    if let Some(("run", m)) = matches.subcommand() {
        return match offline::run(m) {
            Ok(doc) => emit(&format!("{doc}\n")),
            Err(e) => {
                eprintln!("caliper: {e}");
                ExitCode::from(2)
            }
        };
    }
    let cli = match Cli::from_arg_matches(&matches) {
        Ok(c) => c,
        Err(e) => e.exit(),
    };
    match cli.command {
        Command::Openapi => emit(&caliper_service::openapi_json()),
        Command::Run => ExitCode::from(2),
        Command::Token(args) => token(args),
        Command::Serve {
            config,
            shutdown_grace_secs,
        } => serve(*config, Duration::from_secs(shutdown_grace_secs)),
    }
}

/// Write to stdout; a closed pipe (`caliper run … | head`) is not an error worth a panic.
fn emit(text: &str) -> ExitCode {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|_| out.flush()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("caliper: cannot write output: {e}");
            ExitCode::FAILURE
        }
    }
}

fn token(args: caliper_service::token_cli::TokenArgs) -> ExitCode {
    let rt = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("caliper: cannot start runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match rt.block_on(caliper_service::token_cli::run(args)) {
        Ok(text) => emit(&text),
        Err(e) => {
            eprintln!("caliper: {e}");
            ExitCode::from(2)
        }
    }
}

fn serve(args: ConfigArgs, grace: Duration) -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "info,sqlx=warn,tower_http=info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let config = match args.resolve() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("caliper: {e}");
            return ExitCode::from(2);
        }
    };
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("caliper: cannot start runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    if config.auth_required() {
        let store = if config.shared_store() {
            "--database-url …".to_string()
        } else {
            format!("--data-dir {}", config.data_dir.display())
        };
        eprintln!(
            "caliper: bearer tokens required on every route but /healthz, /readyz, /openapi.json, /docs and /ui \
             (make one with `caliper token create --scope admin --name me {store}`)"
        );
    } else {
        eprintln!(
            "caliper: running OPEN, without tokens: anyone who reaches {} can use the API \
             (pass --auth to require tokens; they are required by themselves beyond loopback)",
            config.listen
        );
    }
    let code = rt.block_on(async move {
        let server = match caliper_service::server::start(config).await {
            Ok(s) => s,
            Err(e) => {
                eprintln!("caliper: {e}");
                return ExitCode::FAILURE;
            }
        };
        // Tests and scripts read this line to learn the port when listening on :0.
        println!("caliper listening on http://{}", server.addr);
        tracing::info!(addr = %server.addr, "listening");
        wait_for_signal().await;
        tracing::info!("shutting down");
        server.shutdown(grace).await;
        ExitCode::SUCCESS
    });
    // Do not wait for threads still running: an abandoned job thread dies with the process.
    rt.shutdown_timeout(Duration::from_millis(200));
    code
}

async fn wait_for_signal() {
    let ctrl_c = tokio::signal::ctrl_c();
    #[cfg(unix)]
    {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(s) => s,
                Err(_) => {
                    let _ = ctrl_c.await;
                    return;
                }
            };
        tokio::select! {
            _ = ctrl_c => {}
            _ = term.recv() => {}
        }
    }
    #[cfg(not(unix))]
    {
        let _ = ctrl_c.await;
    }
}
