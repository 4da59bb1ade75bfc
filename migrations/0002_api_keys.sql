-- Issue 19: API keys and ownership, idempotent retries, job events, webhooks.

-- API keys: only a SHA-256 hash of the secret is kept. A revoked key stays (its scenes and
-- jobs keep their owner); a name can be reused once the key holding it is revoked.
CREATE TABLE api_keys (
    id                INTEGER PRIMARY KEY AUTOINCREMENT,
    name              TEXT NOT NULL,
    secret_sha256     TEXT NOT NULL UNIQUE,      -- hex
    admin             INTEGER NOT NULL DEFAULT 0,
    max_running_jobs  INTEGER,                   -- queued + running; NULL = no limit
    max_scene_bytes   INTEGER,                   -- stored upload bytes; NULL = no limit
    webhook_secret    TEXT NOT NULL,             -- base64 of the HMAC key (signs webhooks)
    created_at        TEXT NOT NULL,
    revoked_at        TEXT
);
CREATE UNIQUE INDEX api_keys_active_name ON api_keys(name) WHERE revoked_at IS NULL;

-- Owner: the key that created the row (NULL: created without keys, visible to admins only
-- once keys exist).
ALTER TABLE scenes ADD COLUMN owner INTEGER;
ALTER TABLE scenes ADD COLUMN upload_bytes INTEGER NOT NULL DEFAULT 0;
ALTER TABLE jobs ADD COLUMN owner INTEGER;
ALTER TABLE jobs ADD COLUMN webhook_url TEXT;
CREATE INDEX scenes_by_owner ON scenes(owner);
CREATE INDEX jobs_by_owner ON jobs(owner, status);

-- Idempotency keys: one row per (owner, route, key); status NULL while the first request
-- is in flight. Rows older than 24 h are ignored and purged.
CREATE TABLE idempotency (
    owner        INTEGER NOT NULL,              -- key id, 0 without keys
    route        TEXT NOT NULL,
    key          TEXT NOT NULL,
    body_sha256  TEXT NOT NULL,
    status       INTEGER,
    headers      TEXT,                          -- JSON [[name, value], ...]
    body         BLOB,
    created_at   INTEGER NOT NULL,              -- unix seconds
    PRIMARY KEY (owner, route, key)
);
CREATE INDEX idempotency_by_age ON idempotency(created_at);

-- Everything a job's event stream shows, in the order it happened: each trace step and
-- each state change. Written by triggers, so every writer of jobs and traces is covered.
CREATE TABLE job_events (
    id      INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    kind    TEXT NOT NULL,                      -- 'step' | 'status'
    data    TEXT NOT NULL                       -- JSON
);
CREATE INDEX job_events_by_job ON job_events(job_id, id);

CREATE TRIGGER job_events_on_create AFTER INSERT ON jobs BEGIN
    INSERT INTO job_events (job_id, kind, data)
    VALUES (NEW.id, 'status', json_object('status', NEW.status, 'attempts', NEW.attempts));
END;

CREATE TRIGGER job_events_on_status AFTER UPDATE OF status ON jobs
WHEN NEW.status IS NOT OLD.status BEGIN
    INSERT INTO job_events (job_id, kind, data)
    VALUES (NEW.id, 'status', json_object('status', NEW.status, 'attempts', NEW.attempts));
END;

CREATE TRIGGER job_events_on_step AFTER INSERT ON job_trace BEGIN
    INSERT INTO job_events (job_id, kind, data)
    VALUES (NEW.job_id, 'step', CASE
        WHEN json_valid(NEW.data) AND json_type(NEW.data) = 'object' THEN json_set(NEW.data, '$.step', NEW.step)
        WHEN json_valid(NEW.data) THEN json_object('step', NEW.step, 'data', json(NEW.data))
        ELSE json_object('step', NEW.step, 'data', NULL) END);
END;

-- Webhooks: a job reaching a terminal state with a webhook_url is queued for delivery;
-- each attempt is recorded. The queue survives restarts.
CREATE TABLE webhook_queue (
    job_id      TEXT PRIMARY KEY REFERENCES jobs(id) ON DELETE CASCADE,
    msg_id      TEXT NOT NULL,
    attempts    INTEGER NOT NULL DEFAULT 0,
    first_at    INTEGER NOT NULL,               -- unix ms when queued
    next_at     INTEGER NOT NULL,               -- unix ms of the next attempt
    state       TEXT NOT NULL DEFAULT 'pending' -- pending | delivered | failed
);
CREATE INDEX webhook_queue_due ON webhook_queue(state, next_at);

CREATE TABLE webhook_deliveries (
    id           INTEGER PRIMARY KEY AUTOINCREMENT,
    job_id       TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    at           TEXT NOT NULL,
    status       INTEGER,                       -- HTTP status, NULL when no answer
    error        TEXT
);
CREATE INDEX webhook_deliveries_by_job ON webhook_deliveries(job_id, id);

CREATE TRIGGER webhook_on_terminal AFTER UPDATE OF status ON jobs
WHEN NEW.webhook_url IS NOT NULL
     AND NEW.status IN ('succeeded', 'failed', 'canceled')
     AND OLD.status NOT IN ('succeeded', 'failed', 'canceled') BEGIN
    INSERT OR IGNORE INTO webhook_queue (job_id, msg_id, first_at, next_at)
    VALUES (NEW.id, 'msg_' || NEW.id,
            CAST((julianday('now') - 2440587.5) * 86400000 AS INTEGER),
            CAST((julianday('now') - 2440587.5) * 86400000 AS INTEGER));
END;
