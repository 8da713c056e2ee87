"""The RL learner: networks, MPO, Retrace, replay, normaliser, reward sources, the compiled loop."""
