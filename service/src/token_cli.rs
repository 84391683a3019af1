//! `caliper token …`: manage access tokens straight in the store, without a running server
//! (that is how the first admin token is made).

use std::path::PathBuf;

use clap::{Args, Subcommand};
use uuid::Uuid;

use crate::store::{PgStore, Scope, SqliteStore, Store};

/// Where the tokens live.
#[derive(Debug, Args)]
pub struct TokenArgs {
    /// Data directory of the embedded store (as for `caliper serve`).
    #[arg(
        long,
        env = "CALIPER_DATA_DIR",
        default_value = "./caliper-data",
        global = true
    )]
    pub data_dir: PathBuf,
    /// PostgreSQL store shared by replicas (as for `caliper serve`); overrides `--data-dir`.
    #[arg(long, env = "CALIPER_DATABASE_URL", global = true)]
    pub database_url: Option<String>,
    #[command(subcommand)]
    pub action: TokenAction,
}

#[derive(Debug, Subcommand)]
pub enum TokenAction {
    /// Create a token and print its secret (shown this once).
    Create {
        /// What it is for (shown in lists).
        #[arg(long)]
        name: String,
        /// admin (manage tokens and everything else), write (upload, queue, cancel, read) or read.
        #[arg(long, value_parser = parse_scope)]
        scope: Scope,
        /// Limit it to this device serial (repeat for several); default: the whole fleet.
        #[arg(long = "device")]
        devices: Vec<String>,
    },
    /// List tokens (never their secrets).
    List,
    /// Revoke a token by id: it stops working at once.
    Revoke { id: Uuid },
}

fn parse_scope(s: &str) -> Result<Scope, String> {
    Scope::parse(s).ok_or_else(|| format!("{s:?} is not a scope: admin, write or read"))
}

/// Run a token command; the text to print on success.
pub async fn run(args: TokenArgs) -> Result<String, String> {
    if let Some(url) = args.database_url.as_deref().filter(|u| !u.is_empty()) {
        let store = PgStore::connect(url)
            .await
            .map_err(|e| format!("cannot open the store: {e}"))?;
        return run_on(&store, args.action).await;
    }
    std::fs::create_dir_all(&args.data_dir)
        .map_err(|e| format!("cannot create {}: {e}", args.data_dir.display()))?;
    let store = SqliteStore::open(&args.data_dir.join("caliper.db"))
        .await
        .map_err(|e| format!("cannot open the store: {e}"))?;
    run_on(&store, args.action).await
}

async fn run_on(store: &dyn Store, action: TokenAction) -> Result<String, String> {
    match action {
        TokenAction::Create {
            name,
            scope,
            devices,
        } => {
            let devices = (!devices.is_empty()).then_some(devices);
            let new = crate::auth::generate(&name, scope, devices, crate::clock::now_ms())
                .map_err(|e| e.to_string())?;
            store
                .insert_token(&new.record, &new.hash)
                .await
                .map_err(|e| e.to_string())?;
            eprintln!(
                "caliper: token {} ({}) created; its secret is printed once, below",
                new.record.id,
                scope.as_str()
            );
            Ok(format!("{}\n", new.secret))
        }
        TokenAction::List => {
            let mut out = String::from("id\tname\tprefix\tscope\tdevices\tcreated\trevoked\n");
            for t in store.list_tokens().await.map_err(|e| e.to_string())? {
                out.push_str(&format!(
                    "{}\t{}\t{}…\t{}\t{}\t{}\t{}\n",
                    t.id,
                    t.name,
                    t.prefix,
                    t.scope.as_str(),
                    t.devices.map_or("*".into(), |d| d.join(",")),
                    crate::clock::rfc3339(t.created_at),
                    t.revoked_at.map_or("-".into(), crate::clock::rfc3339),
                ));
            }
            Ok(out)
        }
        TokenAction::Revoke { id } => {
            if store
                .revoke_token(id, crate::clock::now_ms())
                .await
                .map_err(|e| e.to_string())?
            {
                Ok(format!("revoked {id}\n"))
            } else {
                Err(format!("no token {id}"))
            }
        }
    }
}
