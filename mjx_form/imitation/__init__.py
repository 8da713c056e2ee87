"""Imitation from observations: effect models, the FORM reward, the FORM pipeline."""
