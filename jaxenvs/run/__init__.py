"""The run layer: the config of a run, its programs, the loop and its checkpoints,
results, evaluation, the device placement of a trainer, the caches."""
