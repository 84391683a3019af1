-- Caliper schema, version 3: access tokens and device-scoped datasets (production profile).
-- A token's secret is never stored: `hash` is the SHA-256 of it (secrets are 160-bit random,
-- so a fast hash is enough); `prefix` is the start of the secret, for matching leaks.
CREATE TABLE tokens (
    id         TEXT PRIMARY KEY,
    name       TEXT NOT NULL,
    prefix     TEXT NOT NULL,
    hash       TEXT NOT NULL UNIQUE,
    scope      TEXT NOT NULL CHECK (scope IN ('read', 'write', 'admin')),
    devices    TEXT,
    created_at INTEGER NOT NULL,
    revoked_at INTEGER
);
-- The serials of the device-scoped token that uploaded a dataset (JSON array); NULL: fleet-wide.
ALTER TABLE datasets ADD COLUMN devices TEXT;
