"""The FORM paper's Table 1 returns (mean over 3 seeds; ../shared/DESIGN.md) and its
demonstrations per task, for comparison only. Constants only: importing this starts nothing
(scripts/report.py runs without JAX)."""

# Table 1's columns, by run.py's --method names ("expert": the MPO experts).
COLUMNS = ("expert", "bc", "bco", "gaifo", "gaifo_gp", "vaifo", "vaifo_gp", "form")
# Table 1's rows: per task, the return of each column.
TABLE1 = {
    "reacher_easy": (974.6, 970.3, 966.6, 869.9, 915.9, 861.6, 901.3, 950.2),
    "reacher_hard": (981.3, 892.4, 940.1, 818.7, 783.7, 604.4, 891.0, 957.3),
    "cheetah_run": (930.5, 227.5, 75.7, 607.6, 921.3, 820.0, 918.3, 827.9),
    "quadruped_walk": (972.4, 752.1, 191.9, 672.6, 963.6, 927.8, 945.8, 963.6),
    "quadruped_run": (962.9, 719.2, 271.4, 952.5, 952.3, 926.6, 950.0, 948.5),
    "hopper_stand": (965.8, 534.1, 91.4, 400.0, 748.5, 835.8, 891.2, 815.7),
    "hopper_hop": (711.5, 98.4, 9.1, 689.2, 694.4, 610.5, 683.6, 636.2),
    "walker_stand": (993.6, 731.7, 385.9, 989.4, 985.4, 989.4, 986.0, 985.1),
    "walker_walk": (983.2, 719.5, 61.9, 976.5, 981.6, 971.2, 975.2, 977.8),
    "walker_run": (952.1, 108.5, 39.0, 949.5, 947.6, 949.0, 948.5, 942.0),
    "humanoid_stand": (905.9, 780.7, 10.0, 4.9, 856.2, 257.5, 863.5, 704.6),
    "humanoid_walk": (809.5, 293.9, 9.6, 1.2, 798.4, 658.2, 795.5, 783.0),
    "humanoid_run": (736.6, 54.2, 1.0, 0.6, 683.4, 676.6, 691.6, 691.1),
}
_BY_COLUMN = {name: {task: row[i] for task, row in TABLE1.items()}
              for i, name in enumerate(COLUMNS)}
# The MPO experts' returns, and FORM's, by task.
EXPERT, FORM = _BY_COLUMN["expert"], _BY_COLUMN["form"]
# The baselines' returns, by method and task.
BASELINES = {method: _BY_COLUMN[method] for method in COLUMNS[1:-1]}
# Their column names in the paper's Table 1.
BASELINE_NAMES = {"bc": "BC", "bco": "BCO", "gaifo": "GAIfO", "gaifo_gp": "GAIfO+GP",
                  "vaifo": "VAIfO", "vaifo_gp": "VAIfO+GP"}
# The demonstrations per task the paper's imitation methods learn from.
DEMONSTRATIONS = 1000
# The experts issue's bar: an expert reaches this fraction of the paper's expert return.
EXPERT_BAR = 0.95
