-- Caliper schema, version 1. Timestamps are integer milliseconds since the Unix epoch,
-- computed by the service (no database-specific time functions in queries).
CREATE TABLE datasets (
    id          TEXT PRIMARY KEY,
    kind        TEXT NOT NULL,
    created_at  INTEGER NOT NULL,
    total_bytes INTEGER NOT NULL,
    sha256      TEXT NOT NULL,
    file_count  INTEGER NOT NULL
);
CREATE TABLE dataset_files (
    dataset_id TEXT NOT NULL REFERENCES datasets(id) ON DELETE CASCADE,
    idx        INTEGER NOT NULL,
    name       TEXT NOT NULL,
    sha256     TEXT NOT NULL,
    size       INTEGER NOT NULL,
    media_type TEXT NOT NULL,
    image      TEXT,
    PRIMARY KEY (dataset_id, idx)
);
CREATE INDEX dataset_files_sha256 ON dataset_files (sha256);
CREATE TABLE jobs (
    id               TEXT PRIMARY KEY,
    kind             TEXT NOT NULL,
    dataset_id       TEXT NOT NULL,
    device           TEXT,
    sensor           TEXT,
    params           TEXT NOT NULL,
    status           TEXT NOT NULL CHECK (status IN ('queued', 'running', 'succeeded', 'failed', 'canceled')),
    attempt          INTEGER NOT NULL DEFAULT 0,
    max_attempts     INTEGER NOT NULL,
    run_at           INTEGER NOT NULL,
    lease_owner      TEXT,
    lease_expires_at INTEGER,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    progress         TEXT,
    error            TEXT,
    result           TEXT,
    document_rev     INTEGER,
    idempotency_key  TEXT UNIQUE,
    request_hash     TEXT,
    created_at       INTEGER NOT NULL,
    started_at       INTEGER,
    finished_at      INTEGER
);
CREATE INDEX jobs_runnable ON jobs (run_at, id) WHERE status = 'queued';
CREATE INDEX jobs_leases ON jobs (lease_expires_at) WHERE status = 'running';
CREATE INDEX jobs_dataset ON jobs (dataset_id, status);
CREATE INDEX jobs_finished ON jobs (finished_at) WHERE finished_at IS NOT NULL;
CREATE INDEX jobs_device ON jobs (device, id);
CREATE TABLE job_attempts (
    job_id      TEXT NOT NULL,
    attempt     INTEGER NOT NULL,
    worker      TEXT NOT NULL,
    started_at  INTEGER NOT NULL,
    finished_at INTEGER,
    outcome     TEXT,
    error       TEXT,
    PRIMARY KEY (job_id, attempt)
);
CREATE TABLE artifacts (
    job_id     TEXT NOT NULL,
    name       TEXT NOT NULL,
    media_type TEXT NOT NULL,
    sha256     TEXT NOT NULL,
    size       INTEGER NOT NULL,
    PRIMARY KEY (job_id, name)
);
CREATE INDEX artifacts_sha256 ON artifacts (sha256);
CREATE TABLE documents (
    device     TEXT NOT NULL,
    sensor     TEXT NOT NULL,
    kind       TEXT NOT NULL,
    rev        INTEGER NOT NULL,
    etag       TEXT NOT NULL,
    schema     TEXT NOT NULL,
    created_at INTEGER NOT NULL,
    job_id     TEXT,
    body       TEXT NOT NULL,
    PRIMARY KEY (device, sensor, kind, rev)
);
