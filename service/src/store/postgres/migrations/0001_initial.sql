-- Caliper on PostgreSQL, version 1: the same model as the embedded SQLite schema (versions
-- 1–3 there), in one script. Times are integer milliseconds since the Unix epoch; leases use
-- the database's clock so replicas with skewed clocks agree.
CREATE TABLE datasets (
    id          TEXT PRIMARY KEY,
    kind        TEXT NOT NULL,
    created_at  BIGINT NOT NULL,
    total_bytes BIGINT NOT NULL,
    sha256      TEXT NOT NULL,
    file_count  BIGINT NOT NULL,
    devices     TEXT[]
);
CREATE TABLE dataset_files (
    dataset_id TEXT NOT NULL REFERENCES datasets(id) ON DELETE CASCADE,
    idx        BIGINT NOT NULL,
    name       TEXT NOT NULL,
    sha256     TEXT NOT NULL,
    size       BIGINT NOT NULL,
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
    attempt          BIGINT NOT NULL DEFAULT 0,
    max_attempts     BIGINT NOT NULL,
    run_at           BIGINT NOT NULL,
    lease_owner      TEXT,
    lease_expires_at BIGINT,
    cancel_requested BOOLEAN NOT NULL DEFAULT FALSE,
    progress         TEXT,
    error            TEXT,
    result           TEXT,
    document_rev     BIGINT,
    idempotency_key  TEXT UNIQUE,
    request_hash     TEXT,
    created_at       BIGINT NOT NULL,
    started_at       BIGINT,
    finished_at      BIGINT
);
CREATE INDEX jobs_runnable ON jobs (run_at, id) WHERE status = 'queued';
CREATE INDEX jobs_leases ON jobs (lease_expires_at) WHERE status = 'running';
CREATE INDEX jobs_dataset ON jobs (dataset_id, status);
CREATE INDEX jobs_finished ON jobs (finished_at) WHERE finished_at IS NOT NULL;
CREATE INDEX jobs_device ON jobs (device, id);
CREATE TABLE job_attempts (
    job_id      TEXT NOT NULL,
    attempt     BIGINT NOT NULL,
    worker      TEXT NOT NULL,
    started_at  BIGINT NOT NULL,
    finished_at BIGINT,
    outcome     TEXT,
    error       TEXT,
    PRIMARY KEY (job_id, attempt)
);
CREATE TABLE artifacts (
    job_id     TEXT NOT NULL,
    name       TEXT NOT NULL,
    media_type TEXT NOT NULL,
    sha256     TEXT NOT NULL,
    size       BIGINT NOT NULL,
    PRIMARY KEY (job_id, name)
);
CREATE INDEX artifacts_sha256 ON artifacts (sha256);
CREATE TABLE documents (
    device     TEXT NOT NULL,
    sensor     TEXT NOT NULL,
    kind       TEXT NOT NULL,
    rev        BIGINT NOT NULL,
    etag       TEXT NOT NULL,
    schema     TEXT NOT NULL,
    created_at BIGINT NOT NULL,
    job_id     TEXT,
    body       TEXT NOT NULL,
    PRIMARY KEY (device, sensor, kind, rev)
);
CREATE INDEX documents_job ON documents (job_id);
CREATE TABLE blob_pins (
    token      TEXT NOT NULL,
    sha256     TEXT NOT NULL,
    expires_at BIGINT NOT NULL,
    PRIMARY KEY (token, sha256)
);
CREATE INDEX blob_pins_sha256 ON blob_pins (sha256);
CREATE TABLE blob_gc (
    sha256 TEXT PRIMARY KEY,
    since  BIGINT NOT NULL
);
CREATE TABLE tokens (
    id         TEXT PRIMARY KEY,
    name       TEXT NOT NULL,
    prefix     TEXT NOT NULL,
    hash       TEXT NOT NULL UNIQUE,
    scope      TEXT NOT NULL CHECK (scope IN ('read', 'write', 'admin')),
    devices    TEXT[],
    created_at BIGINT NOT NULL,
    revoked_at BIGINT
);
