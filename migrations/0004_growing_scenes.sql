-- Scenes that grow (issue 21): a revision counter bumped on every change of a scene's
-- frames, and each frame's file stem under color/ and instance/ (NULL: its idx, as
-- stored before frames could be appended or removed).
ALTER TABLE scenes ADD COLUMN revision INTEGER NOT NULL DEFAULT 0;
ALTER TABLE frames ADD COLUMN file TEXT;
