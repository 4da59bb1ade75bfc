-- Scenes: one row per uploaded scene; visible to readers only once status != 'importing'.
CREATE TABLE scenes (
    id              TEXT PRIMARY KEY,
    name            TEXT NOT NULL,
    layout          TEXT NOT NULL,             -- 'scannet' | 'posed'
    status          TEXT NOT NULL,             -- 'indexing' | 'ready' | 'failed'
    color_width     INTEGER NOT NULL,
    color_height    INTEGER NOT NULL,
    depth_width     INTEGER NOT NULL,
    depth_height    INTEGER NOT NULL,
    color_k         TEXT NOT NULL,             -- JSON Intrinsics
    depth_k         TEXT,                      -- JSON Intrinsics or NULL
    axis_align      TEXT,                      -- JSON [16] row-major or NULL
    has_instances   INTEGER NOT NULL DEFAULT 0,
    frame_count     INTEGER NOT NULL,
    unusable_count  INTEGER NOT NULL,
    index_detector  TEXT,
    index_done      INTEGER NOT NULL DEFAULT 0,
    index_total     INTEGER NOT NULL DEFAULT 0,
    error           TEXT,
    created_at      TEXT NOT NULL
);

-- Frames in numeric order of their name; idx is the five-digit image id shown to the VLM.
CREATE TABLE frames (
    scene_id    TEXT NOT NULL REFERENCES scenes(id) ON DELETE CASCADE,
    idx         INTEGER NOT NULL,
    name        TEXT NOT NULL,
    pose        BLOB NOT NULL,                 -- 16 little-endian f64, row-major camera-to-world
    usable      INTEGER NOT NULL,
    depth       BLOB NOT NULL,                 -- lz4-compressed little-endian u16 millimetres
    PRIMARY KEY (scene_id, idx)
);

-- Cached 2D detections per frame, per detector.
CREATE TABLE detections (
    scene_id    TEXT NOT NULL REFERENCES scenes(id) ON DELETE CASCADE,
    detector    TEXT NOT NULL,
    frame_idx   INTEGER NOT NULL,
    label       TEXT NOT NULL,
    score       REAL NOT NULL,
    x1 REAL NOT NULL, y1 REAL NOT NULL, x2 REAL NOT NULL, y2 REAL NOT NULL
);
CREATE INDEX detections_by_scene ON detections(scene_id, detector, label);

CREATE TABLE jobs (
    seq               INTEGER PRIMARY KEY AUTOINCREMENT,
    id                TEXT NOT NULL UNIQUE,
    scene_id          TEXT NOT NULL,
    query             TEXT NOT NULL,
    status            TEXT NOT NULL,           -- queued | running | succeeded | failed | canceled
    attempts          INTEGER NOT NULL DEFAULT 0,
    cancel_requested  INTEGER NOT NULL DEFAULT 0,
    created_at        TEXT NOT NULL,
    started_at        TEXT,
    finished_at       TEXT,
    error             TEXT,                    -- JSON {code, detail}
    result            TEXT                     -- JSON
);
CREATE INDEX jobs_by_status ON jobs(status, seq);
CREATE INDEX jobs_by_scene ON jobs(scene_id, seq);

-- The trace of a job's current attempt, one row per step, in order.
CREATE TABLE job_trace (
    job_id  TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    seq     INTEGER NOT NULL,
    step    TEXT NOT NULL,
    data    TEXT NOT NULL,                     -- JSON
    PRIMARY KEY (job_id, seq)
);
