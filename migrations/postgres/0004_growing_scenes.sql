-- PostgreSQL mirror of ../0004_growing_scenes.sql.
ALTER TABLE scenes ADD COLUMN revision BIGINT NOT NULL DEFAULT 0;
ALTER TABLE frames ADD COLUMN file TEXT;
