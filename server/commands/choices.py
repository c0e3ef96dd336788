"""Names the command line offers as choices, without importing what implements them (the
filters and the simulator pull in numpy, scipy and numba). tests/test_cli_startup.py checks
they match ``estimator.orientation.FILTERS`` and ``estimator.simulation.EXERCISES``."""

#: Orientation filters (``estimator.orientation.FILTERS``) and the default one.
FILTER_NAMES = ("ekf", "euler-cf", "qcf")
DEFAULT_FILTER = "qcf"

#: Simulated exercises (``estimator.simulation.EXERCISES``).
EXERCISE_NAMES = ("elbow_flexion", "shoulder_abduction", "shoulder_flexion", "abduction_120",
                  "shoulder_rotation", "wrist_flexion", "pronation", "wrist_deviation", "reach",
                  "trunk_reach", "elbow_wrist", "drinking", "shrug", "long_session",
                  "long_concurrent", "shoulder_sets", "shoulder_sets_no_rest",
                  "shoulder_sets_nonstop", "still")
