-- Facts of an uploaded video clip (codec, size, rotation, frame rate, counts), probed at upload.
ALTER TABLE dataset_files ADD COLUMN video TEXT;
