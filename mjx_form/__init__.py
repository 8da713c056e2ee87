"""mjx-form: imitation from observation (FORM and baselines) on the Control Suite, on MJX.

  sim/        the simulation core the tasks build on: Task API, physics, auto-reset, parity
  rl/         the learner: networks, MPO, Retrace, replay, normaliser, the compiled loop, runs
  imitation/  learning from observations: effect models, FORM's reward, the FORM pipeline
  files/      what runs read and write: demonstrations, policies, effect models, checkpoints,
              result records
  cpu.py, mesh.py   XLA settings for the CPU; the device mesh
  paper.py    the paper's Table 1 returns (comparison only)
"""
