//! Per-replica cache of bearer-token lookups, so that a request does not pay a database round
//! trip to learn who sent it.
//!
//! Tokens never change after creation except by revocation, so a cached record is right until
//! its token is revoked. A revocation must hold on every replica from the revoking client's
//! next request, whichever replica that reaches, so the revocation does not return until every
//! replica that caches has forgotten the token:
//!
//! 1. A replica caches only while its `LISTEN` connection is up and it is registered in the
//!    database's `token_caches` table with a heartbeat younger than [`LIVE_WINDOW`] by its own
//!    monotonic clock (the window starts before the heartbeat is sent, so it ends before the
//!    database sees the row as older than [`LEASE`]).
//! 2. A revocation takes the next number in commit order and announces it with `NOTIFY` at
//!    commit. Each listening replica empties its cache and writes the number as applied.
//! 3. The revoking call waits until every registered replica has applied the number or has a
//!    heartbeat older than [`LEASE`] — a replica that cannot heartbeat has stopped serving from
//!    its cache by then — and only then answers.
//!
//! A replica joins with the revocations committed so far marked as applied: its cache is
//! empty and its `LISTEN` is already up, so it hears every later one. With no `LISTEN` at all
//! (the embedded SQLite profile, where `caliper token revoke` may write to the database from
//! another process) the cache is never used.
//!
//! A lookup that raced with a revocation must not put the old record back: every emptying
//! bumps a generation, and a record read from the database is stored only if the generation
//! is the one seen before the read.

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::store::TokenRecord;

/// A registered replica silent this long (by the database's clock) no longer delays
/// revocations.
pub const LEASE: Duration = Duration::from_secs(5);
/// How long after it started sending its last successful heartbeat a replica serves from its
/// cache: half the lease, a margin for clock rates and scheduling.
pub const LIVE_WINDOW: Duration = Duration::from_millis(2500);
// The window must end before the lease does.
const _: () = assert!(LIVE_WINDOW.as_millis() < LEASE.as_millis());
/// How often a caching replica heartbeats.
pub const HEARTBEAT: Duration = Duration::from_secs(1);
/// Longest a record is trusted without asking the database again (a bound on the damage of a
/// bug in the protocol above).
const MAX_AGE: Duration = Duration::from_secs(60);
/// Most records kept; the cache starts over when full (tokens are few; this bounds memory
/// against a flood of distinct valid tokens).
const MAX_ENTRIES: usize = 10_000;

#[derive(Default)]
struct Inner {
    entries: HashMap<String, (TokenRecord, Instant)>,
    /// Serving from the cache is allowed until then; `None`: not registered or not listening.
    live_until: Option<Instant>,
}

impl Inner {
    fn live(&self) -> bool {
        self.live_until.is_some_and(|t| Instant::now() < t)
    }
}

/// See the module docs.
#[derive(Default)]
pub struct TokenCache {
    inner: Mutex<Inner>,
    generation: AtomicU64,
}

impl TokenCache {
    /// The valid token with this secret hash, if cached, fresh, and the cache is live.
    pub fn get(&self, hash: &str) -> Option<TokenRecord> {
        let inner = self.inner.lock().ok()?;
        if !inner.live() {
            return None;
        }
        let (t, at) = inner.entries.get(hash)?;
        (at.elapsed() < MAX_AGE).then(|| t.clone())
    }

    /// The generation to pass to [`TokenCache::put`] for a lookup starting now.
    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::Acquire)
    }

    /// Remember a valid (unrevoked) token read from the database, unless the cache was
    /// emptied since `generation` was taken or is not live.
    pub fn put(&self, hash: &str, token: &TokenRecord, generation: u64) {
        if token.revoked_at.is_some() {
            return;
        }
        let Ok(mut inner) = self.inner.lock() else {
            return;
        };
        // Checked under the lock that `invalidate` also takes: no emptying can slip between.
        if !inner.live() || self.generation.load(Ordering::Acquire) != generation {
            return;
        }
        if inner.entries.len() >= MAX_ENTRIES {
            inner.entries.clear();
        }
        inner
            .entries
            .insert(hash.to_string(), (token.clone(), Instant::now()));
    }

    /// Forget everything (a token was revoked somewhere).
    pub fn invalidate(&self) {
        if let Ok(mut inner) = self.inner.lock() {
            Self::clear(&mut inner, &self.generation);
        }
    }

    fn clear(inner: &mut Inner, generation: &AtomicU64) {
        generation.fetch_add(1, Ordering::AcqRel);
        inner.entries.clear();
    }

    /// A registration or heartbeat that started at `sent` succeeded: serve from the cache
    /// until `sent + LIVE_WINDOW`. After a lapse the cache starts empty, since revocations
    /// may have been settled without this replica meanwhile.
    pub fn renew(&self, sent: Instant) {
        if let Ok(mut inner) = self.inner.lock() {
            if !inner.live() {
                Self::clear(&mut inner, &self.generation);
            }
            let until = sent + LIVE_WINDOW;
            inner.live_until = Some(inner.live_until.map_or(until, |t| t.max(until)));
        }
    }

    /// Stop serving from the cache (the `LISTEN` connection is lost, or shutdown) and empty it.
    pub fn stop(&self) {
        if let Ok(mut inner) = self.inner.lock() {
            inner.live_until = None;
            Self::clear(&mut inner, &self.generation);
        }
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
        c.renew(Instant::now());
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
        c.stop();
        assert!(c.get("h").is_none());
    }

    #[test]
    fn a_lapsed_heartbeat_stops_serving_and_the_renewal_starts_empty() {
        let c = TokenCache::default();
        let t = token();
        let Some(old) = Instant::now().checked_sub(LIVE_WINDOW + Duration::from_millis(10)) else {
            return;
        };
        // A heartbeat sent longer ago than the live window does not make the cache live.
        c.renew(old);
        c.put("h", &t, c.generation());
        assert!(c.get("h").is_none(), "served past the live window");
        c.renew(Instant::now());
        c.put("h", &t, c.generation());
        assert!(c.get("h").is_some());
        // A renewal while live keeps what is cached.
        c.renew(Instant::now());
        assert!(c.get("h").is_some());
        // The window runs out with the entry still stored: not served, and dropped on renewal.
        if let Ok(mut inner) = c.inner.lock() {
            inner.live_until = Some(old);
        }
        assert!(c.get("h").is_none(), "served past the live window");
        c.renew(Instant::now());
        assert!(
            c.get("h").is_none(),
            "a renewal after a lapse kept old entries"
        );
    }
}
