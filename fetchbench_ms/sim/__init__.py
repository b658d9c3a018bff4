"""The simulator's plumbing shared by the env and the task sampler: physics rates and
solver settings, catalog objects as SAPIEN bodies (``bodies``), and the settling of freshly
placed objects (``settle``), so a task settled while it is sampled rests the same way when
the env loads it."""
