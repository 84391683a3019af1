-- Caliper schema, version 2: transactional blob lifetime (issue D2).
-- A pin is a reference to a blob written *before* the blob is trusted (an upload or an
-- artifact on its way in); garbage collection never removes a pinned blob.
CREATE TABLE blob_pins (
    token      TEXT NOT NULL,
    sha256     TEXT NOT NULL,
    expires_at INTEGER NOT NULL,
    PRIMARY KEY (token, sha256)
);
CREATE INDEX blob_pins_sha256 ON blob_pins (sha256);
-- Blobs that may have lost their last reference, and since when; collected after a grace period
-- if still unreferenced, inside the store's write transaction.
CREATE TABLE blob_gc (
    sha256 TEXT PRIMARY KEY,
    since  INTEGER NOT NULL
);
CREATE INDEX documents_job ON documents (job_id);
