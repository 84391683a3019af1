-- Replicas that cache token lookups, and the last revocation each has applied: a revocation
-- returns only once every live caching replica has emptied its cache (service/src/token_cache.rs).
-- `revocations.n` counts revocations in commit order (the row lock serialises them), so a
-- replica that has applied revocation n has applied every earlier one.
CREATE TABLE token_revocations (only_row BOOLEAN PRIMARY KEY DEFAULT TRUE CHECK (only_row), n BIGINT NOT NULL);
INSERT INTO token_revocations (n) VALUES (0);
CREATE TABLE token_caches (
    replica TEXT PRIMARY KEY,
    applied BIGINT NOT NULL,
    heartbeat_ms BIGINT NOT NULL
);
