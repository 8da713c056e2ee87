"""Files: demonstrations, policies, effect models, checkpoints and result records (no pickle)."""
