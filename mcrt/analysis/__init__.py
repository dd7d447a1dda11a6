"""Analysis layer: error metrics, statistics, pattern analysis, convergence."""
