"""The distributed layer: everything that talks to Ray lives here (and in tune_jobs/)."""
