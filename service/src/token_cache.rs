//! Per-replica cache of bearer-token lookups, so that a request does not pay a database round
//! trip to learn who sent it.
//!
//! Tokens never change after creation except by revocation, so a cached record is right until
//! its token is revoked. Revocation reaches every replica through the database: the store
//! announces it with `NOTIFY` in the revoking transaction, and each replica's `LISTEN` task
//! empties its cache when the notification arrives (PostgreSQL signals the listeners at
//! commit, so this normally happens before the revoking client has its answer). The cache is used only while that `LISTEN` connection is up: a replica
//! that lost it (and so could miss a revocation) goes back to the database for every request
//! until it has reconnected. With no `LISTEN` at all (the embedded SQLite profile, where
//! `caliper token revoke` may write to the database from another process) it is never used.
//!
//! A lookup that raced with a revocation must not put the old record back: every emptying
//! bumps a generation, and a record read from the database is stored only if the generation
//! is the one seen before the read.

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::store::TokenRecord;

/// Longest a record is trusted without asking the database again (a bound on the damage of a
/// lost notification that the connection state did not reveal).
const MAX_AGE: Duration = Duration::from_secs(60);
/// Most records kept; the cache starts over when full (tokens are few; this bounds memory
/// against a flood of distinct valid tokens).
const MAX_ENTRIES: usize = 10_000;

/// See the module docs.
#[derive(Default)]
pub struct TokenCache {
    entries: Mutex<HashMap<String, (TokenRecord, Instant)>>,
    generation: AtomicU64,
    live: AtomicBool,
}

impl TokenCache {
    /// The valid token with this secret hash, if cached, fresh, and the cache is live.
    pub fn get(&self, hash: &str) -> Option<TokenRecord> {
        if !self.live.load(Ordering::Acquire) {
            return None;
        }
        let entries = self.entries.lock().ok()?;
        let (t, at) = entries.get(hash)?;
        (at.elapsed() < MAX_AGE).then(|| t.clone())
    }

    /// The generation to pass to [`TokenCache::put`] for a lookup starting now.
    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::Acquire)
    }

    /// Remember a valid (unrevoked) token read from the database, unless the cache was
    /// emptied since `generation` was taken or is not live.
    pub fn put(&self, hash: &str, token: &TokenRecord, generation: u64) {
        if token.revoked_at.is_some() || !self.live.load(Ordering::Acquire) {
            return;
        }
        let Ok(mut entries) = self.entries.lock() else {
            return;
        };
        // Checked under the lock that `invalidate` also takes: no emptying can slip between.
        if self.generation.load(Ordering::Acquire) != generation {
            return;
        }
        if entries.len() >= MAX_ENTRIES {
            entries.clear();
        }
        entries.insert(hash.to_string(), (token.clone(), Instant::now()));
    }

    /// Forget everything (a token was revoked somewhere).
    pub fn invalidate(&self) {
        if let Ok(mut entries) = self.entries.lock() {
            self.generation.fetch_add(1, Ordering::AcqRel);
            entries.clear();
        }
    }

    /// Whether revocations are being heard; turning it either way empties the cache.
    pub fn set_live(&self, live: bool) {
        self.live.store(live, Ordering::Release);
        self.invalidate();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::Scope;

    fn token() -> TokenRecord {
        TokenRecord {
            id: uuid::Uuid::now_v7(),
            name: "t".into(),
            prefix: "clp_x".into(),
            scope: Scope::Read,
            devices: None,
            created_at: 0,
            revoked_at: None,
        }
    }

    #[test]
    fn only_live_caches_serve_and_a_racing_lookup_cannot_restore_a_revoked_token() {
        let c = TokenCache::default();
        let t = token();
        c.put("h", &t, c.generation());
        assert!(c.get("h").is_none(), "not live: nothing cached");
        c.set_live(true);
        let g = c.generation();
        c.put("h", &t, g);
        assert_eq!(c.get("h").map(|r| r.id), Some(t.id));
        // A lookup starts, a revocation empties the cache, the lookup ends with the old row.
        let g = c.generation();
        c.invalidate();
        c.put("h", &t, g);
        assert!(c.get("h").is_none(), "a stale read was cached");
        // Revoked records are never cached; losing the connection empties and disables.
        let mut revoked = token();
        revoked.revoked_at = Some(1);
        c.put("r", &revoked, c.generation());
        assert!(c.get("r").is_none());
        c.put("h", &t, c.generation());
        c.set_live(false);
        assert!(c.get("h").is_none());
    }
}
