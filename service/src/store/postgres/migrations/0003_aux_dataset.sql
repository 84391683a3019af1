-- A second dataset a job reads besides its own (deblur's IMU log for a clip), so that the
-- dataset cannot be deleted while the job is queued or running.
ALTER TABLE jobs ADD COLUMN aux_dataset_id TEXT;
CREATE INDEX jobs_aux_dataset ON jobs (aux_dataset_id) WHERE aux_dataset_id IS NOT NULL;
