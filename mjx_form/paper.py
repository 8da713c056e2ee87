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
# The baselines' returns, by run.py's --method name.
BASELINES = {
    "bc": {"reacher_easy": 970.3, "reacher_hard": 892.4, "cheetah_run": 227.5,
           "quadruped_walk": 752.1, "quadruped_run": 719.2, "hopper_stand": 534.1,
           "hopper_hop": 98.4, "walker_stand": 731.7, "walker_walk": 719.5, "walker_run": 108.5,
           "humanoid_stand": 780.7, "humanoid_walk": 293.9, "humanoid_run": 54.2},
    "bco": {"reacher_easy": 966.6, "reacher_hard": 940.1, "cheetah_run": 75.7,
            "quadruped_walk": 191.9, "quadruped_run": 271.4, "hopper_stand": 91.4,
            "hopper_hop": 9.1, "walker_stand": 385.9, "walker_walk": 61.9, "walker_run": 39.0,
            "humanoid_stand": 10.0, "humanoid_walk": 9.6, "humanoid_run": 1.0},
    "gaifo": {"reacher_easy": 869.9, "reacher_hard": 818.7, "cheetah_run": 607.6,
              "quadruped_walk": 672.6, "quadruped_run": 952.5, "hopper_stand": 400.0,
              "hopper_hop": 689.2, "walker_stand": 989.4, "walker_walk": 976.5,
              "walker_run": 949.5, "humanoid_stand": 4.9, "humanoid_walk": 1.2,
              "humanoid_run": 0.6},
    "gaifo_gp": {"reacher_easy": 915.9, "reacher_hard": 783.7, "cheetah_run": 921.3,
                 "quadruped_walk": 963.6, "quadruped_run": 952.3, "hopper_stand": 748.5,
                 "hopper_hop": 694.4, "walker_stand": 985.4, "walker_walk": 981.6,
                 "walker_run": 947.6, "humanoid_stand": 856.2, "humanoid_walk": 798.4,
                 "humanoid_run": 683.4},
    "vaifo": {"reacher_easy": 861.6, "reacher_hard": 604.4, "cheetah_run": 820.0,
              "quadruped_walk": 927.8, "quadruped_run": 926.6, "hopper_stand": 835.8,
              "hopper_hop": 610.5, "walker_stand": 989.4, "walker_walk": 971.2,
              "walker_run": 949.0, "humanoid_stand": 257.5, "humanoid_walk": 658.2,
              "humanoid_run": 676.6},
    "vaifo_gp": {"reacher_easy": 901.3, "reacher_hard": 891.0, "cheetah_run": 918.3,
                 "quadruped_walk": 945.8, "quadruped_run": 950.0, "hopper_stand": 891.2,
                 "hopper_hop": 683.6, "walker_stand": 986.0, "walker_walk": 975.2,
                 "walker_run": 948.5, "humanoid_stand": 863.5, "humanoid_walk": 795.5,
                 "humanoid_run": 691.6},
}
# Their column names in the paper's Table 1.
BASELINE_NAMES = {"bc": "BC", "bco": "BCO", "gaifo": "GAIfO", "gaifo_gp": "GAIfO+GP",
                  "vaifo": "VAIfO", "vaifo_gp": "VAIfO+GP"}
