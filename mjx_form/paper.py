"""The FORM paper's Table 1 returns (mean over 3 seeds; ../shared/DESIGN.md), for comparison
only. Constants only: importing this starts nothing (scripts/report.py runs without JAX)."""

# The MPO experts' returns.
EXPERT = {"reacher_easy": 974.6, "reacher_hard": 981.3, "cheetah_run": 930.5,
          "quadruped_walk": 972.4, "quadruped_run": 962.9, "hopper_stand": 965.8,
          "hopper_hop": 711.5, "walker_stand": 993.6, "walker_walk": 983.2,
          "walker_run": 952.1, "humanoid_stand": 905.9, "humanoid_walk": 809.5,
          "humanoid_run": 736.6}
# FORM's returns.
FORM = {"reacher_easy": 950.2, "reacher_hard": 957.3, "cheetah_run": 827.9,
        "quadruped_walk": 963.6, "quadruped_run": 948.5, "hopper_stand": 815.7,
        "hopper_hop": 636.2, "walker_stand": 985.1, "walker_walk": 977.8,
        "walker_run": 942.0, "humanoid_stand": 704.6, "humanoid_walk": 783.0,
        "humanoid_run": 691.1}
# The experts issue's bar: an expert reaches this fraction of the paper's expert return.
EXPERT_BAR = 0.95
